"""Algebraic loops (issue 18, item 2): direct-feedthrough sub-models whose outputs depend on
each other at the same instant are solved together at every communication point."""

from __future__ import annotations

import numpy as np
import pytest

import cosimstep
from cosimstep.submodel import Capabilities, Port, SubModel


class Affine(SubModel):
    """y = gain * u + bias + x, with a state x' = rate (so that time matters): direct
    feedthrough from u to y."""

    def __init__(self, gain: float, bias: float, rate: float = 0.0) -> None:
        self.gain, self.bias, self.rate = gain, bias, rate
        self.inputs = (Port("u", "1", 0.0),)
        self.outputs = (Port("y", "1", 0.0),)
        self.capabilities = Capabilities(can_save_state=True, feedthrough={"y": ("u",)})
        self.x, self.u = 0.0, 0.0

    def initialize(self, t0: float) -> None:
        self.x = 0.0

    def set_inputs(self, values: np.ndarray) -> None:
        self.u = float(values[0])

    def do_step(self, t: float, h: float) -> None:
        self.x += self.rate * h

    def get_outputs(self) -> np.ndarray:
        return np.array([self.gain * self.u + self.bias + self.x])

    def save_state(self) -> object:
        return self.x

    def restore_state(self, token: object) -> None:
        self.x = float(token)


def loop(gain_a: float = 2.0, gain_b: float = -1.5) -> cosimstep.System:
    system = cosimstep.System().add("a", Affine(gain_a, 1.0, rate=1.0))
    system.add("b", Affine(gain_b, 0.0))
    return system.connect("a.y", "b.u").connect("b.y", "a.u")


def test_a_loop_is_listed_not_refused() -> None:
    system = loop()
    assert system.problems() == []
    assert system.loops() == [["a.u", "a.y", "b.u", "b.y"]]
    assert system.compile().loops == [(0, 1)]


def test_a_loop_with_gain_three_is_solved_at_every_point() -> None:
    """a.y = 2 b.y + 1 + t and b.y = -1.5 a.y: a.y = (1 + t) / 4 exactly; substituting round
    the loop multiplies an error by -3 each time, so one pass (or a fixed-point iteration)
    diverges."""
    result = cosimstep.simulate(loop(), 1.0, cosimstep.Fixed(0.1))
    assert result.success, result.message
    assert np.max(np.abs(result["a.y"] - (1 + result.times) / 4)) < 1e-12
    assert np.max(np.abs(result["b.y"] + 1.5 * result["a.y"])) < 1e-12
    assert result.loops["solves"] == 11 and result.loops["residual_max"] <= 1e-8
    assert result.calls_total == 20  # solving calls no step


def test_a_loop_without_a_solution_ends_the_run_with_the_residual() -> None:
    """a.y = b.y + 1 and b.y = a.y: no solution; the run fails at t = 0 saying so."""
    result = cosimstep.simulate(loop(1.0, 1.0), 1.0, cosimstep.Fixed(0.1))
    assert result.status == "failed"
    assert "the algebraic loop through a.y, b.y was not solved: residual" in result.message


@pytest.mark.parametrize("coupling", ["explicit", "iqn-ils"])
def test_a_loop_under_each_coupling(coupling: str) -> None:
    result = cosimstep.simulate(loop(), 1.0, cosimstep.Fixed(0.25),
                                cosimstep.MasterOptions(coupling=coupling))
    assert result.success, result.message
    assert np.max(np.abs(result["a.y"] - (1 + result.times) / 4)) < 1e-9

"""A connection between two arrays (issue 20, item 2): ``a.y -> b.u`` stands for one
connection per element pair when both are arrays of equal size (ports ``y[1]`` …, as FMI 3.0
array variables become); unequal sizes are one configuration problem."""

from __future__ import annotations

from typing import Any

import numpy as np

import cosimstep
from cosimstep.submodel import Capabilities, Port, SubModel


class Decay(SubModel):
    """``y_i' = -k y_i + u_i`` per element (explicit Euler, inputs held), ``y_i(0) = i``."""

    def __init__(self, n: int = 3, k: float = 1.0) -> None:
        self.n, self.k = n, k
        self.inputs = tuple(Port(f"u[{i + 1}]", "1", 0.0) for i in range(n))
        self.outputs = tuple(Port(f"y[{i + 1}]", "1", float(i + 1)) for i in range(n))
        self.capabilities = Capabilities(can_save_state=True)

    def initialize(self, t0: float) -> None:
        self.y, self.u = np.arange(1.0, self.n + 1), np.zeros(self.n)

    def set_inputs(self, values: np.ndarray) -> None:
        self.u = np.array(values, dtype=float)

    def do_step(self, t: float, h: float) -> None:
        self.y = self.y + h * (-self.k * self.y + self.u)

    def get_outputs(self) -> np.ndarray:
        return self.y.copy()

    def save_state(self) -> Any:
        return self.y.copy(), self.u.copy()

    def restore_state(self, token: Any) -> None:
        self.y, self.u = token[0].copy(), token[1].copy()


def test_a_whole_array_connection_equals_its_elements() -> None:
    whole = cosimstep.System().add("a", Decay()).add("b", Decay(k=2.0))
    whole.connect("a.y", "b.u", gain=0.5)
    elements = cosimstep.System().add("a", Decay()).add("b", Decay(k=2.0))
    for i in (1, 2, 3):
        elements.connect(f"a.y[{i}]", f"b.u[{i}]", gain=0.5)
    assert whole.problems() == []
    r1 = cosimstep.simulate(whole, 1.0, cosimstep.Fixed(0.1))
    r2 = cosimstep.simulate(elements, 1.0, cosimstep.Fixed(0.1))
    assert r1.success and np.array_equal(r1.values, r2.values)
    alone = cosimstep.simulate(cosimstep.System().add("b", Decay(k=2.0)), 1.0,
                               cosimstep.Fixed(0.1))
    assert r1["b.y[3]"][-1] > alone["b.y[3]"][-1] + 0.1  # the inputs did arrive


def test_arrays_of_different_sizes_are_one_problem() -> None:
    system = cosimstep.System().add("a", Decay(n=2)).add("b", Decay())
    system.connect("a.y", "b.u")
    problems = [str(p) for p in system.problems()]
    assert problems == ["connection a.y -> b.u: arrays of different sizes: 2 outputs, 3 inputs "
                        "(fix: connect arrays of equal size, or single elements (model.y[2]))"]

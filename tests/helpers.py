"""Small Python sub-models used by several tests."""

from __future__ import annotations

import sys
import time
from typing import Any

import numpy as np

from cosimstep import Capabilities, Port, SubModel


class Integrator(SubModel):
    """x' = u (exact for a polynomial input of degree <= 2 it is told about); output x."""

    def __init__(self, unit: str = "1", x0: float = 0.0, feedthrough: bool = False) -> None:
        self.inputs = (Port("u", unit, 0.0),)
        self.outputs = (Port("x", unit, x0),)
        self.capabilities = Capabilities(can_save_state=True, max_input_derivative_order=2)
        self.x0 = x0
        self.x = x0
        self.u = np.zeros(1)
        self.du = np.zeros((2, 1))
        self.seen: list[float] = []

    def initialize(self, t0: float) -> None:
        self.x = self.x0

    def set_inputs(self, values: np.ndarray) -> None:
        self.u = np.array(values, float)
        self.du[:] = 0.0
        self.seen.append(float(values[0]))

    def set_input_derivatives(self, derivatives: np.ndarray) -> None:
        self.du[: derivatives.shape[0]] = derivatives

    def do_step(self, t: float, h: float) -> None:
        self.x += h * self.u[0] + h * h / 2 * self.du[0, 0] + h**3 / 6 * self.du[1, 0]

    def get_outputs(self) -> np.ndarray:
        return np.array([self.x])

    def save_state(self) -> Any:
        return self.x

    def restore_state(self, token: Any) -> None:
        self.x = token


class Gain(SubModel):
    """y = k u with direct feedthrough (no state)."""

    def __init__(self, k: float = 1.0) -> None:
        self.k = k
        self.inputs = (Port("u", "1", 0.0),)
        self.outputs = (Port("y", "1", 0.0),)
        self.capabilities = Capabilities(can_save_state=True, feedthrough={"y": ("u",)})
        self.u = 0.0

    def set_inputs(self, values: np.ndarray) -> None:
        self.u = float(values[0])

    def do_step(self, t: float, h: float) -> None:
        pass

    def get_outputs(self) -> np.ndarray:
        return np.array([self.k * self.u])

    def save_state(self) -> Any:
        return self.u

    def restore_state(self, token: Any) -> None:
        self.u = token


class Clock(SubModel):
    """Outputs its own time; misbehaves from ``fail_at`` on in the way ``mode`` says."""

    def __init__(self, fail_at: float = float("inf"), mode: str = "raise") -> None:
        self.inputs = ()
        self.outputs = (Port("time", "s", 0.0),)
        self.fail_at, self.mode = fail_at, mode
        self.t = 0.0

    def set_inputs(self, values: np.ndarray) -> None:
        pass

    def do_step(self, t: float, h: float) -> None:
        if t + h > self.fail_at + 1e-12:
            if self.mode == "raise":
                raise RuntimeError("solver diverged")
            if self.mode == "hang":
                time.sleep(30)
            if self.mode == "exit":
                sys.exit(3)
        self.t = t + h

    def get_outputs(self) -> np.ndarray:
        if self.mode == "nan" and self.t > self.fail_at + 1e-12:
            return np.array([np.nan])
        return np.array([self.t])


class Jump(SubModel):
    """Outputs 0 before ``at`` and 1 from then on, *without* declaring a time event."""

    def __init__(self, at: float = 1.0) -> None:
        self.inputs = ()
        self.outputs = (Port("y", "1", 0.0),)
        self.capabilities = Capabilities(can_save_state=True)
        self.at, self.t = at, 0.0

    def initialize(self, t0: float) -> None:
        self.t = t0

    def set_inputs(self, values: np.ndarray) -> None:
        pass

    def do_step(self, t: float, h: float) -> None:
        self.t = t + h

    def get_outputs(self) -> np.ndarray:
        return np.array([1.0 if self.t >= self.at else 0.0])

    def save_state(self) -> Any:
        return self.t

    def restore_state(self, token: Any) -> None:
        self.t = token


class Follower(SubModel):
    """A very fast first-order lag (τ → 0): its state is its input at the end of each step.

    Unlike a feedthrough gain its output is a *state*, so a wrong input trajectory over a step
    shows in the output by its full size however short the step — the case no step size cures.
    """

    def __init__(self) -> None:
        self.inputs = (Port("u", "1", 0.0),)
        self.outputs = (Port("x", "1", 0.0),)
        self.capabilities = Capabilities(can_save_state=True, max_input_derivative_order=3)
        self.x = 0.0
        self.u = np.zeros(1)
        self.du = np.zeros((3, 1))

    def initialize(self, t0: float) -> None:
        self.x = 0.0

    def set_inputs(self, values: np.ndarray) -> None:
        self.u = np.array(values, float)
        self.du[:] = 0.0

    def set_input_derivatives(self, derivatives: np.ndarray) -> None:
        self.du[: derivatives.shape[0]] = derivatives

    def do_step(self, t: float, h: float) -> None:
        self.x = float(self.u[0] + h * self.du[0, 0] + h**2 / 2 * self.du[1, 0]
                       + h**3 / 6 * self.du[2, 0])

    def get_outputs(self) -> np.ndarray:
        return np.array([self.x])

    def save_state(self) -> Any:
        return self.x

    def restore_state(self, token: Any) -> None:
        self.x = token


def fmu_pendulum(bar_fmus: dict, model_class: Any = None) -> Any:
    """The slow split double pendulum made of the two C bar FMUs (theta1 = 0.4, theta2 = -0.3)."""
    import cosimstep
    from cosimstep.adapters.fmu import FmuSubModel

    cls = model_class or FmuSubModel
    system = cosimstep.System()
    system.add("bar1", cls(bar_fmus[1], {"theta": 0.4, "omega": 0.0,
                                         "theta2": -0.3, "omega2": 0.0}))
    system.add("bar2", cls(bar_fmus[2], {"theta": -0.3, "omega": 0.0,
                                         "theta1": 0.4, "omega1": 0.0}))
    system.connect("bar1.theta", "bar2.theta1").connect("bar1.omega", "bar2.omega1")
    system.connect("bar2.theta", "bar1.theta2").connect("bar2.omega", "bar1.omega2")
    return system

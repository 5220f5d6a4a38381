"""Two oscillators joined by a spring–damper that is a sub-model of its own (benchmark problem 7).

    m1 x1'' = −k1 x1 − c1 x1' − F          (sub-model ``mass1``: input F, outputs x1, v1)
    m2 x2'' = −k2 x2 − c2 x2' + F          (sub-model ``mass2``: input F, outputs x2, v2)
    F = k (x1 − x2) + c (v1 − v2)          (sub-model ``spring``: direct feedthrough)

The spring computes the force from both masses' positions and velocities at the same instant and
hands it on at once: its output depends on its inputs directly, so the master settles it at
every communication point, and under Gauss–Seidel its place in the order matters. With ``k`` far
above ``k1`` and ``k2`` the coupling is stiff (issue 18's stiff two-mass example).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from cosimstep.adapters.ode import InternalSolver, OdeSubModel, ParameterSchedule
from cosimstep.submodel import Capabilities, Port, SubModel

START = ("x1", "v1", "x2", "v2")


def default_parameters() -> dict[str, float]:
    """Problem 7: k1 = 10, c1 = 0.2, k2 = 20, c2 = 0.3, k = 10, c = 0.5, unit masses."""
    return {"m1": 1.0, "k1": 10.0, "c1": 0.2, "m2": 1.0, "k2": 20.0, "c2": 0.3, "k": 10.0,
            "c": 0.5}


def force(x: np.ndarray, p: Mapping[str, float]) -> np.ndarray:
    """The spring-damper's force from the states ``x1, v1, x2, v2`` (rows; any columns)."""
    return p["k"] * (x[0] - x[2]) + p["c"] * (x[1] - x[3])


def monolithic(parameters: ParameterSchedule, start: Mapping[str, float],
               solver: InternalSolver | None = None) -> OdeSubModel:
    def rhs(t: float, x: np.ndarray, u: np.ndarray, p: Mapping[str, float]) -> np.ndarray:
        f = force(x, p)
        return np.array([x[1], (-p["k1"] * x[0] - p["c1"] * x[1] - f) / p["m1"],
                         x[3], (-p["k2"] * x[2] - p["c2"] * x[3] + f) / p["m2"]])

    states = [Port(n, "m" if n[0] == "x" else "m/s", float(start.get(n, 0.0))) for n in START]
    return OdeSubModel(rhs, states, parameters=parameters, solver=solver)


def _mass(i: int) -> Any:
    sign = -1.0 if i == 1 else 1.0

    def build(parameters: ParameterSchedule, start: Mapping[str, float],
              solver: InternalSolver | None = None) -> OdeSubModel:
        def rhs(t: float, x: np.ndarray, u: np.ndarray, p: Mapping[str, float]) -> np.ndarray:
            return np.array([x[1], (-p[f"k{i}"] * x[0] - p[f"c{i}"] * x[1] + sign * u[0])
                             / p[f"m{i}"]])

        states = [Port(f"x{i}", "m", float(start.get(f"x{i}", 0.0))),
                  Port(f"v{i}", "m/s", float(start.get(f"v{i}", 0.0)))]
        x = np.array([float(start.get(n, 0.0)) for n in START])
        pull = Port("F", "N", force(x, parameters.at(0.0)))  # until the spring is read
        return OdeSubModel(rhs, states, inputs=[pull], parameters=parameters, solver=solver)

    build.__doc__ = f"Mass {i}: states x{i}, v{i}; input F (the spring's force)."
    return build


mass1, mass2 = _mass(1), _mass(2)


class Spring(SubModel):
    """F = k (x1 − x2) + c (v1 − v2) from its inputs at the same instant: no state, direct
    feedthrough from every input."""

    def __init__(self, parameters: ParameterSchedule, start: Mapping[str, float]) -> None:
        self.parameters = parameters
        self.inputs = tuple(Port(n, "m" if n[0] == "x" else "m/s", float(start.get(n, 0.0)))
                            for n in START)
        self.outputs = (Port("F", "N"),)
        self.capabilities = Capabilities(can_save_state=True, feedthrough={"F": START})
        self._u = np.array([p.start for p in self.inputs], dtype=float)
        self._t = 0.0

    def initialize(self, t0: float) -> None:
        self._t = t0

    def set_inputs(self, values: np.ndarray) -> None:
        self._u = np.array(values, dtype=float)

    def do_step(self, t: float, h: float) -> None:
        self._t = t + h

    def get_outputs(self) -> np.ndarray:
        return np.array([force(self._u, self.parameters.at(self._t))])

    def save_state(self) -> Any:
        return self._t, self._u.copy()

    def restore_state(self, token: Any) -> None:
        self._t, self._u = token[0], token[1].copy()

    def time_events(self) -> tuple[float, ...]:
        return tuple(self.parameters.times)


def spring(parameters: ParameterSchedule, start: Mapping[str, float],
           solver: InternalSolver | None = None) -> Spring:
    return Spring(parameters, start)

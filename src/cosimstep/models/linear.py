"""Two-way coupled linear system (benchmark problems 6 and 9): a fast oscillator and a slow lag.

    u' = λ v + w,   v' = −λ u      (sub-model ``a``: the fast part, frequency λ rad/s)
    w' = −w + u                    (sub-model ``b``: the slow part, time constant 1 s)

``λ`` is the time-scale ratio. Sub-model ``a`` receives ``w`` and outputs ``u`` and ``v``;
sub-model ``b`` receives ``u`` and outputs ``w``. The start values of problem 6
(``u0 = 1 − w0/(λ² + 1)``, ``v0 = −w0 λ/(λ² + 1)``, ``w0 = 1000``) put ``u'`` near zero, so the
fast oscillation is small against the slow decay of ``w`` — the situation multi-rate is for.
Being linear, the monolithic model has the exact solution ``x(t) = expm(A t) x0``
(:func:`exact`), which the tests compare with the DOP853 reference.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from cosimstep.adapters.ode import InternalSolver, OdeSubModel, ParameterSchedule
from cosimstep.submodel import Port


def default_parameters() -> dict[str, float]:
    return {"lam": 100.0}


def start_values(lam: float, w0: float = 1000.0) -> dict[str, float]:
    """Problem 6's start values for a given ``λ``."""
    return {"u": 1.0 - w0 / (lam**2 + 1.0), "v": -w0 * lam / (lam**2 + 1.0), "w": w0}


def matrix(lam: float) -> np.ndarray:
    return np.array([[0.0, lam, 1.0], [-lam, 0.0, 0.0], [1.0, 0.0, -1.0]])


def exact(lam: float, x0: np.ndarray, times: np.ndarray) -> np.ndarray:
    """``expm(A t) x0`` at every time, rows (u, v, w)."""
    from scipy.linalg import expm

    a = matrix(lam)
    return np.array([expm(a * t) @ x0 for t in times])


def _ports(start: Mapping[str, float], names: tuple[str, ...]) -> list[Port]:
    return [Port(n, "1", float(start.get(n, 0.0))) for n in names]


def monolithic(parameters: ParameterSchedule, start: Mapping[str, float],
               solver: InternalSolver | None = None) -> OdeSubModel:
    def rhs(t: float, x: np.ndarray, u: np.ndarray, p: Mapping[str, float]) -> np.ndarray:
        lam = p["lam"]
        return np.array([lam * x[1] + x[2], -lam * x[0], -x[2] + x[0]])

    return OdeSubModel(rhs, _ports(start, ("u", "v", "w")), parameters=parameters, solver=solver)


def fast(parameters: ParameterSchedule, start: Mapping[str, float],
         solver: InternalSolver | None = None) -> OdeSubModel:
    """Sub-model ``a``: states ``u``, ``v``; input ``w``."""

    def rhs(t: float, x: np.ndarray, u: np.ndarray, p: Mapping[str, float]) -> np.ndarray:
        lam = p["lam"]
        return np.array([lam * x[1] + u[0], -lam * x[0]])

    return OdeSubModel(rhs, _ports(start, ("u", "v")), inputs=_ports(start, ("w",)),
                       parameters=parameters, solver=solver)


def slow(parameters: ParameterSchedule, start: Mapping[str, float],
         solver: InternalSolver | None = None) -> OdeSubModel:
    """Sub-model ``b``: state ``w``; input ``u``."""

    def rhs(t: float, x: np.ndarray, u: np.ndarray, p: Mapping[str, float]) -> np.ndarray:
        return np.array([-x[0] + u[0]])

    return OdeSubModel(rhs, _ports(start, ("w",)), inputs=_ports(start, ("u",)),
                       parameters=parameters, solver=solver)

"""Chain pendulums: the thesis's double (4.2.1) and triple (4.2.7, appendix D) pendulum.

Point masses ``m_i`` on massless bars ``l_i``, angles from the vertical. For a chain of ``N`` bars
the Lagrange equations are ``M(θ) θ'' = f(θ, θ')`` with

    M_ij = μ_max(i,j) l_i l_j cos(θ_i − θ_j)
    f_i  = −Σ_j μ_max(i,j) l_i l_j sin(θ_i − θ_j) θ_j'² − μ_i g l_i sin θ_i,   μ_k = Σ_{k'≥k} m_k'

For N = 3 this is the system whose solved form the thesis prints in appendix D (the tests check
the two agree). The small-angle form the thesis used for the double pendulum replaces cos by 1,
sin x by x and drops the velocity terms, which makes it linear.

A *split* model has one sub-model per bar (thesis fig. 38–40): bar ``i`` integrates its own angle
and angular velocity and receives the other bars' angles and angular velocities as inputs.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from cosimstep.adapters.ode import InternalSolver, OdeSubModel, ParameterSchedule
from cosimstep.submodel import Port

G = 9.81


def default_parameters(n: int) -> dict[str, float]:
    """Unit masses and lengths, g = 9.81, nonlinear equations."""
    params: dict[str, float] = {"g": G, "linear": 0.0}
    for i in range(1, n + 1):
        params[f"m{i}"] = 1.0
        params[f"l{i}"] = 1.0
    return params


def chain_accelerations(theta: np.ndarray, omega: np.ndarray, p: Mapping[str, float],
                        n: int) -> np.ndarray:
    """Angular accelerations of an ``n``-bar chain pendulum."""
    m = [p[f"m{i}"] for i in range(1, n + 1)]
    ell = [p[f"l{i}"] for i in range(1, n + 1)]
    g = p["g"]
    mu = [sum(m[k:]) for k in range(n)]
    linear = bool(p.get("linear", 0.0))
    if n == 2:  # explicit 2x2 solve: this runs inside every internal solver stage
        return _double_accelerations(theta, omega, mu, ell, g, linear)
    mass = np.empty((n, n))
    force = np.empty(n)
    for i in range(n):
        force[i] = -mu[i] * g * ell[i] * (theta[i] if linear else math.sin(theta[i]))
        for j in range(n):
            coupling = mu[max(i, j)] * ell[i] * ell[j]
            if linear:
                mass[i, j] = coupling
            else:
                d = theta[i] - theta[j]
                mass[i, j] = coupling * math.cos(d)
                force[i] -= coupling * math.sin(d) * omega[j] ** 2
    return np.linalg.solve(mass, force)


def _double_accelerations(theta: np.ndarray, omega: np.ndarray, mu: list[float],
                          ell: list[float], g: float, linear: bool) -> np.ndarray:
    t1, t2 = float(theta[0]), float(theta[1])
    w1, w2 = float(omega[0]), float(omega[1])
    l1, l2 = ell
    if linear:
        c, s, s1, s2 = 1.0, 0.0, t1, t2
    else:
        c, s, s1, s2 = math.cos(t1 - t2), math.sin(t1 - t2), math.sin(t1), math.sin(t2)
    a11, a12 = mu[0] * l1 * l1, mu[1] * l1 * l2 * c
    a22 = mu[1] * l2 * l2
    f1 = -mu[1] * l1 * l2 * s * w2 * w2 - mu[0] * g * l1 * s1
    f2 = mu[1] * l1 * l2 * s * w1 * w1 - mu[1] * g * l2 * s2
    det = a11 * a22 - a12 * a12
    return np.array([(f1 * a22 - a12 * f2) / det, (a11 * f2 - a12 * f1) / det])


def monolithic(n: int, parameters: ParameterSchedule, start: Mapping[str, float],
               solver: InternalSolver | None = None) -> OdeSubModel:
    """The whole chain as one sub-model: states ``theta1..n`` then ``omega1..n``."""

    def rhs(t: float, x: np.ndarray, u: np.ndarray, p: Mapping[str, float]) -> np.ndarray:
        return np.concatenate([x[n:], chain_accelerations(x[:n], x[n:], p, n)])

    states = [Port(f"theta{i}", "rad", float(start.get(f"theta{i}", 0.0)))
              for i in range(1, n + 1)]
    states += [Port(f"omega{i}", "rad/s", float(start.get(f"omega{i}", 0.0)))
               for i in range(1, n + 1)]
    return OdeSubModel(rhs, states, parameters=parameters, solver=solver)


def bar(n: int, i: int, parameters: ParameterSchedule, start: Mapping[str, float],
        solver: InternalSolver | None = None) -> OdeSubModel:
    """Bar ``i`` (1-based) of an ``n``-bar chain as a black-box sub-model.

    States/outputs ``theta`` and ``omega``; inputs ``theta<j>`` and ``omega<j>`` for every other
    bar ``j`` (their start values are the chain's initial condition).
    """
    others = [j for j in range(1, n + 1) if j != i]
    k = i - 1

    def rhs(t: float, x: np.ndarray, u: np.ndarray, p: Mapping[str, float]) -> np.ndarray:
        theta = np.empty(n)
        omega = np.empty(n)
        theta[k], omega[k] = x[0], x[1]
        for slot, j in enumerate(others):
            theta[j - 1] = u[2 * slot]
            omega[j - 1] = u[2 * slot + 1]
        return np.array([x[1], chain_accelerations(theta, omega, p, n)[k]])

    states = [Port("theta", "rad", float(start.get(f"theta{i}", 0.0)), f"angle of bar {i}"),
              Port("omega", "rad/s", float(start.get(f"omega{i}", 0.0)),
                   f"angular velocity of bar {i}")]
    inputs: list[Port] = []
    for j in others:
        inputs.append(Port(f"theta{j}", "rad", float(start.get(f"theta{j}", 0.0))))
        inputs.append(Port(f"omega{j}", "rad/s", float(start.get(f"omega{j}", 0.0))))
    return OdeSubModel(rhs, states, inputs=inputs, parameters=parameters, solver=solver)

"""Problems built around time-scale separation: a stiff boundary layer and the KPR problems.

The Kværnø–Prothero–Robinson (KPR) problems have a known exact solution (:func:`kpr_exact`),
which the tests compare the monolithic reference with.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping

import numpy as np

from cosimstep.adapters.ode import RK4, OdeSubModel, SolveIvp
from cosimstep.reference import Reference
from cosimstep.suite.base import ports
from cosimstep.system import System

# -- singularly perturbed system with an initial boundary layer ----------------------------
EPS = 1e-4


def boundary_layer() -> tuple[System, Reference]:
    """Singularly perturbed pair: slow y' = −y + (1 − y²/2)·z, fast ε z' = −z + cos 2t − y/2.

    ε = 1e-4 s, y(0) = 0.5, z(0) = −2 (the slow manifold z = cos 2t − y/2 is at 0.75 then);
    2 s. The slow sub-model (RK4) holds y and receives z; the fast one holds z, receives y and
    integrates its stiff equation with Radau (rtol 1e-10, atol 1e-12). Time scales: an initial
    boundary layer of a few ε (z jumps by 2.75 within ~5e-4 s), then z follows the slow
    manifold; y varies on the 1 s scale. What can go wrong: any step across the layer hands
    the slow sub-model an input that is wrong by O(1) (a first step of size h leaves an O(h)
    error in y that decays only like e^−t); extrapolating z from samples around the layer
    overshoots; after the layer z responds to y practically instantly, so the coupling acts as
    an algebraic loop of gain |∂y'/∂z · ∂z/∂y| ≤ 1/2.
    """

    def slow(t: float, x: np.ndarray, u: np.ndarray, _: Mapping) -> np.ndarray:
        y = x[0]
        return np.array([-y + (1.0 - 0.5 * y * y) * u[0]])

    def fast(t: float, x: np.ndarray, u: np.ndarray, _: Mapping) -> np.ndarray:
        return np.array([(-x[0] + math.cos(2.0 * t) - 0.5 * u[0]) / EPS])

    def whole(t: float, x: np.ndarray, u: np.ndarray, _: Mapping) -> np.ndarray:
        y, z = x
        return np.array([-y + (1.0 - 0.5 * y * y) * z, (-z + math.cos(2.0 * t) - 0.5 * y) / EPS])

    y0, z0 = 0.5, -2.0
    system = System()
    system.add("slow", OdeSubModel(slow, ports({"y": ("1", y0)}), inputs=ports({"z": ("1", z0)}),
                                   solver=RK4(max_dt=1e-3)))
    system.add("fast", OdeSubModel(fast, ports({"z": ("1", z0)}), inputs=ports({"y": ("1", y0)}),
                                   solver=SolveIvp("Radau", rtol=1e-10, atol=1e-12)))
    system.connect("slow.y", "fast.y")
    system.connect("fast.z", "slow.z")
    mono = OdeSubModel(whole, ports({"y": ("1", y0), "z": ("1", z0)}))
    return system, Reference(mono, {"slow.y": "y", "fast.z": "z"})


# -- Kværnø–Prothero–Robinson --------------------------------------------------------------
KPR = {"G": -10.0, "e": 0.5, "omega": 100.0}
"""Coupling matrix [[G, e], [e, −1]] acting on the residuals, fast angular frequency ω."""


def _phase_constant(omega: float, until: float) -> tuple[Callable, Callable]:
    return (lambda t: omega * t), (lambda t: omega)


def _phase_chirp(omega: float, until: float) -> tuple[Callable, Callable]:
    """φ(t) = ω (t + t²/(2T)): the instantaneous frequency φ' rises from ω to 2ω at T."""
    return (lambda t: omega * (t + t * t / (2.0 * until))), (lambda t: omega * (1.0 + t / until))


def kpr_exact(times: np.ndarray, chirp: bool = False, until: float = 5.0) -> np.ndarray:
    """Exact KPR solution, rows ``(u, v)``: u = √(3 + cos φ(t)), v = √(2 + cos t)."""
    times = np.asarray(times, dtype=float)
    phase = (_phase_chirp if chirp else _phase_constant)(KPR["omega"], until)[0]
    return np.column_stack([np.sqrt(3.0 + np.cos(phase(times))), np.sqrt(2.0 + np.cos(times))])


def _kpr(chirp: bool, until: float) -> tuple[System, Reference]:
    G, e = KPR["G"], KPR["e"]
    phase, rate = (_phase_chirp if chirp else _phase_constant)(KPR["omega"], until)

    def residual_u(t: float, u: float) -> float:
        return (-3.0 + u * u - math.cos(phase(t))) / (2.0 * u)

    def residual_v(t: float, v: float) -> float:
        return (-2.0 + v * v - math.cos(t)) / (2.0 * v)

    def du(t: float, u: float, v: float) -> float:
        return G * residual_u(t, u) + e * residual_v(t, v) - rate(t) * math.sin(phase(t)) / (2 * u)

    def dv(t: float, u: float, v: float) -> float:
        return e * residual_u(t, u) - residual_v(t, v) - math.sin(t) / (2.0 * v)

    def fast(t: float, x: np.ndarray, u: np.ndarray, _: Mapping) -> np.ndarray:
        return np.array([du(t, x[0], u[0])])

    def slow(t: float, x: np.ndarray, u: np.ndarray, _: Mapping) -> np.ndarray:
        return np.array([dv(t, u[0], x[0])])

    def whole(t: float, x: np.ndarray, u: np.ndarray, _: Mapping) -> np.ndarray:
        return np.array([du(t, x[0], x[1]), dv(t, x[0], x[1])])

    u0, v0 = kpr_exact(np.array([0.0]), chirp, until)[0]
    # The slow rhs contains cos φ(t) too (inside the u residual), so both solvers resolve φ.
    dt = 1e-4 if not chirp else 5e-5
    system = System()
    system.add("fast", OdeSubModel(fast, ports({"u": ("1", u0)}), inputs=ports({"v": ("1", v0)}),
                                   solver=RK4(max_dt=dt)))
    system.add("slow", OdeSubModel(slow, ports({"v": ("1", v0)}), inputs=ports({"u": ("1", u0)}),
                                   solver=RK4(max_dt=dt)))
    system.connect("fast.u", "slow.u")
    system.connect("slow.v", "fast.v")
    mono = OdeSubModel(whole, ports({"u": ("1", u0), "v": ("1", v0)}))
    return system, Reference(mono, {"fast.u": "u", "slow.v": "v"})


KPR_SOURCE = ("adapted from the Kværnø–Prothero–Robinson multirate test problem of A. Sandu "
              "(2019), 'A class of multirate infinitesimal GARK methods', SIAM J. Numer. Anal. "
              "57(5):2300–2327 (fast component √(3 + cos ωt), slow √(2 + cos t)), as in SUNDIALS' "
              "ark_kpr_mri example and R. Chinomona, D. R. Reynolds (2021), 'Implicit-explicit "
              "multirate infinitesimal GARK methods', SIAM J. Sci. Comput. 43(5); coupling "
              "matrix [[G, e], [e, −1]] with G = −10 (Sandu's fast rate λf; SUNDIALS' default G = "
              "−100 sits on its slow component), e = 0.5 and ω = 100 (SUNDIALS' defaults)")


def kpr_separated() -> tuple[System, Reference]:
    """KPR problem: fast u = √(3 + cos ωt), slow v = √(2 + cos t), ω = 100 rad/s, 5 s.

    u' = G a(t,u) + e b(t,v) − ω sin ωt / (2u),  v' = e a(t,u) − b(t,v) − sin t / (2v),
    a = (−3 + u² − cos ωt)/(2u), b = (−2 + v² − cos t)/(2v); G = −10, e = 0.5. The fast
    sub-model holds u and receives v, the slow one holds v and receives u. Time scales: the
    forcing period 2π/ω ≈ 0.063 s against 2π s; the residuals relax at rates 10 and 1 s⁻¹.
    What can go wrong: a step longer than the fast period makes the polynomial extrapolation of
    u meaningless, and the right-hand sides divide by u and v — an extrapolated u or v near 0
    (reachable by a wild quadratic) blows the sub-models up: the "singularity" class.
    """
    return _kpr(chirp=False, until=5.0)


def kpr_chirp() -> tuple[System, Reference]:
    """KPR with a chirped fast forcing: φ(t) = ω (t + t²/(2T)), T = 5 s, so the fast frequency
    rises from ω = 100 to 200 rad/s over the run; u = √(3 + cos φ(t)) (the forcing term uses
    φ'(t)), v as in :func:`kpr_separated`. What can go wrong: the step that resolved the fast
    part at the start is twice too long at the end; a controller must keep shrinking it.
    """
    return _kpr(chirp=True, until=5.0)

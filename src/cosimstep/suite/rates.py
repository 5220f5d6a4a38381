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


def kpr_forced() -> tuple[System, Reference]:
    """KPR with separated scales: the forcing comes from a sub-model of its own, and the slow
    part reads the fast part's residual instead of its state; ω = 100 rad/s, 5 s.

    Sub-models: ``source`` integrates the forcing p = cos ωt, q = sin ωt (p' = −ωq, q' = ωp);
    ``fast`` holds u and the residual w and receives p, q and v,
    u' = G a + e b(t,v) − ω q/(2u) with a = (u² − 3 − p)/(2u), and w' = da/dt along the
    solution (∂a/∂u·u' + ∂a/∂p·p'), so w = a; ``slow`` holds v and receives w,
    v' = e w − b(t,v) − sin t/(2v). G, e, b as in :func:`kpr_separated`. The exact solution is
    that of the KPR problem: u = √(3 + cos ωt), v = √(2 + cos t), and w = 0.

    Why this split: in :func:`kpr_separated` the slow sub-model evaluates the fast residual
    itself and so reads u at the fast frequency. Here nothing the slow one exchanges is fast,
    while the fast one receives its forcing through the coupling (a signal source, a wave load)
    and must take communication steps that resolve it: the situation in which a multi-rate
    master should let the slow part take far longer steps (the scale ratio, ω over the slow
    rate of 1 s⁻¹, is 100; issue 13, item 6). What can go wrong: a single-rate master steps
    the slow part at the forcing's rate; and a perturbation of w is never damped (w only
    integrates da/dt, like a position integrating a velocity) and drives v, so an error there
    lasts the whole run, while the larger part of a local error, in u, fades at rate |G|: a
    short look at a perturbation sees it fade.
    """
    G, e, omega = KPR["G"], KPR["e"], KPR["omega"]

    def b(t: float, v: float) -> float:
        return (-2.0 + v * v - math.cos(t)) / (2.0 * v)

    def rates(t: float, u: float, v: float, p: float, q: float) -> tuple[float, float]:
        du = G * (u * u - 3.0 - p) / (2.0 * u) + e * b(t, v) - omega * q / (2.0 * u)
        return du, (0.5 + (3.0 + p) / (2.0 * u * u)) * du + omega * q / (2.0 * u)

    def dv(t: float, v: float, w: float) -> float:
        return e * w - b(t, v) - math.sin(t) / (2.0 * v)

    def source(t: float, x: np.ndarray, u: np.ndarray, _: Mapping) -> np.ndarray:
        return np.array([-omega * x[1], omega * x[0]])

    def fast(t: float, x: np.ndarray, u: np.ndarray, _: Mapping) -> np.ndarray:
        return np.array(rates(t, x[0], u[2], u[0], u[1]))

    def slow(t: float, x: np.ndarray, u: np.ndarray, _: Mapping) -> np.ndarray:
        return np.array([dv(t, x[0], u[0])])

    def whole(t: float, x: np.ndarray, u: np.ndarray, _: Mapping) -> np.ndarray:
        p, q, uu, w, v = x
        return np.array([-omega * q, omega * p, *rates(t, uu, v, p, q), dv(t, v, w)])

    u0, v0 = kpr_exact(np.array([0.0]))[0]
    start = {"p": ("1", 1.0), "q": ("1", 0.0), "u": ("1", u0), "w": ("1", 0.0), "v": ("1", v0)}

    def pick(*names: str) -> dict[str, tuple[str, float]]:
        return {n: start[n] for n in names}

    system = System()
    system.add("source", OdeSubModel(source, ports(pick("p", "q")), solver=RK4(max_dt=1e-4)))
    system.add("fast", OdeSubModel(fast, ports(pick("u", "w")), inputs=ports(pick("p", "q", "v")),
                                   solver=RK4(max_dt=1e-4)))
    # nothing the slow sub-model integrates varies faster than its communication steps
    system.add("slow", OdeSubModel(slow, ports(pick("v")), inputs=ports(pick("w")),
                                   solver=RK4(max_dt=1e-2)))
    for port in ("p", "q"):
        system.connect(f"source.{port}", f"fast.{port}")
    system.connect("slow.v", "fast.v")
    system.connect("fast.w", "slow.w")
    mono = OdeSubModel(whole, ports(start))
    names = {"source": ("p", "q"), "fast": ("u", "w"), "slow": ("v",)}
    return system, Reference(mono, {f"{m}.{n}": n for m, ns in names.items() for n in ns})

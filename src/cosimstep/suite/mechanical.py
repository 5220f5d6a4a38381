"""Linear mechanical problems: two-mass oscillators, a quarter car, a duplicated state.

Every component is one sub-model whose states are its outputs; no sub-model has direct
feedthrough. Forces that depend on two components (a coupling spring, a suspension) are computed
by each side from the partner's position and velocity ("displacement–displacement coupling").
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from cosimstep.adapters.ode import RK4, OdeSubModel, ParameterSchedule
from cosimstep.reference import Reference
from cosimstep.suite.base import UnannouncedEvents, connect_both_ways, ports
from cosimstep.system import System

SCHWEIZER = ("adapted from B. Schweizer, P. Li, D. Lu (2015), 'Explicit and implicit "
             "cosimulation methods: stability and convergence analysis for different solver "
             "coupling approaches', J. Comput. Nonlinear Dynam. 10(5), 051007 (two-mass "
             "oscillator, displacement/displacement coupling; our parameters)")


# -- two-mass oscillator -------------------------------------------------------------------
def two_mass(p: Mapping[str, float], x1: float = 1.0,
             max_dt: float = 1e-3) -> tuple[System, Reference]:
    """Masses ``m1``, ``m2`` on springs/dampers ``k1, c1`` and ``k2, c2`` to the ground, joined by
    a coupling spring–damper ``kc, dc``. Each mass sub-model receives the other's position and
    velocity and computes the coupling force itself."""

    def mass(i: int, j: int) -> OdeSubModel:
        m, k, c, kc, dc = p[f"m{i}"], p[f"k{i}"], p[f"c{i}"], p["kc"], p["dc"]

        def rhs(t: float, x: np.ndarray, u: np.ndarray, _: Mapping) -> np.ndarray:
            coupling = kc * (u[0] - x[0]) + dc * (u[1] - x[1])
            return np.array([x[1], (-k * x[0] - c * x[1] + coupling) / m])

        start = {1: x1, 2: 0.0}
        return OdeSubModel(rhs, ports({"x": ("m", start[i]), "v": ("m/s", 0.0)}),
                           inputs=ports({f"x{j}": ("m", start[j]), f"v{j}": ("m/s", 0.0)}),
                           solver=RK4(max_dt=max_dt))

    def whole(t: float, x: np.ndarray, u: np.ndarray, _: Mapping) -> np.ndarray:
        f = p["kc"] * (x[2] - x[0]) + p["dc"] * (x[3] - x[1])
        return np.array([x[1], (-p["k1"] * x[0] - p["c1"] * x[1] + f) / p["m1"],
                         x[3], (-p["k2"] * x[2] - p["c2"] * x[3] - f) / p["m2"]])

    system = System().add("mass1", mass(1, 2)).add("mass2", mass(2, 1))
    connect_both_ways(system, "mass1", "mass2", {"x": "x1", "v": "v1"}, {"x": "x2", "v": "v2"})
    mono = OdeSubModel(whole, ports({"x1": ("m", x1), "v1": ("m/s", 0.0), "x2": ("m", 0.0),
                                     "v2": ("m/s", 0.0)}))
    mapping = {"mass1.x": "x1", "mass1.v": "v1", "mass2.x": "x2", "mass2.v": "v2"}
    return system, Reference(mono, mapping)


def two_mass_stiff() -> tuple[System, Reference]:
    """Two-mass oscillator whose coupling spring is 10× stiffer than the masses' own springs.

    m1 = m2 = 1 kg, k1 = k2 = 10 N/m, c1 = c2 = 0.1 Ns/m, kc = 100 N/m, dc = 0.5 Ns/m;
    x1(0) = 1 m, everything else 0; 10 s. Time scales: in-phase mode √10 ≈ 3.2 rad/s (period
    2 s), anti-phase mode √210 ≈ 14.5 rad/s (period 0.43 s), both lightly damped. What can go
    wrong: the stiff coupling makes explicit co-simulation unstable at steps that would resolve
    the motion comfortably (the coupling force changes by kc·Δx over a step the partner does
    not see); errors hardly decay, so they accumulate over the run.
    """
    return two_mass({"m1": 1.0, "m2": 1.0, "k1": 10.0, "k2": 10.0, "c1": 0.1, "c2": 0.1,
                     "kc": 100.0, "dc": 0.5})


def two_mass_damped() -> tuple[System, Reference]:
    """The two-mass oscillator with heavy damping everywhere, so that errors decay.

    m1 = m2 = 1 kg, k1 = 10, k2 = 40, kc = 10 N/m, c1 = c2 = 2, dc = 5 Ns/m; x1(0) = 1 m,
    10 s. Time scales: two modes of 5.1 and 5.9 rad/s with damping ratios 0.30 and 0.93;
    after ~3 s the motion has decayed by two orders. What can go wrong: little — the
    easy case. A controller should reach its tolerance with few steps and grow them as the
    motion dies out; the damper terms make the exchanged velocities matter as much as the
    positions.
    """
    return two_mass({"m1": 1.0, "m2": 1.0, "k1": 10.0, "k2": 40.0, "c1": 2.0, "c2": 2.0,
                     "kc": 10.0, "dc": 5.0})


# -- quarter car ---------------------------------------------------------------------------
QUARTER_CAR = {"ms": 250.0, "mu": 35.0, "ks": 16000.0, "cs": 1000.0, "kt": 150000.0}
ROAD_STEP_TIME = 1.0
ROAD_STEP = 0.05


def quarter_car(announced: bool) -> tuple[System, Reference]:
    """Chassis | wheel split of a quarter car; the road under the tyre steps up at t = 1 s.

    The road height is a parameter of the wheel's right-hand side that changes at 1 s (a
    :class:`ParameterSchedule`), i.e. a function of t that every piece of a piecewise-integrated
    step sees on its own side of the jump. (A plain ``road = 0.05 if t >= 1`` inside ``rhs``
    would be evaluated at t = 1 by the last RK4 stage of the step *ending* at the jump — on the
    wrong side — an error of about Δt·kt·0.05/(6 mu) in the wheel velocity.) The schedule's
    change time is announced as the wheel's time event; the unannounced wheel hides it.
    """
    p = QUARTER_CAR
    road = ParameterSchedule({"road": 0.0}, [(ROAD_STEP_TIME, {"road": ROAD_STEP})])

    def suspension(xs: float, vs: float, xu: float, vu: float) -> float:
        """Force of the suspension on the chassis (upwards positive)."""
        return p["ks"] * (xu - xs) + p["cs"] * (vu - vs)

    def chassis(t: float, x: np.ndarray, u: np.ndarray, _: Mapping) -> np.ndarray:
        return np.array([x[1], suspension(x[0], x[1], u[0], u[1]) / p["ms"]])

    def wheel(t: float, x: np.ndarray, u: np.ndarray, q: Mapping) -> np.ndarray:
        tyre = p["kt"] * (q["road"] - x[0])
        return np.array([x[1], (tyre - suspension(u[0], u[1], x[0], x[1])) / p["mu"]])

    def whole(t: float, x: np.ndarray, u: np.ndarray, q: Mapping) -> np.ndarray:
        f = suspension(x[0], x[1], x[2], x[3])
        return np.array([x[1], f / p["ms"], x[3],
                         (p["kt"] * (q["road"] - x[2]) - f) / p["mu"]])

    position = {"x": ("m", 0.0), "v": ("m/s", 0.0)}
    wheel_kind = OdeSubModel if announced else UnannouncedEvents
    system = System()
    system.add("chassis", OdeSubModel(chassis, ports(position),
                                      inputs=ports({"xu": ("m", 0.0), "vu": ("m/s", 0.0)}),
                                      solver=RK4(max_dt=1e-3)))
    system.add("wheel", wheel_kind(wheel, ports(position),
                                   inputs=ports({"xs": ("m", 0.0), "vs": ("m/s", 0.0)}),
                                   parameters=road, solver=RK4(max_dt=1e-4)))
    connect_both_ways(system, "chassis", "wheel", {"x": "xs", "v": "vs"}, {"x": "xu", "v": "vu"})
    mono = OdeSubModel(whole, ports({"xs": ("m", 0.0), "vs": ("m/s", 0.0), "xu": ("m", 0.0),
                                     "vu": ("m/s", 0.0)}), parameters=road)
    mapping = {"chassis.x": "xs", "chassis.v": "vs", "wheel.x": "xu", "wheel.v": "vu"}
    return system, Reference(mono, mapping)


def quarter_car_announced() -> tuple[System, Reference]:
    """Quarter car hitting a 5 cm road step at t = 1 s, the step announced as a time event.

    Chassis ms = 250 kg, wheel mu = 35 kg, suspension ks = 16 kN/m, cs = 1 kNs/m, tyre
    kt = 150 kN/m; at rest in static equilibrium (deviations from it), 3 s. Time scales: body
    bounce ≈ 7.7 rad/s (1.2 Hz), wheel hop ≈ 68 rad/s (11 Hz, damping ratio ≈ 0.2), excited
    by the step. What can go wrong: the master must land on t = 1 s, restart its extrapolation
    there (the history before the jump says nothing after it) and resolve the 11 Hz transient
    of the wheel while the chassis could take long steps.
    """
    return quarter_car(announced=True)


def quarter_car_unannounced() -> tuple[System, Reference]:
    """The same quarter car, but the wheel does not announce its road step (see
    :class:`~cosimstep.suite.base.UnannouncedEvents`): it integrates the jump correctly itself,
    the master learns about it only from the wheel's outputs. What can go wrong: a step that
    straddles 1 s hands the chassis an extrapolation from before the jump; an adaptive
    controller has to detect the jump from the error estimate and shrink its step onto it.
    """
    return quarter_car(announced=False)


# -- duplicated state ----------------------------------------------------------------------
DUPLICATED = {"m": 1.0, "k": 20.0, "c": 0.4, "ka": 30.0, "ca": 3.0, "tau": 0.05}


def duplicated_state() -> tuple[System, Reference]:
    """A mass–spring–damper and an actuator that integrates its *own copy* of the position.

    Mass: x' = v, m v' = −k x − c v + F (input F). Actuator: x_a' = v (input v: the mass's
    velocity), τ F' = −F − ka x_a − ca v (a lagged position/velocity feedback force). The
    monolithic model has a single x; both copies (mass.x and actuator.x) are mapped to it.
    m = 1 kg, k = 20 N/m, c = 0.4 Ns/m, ka = 30 N/m, ca = 3 Ns/m, τ = 0.05 s; x(0) = 0.1 m,
    everything else 0; 10 s. Time scales: an oscillation of 7.3 rad/s (damping ratio 0.13)
    and a decay at 19 s⁻¹ from the 0.05 s force lag. What can go wrong: the two copies of x
    differ by the integral of the coupling error in v — a mode with eigenvalue 0 that nothing
    pulls back, so the copies drift apart with every step's error instead of forgetting it; an
    estimate that looks at single steps only can miss the accumulated drift.
    """
    p = DUPLICATED
    x0 = 0.1

    def mass(t: float, x: np.ndarray, u: np.ndarray, _: Mapping) -> np.ndarray:
        return np.array([x[1], (-p["k"] * x[0] - p["c"] * x[1] + u[0]) / p["m"]])

    def actuator(t: float, x: np.ndarray, u: np.ndarray, _: Mapping) -> np.ndarray:
        return np.array([u[0], (-x[1] - p["ka"] * x[0] - p["ca"] * u[0]) / p["tau"]])

    def whole(t: float, x: np.ndarray, u: np.ndarray, _: Mapping) -> np.ndarray:
        return np.array([x[1], (-p["k"] * x[0] - p["c"] * x[1] + x[2]) / p["m"],
                         (-x[2] - p["ka"] * x[0] - p["ca"] * x[1]) / p["tau"]])

    system = System()
    system.add("mass", OdeSubModel(mass, ports({"x": ("m", x0), "v": ("m/s", 0.0)}),
                                   inputs=ports({"F": ("N", 0.0)}), solver=RK4(max_dt=1e-3)))
    system.add("actuator", OdeSubModel(
        actuator, ports({"x": ("m", x0), "F": ("N", 0.0)},
                        {"x": "the actuator's own copy of the mass position"}),
        inputs=ports({"v": ("m/s", 0.0)}), solver=RK4(max_dt=1e-3)))
    system.connect("mass.v", "actuator.v")
    system.connect("actuator.F", "mass.F")
    mono = OdeSubModel(whole, ports({"x": ("m", x0), "v": ("m/s", 0.0), "F": ("N", 0.0)}))
    mapping = {"mass.x": "x", "mass.v": "v", "actuator.x": "x", "actuator.F": "F"}
    return system, Reference(mono, mapping)

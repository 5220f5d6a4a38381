"""Five engineering plants for the holdout (``benchmarks/holdout.py``).

Built as an out-of-sample check of the error control: none was in the suite or the holdout,
and they were run before anything was changed by what they showed. Two of them hold a state
that integrates another's and so keeps its part of every error for the rest of the run (the PI
controller's integral, the enzyme's product); the error memory, read then from the norm of the
probe's difference, missed it, and each output's memory was argued on them (docs/concepts.md,
"Integrating outputs: each output's memory"), so for that change they are no longer unseen.
Each is split into two or three sub-models the way a user coupling tools would split it
(``OdeSubModel`` with fixed-step RK4 inside, so that what is measured is the coupling's error),
with a monolithic ``OdeSubModel`` as the reference.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from cosimstep import System
from cosimstep.adapters.ode import RK4, OdeSubModel
from cosimstep.reference import Reference
from cosimstep.suite.base import connect_both_ways, ports


def ode_model(rhs: Callable, states: dict[str, tuple[str, float]],
              inputs: dict[str, tuple[str, float]], events: tuple[float, ...] = (),
              max_dt: float = 1e-3) -> OdeSubModel:
    """A sub-model as the suite and the holdout build them (``benchmarks/holdout.py`` uses it
    too): fixed-step RK4 inside, so that what is measured is the coupling's error, not the
    internal solver's."""
    return OdeSubModel(rhs, ports(states), inputs=ports(inputs), solver=RK4(max_dt=max_dt),
                       time_events=events)


# --------------------------------------------------------------------------------------------
# 1. PI-controlled DC motor: electrical | mechanical | controller, setpoint step at 0.5 s
# Source: the DC motor speed model of the "Control Tutorials for MATLAB and Simulink" (CTMS),
# W. Messner, D. Tilbury, Univ. of Michigan / Carnegie Mellon, "DC Motor Speed: System
# Modeling" (J = 0.01 kg m^2, b = 0.1 N m s, K = Ke = Kt = 0.01, R = 1 ohm, L = 0.5 H) and its
# "PID Controller Design" page (Kp = 100, Ki = 200; we drop Kd). The controller's output goes
# through a first-order amplifier lag (tau = 0.01 s, ours) so that no sub-model has direct
# feedthrough; the 1 rad/s setpoint step at 0.5 s is announced as a time event.
# --------------------------------------------------------------------------------------------
DC = dict(J=0.01, b=0.1, K=0.01, R=1.0, L=0.5, Kp=100.0, Ki=200.0, tau=0.01, t_step=0.5)


def _setpoint(t: float) -> float:
    return 1.0 if t >= DC["t_step"] else 0.0


def dc_motor() -> tuple[System, Reference]:
    p = DC

    def electrical(t, x, u, _):  # x = [i]; u = [V, w]
        return np.array([(u[0] - p["R"] * x[0] - p["K"] * u[1]) / p["L"]])

    def mechanical(t, x, u, _):  # x = [w]; u = [i]
        return np.array([(p["K"] * u[0] - p["b"] * x[0]) / p["J"]])

    def controller(t, x, u, _):  # x = [I, V]; u = [w]
        e = _setpoint(t) - u[0]
        return np.array([e, (p["Kp"] * e + p["Ki"] * x[0] - x[1]) / p["tau"]])

    def whole(t, x, u, _):  # x = [i, w, I, V]
        i, w, integral, v = x
        e = _setpoint(t) - w
        return np.array([(v - p["R"] * i - p["K"] * w) / p["L"],
                         (p["K"] * i - p["b"] * w) / p["J"],
                         e, (p["Kp"] * e + p["Ki"] * integral - v) / p["tau"]])

    ev = (p["t_step"],)
    system = System()
    system.add("elec", ode_model(electrical, {"i": ("A", 0.0)},
                                 {"V": ("V", 0.0), "w": ("rad/s", 0.0)}))
    system.add("mech", ode_model(mechanical, {"w": ("rad/s", 0.0)}, {"i": ("A", 0.0)}))
    system.add("ctrl", ode_model(controller, {"I": ("rad", 0.0), "V": ("V", 0.0)},
                                 {"w": ("rad/s", 0.0)}, events=ev))
    system.connect("ctrl.V", "elec.V")
    system.connect("mech.w", "elec.w")
    system.connect("mech.w", "ctrl.w")
    system.connect("elec.i", "mech.i")
    mono = OdeSubModel(whole, ports({"i": ("A", 0.0), "w": ("rad/s", 0.0), "I": ("rad", 0.0),
                                     "V": ("V", 0.0)}), time_events=ev)
    return system, Reference(mono, {"elec.i": "i", "mech.w": "w", "ctrl.I": "I",
                                     "ctrl.V": "V"})


# --------------------------------------------------------------------------------------------
# 2. Four-storey shear building, lower two storeys | upper two storeys (force/velocity split)
# Source: the lumped-mass shear-building model of A. K. Chopra, "Dynamics of Structures",
# 4th ed., Pearson 2012, ch. 9 (multi-storey shear frames, storey stiffness k_j between floors
# j-1 and j, classical damping); our scaled parameters (m = 1, k = 400/300/200/100,
# stiffness-proportional dampers c_j = 0.01 k_j, zeta = 0.005 omega) and initial shape.
# The split is at the 3rd storey's spring: the upper half integrates the inter-storey drifts
# d3 = x3 - x2, d4 = x4 - x3 (the springs belong to it), receives floor 2's velocity and returns
# the drift d3 and its own floor 3 velocity, from which the lower half computes the storey
# force k3 d3 + c3 (v3 - v2): a force/velocity (power-bond) interface, no duplicated state.
# --------------------------------------------------------------------------------------------
SB = dict(m=(1.0, 1.0, 1.0, 1.0), k=(400.0, 300.0, 200.0, 100.0))
SB_C = tuple(0.2 * k / 20.0 for k in SB["k"])  # ~ stiffness-proportional damping
SB_X0 = (2.0, 4.0, 6.0, 8.0)  # initial floor displacements (cm: values of order 1), at rest


def shear_building() -> tuple[System, Reference]:
    m1, m2, m3, m4 = SB["m"]
    k1, k2, k3, k4 = SB["k"]
    c1, c2, c3, c4 = SB_C
    x1, x2, x3, x4 = SB_X0
    d3, d4 = x3 - x2, x4 - x3

    def lower(t, x, u, _):  # x = [x1, v1, x2, v2]; u = [d3, v3]
        f1 = k1 * x[0] + c1 * x[1]
        f2 = k2 * (x[2] - x[0]) + c2 * (x[3] - x[1])
        f3 = k3 * u[0] + c3 * (u[1] - x[3])
        return np.array([x[1], (f2 - f1) / m1, x[3], (f3 - f2) / m2])

    def upper(t, x, u, _):  # x = [d3, v3, d4, v4]; u = [v2]
        f3 = k3 * x[0] + c3 * (x[1] - u[0])
        f4 = k4 * x[2] + c4 * (x[3] - x[1])
        return np.array([x[1] - u[0], (f4 - f3) / m3, x[3] - x[1], -f4 / m4])

    def whole(t, x, u, _):  # x = [x1, v1, x2, v2, d3, v3, d4, v4]
        low = lower(t, x[:4], np.array([x[4], x[5]]), None)
        up = upper(t, x[4:], np.array([x[3]]), None)
        return np.concatenate([low, up])

    s_low = {"x1": ("cm", x1), "v1": ("cm/s", 0.0), "x2": ("cm", x2), "v2": ("cm/s", 0.0)}
    s_up = {"d3": ("cm", d3), "v3": ("cm/s", 0.0), "d4": ("cm", d4), "v4": ("cm/s", 0.0)}
    system = System()
    system.add("lower", ode_model(lower, s_low, {"d3": ("cm", d3), "v3": ("cm/s", 0.0)}))
    system.add("upper", ode_model(upper, s_up, {"v2": ("cm/s", 0.0)}))
    system.connect("lower.v2", "upper.v2")
    system.connect("upper.d3", "lower.d3")
    system.connect("upper.v3", "lower.v3")
    mono = OdeSubModel(whole, ports({**s_low, **s_up}))
    mapping = {f"lower.{n}": n for n in s_low} | {f"upper.{n}": n for n in s_up}
    return system, Reference(mono, mapping)


# --------------------------------------------------------------------------------------------
# 3. Exothermic CSTR (first order A -> B, Arrhenius) | cooling jacket
# Source: the CSTR of D. E. Seborg, T. F. Edgar, D. A. Mellichamp, "Process Dynamics and
# Control", 2nd ed., Wiley 2004, Example 2.5 / exercise data (q = 100 L/min, V = 100 L,
# rho = 1000 g/L, Cp = 0.239 J/(g K), -dH = 5e4 J/mol, E/R = 8750 K, k0 = 7.2e10 1/min,
# UA = 5e4 J/(min K), c_Af = 1 mol/L, T_f = 350 K), with the coolant temperature made a state
# of a cooling jacket (jacket energy balance as in B. W. Bequette, "Process Dynamics:
# Modeling, Analysis, and Simulation", Prentice Hall 1998, section 13; our jacket volume
# 10 L of water, flow 60 L/min, inlet 290 K). Start at Seborg's nominal operating point
# (0.5 mol/L, 350 K, coolant 300 K), the reactor's steady state with the coolant held, but
# not the coupled system's (the jacket is 0.25 K/min off balance there): the reactor drifts
# off it over ~2 min and settles on its cold, low-conversion steady state (317 K); 10 min. (A
# start filled with feed ran away to 540 K, too stiff for the RK4 inside, so it was not used.)
# --------------------------------------------------------------------------------------------
CSTR = dict(q=100.0, V=100.0, rhoCp=1000.0 * 0.239, dH=5e4, ER=8750.0, k0=7.2e10, UA=5e4,
            caf=1.0, Tf=350.0, Vj=10.0, qj=60.0, rhoCpj=4184.0, Tjin=290.0)
CSTR_X0 = (0.5, 350.0, 300.0)  # c_A (mol/L), T (K), T_j (K): the textbook steady state


def cstr() -> tuple[System, Reference]:
    p = CSTR

    def reactor_rates(ca, T, Tj):
        r = p["k0"] * math.exp(-p["ER"] / T) * ca
        return np.array([p["q"] / p["V"] * (p["caf"] - ca) - r,
                         p["q"] / p["V"] * (p["Tf"] - T) + p["dH"] / p["rhoCp"] * r
                         - p["UA"] / (p["V"] * p["rhoCp"]) * (T - Tj)])

    def jacket_rate(T, Tj):
        return (p["qj"] / p["Vj"] * (p["Tjin"] - Tj)
                + p["UA"] / (p["Vj"] * p["rhoCpj"]) * (T - Tj))

    def reactor(t, x, u, _):  # x = [ca, T]; u = [Tj]
        return reactor_rates(x[0], x[1], u[0])

    def jacket(t, x, u, _):  # x = [Tj]; u = [T]
        return np.array([jacket_rate(u[0], x[0])])

    def whole(t, x, u, _):
        return np.append(reactor_rates(x[0], x[1], x[2]), jacket_rate(x[1], x[2]))

    ca0, T0, Tj0 = CSTR_X0
    system = System()
    system.add("reactor", ode_model(reactor, {"ca": ("mol/L", ca0), "T": ("K", T0)},
                                    {"Tj": ("K", Tj0)}))
    system.add("jacket", ode_model(jacket, {"Tj": ("K", Tj0)}, {"T": ("K", T0)}))
    connect_both_ways(system, "reactor", "jacket", {"T": "T"}, {"Tj": "Tj"})
    mono = OdeSubModel(whole, ports({"ca": ("mol/L", ca0), "T": ("K", T0), "Tj": ("K", Tj0)}))
    return system, Reference(mono, {"reactor.ca": "ca", "reactor.T": "T", "jacket.Tj": "Tj"})


# --------------------------------------------------------------------------------------------
# 4. Michaelis-Menten enzyme kinetics with full mass action, slow (S, P) | fast complex C
# Source: L. Michaelis, M. L. Menten (1913), Biochem. Z. 49:333-369; G. E. Briggs,
# J. B. S. Haldane (1925), Biochem. J. 19(2):338-339; time-scale analysis of L. A. Segel,
# M. Slemrod (1989), SIAM Review 31(3):446-477. E + S <-> C -> E + P with k1 = 25, k-1 = 12.5,
# k2 = 12.5 (K_M = 1), E0 = 0.08, S0 = 1 (our values): the complex relaxes in
# 1/(k1 (S + K_M)) ~ 0.02 s, the substrate is consumed over (K_M + S0)/(k2 E0) ~ 2 s, a ratio
# of about 100; C starts at 0 (a stable initial layer). The fast side holds C and uses the
# conservation E = E0 - C; 8 s.
# --------------------------------------------------------------------------------------------
MM = dict(k1=25.0, km1=12.5, k2=12.5, E0=0.08, S0=1.0)


def enzyme() -> tuple[System, Reference]:
    p = MM

    def binding(S, C):  # net rate of E + S -> C
        return p["k1"] * (p["E0"] - C) * S - p["km1"] * C

    def slow(t, x, u, _):  # x = [S, P]; u = [C]
        return np.array([-binding(x[0], u[0]), p["k2"] * u[0]])

    def fast(t, x, u, _):  # x = [C]; u = [S]
        return np.array([binding(u[0], x[0]) - p["k2"] * x[0]])

    def whole(t, x, u, _):  # x = [S, P, C]
        S, _, C = x
        return np.array([-binding(S, C), p["k2"] * C, binding(S, C) - p["k2"] * C])

    system = System()
    system.add("slow", ode_model(slow, {"S": ("mol/L", p["S0"]), "P": ("mol/L", 0.0)},
                                 {"C": ("mol/L", 0.0)}))
    system.add("fast", ode_model(fast, {"C": ("mol/L", 0.0)}, {"S": ("mol/L", p["S0"])},
                                 max_dt=2e-4))
    connect_both_ways(system, "slow", "fast", {"S": "S"}, {"C": "C"})
    mono = OdeSubModel(whole, ports({"S": ("mol/L", p["S0"]), "P": ("mol/L", 0.0),
                                     "C": ("mol/L", 0.0)}))
    return system, Reference(mono, {"slow.S": "S", "slow.P": "P", "fast.C": "C"})


# --------------------------------------------------------------------------------------------
# 5. Bus quarter-car suspension, body | wheel, driven by the road r(t) = A sin(30 t) sin(0.5 t)
# Source: the bus suspension model of the "Control Tutorials for MATLAB and Simulink",
# "Suspension: System Modeling" (body m1 = 2500 kg, wheel m2 = 320 kg, k1 = 80 kN/m,
# b1 = 350 N s/m, tyre k2 = 500 kN/m, b2 = 15020 N s/m); passive (no actuator), our road
# A = 10 mm (a smooth but fast forcing: beats at 29.5 and 30.5 rad/s under a 12.6 s envelope),
# tyre spring and damper fed by r and r'. Start at rest; 8 s.
# --------------------------------------------------------------------------------------------
# the road amplitude A in mm: positions in mm, values of order 1
BUS = dict(m1=2500.0, m2=320.0, k1=8e4, b1=350.0, k2=5e5, b2=15020.0, A=10.0)


def _road(t: float) -> tuple[float, float]:
    a = BUS["A"]
    return (a * math.sin(30.0 * t) * math.sin(0.5 * t),
            a * (30.0 * math.cos(30.0 * t) * math.sin(0.5 * t)
                 + 0.5 * math.sin(30.0 * t) * math.cos(0.5 * t)))


def bus_suspension() -> tuple[System, Reference]:
    p = BUS

    def spring(x1, v1, x2, v2):  # suspension force on the body (up positive)
        return p["k1"] * (x2 - x1) + p["b1"] * (v2 - v1)

    def tyre(t, x2, v2):
        r, dr = _road(t)
        return p["k2"] * (r - x2) + p["b2"] * (dr - v2)

    def body(t, x, u, _):  # x = [x1, v1]; u = [x2, v2]
        return np.array([x[1], spring(x[0], x[1], u[0], u[1]) / p["m1"]])

    def wheel(t, x, u, _):  # x = [x2, v2]; u = [x1, v1]
        return np.array([x[1], (tyre(t, x[0], x[1]) - spring(u[0], u[1], x[0], x[1]))
                         / p["m2"]])

    def whole(t, x, u, _):
        f = spring(x[0], x[1], x[2], x[3])
        return np.array([x[1], f / p["m1"], x[3], (tyre(t, x[2], x[3]) - f) / p["m2"]])

    rest = {"x": ("mm", 0.0), "v": ("mm/s", 0.0)}
    system = System()
    system.add("body", ode_model(body, rest, {"xw": ("mm", 0.0), "vw": ("mm/s", 0.0)}))
    system.add("wheel", ode_model(wheel, rest, {"xb": ("mm", 0.0), "vb": ("mm/s", 0.0)}))
    connect_both_ways(system, "body", "wheel", {"x": "xb", "v": "vb"}, {"x": "xw", "v": "vw"})
    mono = OdeSubModel(whole, ports({"x1": ("mm", 0.0), "v1": ("mm/s", 0.0), "x2": ("mm", 0.0),
                                     "v2": ("mm/s", 0.0)}))
    return system, Reference(mono, {"body.x": "x1", "body.v": "v1", "wheel.x": "x2",
                                    "wheel.v": "v2"})

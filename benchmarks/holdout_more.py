"""Five more systems kept apart (``benchmarks/holdout.py``): two neurons' and two oscillators'
limit cycles and two settling plants.

Built for an out-of-sample check of ``pc``'s signed local estimate (docs/concepts.md, "The sign
of the corrector's input error") and run with the code before and after it, unseen, before
they joined the holdout: a Morris–Lecar neuron, two mutually coupled Van der Pol oscillators,
the Rosenzweig–MacArthur predator–prey cycle, two interconnected tanks with a pump step, and a
four-mass chain with a hardening spring at its split. Sub-models and references are built as
in :mod:`holdout_plants` (fixed-step RK4 inside every sub-model, a monolithic reference), so
that what is measured is the coupling's error.
"""

from __future__ import annotations

import math

import numpy as np

from cosimstep import System
from cosimstep.adapters.ode import OdeSubModel
from cosimstep.reference import Reference
from cosimstep.suite.base import connect_both_ways, ports
from holdout_plants import ode_model

# --------------------------------------------------------------------------------------------
# 1. Morris-Lecar neuron, membrane voltage V | K+ gating variable w (limit cycle, relaxation-like)
# Source: C. Morris, H. Lecar (1981), "Voltage oscillations in the barnacle giant muscle fiber",
# Biophys. J. 35(1):193-213; the parameter set ("Hopf" regime, I = 100 uA/cm^2) of J. Rinzel,
# G. B. Ermentrout (1998), "Analysis of neural excitability and oscillations", in C. Koch,
# I. Segev (eds.), "Methods in Neuronal Modeling", 2nd ed., MIT Press, ch. 7 (table 7.1).
# Time in ms; period about 87 ms; 250 ms (close to three spikes). Start V = -40 mV, w = 0.
# --------------------------------------------------------------------------------------------
ML = dict(C=20.0, gL=2.0, gCa=4.4, gK=8.0, VL=-60.0, VCa=120.0, VK=-84.0, V1=-1.2, V2=18.0,
          V3=2.0, V4=30.0, phi=0.04, I=100.0)


def _ml_dv(V: float, w: float) -> float:
    p = ML
    minf = 0.5 * (1.0 + math.tanh((V - p["V1"]) / p["V2"]))
    return (p["I"] - p["gL"] * (V - p["VL"]) - p["gCa"] * minf * (V - p["VCa"])
            - p["gK"] * w * (V - p["VK"])) / p["C"]


def _ml_dw(V: float, w: float) -> float:
    p = ML
    winf = 0.5 * (1.0 + math.tanh((V - p["V3"]) / p["V4"]))
    return p["phi"] * (winf - w) * math.cosh((V - p["V3"]) / (2.0 * p["V4"]))


def morris_lecar() -> tuple[System, Reference]:
    V0, w0 = -40.0, 0.0
    system = System()
    system.add("membrane", ode_model(lambda t, x, u, _: np.array([_ml_dv(x[0], u[0])]),
                                     {"V": ("mV", V0)}, {"w": ("1", w0)}, max_dt=0.01))
    system.add("gate", ode_model(lambda t, x, u, _: np.array([_ml_dw(u[0], x[0])]),
                                 {"w": ("1", w0)}, {"V": ("mV", V0)}, max_dt=0.01))
    connect_both_ways(system, "membrane", "gate", {"V": "V"}, {"w": "w"})
    mono = OdeSubModel(lambda t, x, u, _: np.array([_ml_dv(x[0], x[1]), _ml_dw(x[0], x[1])]),
                       ports({"V": ("mV", V0), "w": ("1", w0)}))
    return system, Reference(mono, {"membrane.V": "V", "gate.w": "w"})


# --------------------------------------------------------------------------------------------
# 2. Two mutually coupled Van der Pol relaxation oscillators, oscillator 1 | oscillator 2
# Source: D. W. Storti, R. H. Rand (1982), "Dynamics of two strongly coupled van der Pol
# oscillators", Int. J. Non-Linear Mech. 17(3):143-152 (diffusive position coupling
# x_i'' - mu_i (1 - x_i^2) x_i' + w_i^2 x_i = k (x_j - x_i)); our detuned, strongly relaxing
# parameters mu = 4 and 3, w = 1 and 1.3, k = 0.5 (they lock 2:3; a perturbation does not grow).
# Each in Lienard's coordinates x' = mu (x - x^3/3 - y), y' = (w^2 x - k (x_j - x)) / mu.
# Each sub-model exchanges its x; 40 time units (about five periods of oscillator 1).
# --------------------------------------------------------------------------------------------
CV = dict(mu=(4.0, 3.0), w=(1.0, 1.3), k=0.5)
CV_X0 = ((2.0, 0.0), (-1.0, 0.5))


def _vdp(i: int, x: float, y: float, xj: float) -> np.ndarray:
    mu, w, k = CV["mu"][i], CV["w"][i], CV["k"]
    return np.array([mu * (x - x ** 3 / 3.0 - y), (w * w * x - k * (xj - x)) / mu])


def coupled_vdp() -> tuple[System, Reference]:
    system = System()
    for i, name in enumerate(("osc1", "osc2")):
        system.add(name, ode_model(lambda t, s, u, _, i=i: _vdp(i, s[0], s[1], u[0]),
                                   {"x": ("1", CV_X0[i][0]), "y": ("1", CV_X0[i][1])},
                                   {"xo": ("1", CV_X0[1 - i][0])}))
    connect_both_ways(system, "osc1", "osc2", {"x": "xo"}, {"x": "xo"})
    mono = OdeSubModel(lambda t, s, u, _: np.concatenate([_vdp(0, s[0], s[1], s[2]),
                                                          _vdp(1, s[2], s[3], s[0])]),
                       ports({"x1": ("1", CV_X0[0][0]), "y1": ("1", CV_X0[0][1]),
                              "x2": ("1", CV_X0[1][0]), "y2": ("1", CV_X0[1][1])}))
    return system, Reference(mono, {"osc1.x": "x1", "osc1.y": "y1", "osc2.x": "x2",
                                     "osc2.y": "y2"})


# --------------------------------------------------------------------------------------------
# 3. Rosenzweig-MacArthur predator-prey (logistic prey, Holling type II response), prey | predator
# Source: M. L. Rosenzweig, R. H. MacArthur (1963), "Graphical representation and stability
# conditions of predator-prey interactions", Am. Nat. 97(895):209-223; C. S. Holling (1959),
# Can. Entomol. 91(7):385-398 for the type II response; the nondimensional form
# x' = x (1 - x/K) - x y / (1 + x), y' = b x y / (1 + x) - d y as in S. H. Strogatz,
# "Nonlinear Dynamics and Chaos" (1994), exercise 8.2.x / M. Kot, "Elements of Mathematical
# Ecology" (2001), ch. 6. Our K = 3, b = 1, d = 0.4 (Hopf at K = 7/3, so a limit cycle of
# period about 19, prey down to 0.1). From (2, 0.5); 80 time units (about four periods).
# --------------------------------------------------------------------------------------------
RM = dict(K=3.0, b=1.0, d=0.4)


def rosenzweig_macarthur() -> tuple[System, Reference]:
    K, b, d = RM["K"], RM["b"], RM["d"]

    def prey(x: float, y: float) -> float:
        return x * (1.0 - x / K) - x * y / (1.0 + x)

    def pred(x: float, y: float) -> float:
        return b * x * y / (1.0 + x) - d * y

    x0, y0 = 2.0, 0.5
    system = System()
    system.add("prey", ode_model(lambda t, s, u, _: np.array([prey(s[0], u[0])]),
                                 {"x": ("1", x0)}, {"y": ("1", y0)}))
    system.add("predator", ode_model(lambda t, s, u, _: np.array([pred(u[0], s[0])]),
                                     {"y": ("1", y0)}, {"x": ("1", x0)}))
    connect_both_ways(system, "prey", "predator", {"x": "x"}, {"y": "y"})
    mono = OdeSubModel(lambda t, s, u, _: np.array([prey(s[0], s[1]), pred(s[0], s[1])]),
                       ports({"x": ("1", x0), "y": ("1", y0)}))
    return system, Reference(mono, {"prey.x": "x", "predator.y": "y"})


# --------------------------------------------------------------------------------------------
# 4. Two interconnected water tanks (Torricelli outflows), tank 1 (pumped) | tank 2 (drained),
#    pump voltage step 3 V -> 2 V at 150 s (announced). Damped, settling, nonlinear.
# Source: the tank model of K. H. Johansson (2000), "The quadruple-tank process: a
# multivariable laboratory process with an adjustable zero", IEEE Trans. Control Syst.
# Technol. 8(3):456-465 (Bernoulli outflow a sqrt(2 g h), A = 28 cm^2, a = 0.071 cm^2,
# pump gain 3.33 cm^3/(V s), g = 981 cm/s^2); the two tanks side by side joined by a pipe of
# cross-section a12 = 0.071 cm^2 (flow a12 sign(h1 - h2) sqrt(2 g |h1 - h2|)) is our
# arrangement (h1 > h2 throughout, so the square root is never at zero). From h = (15, 2) cm;
# 400 s.
# --------------------------------------------------------------------------------------------
TK = dict(A=28.0, a=0.071, a12=0.071, g=981.0, kp=3.33, v=(3.0, 2.0), t_step=150.0)


def _pump(t: float) -> float:
    return TK["kp"] * (TK["v"][0] if t < TK["t_step"] else TK["v"][1])


def _q12(h1: float, h2: float) -> float:
    dh = h1 - h2
    return TK["a12"] * math.copysign(math.sqrt(2.0 * TK["g"] * abs(dh)), dh)


def _qout(h2: float) -> float:
    return TK["a"] * math.sqrt(2.0 * TK["g"] * max(h2, 0.0))


def two_tanks() -> tuple[System, Reference]:
    A = TK["A"]
    h10, h20 = 15.0, 2.0
    ev = (TK["t_step"],)
    system = System()
    system.add("tank1", ode_model(lambda t, s, u, _: np.array([(_pump(t) - _q12(s[0], u[0]))
                                                               / A]),
                                  {"h1": ("cm", h10)}, {"h2": ("cm", h20)}, events=ev,
                                  max_dt=0.02))
    system.add("tank2", ode_model(lambda t, s, u, _: np.array([(_q12(u[0], s[0]) - _qout(s[0]))
                                                               / A]),
                                  {"h2": ("cm", h20)}, {"h1": ("cm", h10)}, max_dt=0.02))
    connect_both_ways(system, "tank1", "tank2", {"h1": "h1"}, {"h2": "h2"})

    def whole(t, s, u, _):
        q = _q12(s[0], s[1])
        return np.array([(_pump(t) - q) / A, (q - _qout(s[1])) / A])

    mono = OdeSubModel(whole, ports({"h1": ("cm", h10), "h2": ("cm", h20)}), time_events=ev)
    return system, Reference(mono, {"tank1.h1": "h1", "tank2.h2": "h2"})


# --------------------------------------------------------------------------------------------
# 5. Four-mass chain with a hardening (Duffing) spring at the split, masses 1-2 | masses 3-4.
#    Damped, settling, nonlinear.
# Source: the cubic (hardening) spring of G. Duffing (1918), "Erzwungene Schwingungen bei
# veraenderlicher Eigenfrequenz", Vieweg; chains of masses joined by linear and cubic springs
# as in A. F. Vakakis et al. (1996), "Normal Modes and Localization in Nonlinear Systems",
# Wiley, and I. Kovacic, M. J. Brennan (eds.) (2011), "The Duffing Equation", Wiley, ch. 1.
# Our parameters: unit masses; springs 40 (ground-m1), 30 (m1-m2), 25 + 400 d^3 (m2-m3, the
# split), 20 (m3-m4); dampers 0.5 in every spring and 0.8 from every mass to ground. Masses 3
# and 4 start displaced by 0.3 and 1.0, all at rest; 15 s (settled to ~1e-3).
# Each side computes the Duffing spring's force from the other's exchanged position and
# velocity (as the suite's two-mass split does with a linear spring).
# --------------------------------------------------------------------------------------------
CH = dict(k=(40.0, 30.0, 25.0, 20.0), kn=400.0, c=0.5, c0=0.8)
CH_X0 = (0.0, 0.0, 0.3, 1.0)


def _duffing(x2: float, v2: float, x3: float, v3: float) -> float:
    """Force of the split spring on mass 2 (and minus it on mass 3)."""
    d = x3 - x2
    return CH["k"][2] * d + CH["kn"] * d ** 3 + CH["c"] * (v3 - v2)


def _left(s: np.ndarray, x3: float, v3: float) -> np.ndarray:
    k, c, c0 = CH["k"], CH["c"], CH["c0"]
    x1, v1, x2, v2 = s
    f1 = k[0] * x1 + c * v1
    f2 = k[1] * (x2 - x1) + c * (v2 - v1)
    f3 = _duffing(x2, v2, x3, v3)
    return np.array([v1, f2 - f1 - c0 * v1, v2, f3 - f2 - c0 * v2])


def _right(s: np.ndarray, x2: float, v2: float) -> np.ndarray:
    k, c, c0 = CH["k"], CH["c"], CH["c0"]
    x3, v3, x4, v4 = s
    f3 = _duffing(x2, v2, x3, v3)
    f4 = k[3] * (x4 - x3) + c * (v4 - v3)
    return np.array([v3, f4 - f3 - c0 * v3, v4, -f4 - c0 * v4])


def duffing_chain() -> tuple[System, Reference]:
    x1, x2, x3, x4 = CH_X0
    s_left = {"x1": ("m", x1), "v1": ("m/s", 0.0), "x2": ("m", x2), "v2": ("m/s", 0.0)}
    s_right = {"x3": ("m", x3), "v3": ("m/s", 0.0), "x4": ("m", x4), "v4": ("m/s", 0.0)}
    system = System()
    system.add("left", ode_model(lambda t, s, u, _: _left(s, u[0], u[1]), s_left,
                                 {"x3": ("m", x3), "v3": ("m/s", 0.0)}))
    system.add("right", ode_model(lambda t, s, u, _: _right(s, u[0], u[1]), s_right,
                                  {"x2": ("m", x2), "v2": ("m/s", 0.0)}))
    connect_both_ways(system, "left", "right", {"x2": "x2", "v2": "v2"},
                      {"x3": "x3", "v3": "v3"})
    mono = OdeSubModel(lambda t, s, u, _: np.concatenate([_left(s[:4], s[4], s[5]),
                                                          _right(s[4:], s[2], s[3])]),
                       ports({**s_left, **s_right}))
    mapping = {f"left.{n}": n for n in s_left} | {f"right.{n}": n for n in s_right}
    return system, Reference(mono, mapping)

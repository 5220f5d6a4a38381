"""A bouncing ball whose impacts drive a spring–damper (benchmark problem 8, issue 14).

    ball:    h'' = −g in flight; at contact (h = 0, falling) v → −e·v
             outputs h [m], v [m/s], J [N·s] (impulse given to the ground so far: discrete)
    damper:  M x'' = −k x − c x' + dJ/dt                  input J; outputs x [m], w [N·s]

The ground the ball hits rests on the spring–damper: each impact hands it the impulse
``m (1 + e) |v|``. The damper integrates ``w = M x' − J`` instead of its velocity, so a jump of
``J`` is a jump of ``x'`` while its own states stay continuous: ``x' = (w + J)/M``,
``w' = −k x − c x'``.

The ball is a black box in the way a co-simulation FMU is: it handles its contacts inside
``do_step`` (its flight is a parabola, so the contact times are exact to rounding). The master
sees the contact as a change of the discrete output ``J`` and lands a communication point on
it (:mod:`cosimstep.loops`, a *state event*).

The monolithic reference (:func:`monolithic`) knows the contact times in closed form:
``t₁ = (v₀ + √(v₀² + 2gh₀))/g`` with impact speed ``V₁ = √(v₀² + 2gh₀)``, then flights of
``2·eᵏ·V₁/g``. With ``q = v − J/m`` (continuous: each jump of ``v`` is ``ΔJ/m``) and ``J`` a
parameter that changes at those times, it is an ODE without resets.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from cosimstep.adapters.ode import InternalSolver, OdeSubModel, ParameterSchedule
from cosimstep.submodel import Capabilities, Port, SubModel


def default_parameters() -> dict[str, float]:
    return {"e": 0.7, "g": 9.81, "m": 1.0, "M": 10.0, "k": 1000.0, "c": 20.0,
            "v_rest": 1e-3}


START = ("h", "v", "x", "w")
DEFAULT_START = {"h": 1.0, "v": 0.0, "x": 0.0, "w": 0.0}


def contacts(p: Mapping[str, float], h0: float, v0: float,
             t0: float, t_end: float) -> list[tuple[float, float]]:
    """The contact times in ``(t0, t_end]`` and each contact's impact speed, in closed form."""
    g, e = p["g"], p["e"]
    speed = math.sqrt(v0 * v0 + 2.0 * g * h0)
    t = t0 + (v0 + speed) / g
    out = []
    while t <= t_end and e * speed >= p["v_rest"]:
        out.append((t, speed))
        speed *= e
        t += 2.0 * speed / g
    return out


class BouncingBall(SubModel):
    """The ball: free flight in closed form, contacts inside :meth:`do_step`.

    A rebound slower than ``v_rest`` ends the bouncing (the ball then rests on the ground), so
    the contacts do not pile up towards the accumulation point of the infinite sequence.
    """

    def __init__(self, p: Mapping[str, float], h0: float = 1.0, v0: float = 0.0) -> None:
        if h0 < 0:
            raise ValueError(f"the ball starts below the ground (h = {h0})")
        self.p = dict(p)
        self.h0, self.v0 = float(h0), float(v0)
        self.inputs = ()
        self.outputs = (Port("h", "m", self.h0, "height above the ground"),
                        Port("v", "m/s", self.v0, "vertical velocity"),
                        Port("J", "N.s", 0.0, "impulse given to the ground so far",
                             discrete=True))
        self.capabilities = Capabilities(can_save_state=True, provides_derivatives=True)
        self._x = np.array([self.h0, self.v0, 0.0])
        self._resting = False

    def initialize(self, t0: float) -> None:
        self._x = np.array([self.h0, self.v0, 0.0])
        self._resting = False

    def set_inputs(self, values: np.ndarray) -> None:
        """No inputs."""

    def do_step(self, t: float, h: float) -> None:
        g, e, m = self.p["g"], self.p["e"], self.p["m"]
        height, v, impulse = self._x
        left = h
        while not self._resting:
            # time to the ground: height + v s − g s²/2 = 0 (rounding may leave it a hair below)
            s = max((v + math.sqrt(max(v * v + 2.0 * g * height, 0.0))) / g, 0.0)
            if s > left:
                height, v = height + v * left - 0.5 * g * left * left, v - g * left
                break
            hit = g * s - v  # impact speed
            left -= s
            height, v = 0.0, e * hit
            if v < self.p["v_rest"]:  # too slow to leave the ground: a last, plastic contact
                impulse += m * hit
                self._resting, v = True, 0.0
            else:
                impulse += m * (1.0 + e) * hit
        self._x = np.array([height, v, impulse])

    def get_outputs(self) -> np.ndarray:
        return self._x.copy()

    def get_output_derivatives(self) -> np.ndarray:
        v = self._x[1]
        return np.array([v, 0.0 if self._resting else -self.p["g"], 0.0])

    def save_state(self) -> Any:
        return self._x.copy(), self._resting

    def restore_state(self, token: Any) -> None:
        x, self._resting = token
        self._x = x.copy()


def _start(start: Mapping[str, float], name: str) -> float:
    return float(start.get(name, DEFAULT_START[name]))


def ball(parameters: ParameterSchedule, start: Mapping[str, float],
         solver: InternalSolver | None = None) -> SubModel:
    return BouncingBall(parameters.at(0.0), _start(start, "h"), _start(start, "v"))


def _damper_rhs(x: float, w: float, impulse: float, p: Mapping[str, float]) -> tuple[float, float]:
    velocity = (w + impulse) / p["M"]
    return velocity, -p["k"] * x - p["c"] * velocity


def damper(parameters: ParameterSchedule, start: Mapping[str, float],
           solver: InternalSolver | None = None) -> OdeSubModel:
    def rhs(t: float, x: np.ndarray, u: np.ndarray, p: Mapping[str, float]) -> np.ndarray:
        return np.array(_damper_rhs(x[0], x[1], u[0], p))

    return OdeSubModel(rhs, [Port("x", "m", _start(start, "x"), "ground displacement"),
                             Port("w", "N.s", _start(start, "w"), "M x' - J")],
                       inputs=[Port("J", "N.s", 0.0, "impulse received so far")],
                       parameters=parameters, solver=solver)


def monolithic(parameters: ParameterSchedule, start: Mapping[str, float],
               solver: InternalSolver | None = None) -> OdeSubModel:
    """Ball and damper in one ODE; ``J`` changes at the closed-form contact times (valid up to
    the last rebound faster than ``v_rest``: the ball's rest is not modelled here)."""
    p = parameters.at(0.0)
    h0, v0 = _start(start, "h"), _start(start, "v")
    changes, impulse = [], 0.0
    for t, speed in contacts(p, h0, v0, 0.0, math.inf):
        impulse += p["m"] * (1.0 + p["e"]) * speed
        changes.append((t, {"J": impulse}))
    schedule = ParameterSchedule({**p, "J": 0.0}, changes)

    def rhs(t: float, x: np.ndarray, u: np.ndarray, q: Mapping[str, float]) -> np.ndarray:
        impulse = q["J"]
        dx, dw = _damper_rhs(x[2], x[3], impulse, q)
        return np.array([x[1] + impulse / q["m"], -q["g"], dx, dw])

    states = [Port("h", "m", h0), Port("q", "m/s", v0, "v - J/m"),
              Port("x", "m", _start(start, "x")), Port("w", "N.s", _start(start, "w"))]
    return OdeSubModel(rhs, states, parameters=schedule, solver=solver)

"""A small cooling loop whose pump can fail (the hybrid example, ``examples/pump_failure.toml``).

    pump:     τ q' = ok·q0 − q                          flow q [kg/s], input ok (1 or 0)
    coolant:  m cp Tc' = q cp (Tin − Tc) + UA (Th − Tc)  input q, Th; output Tc [°C]
    load:     C Th' = P − UA (Th − Tc)                   input Tc; output Th [°C]

A chiller holds the inlet at ``Tin``; the heat load ``P`` reaches the coolant through a heat
exchanger of conductance ``UA``. ``ok`` comes from a failure model (``type = "failure"``):
when the pump fails its flow runs down with time constant ``τ`` and the loop heats up. Time
scales: the pump 5 s, the coolant about 20 s, the load about 100 s.

The monolithic reference (:func:`monolithic`) draws the failure time from the same law and seed
as the failure model (:class:`~cosimstep.events.FailureModel`, Weibull, parameters
``fail_scale``, ``fail_shape``, ``fail_seed``), so split and reference fail at the same instant.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from cosimstep.adapters.ode import InternalSolver, OdeSubModel, ParameterSchedule
from cosimstep.submodel import Port


def default_parameters() -> dict[str, float]:
    return {"q0": 2.0, "tau": 5.0, "cp": 4186.0, "m": 50.0, "Tin": 10.0, "UA": 2000.0,
            "C": 2.0e5, "P": 2.0e4, "fail_scale": 400.0, "fail_shape": 2.0, "fail_seed": 11.0}


START = ("q", "Tc", "Th")


def _state(start: Mapping[str, float], name: str, unit: str) -> Port:
    return Port(name, unit, float(start.get(name, 0.0)))


def failure_time(p: Mapping[str, float], t0: float = 0.0) -> float:
    """The first failure of the Weibull law the failure model draws with the same seed."""
    from cosimstep.events import FailureModel

    model = FailureModel("weibull", scale=p["fail_scale"], shape=p["fail_shape"],
                         seed=int(p["fail_seed"]))
    model.initialize(t0)
    return model.next_event(t0)


def _coolant(q: float, tc: float, th: float, p: Mapping[str, float]) -> float:
    return (q * p["cp"] * (p["Tin"] - tc) + p["UA"] * (th - tc)) / (p["m"] * p["cp"])


def _load(tc: float, th: float, p: Mapping[str, float]) -> float:
    return (p["P"] - p["UA"] * (th - tc)) / p["C"]


def monolithic(parameters: ParameterSchedule, start: Mapping[str, float],
               solver: InternalSolver | None = None) -> OdeSubModel:
    """The whole loop in one model, the pump failing at the failure model's first time."""
    t_fail = failure_time(parameters.at(0.0))

    def rhs(t: float, x: np.ndarray, u: np.ndarray, p: Mapping[str, float]) -> np.ndarray:
        ok = 1.0 if t < t_fail else 0.0
        q, tc, th = x
        return np.array([(ok * p["q0"] - q) / p["tau"], _coolant(q, tc, th, p), _load(tc, th, p)])

    states = [_state(start, "q", "kg/s"), _state(start, "Tc", "degC"),
              _state(start, "Th", "degC")]
    return OdeSubModel(rhs, states, parameters=parameters, solver=solver,
                       time_events=[t_fail] if math.isfinite(t_fail) else [])


def pump(parameters: ParameterSchedule, start: Mapping[str, float],
         solver: InternalSolver | None = None) -> OdeSubModel:
    """Flow ``q``; input ``ok`` (1 while the pump works)."""

    def rhs(t: float, x: np.ndarray, u: np.ndarray, p: Mapping[str, float]) -> np.ndarray:
        return np.array([(u[0] * p["q0"] - x[0]) / p["tau"]])

    return OdeSubModel(rhs, [_state(start, "q", "kg/s")], inputs=[Port("ok", "1", 1.0)],
                       parameters=parameters, solver=solver)


def coolant(parameters: ParameterSchedule, start: Mapping[str, float],
            solver: InternalSolver | None = None) -> OdeSubModel:
    """Coolant temperature ``Tc``; inputs ``q`` and ``Th``."""

    def rhs(t: float, x: np.ndarray, u: np.ndarray, p: Mapping[str, float]) -> np.ndarray:
        return np.array([_coolant(u[0], x[0], u[1], p)])

    inputs = [Port("q", "kg/s", float(start.get("q", 0.0))),
              Port("Th", "degC", float(start.get("Th", 0.0)))]
    return OdeSubModel(rhs, [_state(start, "Tc", "degC")], inputs=inputs,
                       parameters=parameters, solver=solver)


def load(parameters: ParameterSchedule, start: Mapping[str, float],
         solver: InternalSolver | None = None) -> OdeSubModel:
    """Load temperature ``Th``; input ``Tc``."""

    def rhs(t: float, x: np.ndarray, u: np.ndarray, p: Mapping[str, float]) -> np.ndarray:
        return np.array([_load(u[0], x[0], p)])

    return OdeSubModel(rhs, [_state(start, "Th", "degC")],
                       inputs=[Port("Tc", "degC", float(start.get("Tc", 0.0)))],
                       parameters=parameters, solver=solver)

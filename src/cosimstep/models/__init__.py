"""Built-in sub-models, registered by the ``type`` name a system file uses.

Each entry knows its parameters (with defaults) and the start values it reads, so a system file
can be checked before anything runs.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from functools import partial

import numpy as np

from cosimstep.adapters.ode import InternalSolver, ParameterSchedule
from cosimstep.models import bouncing, linear, oscillators, pendulum, ship, thermal
from cosimstep.submodel import SubModel

Builder = Callable[[ParameterSchedule, Mapping[str, float], InternalSolver | None], SubModel]
Derived = Callable[[np.ndarray, Mapping[str, float]], np.ndarray]
"""A quantity of a monolithic model that is no state: from the states (one row each, one column
per time) and the parameters, its values at those times."""


@dataclass(frozen=True)
class ModelKind:
    """A built-in sub-model type."""

    name: str
    description: str
    parameters: Mapping[str, float]
    start: tuple[str, ...]
    build: Builder
    start_values: Mapping[str, float] = field(default_factory=dict)
    """The builder's own start values, by start name (where it has any): an export of the kind
    begins from these rather than from zero."""
    derived: Mapping[str, Derived] = field(default_factory=dict)
    """A monolithic kind's quantities that are no state but that a split exchanges (a coupling
    force): a reference map may name them, so that every exchanged output is measured."""


REGISTRY: dict[str, ModelKind] = {}


def register(kind: ModelKind) -> ModelKind:
    clash = set(kind.derived) & set(kind.start)
    if clash:  # a map entry could not tell the state from the quantity
        raise ValueError(f"model kind '{kind.name}': {sorted(clash)} named as states and as "
                         "derived quantities")
    REGISTRY[kind.name] = kind
    return kind


def _chain_start(n: int) -> tuple[str, ...]:
    return tuple(f"theta{i}" for i in range(1, n + 1)) + tuple(
        f"omega{i}" for i in range(1, n + 1))


for _n, _label in ((2, "double_pendulum"), (3, "triple_pendulum")):
    register(ModelKind(
        _label, f"{_n}-bar pendulum, monolithic (all bars in one model)",
        pendulum.default_parameters(_n), _chain_start(_n), partial(pendulum.monolithic, _n)))
    for _i in range(1, _n + 1):
        register(ModelKind(
            f"{_label}.bar{_i}", f"bar {_i} of the {_n}-bar pendulum, split model",
            pendulum.default_parameters(_n), _chain_start(_n), partial(pendulum.bar, _n, _i)))

register(ModelKind("linear_coupled", "fast oscillator + slow lag (benchmark problems 6, 9), "
                   "monolithic", linear.default_parameters(), ("u", "v", "w"), linear.monolithic))
register(ModelKind("linear_coupled.fast", "fast part: u' = lam v + w, v' = -lam u (input w)",
                   linear.default_parameters(), ("u", "v", "w"), linear.fast))
register(ModelKind("linear_coupled.slow", "slow part: w' = -w + u (input u)",
                   linear.default_parameters(), ("u", "v", "w"), linear.slow))

register(ModelKind("thermal_loop", "cooling loop with a pump that fails (pump, coolant, load), "
                   "monolithic; fails at the failure model's first time",
                   thermal.default_parameters(), thermal.START, thermal.monolithic))
register(ModelKind("thermal_loop.pump", "pump flow q: tau q' = ok q0 - q (input ok)",
                   thermal.default_parameters(), thermal.START, thermal.pump))
register(ModelKind("thermal_loop.coolant", "coolant temperature Tc (inputs q, Th)",
                   thermal.default_parameters(), thermal.START, thermal.coolant))
register(ModelKind("thermal_loop.load", "heat load temperature Th (input Tc)",
                   thermal.default_parameters(), thermal.START, thermal.load))

register(ModelKind("bouncing_ball", "bouncing ball whose impacts drive a spring-damper "
                   "(problem 8), monolithic; contact times in closed form",
                   bouncing.default_parameters(), bouncing.START, bouncing.monolithic))
register(ModelKind("bouncing_ball.ball", "the ball: h, v and the impulse J given to the ground "
                   "(discrete); contacts handled inside its steps",
                   bouncing.default_parameters(), bouncing.START, bouncing.ball))
register(ModelKind("bouncing_ball.damper", "spring-damper under the ground: M x'' = -k x - c x' "
                   "+ dJ/dt (input J)", bouncing.default_parameters(), bouncing.START,
                   bouncing.damper))

register(ModelKind("oscillators", "two oscillators joined by a spring-damper (problem 7), "
                   "monolithic", oscillators.default_parameters(), oscillators.START,
                   oscillators.monolithic, derived={"F": oscillators.force}))
register(ModelKind("oscillators.mass1", "mass 1: m1 x1'' = -k1 x1 - c1 v1 - F (input F)",
                   oscillators.default_parameters(), oscillators.START, oscillators.mass1))
register(ModelKind("oscillators.mass2", "mass 2: m2 x2'' = -k2 x2 - c2 v2 + F (input F)",
                   oscillators.default_parameters(), oscillators.START, oscillators.mass2))
register(ModelKind("oscillators.spring", "the coupling spring-damper: F = k (x1 - x2) + "
                   "c (v1 - v2), direct feedthrough (inputs x1, v1, x2, v2)",
                   oscillators.default_parameters(), oscillators.START, oscillators.spring))

_SHIP = ship.default_parameters()
register(ModelKind("ship", "the ship plant (load zones, chilled-water network, controller), "
                   "monolithic; hit at t_hit, isolation located as a state event", _SHIP,
                   ship.START, ship.monolithic, ship.START_VALUES))
register(ModelKind("ship.hydraulics", "chilled-water network: pumps A and B, supply main with "
                   "an isolable middle section, zone branches (inputs v1..v3, iso, xc, pump_b, "
                   "intact; outputs q1..q3, dq); stiff", _SHIP, ship.START, ship.hydraulics,
                   ship.START_VALUES))
for _i in ship.ZONES:
    register(ModelKind(f"ship.zone{_i}", f"load zone {_i}: temperature T (inputs q, Ts)", _SHIP,
                       ship.START, partial(ship.zone, _i), ship.START_VALUES))
register(ModelKind("ship.chiller", "chiller and water tank: supply temperature Ts (inputs "
                   "T1..T3, q1..q3)", _SHIP, ship.START, ship.chiller,
                   ship.START_VALUES))
register(ModelKind("ship.zone_control", "zone PI controllers: valve positions v1..v3 (inputs "
                   "T1..T3)", _SHIP, ship.START, ship.zone_control,
                   ship.START_VALUES))
register(ModelKind("ship.damage", "damage (discrete events): intact = 1, then 0 from t_hit, or "
                   "from a Weibull lifetime when hit_scale > 0", _SHIP, ship.START, ship.damage))
register(ModelKind("ship.isolation", "plant controller (discrete events): armed at t_arm, "
                   "isolates the section when pm falls to p_alarm (outputs iso, xc, pump_b)",
                   _SHIP, ship.START, ship.isolation))

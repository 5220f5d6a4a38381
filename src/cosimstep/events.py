"""Discrete-event sub-models: their own clock, piecewise-constant outputs (thesis 3.3.5, 4.3.5).

A :class:`DiscreteEventModel` does nothing between its events: its outputs hold. It tells the
master when its next event is (:meth:`~DiscreteEventModel.next_event`; that time may change
after each event), and at an event it reads its inputs and sets new outputs
(:meth:`~DiscreteEventModel.fire`). The run kernel (:mod:`cosimstep.kernel`) makes each such
model an actor at its next event time: the continuous sub-models step exactly up to that time,
the event fires with the inputs as they are there, and the continuous sub-models go on from the
new outputs with their input extrapolation restarted (a jump is not a trend).

Shipped kinds:

- :class:`FailureModel`: a component that fails after a lifetime drawn from an exponential or
  Weibull law (:mod:`scipy.stats`), seeded so that every run is reproducible, and is optionally
  repaired after a fixed repair time (then a new lifetime starts);
- :class:`Timetable`: outputs that change at listed times;
- :class:`ThresholdMonitor`: fires when a continuous input crosses a level, with hysteresis — a
  *state event* (:meth:`DiscreteEventModel.indicator`), located by rollback and bracketing.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from cosimstep.submodel import Capabilities, Port, SubModel

MAX_EVENTS = 100
"""Events at one time after which a run ends failed: sub-models that keep firing each other."""


@dataclass(frozen=True)
class Event:
    """One event of a run: when, which sub-model, what kind, and what it set."""

    t: float
    source: str
    kind: str
    payload: dict[str, float]
    late: bool = False
    """A state event fired at the end of the step that crossed it, not located (the
    controller keeps no saved state to go back to, e.g. a fixed step): up to a step late."""

    def to_dict(self) -> dict[str, Any]:
        return {"t": self.t, "source": self.source, "kind": self.kind, "payload": self.payload,
                "late": self.late}


class DiscreteEventModel(SubModel):
    """Base class of sub-models that change only at their own events.

    Subclasses give :attr:`outputs` (their ``start`` values are the outputs before the first
    event) and :attr:`inputs`, and implement :meth:`next_event` and :meth:`fire`; the state
    they keep between events must be in :meth:`_state` / :meth:`_set_state` if it is more
    than the outputs (so a rejected step can be re-run).
    """

    kind = "event"

    def __init__(self) -> None:
        self.capabilities = Capabilities(can_save_state=True)
        self._u = np.zeros(len(self.inputs))
        self._y = np.array([p.start or 0.0 for p in self.outputs], dtype=float)

    def next_event(self, t: float) -> float:
        """The time of the next event strictly after ``t`` (``math.inf``: none)."""
        raise NotImplementedError

    def fire(self, t: float, inputs: np.ndarray) -> tuple[np.ndarray, str]:
        """The event at ``t``: the new outputs and a short name of what happened."""
        raise NotImplementedError

    def indicator(self, inputs: np.ndarray) -> float | None:
        """A *state event*: a function of the inputs whose crossing of zero (from below) is the
        event; ``None`` for models whose events are all scheduled (:meth:`next_event`). The
        master locates the crossing inside a step (:mod:`cosimstep.loops`) and fires there."""
        return None

    def initialize(self, t0: float) -> None:
        self._y = np.array([p.start or 0.0 for p in self.outputs], dtype=float)

    def set_inputs(self, values: np.ndarray) -> None:
        self._u = np.array(values, dtype=float)

    def do_step(self, t: float, h: float) -> None:
        """Nothing: the outputs hold between events (the kernel lands every step on them)."""

    def get_outputs(self) -> np.ndarray:
        return self._y.copy()

    def apply(self, t: float, inputs: np.ndarray) -> str:
        """Fire the event at ``t`` with ``inputs``; the outputs change, the kind is returned."""
        self._u = np.array(inputs, dtype=float)
        y, kind = self.fire(t, self._u)
        self._y = np.array(y, dtype=float)
        return kind

    def _state(self) -> Any:
        return None

    def _set_state(self, state: Any) -> None:
        """Restore what :meth:`_state` returned."""

    def save_state(self) -> Any:
        return self._y.copy(), self._u.copy(), self._state()

    def restore_state(self, token: Any) -> None:
        y, u, state = token
        self._y, self._u = y.copy(), u.copy()
        self._set_state(state)


LAWS = ("exponential", "weibull")


class FailureModel(DiscreteEventModel):
    """A component's health: output ``ok`` is 1 while it works and 0 after it failed.

    Lifetimes are drawn from ``scipy.stats.expon(scale=scale)`` or
    ``scipy.stats.weibull_min(shape, scale=scale)`` with a generator seeded by ``seed``, so the
    same seed gives the same failure times in every run. With ``repair`` > 0 the component works
    again ``repair`` seconds after each failure and a new lifetime starts; without it, it fails
    once.
    """

    kind = "failure"

    def __init__(self, law: str = "weibull", scale: float = 1.0, shape: float = 1.0,
                 seed: int = 0, repair: float = 0.0) -> None:
        problems = failure_problems(law, scale, shape, repair)
        if problems:
            raise ValueError("; ".join(problems))
        self.law, self.scale, self.shape = law, float(scale), float(shape)
        self.seed, self.repair = int(seed), float(repair)
        self.outputs = (Port("ok", "1", 1.0, "1 while working, 0 after a failure"),)
        self.inputs = ()
        super().__init__()
        self._next = math.inf
        self._rng = np.random.default_rng(self.seed)

    def lifetime(self) -> float:
        """One lifetime from the law (advances the generator)."""
        from scipy import stats

        dist = stats.expon(scale=self.scale) if self.law == "exponential" \
            else stats.weibull_min(self.shape, scale=self.scale)
        return float(dist.rvs(random_state=self._rng))

    def initialize(self, t0: float) -> None:
        super().initialize(t0)
        self._rng = np.random.default_rng(self.seed)  # every run draws the same times
        self._next = t0 + self.lifetime()

    def next_event(self, t: float) -> float:
        return self._next

    def fire(self, t: float, inputs: np.ndarray) -> tuple[np.ndarray, str]:
        if self._y[0] > 0.5:  # it fails
            self._next = t + self.repair if self.repair > 0 else math.inf
            return np.array([0.0]), "failure"
        self._next = t + self.lifetime()  # repaired: a new life
        return np.array([1.0]), "repair"

    def _state(self) -> Any:
        return self._next, self._rng.bit_generator.state

    def _set_state(self, state: Any) -> None:
        self._next, rng_state = state
        self._rng.bit_generator.state = rng_state


def failure_problems(law: str, scale: float, shape: float, repair: float) -> list[str]:
    """What is wrong with a failure model's settings (empty: nothing)."""
    problems = []
    if law not in LAWS:
        problems.append(f"law '{law}' is not one of {', '.join(LAWS)}")
    for name, value in (("scale", scale), ("shape", shape)):
        if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
            problems.append(f"{name} must be a positive number, got {value!r}")
    if not (isinstance(repair, int | float) and math.isfinite(repair) and repair >= 0):
        problems.append(f"repair must be a number >= 0, got {repair!r}")
    return problems


class Timetable(DiscreteEventModel):
    """Outputs that change at listed times: ``times[i]`` sets the outputs to ``values[i]``.

    ``outputs`` names the outputs; ``start`` gives their values before the first time.
    """

    kind = "timetable"

    def __init__(self, times: Sequence[float], values: Sequence[Sequence[float]],
                 outputs: Sequence[str] = ("y",), start: Sequence[float] | None = None,
                 units: Sequence[str] | None = None) -> None:
        problems = timetable_problems(times, values, outputs, start)
        if problems:
            raise ValueError("; ".join(problems))
        units = list(units) if units is not None else ["1"] * len(outputs)
        start = list(start) if start is not None else [0.0] * len(outputs)
        self.times = [float(t) for t in times]
        self.values = [np.array(v, dtype=float) for v in values]
        self.outputs = tuple(Port(n, u, float(s)) for n, u, s in zip(outputs, units, start))
        self.inputs = ()
        super().__init__()
        self._i = 0

    def initialize(self, t0: float) -> None:
        super().initialize(t0)
        self._i = int(np.searchsorted(self.times, t0, side="right"))
        if self._i:  # a run starting after some entries starts from the latest of them
            self._y = self.values[self._i - 1].copy()

    def next_event(self, t: float) -> float:
        return self.times[self._i] if self._i < len(self.times) else math.inf

    def fire(self, t: float, inputs: np.ndarray) -> tuple[np.ndarray, str]:
        y = self.values[self._i]
        self._i += 1
        return y, "timetable"

    def _state(self) -> Any:
        return self._i

    def _set_state(self, state: Any) -> None:
        self._i = state


class ThresholdMonitor(DiscreteEventModel):
    """Output ``alarm`` turns 1 when input ``x`` rises to ``level`` and back to 0 when it falls
    below ``level - hysteresis``: a state event, located inside the step where it happens."""

    kind = "threshold"

    def __init__(self, level: float = 0.0, hysteresis: float = 0.0, unit: str = "1") -> None:
        problems = []
        for name, value in (("level", level), ("hysteresis", hysteresis)):
            if isinstance(value, bool) or not isinstance(value, int | float) \
                    or not math.isfinite(value):
                problems.append(f"{name} must be a finite number, got {value!r}")
        if not problems and hysteresis < 0:
            problems.append(f"hysteresis must be >= 0, got {hysteresis!r}")
        if problems:
            raise ValueError("; ".join(problems))
        self.level, self.hysteresis = float(level), float(hysteresis)
        self.inputs = (Port("x", unit, 0.0, "the watched signal"),)
        self.outputs = (Port("alarm", "1", 0.0, "1 after x reached level"),)
        super().__init__()

    def indicator(self, inputs: np.ndarray) -> float | None:
        x = float(inputs[0])
        return x - self.level if self._y[0] < 0.5 else (self.level - self.hysteresis) - x

    def next_event(self, t: float) -> float:
        return math.inf  # only state events

    def fire(self, t: float, inputs: np.ndarray) -> tuple[np.ndarray, str]:
        if self._y[0] < 0.5:
            return np.array([1.0]), "rise"
        return np.array([0.0]), "fall"


def timetable_problems(times: Sequence[float], values: Sequence[Sequence[float]],
                       outputs: Sequence[str], start: Sequence[float] | None) -> list[str]:
    """What is wrong with a timetable's settings (empty: nothing)."""
    problems = []
    if len(times) != len(values):
        problems.append(f"{len(times)} times but {len(values)} rows of values")
    if any(b <= a for a, b in itertools.pairwise(times)):
        problems.append("times must increase")
    if any(len(v) != len(outputs) for v in values):
        problems.append(f"every row of values needs {len(outputs)} value(s), one per output")
    if start is not None and len(start) != len(outputs):
        problems.append(f"start needs {len(outputs)} value(s), one per output")
    return problems


KINDS: dict[str, tuple[type[DiscreteEventModel], str]] = {
    "failure": (FailureModel, "component failure: output ok = 1, then 0 after a lifetime "
                "(law = 'exponential' | 'weibull', scale, shape, seed, repair)"),
    "timetable": (Timetable, "outputs that change at listed times (times, values, outputs, "
                  "start, units)"),
    "threshold": (ThresholdMonitor, "alarm = 1 when input x reaches level, 0 below level - "
                  "hysteresis (a state event)"),
}
"""The discrete-event kinds a system file names with ``type``."""


__all__ = ["KINDS", "MAX_EVENTS", "DiscreteEventModel", "Event", "FailureModel", "ThresholdMonitor",
           "Timetable"]

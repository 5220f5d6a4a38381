"""Controllers without error control: a fixed step and a seeded random step (thesis 4.2.2)."""

from __future__ import annotations

import math

import numpy as np

from cosimstep.controllers.base import Attempt, Controller, StepContext
from cosimstep.errors import is_number


class Fixed(Controller):
    """A constant communication step (thesis 4.2.2)."""

    name = "fixed"

    def __init__(self, step: float, locate_events: bool = False) -> None:
        """``locate_events``: save the sub-models' state before every step, so a state event
        inside a step is located by rollback (one step cut short at the crossing, then the
        fixed step again). Off by default: a fixed-step co-simulation usually fires an event at
        the next communication point, late by up to a step (the run counts them as late)."""
        if not (is_number(step) and step > 0 and math.isfinite(step)):
            raise ValueError(f"`step` must be a positive finite number, got {step!r}")
        self.step = float(step)
        self.locate_events = bool(locate_events)

    def initial_step(self, t0: float, t_end: float) -> float:
        return self.step

    def attempt(self, ctx: StepContext, t: float, h: float) -> Attempt:
        if self.locate_events:
            ctx.save()  # the loop rolls back to it if the step crossed a state event
        return Attempt(ctx.step(t, h), True, self.step)


class Random(Controller):
    """A seeded random step, uniform in ``[hmin, hmax]`` (robustness test of thesis 4.2.2.2)."""

    name = "random"

    def __init__(self, hmin: float = 0.001, hmax: float = 0.01, seed: int = 0) -> None:
        if not 0 < hmin <= hmax:
            raise ValueError(f"need 0 < `hmin` <= `hmax`, got {hmin}, {hmax}")
        self.hmin, self.hmax, self.seed = float(hmin), float(hmax), int(seed)
        self._rng = np.random.default_rng(seed)

    def _draw(self) -> float:
        return float(self._rng.uniform(self.hmin, self.hmax))

    def initial_step(self, t0: float, t_end: float) -> float:
        self._rng = np.random.default_rng(self.seed)
        return self._draw()

    def attempt(self, ctx: StepContext, t: float, h: float) -> Attempt:
        return Attempt(ctx.step(t, h), True, self._draw())

"""Estimators of the *coupling* error — the error a co-simulation master actually makes.

A sub-model integrates its own equations as accurately as it was built to; what the master adds
is that each receiver follows an *assumed* input trajectory (extrapolated from the history)
instead of the one its source really produces. These controllers measure that:

``defect`` (thesis 5.3, fig. 87: slope-free extrapolation predictor–corrector)
    After the step, compare each source's new value with the value the receivers assumed at
    ``t + h``: the defect ``d``. Over the step the input error grows like ``(s/h)^(p+1)``, so the
    receiver's state moves by about ``κ·h·|d|/(p+2)``. The gain ``κ`` (how strongly inputs drive
    the receivers — unknown for a black box) is *measured* now and then by re-running the step
    with the corrected inputs (interpolated through the new values) and comparing; between
    calibrations the estimate costs no calls, and a step inside the band is kept as computed.
``corrector``
    That comparison on every step: predictor (extrapolated inputs), corrector (interpolated),
    error = their difference; the corrector is kept. Two calls per sub-model per step.
``doubling`` (Richardson; as PyFMI's and MasterSim's masters do)
    One step of ``h`` against two of ``h/2``; the two half steps are kept. Three calls.
``embedded``
    The step with extrapolation order ``p`` against order ``p − 1``; error of the lower order, the
    order-``p`` result kept. Two calls.

All four share :class:`~cosimstep.controllers.base.StepPolicy`: mixed tolerance, PI control,
growth limits, ``hmin`` failure, ``hmax``, and by default a *global* error target (each step may
spend a share of ``tol`` proportional to its length).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from cosimstep.controllers.base import Attempt, Controller, StepContext, StepPolicy


def _effective_order(ctx: StepContext) -> int:
    """Extrapolation order the master can reach with the stored history."""
    return min(ctx.order, len(ctx.times) - 1)


class _PolicyController(Controller):
    needs_rollback = True

    def __init__(self, tol: float = 1e-4, h0: float | None = None, **policy: Any) -> None:
        self.policy = StepPolicy(tol=float(tol), **policy)
        self.h0 = h0

    def initial_step(self, t0: float, t_end: float) -> float:
        self.policy.start(t0, t_end)
        return min(self.h0 if self.h0 is not None else 1e-4 * (t_end - t0), self.policy.hmax)

    def _decide(self, ctx: StepContext, token: Any, t: float, h: float, y: np.ndarray,
                error: np.ndarray, values: np.ndarray, k: float, names: list[str]) -> Attempt:
        """Accept or reject (restoring the models to ``t``) and propose the next step."""
        ratio, i = self.policy.ratio(error, values, h)
        accepted = ratio <= 1.0
        k = (k if self.policy.global_error else k + 1) + self.policy.extra_power
        h_next = self.policy.next_step(h, ratio, k, accepted)
        if not accepted:
            ctx.restore(token)
            what = f"{names[i]}: error {abs(error[i]):.3g} is {ratio:.3g}× the allowed" \
                if names else f"error ratio {ratio:.3g}"
            self.policy.check(t, h, h_next, what)
        return Attempt(y, accepted, h_next, ratio)


class Defect(_PolicyController):
    """Fig. 87's band check on the input defect, with a measured input-to-output gain."""

    name = "defect"

    def __init__(self, tol: float = 1e-4, calibrate_every: int = 40, h0: float | None = None,
                 **policy: Any) -> None:
        super().__init__(tol, h0, **policy)
        if calibrate_every < 0:
            raise ValueError("`calibrate_every` must be >= 0 (0: calibrate once)")
        self.calibrate_every = int(calibrate_every)
        self._gain: float | None = None
        self._since = 0

    def initial_step(self, t0: float, t_end: float) -> float:
        self._gain, self._since = None, 0
        return super().initial_step(t0, t_end)

    def event(self, t: float) -> None:
        self._since = max(self._since, self.calibrate_every)  # dynamics changed: re-measure

    def attempt(self, ctx: StepContext, t: float, h: float) -> Attempt:
        q = _effective_order(ctx)
        token = ctx.save()
        y = ctx.step(t, h)
        d, mask = ctx.defect()
        cols = np.flatnonzero(mask)
        names = [ctx.names[j] for j in cols]
        source_error = h * np.abs(d[cols]) / (q + 2)
        calibrate = self._gain is None or (self.calibrate_every > 0
                                           and self._since >= self.calibrate_every)
        if calibrate and cols.size:
            ctx.restore(token)
            y_corrected = ctx.step(t, h, end=y)
            local = np.abs(y_corrected - y)  # the predictor's local coupling error
            scale = self.policy.scale(y)
            seen = float(np.max(source_error / scale[cols]))
            if seen > 1e-13:
                gain = float(np.max(local / scale)) / seen
                self._gain = gain if self._gain is None else max(gain, math.sqrt(gain * self._gain))
            self._since = 0
            attempt = self._decide(ctx, token, t, h, y_corrected, local, y_corrected, q + 1,
                                   ctx.names)
        else:
            error = (self._gain or 1.0) * source_error
            attempt = self._decide(ctx, token, t, h, y, error, y[cols], q + 1, names)
        if attempt.accepted:
            self._since += 1
        return attempt


class Corrector(_PolicyController):
    """Predictor (extrapolated inputs) and corrector (interpolated) on every step."""

    name = "corrector"

    def attempt(self, ctx: StepContext, t: float, h: float) -> Attempt:
        q = _effective_order(ctx)
        token = ctx.save()
        y = ctx.step(t, h)
        ctx.restore(token)
        y_corrected = ctx.step(t, h, end=y)
        return self._decide(ctx, token, t, h, y_corrected, y_corrected - y, y_corrected, q + 1,
                            ctx.names)


class Doubling(_PolicyController):
    """Step doubling: one step of ``h`` against two of ``h/2`` (Richardson)."""

    name = "doubling"

    def attempt(self, ctx: StepContext, t: float, h: float) -> Attempt:
        q = _effective_order(ctx)
        token = ctx.save()
        y_full = ctx.step(t, h)
        ctx.restore(token)
        y_half = ctx.step(t, 0.5 * h)
        y = ctx.step(t + 0.5 * h, 0.5 * h, extra=((t + 0.5 * h, y_half),))
        error = (y_full - y) / (2.0 ** (q + 1) - 1.0)
        return self._decide(ctx, token, t, h, y, error, y, q + 1, ctx.names)


class Embedded(_PolicyController):
    """The step with extrapolation order ``p`` against order ``p − 1``."""

    name = "embedded"

    def attempt(self, ctx: StepContext, t: float, h: float) -> Attempt:
        q = _effective_order(ctx)
        if ctx.order < 1:
            raise ValueError("controller 'embedded' compares extrapolation orders p and p - 1; "
                             "it needs extrapolation >= 1")
        token = ctx.save()
        y_low = ctx.step(t, h, order=max(q - 1, 0))
        ctx.restore(token)
        y = ctx.step(t, h)
        return self._decide(ctx, token, t, h, y, y - y_low, y, max(q, 1), ctx.names)

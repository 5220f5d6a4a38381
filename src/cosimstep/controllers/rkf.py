"""The thesis's RKF23 step control applied to output trajectories (4.2.4, 4.2.5, appendices A, B),
and RKF45 for the comparison of 4.3.6.

Written as the thesis wrote it, deliberately: it runs the step to ``T + ΔT/2`` and to ``T + ΔT``
from the same state, takes slopes of the exchanged variables at the current, half-step and
full-step points, and compares the second-order predictor ``x + ΔT·k2`` with the third-order
corrector ``x + ΔT·(k1 + 4k2 + k3)/6`` against ``tol·max(|x|, 1)``. The new step is
``min(hmax, 0.8·ΔT·(tol/err)^¼)``. The corrector itself is never used: a co-simulation keeps the
sub-models' own result (4.3.6).

What this estimates is how far the *output trajectory* is from being locally quadratic — not the
coupling error the master makes. That is why it can report tol 1e-6 and deliver 1e-3
(measured in docs/benchmarks.md); :mod:`cosimstep.controllers.coupling` estimates the latter.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from cosimstep.controllers.base import Attempt, Controller, StepContext
from cosimstep.controllers.slopes import SLOPES
from cosimstep.errors import StepSizeError

MODES = ("all", "reference")


class _Fehlberg(Controller):
    """Shared machinery: run to the stage times, estimate slopes, compare two combinations."""

    needs_rollback = True
    nodes: ClassVar[tuple[float, ...]]  # stage times as fractions of h (last must be 1)
    power: ClassVar[float]

    def __init__(self, tol: float = 1e-3, mode: str = "all", variable: str | None = None,
                 slopes: str = "cubic", hmax: float | None = None, hmin: float | None = None,
                 h0: float | None = None) -> None:
        if not tol > 0:
            raise ValueError(f"`tol` must be positive, got {tol}")
        if mode not in MODES:
            raise ValueError(f"`mode` must be one of {', '.join(MODES)}, got '{mode}'")
        if slopes not in (*SLOPES, "model"):
            raise ValueError(f"`slopes` must be one of {', '.join([*SLOPES, 'model'])}, "
                             f"got '{slopes}'")
        self.tol, self.mode, self.variable, self.slopes = float(tol), mode, variable, slopes
        self.hmax, self.hmin, self.h0 = hmax, hmin, h0
        self._hmax = self._hmin = 0.0

    def initial_step(self, t0: float, t_end: float) -> float:
        span = t_end - t0  # appendix B's defaults
        self._hmax = self.hmax if self.hmax is not None else span / 2.5
        self._hmin = self.hmin if self.hmin is not None else span / 1e12
        return self.h0 if self.h0 is not None else span / 200

    def _columns(self, ctx: StepContext) -> np.ndarray:
        if self.mode == "all":
            return np.arange(len(ctx.names))
        name = self.variable or ctx.names[0]
        if name not in ctx.names:
            raise ValueError(f"`variable` '{name}' is not an exchanged output; choose one of "
                             f"{', '.join(ctx.names)}")
        return np.array([ctx.names.index(name)])

    def _stages(self, ctx: StepContext, t: float, h: float,
                token: Any) -> tuple[list[np.ndarray], list[Any]]:
        """Values (and grey-box slopes) at ``t + c·h`` for every node, each run from ``t``."""
        values, grey = [], []
        for i, c in enumerate(self.nodes):
            if i > 0:
                ctx.restore(token)
            values.append(ctx.step(t, c * h))
            grey.append(ctx.derivatives() if self.slopes == "model" else None)
        return values, grey

    def attempt(self, ctx: StepContext, t: float, h: float) -> Attempt:
        cols = self._columns(ctx)
        k_first = ctx.derivatives() if self.slopes == "model" else None
        token = ctx.save()
        values, grey = self._stages(ctx, t, h, token)
        x = ctx.history[-1]
        if self.slopes == "model" and k_first is not None and all(g is not None for g in grey):
            k = np.vstack([k_first, *grey])  # slope at t, then at each node
            nodes = (0.0, *self.nodes)
            k = k[np.argsort(nodes)]
        else:
            k = self._fitted_slopes(ctx, t, h, values)
        delta = np.abs(self._difference(k, h))[cols]
        tau = self.tol * np.maximum(np.abs(x[cols]), 1.0)
        accepted = bool(np.all(delta <= tau))
        if not accepted:
            ctx.restore(token)
        delta = np.where(delta == 0.0, 1e-16, delta)
        h_each = 0.8 * h * (tau / delta) ** self.power
        h_next = min(self._hmax, float(h_each.min()))
        if h_next < self._hmin:
            raise StepSizeError(f"{self.name}: step size grew too small ({h_next:.3g} s < hmin "
                                f"{self._hmin:.3g} s) at t = {t:.9g}")
        ratio = float(np.max(delta / tau))
        return Attempt(values[-1], accepted, h_next, ratio)

    def _fitted_slopes(self, ctx: StepContext, t: float, h: float,
                       values: list[np.ndarray]) -> np.ndarray:
        # "model" where some sub-model gives no slopes: the thesis's fitted cubic (it ended the
        # run with KeyError 'model' at t = 0)
        fn = SLOPES["cubic" if self.slopes == "model" else self.slopes]
        past = 1 if self.slopes != "spline" else len(ctx.times) - 1
        past = min(past, len(ctx.times) - 1)
        order = np.argsort(self.nodes)
        times = [*ctx.times[len(ctx.times) - 1 - past:], *(t + self.nodes[i] * h for i in order)]
        rows = np.vstack([ctx.history[len(ctx.history) - 1 - past:],
                          *(values[i] for i in order)])
        at = [t, *(t + c * h for c in sorted(self.nodes))]
        return np.asarray(fn(times, rows, at))

    def _difference(self, k: np.ndarray, h: float) -> np.ndarray:
        raise NotImplementedError


class RKF23(_Fehlberg):
    """The thesis's RKF23 (appendices A, B): half and full step, cubic-fit slopes.

    Options: ``mode`` ``"all"`` (every exchanged variable, minimum step, 4.2.5) or
    ``"reference"`` (one ``variable``, 4.2.4.2); ``slopes`` ``"cubic"`` (thesis), ``"pchip"``,
    ``"spline"`` or ``"model"`` (grey box, 4.3.4); ``hmax``, ``hmin``, ``h0`` default to appendix
    B's span/2.5, span/1e12 and span/200. Costs two calls per sub-model per attempt (the thesis
    counts three: it also re-runs the accepted step, which the saved full-step run makes
    unnecessary).
    """

    name = "rkf23"
    nodes = (0.5, 1.0)
    power = 0.25

    def _difference(self, k: np.ndarray, h: float) -> np.ndarray:
        k1, k2, k3 = k[0], k[1], k[2]
        predictor = h * k2
        corrector = h * (k1 + 4.0 * k2 + k3) / 6.0
        return corrector - predictor


class RKF45(_Fehlberg):
    """Runge–Kutta–Fehlberg 4(5) on output trajectories (thesis 4.3.6, for comparison).

    Five runs per attempt to the Fehlberg stage times (1/4, 3/8, 12/13, 1/2 and 1 of the step),
    slopes from a fit through the previous, current and stage points, and the difference of the
    4th- and 5th-order combinations as error.
    """

    name = "rkf45"
    nodes = (0.25, 0.375, 12 / 13, 0.5, 1.0)
    power = 0.2
    # Fehlberg weights in stage order c = 0, 1/4, 3/8, 12/13, 1, 1/2
    _b4 = np.array([25 / 216, 0.0, 1408 / 2565, 2197 / 4104, -1 / 5, 0.0])
    _b5 = np.array([16 / 135, 0.0, 6656 / 12825, 28561 / 56430, -9 / 50, 2 / 55])

    def _fitted_slopes(self, ctx: StepContext, t: float, h: float,
                       values: list[np.ndarray]) -> np.ndarray:
        # a quintic through previous, current and the five stage points (least squares)
        times = [*ctx.times[-2:], *(t + c * h for c in self.nodes)]
        rows = np.vstack([ctx.history[-2:], *values])
        idx = np.argsort(times)
        tt = np.asarray(times)[idx]
        rr = rows[idx]
        degree = min(5, len(tt) - 1)
        coef = np.polyfit(tt - t, rr, degree)
        d = np.array([np.polyder(c) for c in np.atleast_2d(coef.T)]).T
        stage_t = [0.0, 0.25 * h, 0.375 * h, 12 / 13 * h, h, 0.5 * h]
        return np.stack([np.polyval(d[:, j], stage_t) for j in range(d.shape[1])], axis=1)

    def attempt(self, ctx: StepContext, t: float, h: float) -> Attempt:
        if self.slopes == "model":
            raise ValueError("rkf45 supports fitted slopes only")
        return super().attempt(ctx, t, h)

    def _difference(self, k: np.ndarray, h: float) -> np.ndarray:
        return h * ((self._b5 - self._b4) @ k)

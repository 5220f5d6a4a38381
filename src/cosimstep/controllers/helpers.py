"""The thesis's helpers around step control (4.2.8.1, 5.1, 5.3).

* :func:`fft_hmax` — a largest step from the spectrum of a sample run (fig. 88).
* :func:`fixed_step_from` — a fixed step from a sample adaptive run (4.2.8.1).
* :class:`Switching` — a fixed step while the dynamics are smooth, an adaptive controller when
  they are not (5.1).
* :class:`AdaptiveTolerance` — a tolerance that follows the curvature (5.3).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from cosimstep.controllers.base import Attempt, Controller, StepContext, StepPolicy
from cosimstep.controllers.curvature import second_derivative


@dataclass(frozen=True)
class Spectrum:
    """What :func:`fft_hmax` found."""

    hmax: float
    dominant_hz: float
    highest_hz: float
    frequencies: np.ndarray
    amplitudes: np.ndarray


def fft_hmax(times: np.ndarray, values: np.ndarray, points_per_period: float = 20.0,
             level: float = 0.05) -> Spectrum:
    """Largest sensible step from the spectrum of sampled trajectories (thesis fig. 88).

    Each column is resampled on a uniform grid, detrended and transformed (``scipy.fft.rfft``).
    The *highest* frequency whose amplitude reaches ``level`` × the largest peak sets
    ``hmax = 1 / (points_per_period · f)``: the thesis notes the Nyquist limit (2 points per
    period) is far too coarse for accuracy, so we ask for ``points_per_period`` points.
    """
    from scipy.fft import rfft, rfftfreq

    t = np.asarray(times, dtype=float)
    v = np.atleast_2d(np.asarray(values, dtype=float).T).T
    n = max(len(t), 64)
    grid = np.linspace(t[0], t[-1], n)
    amp_total = np.zeros(n // 2 + 1)
    for j in range(v.shape[1]):
        col = np.interp(grid, t, v[:, j])
        col = col - np.polyval(np.polyfit(grid, col, 1), grid)
        amp_total = np.maximum(amp_total, 2.0 * np.abs(rfft(col)) / n)
    freqs = rfftfreq(n, grid[1] - grid[0])
    amp_total[0] = 0.0
    peak = float(amp_total.max())
    if peak == 0.0:
        raise ValueError("the sample run is constant: no frequency to derive a step from")
    dominant = float(freqs[int(np.argmax(amp_total))])
    highest = float(freqs[np.flatnonzero(amp_total >= level * peak).max()])
    return Spectrum(1.0 / (points_per_period * highest), dominant, highest, freqs, amp_total)


def fixed_step_from(step_sizes: np.ndarray, skip: int = 20, quantile: float = 0.0) -> float:
    """A fixed step from a sample adaptive run (thesis 4.2.8.1: the lowest step it used).

    ``skip`` drops the start-up steps (a controller starts small on purpose); the last step is
    dropped too (shortened to land on the end). ``quantile`` > 0 takes a low quantile instead of
    the minimum, which ignores the few tiny steps right after a discontinuity.
    """
    steps = np.asarray(step_sizes, dtype=float)[skip:-1]
    if steps.size == 0:
        raise ValueError("the sample run has too few steps")
    return float(np.quantile(steps, quantile)) if quantile > 0 else float(steps.min())


class _Wrapping(Controller):
    """A controller that hands the steps to another it builds (``switching``,
    ``adaptive-tol``): its record holds the wrapped one's settings, taken when it is built —
    before a run moves them (``adaptive-tol`` its tolerance, step by step) — so runs that
    differ only in the wrapped controller's options are told apart."""

    def _wrap(self, name: str, h0: float | None, tol: float, options: dict[str, Any]) -> None:
        from cosimstep.controllers import make_controller

        self._inner = make_controller(name, h0, tol, **options)
        self._inner_settings = self._inner.describe()

    def describe(self) -> dict[str, Any]:
        return {**super().describe(), "inner_settings": self._inner_settings}


class Switching(_Wrapping):
    """A fixed step while the dynamics are smooth, an adaptive controller otherwise (5.1).

    Starts adaptive. After ``calm`` accepted adaptive steps without a rejection by more than 2×
    the allowed error (the ratio scatters around the step control's target, so an occasional
    rejection just above 1 is no change of the dynamics) it switches to a fixed step
    (``step``, or the adaptive controller's current step). On the fixed
    step it watches the cost-free input defect (fig. 87) against the same tolerance; a step
    outside the band is rejected and the adaptive controller takes over from it.
    """

    name = "switching"
    needs_rollback = True
    run_state = frozenset({"error_estimate", "switches"})

    def __init__(self, tol: float = 1e-4, adaptive: str = "pc", step: float | None = None,
                 calm: int = 20, h0: float | None = None, **options: Any) -> None:
        self.tol, self.adaptive, self.step, self.calm = float(tol), adaptive, step, int(calm)
        self._wrap(adaptive, h0, tol, options)
        self._band = StepPolicy(tol=float(tol))
        self._fixed: float | None = None
        self._recent: list[float] = []
        self.switches = 0

    def initial_step(self, t0: float, t_end: float) -> float:
        self._band.start(t0, t_end)
        self._fixed, self._recent, self.switches = None, [], 0
        return self._inner.initial_step(t0, t_end)

    def event(self, t: float) -> float | None:
        restart = self._inner.event(t)
        return restart if self._fixed is None else None  # a fixed stretch keeps its step

    def attempt(self, ctx: StepContext, t: float, h: float) -> Attempt:
        if self._fixed is None:
            a = self._inner.attempt(ctx, t, h)
            if a.accepted:
                self._recent.append(h)
                if len(self._recent) >= self.calm:
                    # the step the adaptive controller has settled on, not the smallest calm
                    # one: the first calm steps are often the start-up ramp (measured: the
                    # smallest made the fixed phase 30× too expensive on the toggled pendulum)
                    self._fixed = self.step or min(h, a.h_next)
                    self.switches += 1
                    return Attempt(a.y, True, self._fixed, a.error)
            elif a.error is None or a.error > 2.0:  # not the scatter around the target
                self._recent = []
            return a
        token = ctx.save()
        y = ctx.step(t, h)
        d, mask = ctx.defect()
        q = min(ctx.order, len(ctx.times) - 1)
        ratio, _ = self._band.ratio(h * np.abs(d[mask]) / (q + 2), y[mask], h)
        if ratio <= 1.0:
            return Attempt(y, True, self._fixed, ratio)
        ctx.restore(token)  # dynamics changed: hand over to the adaptive controller
        self._fixed, self._recent = None, []
        self.switches += 1
        return Attempt(y, False, h * max(0.2, 0.9 * ratio ** (-1.0 / (q + 1))), ratio)


class AdaptiveTolerance(_Wrapping):
    """A tolerance that follows the curvature (thesis 5.1/5.3).

    The tolerance handed to an error-controlled controller is scaled by ``1/ρ`` limited to
    ``[1/relax, relax]``, where ρ is the current largest |second derivative| of the exchanged
    variables relative to its running mean: relaxed where the trajectories are straight,
    tightened where they bend.
    """

    name = "adaptive-tol"
    needs_rollback = True

    def __init__(self, tol: float = 1e-4, inner: str = "pc", relax: float = 10.0,
                 h0: float | None = None, **options: Any) -> None:
        if not relax >= 1:
            raise ValueError("`relax` must be >= 1")
        self.tol, self.inner, self.relax = float(tol), inner, float(relax)
        self._wrap(inner, h0, tol, options)
        self._mean: np.ndarray | None = None
        self._n = 0

    def initial_step(self, t0: float, t_end: float) -> float:
        self._mean, self._n = None, 0
        self._set_tol(self.tol)  # a reused controller: not the last run's last tolerance
        return self._inner.initial_step(t0, t_end)

    def event(self, t: float) -> float | None:
        return self._inner.event(t)

    def _set_tol(self, tol: float) -> None:
        policy = getattr(self._inner, "policy", None)
        if policy is not None:
            policy.tol = tol
        else:
            self._inner.tol = tol  # type: ignore[attr-defined]

    def attempt(self, ctx: StepContext, t: float, h: float) -> Attempt:
        if len(ctx.times) >= 3:
            c = np.abs(second_derivative(ctx.times, ctx.history))
            self._n += 1
            self._mean = c if self._mean is None else self._mean + (c - self._mean) / self._n
            rho = float(np.max(c / np.maximum(self._mean, 1e-300)))
            self._set_tol(self.tol * min(self.relax, max(1.0 / self.relax, 1.0 / max(rho,
                                                                                    1e-300))))
        return self._inner.attempt(ctx, t, h)

"""The magnitude an error will be measured at: the low points an output keeps returning to.

The mixed norm ``|e| / (atol + rtol·|y|)`` measures an error by the output's size *where the
error is met*, and an error made at one step is met at every later point while it persists
(the error memory, or the rest of the run). Scaling each step's share of the tolerance by
``|y|`` at that step assumes the output stays that large. An oscillation that passes through
zero breaks that: problem 6 at λ = 20 oscillates with amplitude 40, its steps near the peaks
were allowed 41 × the absolute error of those near zero, and that error was then measured at
the zero crossing half a period later — multi-rate at 10–26 × tol, status ok
(docs/concepts.md, "Oscillations through zero").

The smallest value the output will reach while the error persists is unknown in advance. What
is known is where it has already returned to: a *local minimum of |y|* — a fall followed by a
rise — is a low point of a recurrent motion (a zero crossing, the trough of a sign-definite
oscillation). Those minima within the error's window (the measured memory, else the run so
far) stand in for the future's, and the scale is taken at the smaller of ``|y|`` now and the
lowest of them. A monotone output (a position that grows, a state settling on a value) has no
such minimum, so its scale stays its own: using the window's plain minimum instead would
measure a position that grows from 0 to 100 by its starting value all run, 100× tighter than
the norm asks where the error is met.

Cost: a few array operations per accepted step; the minima are kept in at most
:data:`BUCKETS` time buckets, so a noisy output that turns on every step costs no more.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

BUCKETS = 16
"""The window is kept as this many buckets of minima; the oldest is dropped once it lies
wholly before the window, so the window's far edge is resolved to 1/16 of its length."""


class RecurringLow:
    """Per output, the lowest ``|y|`` that the output fell to and rose from, over a window."""

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self._last: np.ndarray | None = None  # |y| at the last observation
        self._falling: np.ndarray | None = None  # whether |y| fell into the last observation
        # (time of the first and the last minimum in it, the minima)
        self._buckets: deque[tuple[float, float, np.ndarray]] = deque()
        self._low: np.ndarray | None = None  # minimum over the buckets (cached)
        self._time = -math.inf  # of the last observation

    def observe(self, t: float, y: np.ndarray, window: float) -> None:
        """Record the accepted value ``y`` at ``t``; ``window`` is how far back minima count."""
        a = np.abs(y)
        if t < self._time:
            self._rewind()
        self._time = t
        last, falling = self._last, self._falling
        if last is None or falling is None or last.shape != a.shape:
            if last is not None and last.shape != a.shape:
                self.reset()
            self._last, self._falling = a, np.zeros(a.shape, dtype=bool)
            return
        rose = a > last
        turned = falling & rose
        self._falling = (a < last) | (falling & ~rose)  # kept where |y| stood still
        self._last = a
        changed = self._forget(t, window)
        if np.count_nonzero(turned):
            minima = np.where(turned, last, np.inf)
            width = window / BUCKETS
            if self._buckets and t - self._buckets[-1][0] < width:
                first, newest, held = self._buckets[-1]
                self._buckets[-1] = (first, max(newest, t), np.minimum(held, minima))
            else:
                self._buckets.append((t, t, minima))
            changed = True
        if changed:
            self._low = None if not self._buckets else \
                np.min(np.stack([m for _, _, m in self._buckets]), axis=0)

    def _rewind(self) -> None:
        """Time went back (a rollback, a re-run, an undone step): the trend starts again from
        the next value. Comparing it with the dropped step's end made a rising output re-run
        from an earlier point look like a fall and a rise: a low point it never had. The low
        points already recorded stay: they are those of a trajectory close to the re-run one
        (dropping them with every multi-rate rollback lost the zero crossings of problem 6 at
        λ = 20: 13–15 × tol at tol 1e-5 and 1e-6, against 3.9–6.9 kept)."""
        self._last = self._falling = None

    def _forget(self, t: float, window: float) -> bool:
        """Drop the buckets whose latest minimum lies before ``t − window``."""
        dropped = False
        while self._buckets and self._buckets[0][1] < t - window:
            self._buckets.popleft()
            dropped = True
        return dropped

    def level(self, y: np.ndarray) -> np.ndarray:
        """``|y|``, lowered to the recurring low points where the output has them."""
        a = np.abs(y)
        low = self._low
        if low is None or low.shape != a.shape:
            return a
        return np.minimum(a, low)

"""Second-derivative thresholds mapped to steps (thesis 4.2.3, Nairouz & Hoepfer 2009).

The curvature of each exchanged variable is taken from the previous, the current and the new
point (one step into the future, as the thesis does), and the next step is read from a table:
curvature below ``thresholds[0]`` → ``steps[0]``, between ``thresholds[0]`` and ``[1]`` →
``steps[1]``, and so on. There is no error estimate: the table is "gut feeling", as the thesis
says, and must be tuned per model. It is here as the baseline the thesis started from.
"""

from __future__ import annotations

import bisect
from collections.abc import Sequence

import numpy as np

from cosimstep.controllers.base import Attempt, Controller, StepContext


def second_derivative(times: Sequence[float], rows: np.ndarray) -> np.ndarray:
    """Second derivative at the middle of three (unequally spaced) points, per column."""
    t0, t1, t2 = times[-3], times[-2], times[-1]
    h1, h2 = t1 - t0, t2 - t1
    return 2.0 * ((rows[-1] - rows[-2]) / h2 - (rows[-2] - rows[-3]) / h1) / (h1 + h2)


class Curvature(Controller):
    """Step from a curvature table; always accepts."""

    name = "curvature"

    def __init__(self, thresholds: Sequence[float] = (0.5, 2.0, 8.0),
                 steps: Sequence[float] = (0.02, 0.01, 0.005, 0.0025),
                 variable: str | None = None, h0: float | None = None) -> None:
        if len(steps) != len(thresholds) + 1:
            raise ValueError("need one more `steps` than `thresholds`")
        if list(thresholds) != sorted(thresholds) or any(s <= 0 for s in steps):
            raise ValueError("`thresholds` must increase and `steps` be positive")
        self.thresholds = [float(x) for x in thresholds]
        self.steps = [float(x) for x in steps]
        self.variable = variable
        self.h0 = h0

    def initial_step(self, t0: float, t_end: float) -> float:
        return self.h0 if self.h0 is not None else self.steps[-1]

    def attempt(self, ctx: StepContext, t: float, h: float) -> Attempt:
        y = ctx.step(t, h)
        if len(ctx.times) < 2:
            return Attempt(y, True, h)
        rows = np.vstack([ctx.history[-2:], y])
        c = np.abs(second_derivative([*ctx.times[-2:], t + h], rows))
        if self.variable is not None:
            c = c[[ctx.names.index(self.variable)]]
        return Attempt(y, True, self.steps[bisect.bisect_right(self.thresholds, float(c.max()))])

"""The first run of a repeated pair, measured against the repeat (:mod:`cosimstep.tighten`).

A run repeated at a tighter tolerance leaves two solutions of the same system. The repeat is
meant to be the more accurate one (its tolerance is at least twice tighter) and nearly always
is, so the largest difference between the two, in the norm ``tol`` bounds, is about the first
run's error, measured without a reference: 0.42–2.6 × that error (median 0.89) on the suite's
25 repeated runs (docs/concepts.md, "The first run measured by its repeat"). That is what the
summed estimate lacks — each local estimate is right to a factor of a few, but how the errors
add up differs from system to system — and the pair holds it for this system:
:func:`~cosimstep.tighten.calibrated` scales the repeat's estimate by it.

Where: at each of the first run's own points (every sub-model's, :class:`ModelStats`), against
the repeat's points of the same sub-model. The repeat is read between its points by a cubic
through four of them; of the five stencils of four consecutive points that hold or touch the
interval around the time (one centred, two shifted, two wholly on one side of it), the one
closest to the first run's value counts. On smooth stretches all five agree with the repeat's
trajectory to far below the first run's error; at a jump inside the repeat's interval (an
unannounced road step located to within that interval) the stencils that cross it are off by
the jump, and one of the one-sided ones is not. (The re-run estimate, :mod:`cosimstep.estimate`,
reads its finer run by one spline per stretch between *announced* events; a spline through an
unannounced jump rings over its neighbours: the unannounced quarter car at 1e-3 measured 1,230
× its first run's error so, 0.95 × with the stencils.) The price: a jump that the first run
places within a few of the repeat's points of the repeat's own is not counted — an event's
timing error shows only beyond that. Only real outputs that are not piecewise constant are
compared (a switch that moved a step later is no error in the norm).
"""

from __future__ import annotations

from collections.abc import Callable, Collection

import numpy as np

from cosimstep.controllers.base import StepPolicy
from cosimstep.result import SimulationResult
from cosimstep.system import System

SHIFTS = (-3, -2, -1, 0, 1)
"""Where the four points of a stencil start, relative to the repeat's point at or before the
time read: wholly before it (−3), holding its interval (−2, −1, 0), wholly after it (1)."""


def first_error(first: SimulationResult, repeat: SimulationResult, system: System,
                policy: StepPolicy) -> float | None:
    """:func:`difference` in the norm the step policy's ``tol`` bounds (``|e| / (1 + |y|)`` for
    ``atol = rtol = tol``), over the real outputs of ``system`` that are not piecewise
    constant; ``policy``: the first run's."""
    skip = {f"{name}.{port.name}" for name, model in system.models.items()
            for port in model.outputs if port.discrete or port.kind != "real"}
    tol = policy.tol
    return difference(first, repeat, lambda y: policy.scale(y) / tol, skip)


def difference(first: SimulationResult, repeat: SimulationResult,
               scale: Callable[[np.ndarray], np.ndarray], skip: Collection[str] = ()
               ) -> float | None:
    """The largest ``|y_first − y_repeat| / scale(y_repeat)`` over every sub-model's own
    points and its compared outputs (see the module docstring). ``None`` where the two runs
    cannot be compared: a sub-model missing from the repeat, with other columns, or with
    fewer than four points there; a first run whose own points begin after its result's (a
    resumed run keeps only the points since its checkpoint per sub-model: its largest
    difference could lie before them); no output compared at all. ``skip``: output names
    ("model.port") left out."""
    worst, compared = 0.0, False
    for model, own in first.models.items():
        other = repeat.models.get(model)
        names = [n for n in first.names if n.partition(".")[0] == model]
        cols = [c for c, n in enumerate(names) if n not in skip]
        if not cols or own.times.size == 0:
            continue
        if other is None or other.times.size < 4 or other.values.shape[1] != len(names) \
                or own.times[0] > first.times[0]:
            return None
        inside = (own.times >= other.times[0]) & (own.times <= other.times[-1])
        mine = own.values[inside][:, cols]
        near = _nearest(other.times, other.values[:, cols], own.times[inside], mine)
        gap = np.abs(mine - near) / scale(near)
        if np.isfinite(gap).any():
            worst, compared = max(worst, float(np.nanmax(gap))), True
    return worst if compared else None


def _nearest(times: np.ndarray, values: np.ndarray, at: np.ndarray,
             target: np.ndarray) -> np.ndarray:
    """``values`` (rows at ``times``) read at ``at`` by the stencil of :data:`SHIFTS` whose
    cubic comes closest to ``target`` there, per column."""
    n = times.size
    left = np.clip(np.searchsorted(times, at, side="right") - 1, 0, n - 2)
    best = np.full(target.shape, np.nan)
    for shift in SHIFTS:
        start = left + shift
        valid = (start >= 0) & (start + 3 <= n - 1)
        if not valid.any():
            continue
        rows = start[valid, None] + np.arange(4)  # (points, 4): the stencil's indices
        nodes = times[rows]
        x = at[valid, None]
        weights = np.ones_like(nodes)
        with np.errstate(divide="ignore", invalid="ignore"):
            for i in range(4):
                for m in range(4):
                    if m != i:
                        weights[:, i] *= (x[:, 0] - nodes[:, m]) / (nodes[:, i] - nodes[:, m])
            value = np.einsum("pi,pic->pc", weights, values[rows])
        # two of a stencil's points at one time (neither master stores such today) divide
        # by zero: such a stencil is passed over
        value[~np.isfinite(value)] = np.nan
        closer = np.isnan(best[valid]) | (np.abs(value - target[valid])
                                          < np.abs(best[valid] - target[valid]))
        chosen = best[valid]
        chosen[closer] = value[closer]
        best[valid] = chosen
    return best

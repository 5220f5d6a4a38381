"""The global error a run delivered, estimated without a reference, by a second run.

A controller whose delivered error is proportional to its tolerance (what the error control is
built for, and measured on the suite: the delivered error changes by 7–14× per decade of
``tol``) gives, run again at ``FACTOR × tol``, an error about ``FACTOR`` times larger. The two
runs then differ by about ``(FACTOR − 1)`` times the first run's error, whatever made it —
local errors that accumulate, decay, cancel or grow — so their difference divided by
``FACTOR − 1`` estimates it. This is the classical global error estimate by reintegration at a
looser tolerance; the looser run costs about half the calls of the first at ``FACTOR = 10``
(calls go like ``tol^(-1/4)`` for our controllers).

The difference is taken at the looser run's own points, where it has values of its own; the
first run, denser, is read there through a cubic spline of its own points between time events.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

import numpy as np
from scipy.interpolate import make_interp_spline

if TYPE_CHECKING:
    from cosimstep.simulate import SimulationResult

FACTOR = 10.0  # the looser run's tolerance / the run's own


def _read(times: np.ndarray, values: np.ndarray, at: np.ndarray,
          events: Sequence[float]) -> np.ndarray:
    """``values`` (rows at ``times``) at ``at``: a cubic spline per segment between events."""
    out = np.full((len(at), values.shape[1]), np.nan)
    edges = [-np.inf, *events, np.inf]
    for lo, hi in itertools.pairwise(edges):
        inside = (times >= lo) & (times <= hi)
        want = (at >= lo) & (at <= hi)
        t, v = times[inside], values[inside]
        if not want.any() or len(t) == 0:
            continue
        if len(t) == 1:
            out[want] = v[0]
            continue
        t, first = np.unique(t, return_index=True)  # an event point may appear on both sides
        spline = make_interp_spline(t, v[first], k=min(3, len(t) - 1))
        out[want] = spline(np.clip(at[want], t[0], t[-1]))
    return out


def rerun_estimate(run: SimulationResult, looser: SimulationResult,
                   scale: Callable[[np.ndarray], np.ndarray],
                   events: Sequence[float] = ()) -> float:
    """Estimate ``run``'s global error from ``looser`` (the same system at ``FACTOR × tol``).

    ``scale(y)`` is the tolerance's norm per value divided by ``tol`` (``1 + |y|`` for
    ``atol = rtol = tol``). Compared per sub-model at the looser run's own points, up to the
    time both runs reached.
    """
    worst = 0.0
    t_end = min(run.t_end, looser.t_end)
    for name, coarse in looser.models.items():
        fine = run.models[name]
        keep = coarse.times <= t_end * (1 + 1e-12)
        if not keep.any() or len(fine.times) == 0:
            continue
        at = coarse.times[keep]
        ev = [e for e in events if fine.times[0] < e < fine.times[-1]]
        reference = _read(fine.times, fine.values, at, ev)
        diff = np.abs(coarse.values[keep] - reference) / scale(reference)
        if diff.size:
            worst = max(worst, float(np.nanmax(diff)))
    return worst / (FACTOR - 1.0)


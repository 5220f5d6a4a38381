"""The multi-rate master reads a partner's trajectory with the Taylor fit and its evaluation
written out for one signal (issue 15, "same work, faster"): the floats must be those of
``taylor_coefficients`` and ``evaluate_small``, the form it replaced, written out here as the
reference. A change of rounding in a trajectory moves every step after it."""

from __future__ import annotations

import numpy as np

import cosimstep as cs
import cosimstep.race_memory as race_memory
from cosimstep import suite
from cosimstep.extrapolation import evaluate_small, taylor_coefficients
from cosimstep.multirate import STENCIL, _segment_range


def _reference(race, j: int, at: np.ndarray) -> tuple[np.ndarray, bool]:
    """``Multirate._trajectory``'s single-stencil branch as it was written before."""
    tr = race.tracks[race.owner[j]]
    col = j - race.system.output_slices[tr.index].start
    times = tr.times
    first, end = _segment_range(times, -np.inf, np.inf)
    beyond = bool(at[-1] > times[-1] + 1e-12 * max(1.0, abs(times[-1])))
    if beyond:
        start, last = max(first, len(times) - (race.order + 1)), len(times)
    else:
        last = min(end, int(np.searchsorted(times, float(at[-1]))) + STENCIL // 2)
        start = max(first, last - STENCIL)
        last = min(end, start + STENCIL)
    vals = np.array([r[col] for r in tr.rows[start:last]])
    coef = taylor_coefficients(times[start:last], vals[:, None], float(at[0]), last - start - 1)
    return evaluate_small(coef, (at - float(at[0])).tolist())[:, 0], beyond


def test_a_partner_trajectory_is_bit_for_bit_the_taylor_form(monkeypatch) -> None:
    made = []
    init = race_memory.RaceMemory.__init__

    def spy(self, race, members, every=race_memory.PROBE_EVERY):
        init(self, race, members, every)
        made.append(race)

    monkeypatch.setattr(race_memory.RaceMemory, "__init__", spy)
    problem = suite.get("pendulum_mixed")
    system, _ = problem.build()
    result = cs.simulate(system, 1.0, cs.make_controller("pc", None, 1e-4),
                         cs.MasterOptions("multirate", 2))
    assert result.success
    race = made[0]
    rng = np.random.default_rng(5)
    compared = 0
    for _ in range(300):
        j = int(rng.integers(race.system.n_outputs))
        times = race.tracks[race.owner[j]].times
        i = int(rng.integers(4, len(times) - 1))
        h = (times[i + 1] - times[i]) * float(rng.uniform(0.05, 0.9))
        at = times[i] + np.array([0.0, 0.25, 0.5, 0.75, 1.0]) * h
        if rng.random() < 0.2:  # beyond the owner's newest point: extrapolated
            at = times[-1] + np.array([0.1, 0.4, 0.8]) * (times[-1] - times[-2])
        got, beyond = race._trajectory(j, at)
        expected, expected_beyond = _reference(race, j, at)
        assert beyond == expected_beyond
        assert [v.hex() for v in got.tolist()] == [v.hex() for v in expected.tolist()]
        compared += 1
    assert compared == 300

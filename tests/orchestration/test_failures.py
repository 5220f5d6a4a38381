"""A failing sub-model ends the run cleanly, names itself and the time, and loses nothing."""

from __future__ import annotations

import time

import numpy as np
import pytest

from cosimstep import Fixed, MasterOptions, SubModelError, System, read_run, simulate
from helpers import Clock, Integrator


def _system(mode: str) -> System:
    s = System()
    s.add("clock", Clock(fail_at=0.5, mode=mode)).add("sink", Integrator(unit="s"))
    s.connect("clock.time", "sink.u")
    return s


@pytest.mark.parametrize("mode, words", [("raise", "RuntimeError: solver diverged"),
                                         ("nan", "non-finite output(s) clock.time")])
def test_failure_keeps_every_step_before_it(tmp_path, mode, words):
    db = tmp_path / "run.db"
    r = simulate(_system(mode), 1.0, Fixed(0.1), store=db)
    assert r.status == "failed"
    assert "'clock'" in r.message and "t = 0.5" in r.message and words in r.message
    assert r.t_end == pytest.approx(0.5)
    assert r.steps_accepted == 5 and len(r.times) == 6  # t = 0 ... 0.5
    stored = read_run(db)
    assert stored.status == "failed" and stored.message == r.message
    assert np.array_equal(stored.times, r.times)
    assert np.array_equal(stored.values, r.values)
    assert stored.summary["calls"] == {"clock": 6, "sink": 6 if mode == "nan" else 5}


def test_failure_can_raise():
    with pytest.raises(SubModelError) as info:
        simulate(_system("raise"), 1.0, Fixed(0.1), raise_on_failure=True)
    assert info.value.model == "clock"
    assert info.value.t == pytest.approx(0.5)


def test_hanging_submodel_times_out():
    start = time.perf_counter()
    r = simulate(_system("hang"), 1.0, Fixed(0.1), MasterOptions(call_timeout=0.5))
    assert time.perf_counter() - start < 5.0
    assert r.status == "failed" and "no answer within 0.5 s" in r.message
    assert r.steps_accepted == 5

"""Discrete-event sub-models on the run kernel: steps land on their events, the outputs jump
there, extrapolation restarts, and failure times follow their law."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

import cosimstep as cs
from cosimstep.events import FailureModel, ThresholdMonitor, Timetable
from helpers import Integrator

CONTROLLERS = {
    "fixed": lambda: cs.Fixed(0.1),
    "pc": lambda: cs.make_controller("pc", None, 1e-6),
}


def _timetable_system() -> cs.System:
    # u = 0 until 0.25, 1 until 0.7, then 3: x = ∫u is 1.35 at t = 1, exactly, if the steps
    # land on both events and nothing is extrapolated across them (0.25, 0.7 are off the grid)
    system = cs.System()
    system.add("tt", Timetable([0.25, 0.7], [[1.0], [3.0]], outputs=["u"]))
    system.add("int", Integrator())
    system.connect("tt.u", "int.u")
    return system


@pytest.mark.parametrize("master", ["gauss-seidel", "jacobi"])
@pytest.mark.parametrize("controller", sorted(CONTROLLERS))
def test_steps_land_on_the_events_and_nothing_is_extrapolated_across(controller, master):
    result = cs.simulate(_timetable_system(), 1.0, CONTROLLERS[controller](),
                         cs.MasterOptions(master, 2))
    assert result.success, result.message
    assert abs(result["int.x"][-1] - 1.35) < 1e-12
    assert 0.25 in result.times and 0.7 in result.times
    assert [(e.t, e.source, e.kind, e.payload) for e in result.events] == [
        (0.25, "tt", "timetable", {"u": 1.0}), (0.7, "tt", "timetable", {"u": 3.0})]
    summary = result.summary()["events"]
    assert summary[1] == {"t": 0.7, "source": "tt", "kind": "timetable", "payload": {"u": 3.0},
                          "late": False}


def test_fixed_step_call_count_with_events():
    # the step ends on each event and the grid goes on from there in steps of 0.1:
    # 0.1, 0.2, 0.25 | 0.35 ... 0.65, 0.7 | 0.8, 0.9, 1.0 -> 3 + 5 + 3 = 11 calls per sub-model
    result = cs.simulate(_timetable_system(), 1.0, cs.Fixed(0.1), cs.MasterOptions("jacobi", 0))
    assert result.calls == {"tt": 11, "int": 11}
    assert np.allclose(result.times, [0, 0.1, 0.2, 0.25, 0.35, 0.45, 0.55, 0.65, 0.7, 0.8, 0.9,
                                      1.0], rtol=0, atol=1e-12)


def test_a_failure_stops_what_it_feeds():
    # a pump that delivers 1 while it works: the volume pumped is the failure time
    failure = FailureModel("weibull", scale=2.0, shape=1.5, seed=7)
    system = cs.System()
    system.add("pump", failure)
    system.add("tank", Integrator())
    system.connect("pump.ok", "tank.u")
    result = cs.simulate(system, 10.0, cs.make_controller("pc", None, 1e-8),
                         cs.MasterOptions("gauss-seidel", 2))
    assert result.success, result.message
    (event,) = result.events
    assert event.kind == "failure" and event.payload == {"ok": 0.0}
    assert 0.0 < event.t < 10.0
    assert abs(result["tank.x"][-1] - event.t) < 1e-9


def test_the_same_seed_gives_the_same_failures_and_repairs_alternate():
    def run(seed: int) -> list[tuple[float, str]]:
        system = cs.System()
        system.add("c", FailureModel("exponential", scale=1.0, seed=seed, repair=0.5))
        system.add("int", Integrator())
        system.connect("c.ok", "int.u")
        result = cs.simulate(system, 10.0, cs.Fixed(0.05))
        return [(e.t, e.kind) for e in result.events]

    first = run(3)
    assert first == run(3) and first != run(4)
    kinds = [k for _, k in first]
    assert len(kinds) >= 4 and kinds[::2] == ["failure"] * len(kinds[::2]) \
        and kinds[1::2] == ["repair"] * len(kinds[1::2])
    times = [t for t, _ in first]
    assert all(abs((b - a) - 0.5) < 1e-12 for a, b in zip(times[::2], times[1::2]))


@pytest.mark.parametrize(("law", "shape"), [("weibull", 1.7), ("exponential", 1.0)])
def test_1000_seeded_lifetimes_follow_the_law(law, shape):
    times = []
    for seed in range(1000):
        model = FailureModel(law, scale=3.0, shape=shape, seed=seed)
        model.initialize(0.0)
        times.append(model.next_event(0.0))
    dist = stats.weibull_min(shape, scale=3.0) if law == "weibull" else stats.expon(scale=3.0)
    assert stats.kstest(times, dist.cdf).pvalue > 0.01


def test_bad_settings_are_listed_at_once():
    with pytest.raises(ValueError) as info:
        FailureModel("gamma", scale=0.0, shape=-1.0, repair=math.nan)
    message = str(info.value)
    for part in ("law 'gamma'", "scale must be a positive number", "shape must be",
                 "repair must be"):
        assert part in message
    with pytest.raises(ValueError, match="times must increase"):
        Timetable([1.0, 0.5], [[1.0], [2.0]])


@pytest.mark.parametrize("tol", [1e-4, 1e-8])
def test_multirate_lands_every_sub_model_on_the_events(tol):
    result = cs.simulate(_timetable_system(), 1.0, cs.make_controller("pc", None, tol),
                         cs.MasterOptions("multirate", 2))
    assert result.success, result.message
    assert abs(result["int.x"][-1] - 1.35) < 1e-12
    assert [(e.t, e.kind) for e in result.events] == [(0.25, "timetable"), (0.7, "timetable")]
    own = result.models["tt"]
    # the timetable's own points hold both sides of each jump: 0 then 1 at 0.25, 1 then 3 at 0.7
    at = [own.values[i, 0] for i in np.flatnonzero(np.isin(own.times, [0.25, 0.7]))]
    assert at == [0.0, 1.0, 1.0, 3.0]


def test_multirate_failure_stops_what_it_feeds():
    system = cs.System()
    system.add("pump", FailureModel("weibull", scale=2.0, shape=1.5, seed=7))
    system.add("tank", Integrator())
    system.connect("pump.ok", "tank.u")
    result = cs.simulate(system, 10.0, cs.make_controller("pc", None, 1e-8),
                         cs.MasterOptions("multirate", 2))
    (event,) = result.events
    assert abs(result["tank.x"][-1] - event.t) < 1e-9


@pytest.mark.parametrize("resync", ["partial", "complete"])
@pytest.mark.parametrize("tol", [1e-4, 1e-8])
def test_multirate_locates_a_state_event_on_the_trajectories(resync, tol):
    result = cs.simulate(_monitored(0.5, 0.2), 2.0, cs.make_controller("pc", None, tol),
                         cs.MasterOptions("multirate", 2, resync=resync))
    assert result.success, result.message
    crossings = [(e.t, e.kind) for e in result.events if e.source == "mon"]
    assert [k for _, k in crossings] == ["rise", "fall"]
    # x reached 1.0 in one step, past the crossing at 0.5, with mon and z already there: the
    # crossing is found on x's trajectory and z goes back to it
    assert abs(crossings[0][0] - 0.5) < 1e-10 and abs(crossings[1][0] - 1.7) < 1e-10
    assert abs(result["z.x"][-1] - 1.2) < 1e-9
    mon = result.models["mon"]
    assert list(mon.times).count(crossings[0][0]) == 2  # both sides of the jump


def test_multirate_partial_resync_leaves_the_source_alone():
    models = {mode: cs.simulate(_monitored(0.5, 0.2), 2.0, cs.make_controller("pc", None, 1e-6),
                                cs.MasterOptions("multirate", 2, resync=mode)).models
              for mode in ("partial", "complete")}
    # the sub-models' own steps: the error memory's probes step every continuous member of the
    # group, and more often when more of them went back (z: 14 / 29 probe calls)
    calls = {mode: {name: m.calls - m.probes for name, m in stats.items()}
             for mode, stats in models.items()}
    # x (watched, not reached by the alarm) goes back only under complete (measured 20 / 41)
    assert calls["partial"]["x"] < calls["complete"]["x"]
    assert calls["partial"]["z"] == calls["complete"]["z"]


def test_a_rejected_step_restores_the_generator():
    model = FailureModel("exponential", scale=1.0, seed=1, repair=0.1)
    model.initialize(0.0)
    token = model.save_state()
    model.apply(model.next_event(0.0), np.zeros(0))
    model.apply(model.next_event(0.0), np.zeros(0))  # repaired: draws a new lifetime
    after = model.next_event(0.0)
    model.restore_state(token)
    model.apply(model.next_event(0.0), np.zeros(0))
    model.apply(model.next_event(0.0), np.zeros(0))
    assert model.next_event(0.0) == after


def test_event_kinds_from_a_system_file(tmp_path):
    from click.testing import CliRunner

    from cosimstep.cli import main

    file = tmp_path / "s.toml"
    file.write_text(
        'until = 10.0\n[models.pump]\ntype = "failure"\n'
        'parameters = { law = "weibull", scale = 4.0, shape = 2.0, seed = 3 }\n'
        '[models.tank]\ntype = "linear_coupled.slow"\n'
        '[[connections]]\nfrom = "pump.ok"\nto = "tank.u"\n')
    spec = cs.load_system(file)
    result = cs.simulate(spec.system, spec.until, cs.make_controller("pc", None, 1e-6))
    (event,) = result.events
    assert event.source == "pump" and event.kind == "failure"
    file.write_text(file.read_text().replace('law = "weibull", scale = 4.0',
                                             'law = "gamma", scale = -4.0')
                    + '[models.times]\ntype = "timetable"\n'
                      'parameters = { times = [2.0, 1.0], values = [[1.0], [2.0]] }\n')
    res = CliRunner().invoke(main, ["run", str(file)])
    assert res.exit_code == 2 and "Traceback" not in res.output
    assert "law 'gamma'" in res.output and "scale must be a positive number" in res.output
    assert "times must increase" in res.output  # every problem at once
    file.write_text(
        'until = 1.0\n[models.times]\ntype = "timetable"\n'
        'parameters = { times = [-1.0, 0.5], values = [[1.0], [2.0]] }\n'
        '[models.mon]\ntype = "threshold"\nparameters = { level = 0.5 }\n'
        '[models.tank]\ntype = "linear_coupled.slow"\n'
        '[[connections]]\nfrom = "tank.w"\nto = "mon.temperature"\n')
    res = CliRunner().invoke(main, ["run", str(file)])
    assert res.exit_code == 2 and "Traceback" not in res.output
    assert "before the start" in res.output  # an event time in the past
    assert "no input 'temperature'" in res.output and "its inputs are: x" in res.output


def _monitored(level: float, hysteresis: float) -> cs.System:
    # x rises at 1/s until t = 1, then falls at 1/s; the alarm drives an integrator z
    system = cs.System()
    system.add("slope", Timetable([1.0], [[-1.0]], outputs=["u"], start=[1.0]))
    system.add("x", Integrator())
    system.add("mon", ThresholdMonitor(level=level, hysteresis=hysteresis))
    system.add("z", Integrator())
    system.connect("slope.u", "x.u")
    system.connect("x.x", "mon.x")
    system.connect("mon.alarm", "z.u")
    return system


def test_a_state_event_is_located_inside_the_step():
    result = cs.simulate(_monitored(0.5, 0.2), 2.0, cs.make_controller("pc", None, 1e-6),
                         cs.MasterOptions("gauss-seidel", 2))
    assert result.success, result.message
    crossings = [(e.t, e.kind) for e in result.events if e.source == "mon"]
    assert [k for _, k in crossings] == ["rise", "fall"]
    # x = t up to 1, then 2 - t: the alarm rises at x = 0.5 and falls below 0.5 - 0.2 at 1.7
    assert abs(crossings[0][0] - 0.5) < 1e-10 and abs(crossings[1][0] - 1.7) < 1e-10
    assert abs(result["z.x"][-1] - 1.2) < 1e-9  # the alarm was on from 0.5 to 1.7
    assert result.summary()["events_late"] == 0


def test_without_rollback_a_state_event_fires_late_by_at_most_a_step():
    h = 0.15
    result = cs.simulate(_monitored(0.5, 0.2), 2.0, cs.Fixed(h),
                         cs.MasterOptions("gauss-seidel", 2))
    crossings = [e.t for e in result.events if e.source == "mon"]
    assert len(crossings) == 2
    delays = [crossings[0] - 0.5, crossings[1] - 1.7]
    assert all(e.late for e in result.events if e.source == "mon")  # and it says so
    assert result.summary()["events_late"] == 2
    assert all(0.0 <= d < h for d in delays), delays
    assert abs(result["z.x"][-1] - (1.2 - delays[0] + delays[1])) < 1e-9


def test_an_endless_event_loop_ends_the_run_and_names_the_models():
    # a watches b's alarm, b watches 1 - a's alarm: each firing pushes the other past its level
    # at the same time, forever
    system = cs.System()
    system.add("a", ThresholdMonitor(level=0.5))
    system.add("b", ThresholdMonitor(level=0.5))
    system.add("x", Integrator())
    system.connect("b.alarm", "a.x")
    system.connect("a.alarm", "b.x", gain=-1.0, offset=1.0)  # above 0.5 at the start
    system.connect("a.alarm", "x.u")
    for master in ("gauss-seidel", "multirate"):
        result = cs.simulate(system, 1.0, cs.make_controller("pc", None, 1e-6),
                             cs.MasterOptions(master, 2))
        assert result.status == "failed"
        assert "more than 100 events" in result.message
        assert "endless event loop" in result.message
        assert "a, b keep firing each other" in result.message
        assert len(result.events) >= 100 and len(result.times) >= 1  # what happened is kept


def test_events_are_stored_and_marked_on_the_plot(tmp_path):
    from cosimstep.plotting import plot_run
    from cosimstep.store import read_run

    db = tmp_path / "events.db"
    result = cs.simulate(_timetable_system(), 1.0, cs.Fixed(0.1), store=db)
    stored = read_run(db)
    assert stored.events == [e.to_dict() for e in result.events]
    assert [e["t"] for e in stored.events] == [0.25, 0.7]
    assert stored.summary["events"][0]["kind"] == "timetable"
    assert plot_run(stored, tmp_path / "events.png").stat().st_size > 10_000


@pytest.mark.parametrize("master", ["gauss-seidel", "multirate"])
def test_pump_failure_example_against_its_monolithic_reference(examples, master):
    from cosimstep.models.thermal import failure_time

    spec = cs.load_system(examples / "pump_failure.toml")
    result = cs.simulate(spec.system, spec.until, cs.make_controller("pc", None, 1e-4),
                         cs.MasterOptions(master, 2), reference=spec.reference)
    assert result.success, result.message
    (event,) = result.events
    assert event.source == "health" and event.kind == "failure"
    t_fail = failure_time({"fail_scale": 400.0, "fail_shape": 2.0, "fail_seed": 11.0})
    assert event.t == t_fail and 0.0 < t_fail < spec.until  # the same instant as the reference
    # measured max |e| / (1 + |y|): 1.0e-6 (gauss-seidel, 872 calls), 1.1e-5 (multirate, 282)
    assert result.error.max_scaled < 1e-4
    assert result["load.Th"][-1] > result["load.Th"][0] + 10.0  # the loop heats up after it

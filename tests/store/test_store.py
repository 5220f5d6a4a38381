"""The SQLite results store holds every exchanged value and can be read back."""

from __future__ import annotations

import sqlite3

import numpy as np
import pytest

from cosimstep import Fixed, load_system, read_run, simulate
from cosimstep.store import runs


def test_store_round_trip_and_sql(examples, tmp_path):
    spec = load_system(examples / "double_pendulum_toggled.toml")
    db = tmp_path / "r.db"
    result = simulate(spec.system, 2.5, Fixed(0.01), spec.master, reference=spec.reference,
                      store=db, name=spec.name)
    stored = read_run(db)
    assert stored.status == "ok" and stored.system == "double_pendulum_toggled"
    assert stored.names == ["bar1.theta", "bar1.omega", "bar2.theta", "bar2.omega"]
    assert stored.units == ["rad", "rad/s", "rad", "rad/s"]
    assert np.array_equal(stored.times, result.times)
    assert np.array_equal(stored.values, result.values)
    assert np.allclose(stored.reference, result.reference)
    assert stored.summary["calls_total"] == result.calls_total == 500
    assert stored.attempts.shape == (250, 3) and np.all(stored.attempts[:, 2] == 1)
    df = stored.to_pandas()
    assert df.loc[1.0, "bar1.theta"] == result["bar1.theta"][100]
    with sqlite3.connect(db) as con:  # plain SQL works
        n, size = con.execute("SELECT SUM(n), SUM(length(data)) FROM point_block "
                              "WHERE run_id = ?", (stored.run_id,)).fetchone()
        calls = dict(con.execute("SELECT model, calls FROM calls").fetchall())
    assert n == 251 and size == 251 * (1 + 4) * 8  # t and four values a point, float64
    assert calls == {"bar1": 250, "bar2": 250}


def test_store_appends_runs(examples, tmp_path):
    spec = load_system(examples / "double_pendulum_slow.toml")
    db = tmp_path / "r.db"
    for step in (0.1, 0.05):
        simulate(spec.system, 1.0, Fixed(step), store=db, name=f"h={step}")
    assert [r[1] for r in runs(db)] == ["h=0.1", "h=0.05"]
    assert len(read_run(db, 1).times) == 11 and len(read_run(db).times) == 21


def _long_run(examples, db):
    """A fixed-step run in a subprocess that lasts minutes, returned once it has committed
    points to ``db``, with the number committed."""
    import sqlite3
    import subprocess
    import sys
    import time

    proc = subprocess.Popen([sys.executable, "-m", "cosimstep", "run",
                             str(examples / "linear_coupled.toml"), "--until", "100",
                             "--master", "gauss-seidel", "--controller", "fixed",
                             "--step", "1e-6", "--out", str(db)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline, points = time.monotonic() + 60, 0
    while time.monotonic() < deadline and points == 0:
        time.sleep(0.2)
        try:
            with sqlite3.connect(db) as con:
                points = con.execute("SELECT COALESCE(SUM(n), 0) FROM point_block"
                                     ).fetchone()[0]
        except sqlite3.OperationalError:
            points = 0  # not created yet, or the schema is still being written
    return proc, points


def test_a_killed_run_is_listed_abandoned_and_can_be_deleted(examples, tmp_path):
    import signal

    from click.testing import CliRunner

    from cosimstep.cli import main
    from cosimstep.store import run_table

    db = tmp_path / "killed.db"
    proc, points = _long_run(examples, db)
    try:
        assert points > 0
        assert [r["status"] for r in run_table(db)] == ["running"]  # alive
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.communicate()
    (run,) = run_table(db)
    assert run["status"] == "abandoned" and run["pid"] == proc.pid
    res = CliRunner().invoke(main, ["runs", str(db)])
    assert res.exit_code == 0 and "abandoned" in res.output
    res = CliRunner().invoke(main, ["runs", str(db), "--delete", "1"])
    assert res.exit_code == 0 and run_table(db) == []


def test_sigterm_ends_a_run_interrupted_with_its_results(examples, tmp_path):
    import signal

    from cosimstep.store import read_run

    db = tmp_path / "term.db"
    proc, points = _long_run(examples, db)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 1, err
    assert "Traceback" not in err
    stored = read_run(db)
    assert stored.status == "interrupted" and "SIGTERM" in stored.message
    assert points > 0 and len(stored.times) >= points
    assert stored.summary["t_end"] == stored.times[-1]


def test_an_interrupt_inside_a_store_write_loses_nothing_and_raises_nothing(examples, tmp_path,
                                                                             monkeypatch):
    # Ctrl-C can land between handing rows to the store and noting them as handed: the rows
    # are then handed again when the run ends (the UNIQUE-constraint crash of issue 19)
    import cosimstep
    from cosimstep.store import Store, read_run

    original, seen = Store.add_points, []

    def interrupted_write(self, first_step, times, rows):
        original(self, first_step, times, rows)
        seen.append(first_step)
        if len(seen) == 3:
            raise KeyboardInterrupt

    monkeypatch.setattr(Store, "add_points", interrupted_write)
    spec = cosimstep.load_system(examples / "double_pendulum_slow.toml")
    db = tmp_path / "int.db"
    runs = 0
    with pytest.raises(cosimstep.RunInterrupted) as info:
        for _ in range(3):  # a script's loop of runs stops at the first Ctrl-C
            runs += 1
            cosimstep.simulate(spec.system, 10.0, cosimstep.Fixed(1e-4), store=db)
    assert runs == 1 and isinstance(info.value, KeyboardInterrupt)
    result = info.value.result
    import pickle  # a run in a worker process comes back whole

    assert pickle.loads(pickle.dumps(info.value)).result.message == result.message
    assert result.status == "interrupted"
    stored = read_run(db)
    assert stored.status == "interrupted"
    assert np.array_equal(stored.times, result.times)  # every step, once
    assert np.array_equal(stored.values, result.values)


def test_an_interrupt_after_a_flush_wrote_and_before_it_cleared_raises_nothing(examples,
                                                                              tmp_path,
                                                                              monkeypatch):
    # seen once in a clean-clone test run: 'UNIQUE constraint failed: attempt.run_id,
    # attempt.seq' after an interrupt. The attempts were written, the buffers not yet cleared,
    # and the final flush wrote them again (this test fails so without INSERT OR REPLACE)
    import cosimstep
    from cosimstep.store import Store, read_run

    calls = []

    def flush_interrupted_before_clearing(self):
        calls.append(1)
        if len(calls) == 2:
            db, rid = self._db, self.run_id
            db.executemany("INSERT OR REPLACE INTO point_block VALUES (?, ?, ?, ?)",
                           [(rid, *b) for b in self._points.blocks()])
            db.executemany("INSERT OR REPLACE INTO step_block VALUES (?, ?, ?, ?)",
                           [(rid, *b) for b in self._steps.blocks()])
            db.executemany("INSERT OR REPLACE INTO attempt VALUES (?, ?, ?, ?, ?, ?, ?)",
                           self._attempts)
            db.commit()
            raise KeyboardInterrupt
        original(self)

    original, init = Store.flush, Store.__init__
    monkeypatch.setattr(Store, "flush", flush_interrupted_before_clearing)
    monkeypatch.setattr(Store, "__init__", lambda self, path: init(self, path, 0.0))
    spec = cosimstep.load_system(examples / "double_pendulum_slow.toml")
    db = tmp_path / "flush.db"
    with pytest.raises(cosimstep.RunInterrupted) as info:
        cosimstep.simulate(spec.system, 2.0, cosimstep.make_controller("pc", None, 1e-4),
                           store=db)
    result = info.value.result
    assert result.status == "interrupted", result.message
    stored = read_run(db)
    assert stored.status == "interrupted"
    assert np.array_equal(stored.times, result.times)


@pytest.mark.parametrize("master", ["gauss-seidel", "multirate"])
def test_output_interval_stores_a_grid(examples, tmp_path, master):
    import cosimstep
    from cosimstep.store import read_run

    spec = cosimstep.load_system(examples / "double_pendulum_slow.toml")
    controller = (cosimstep.Fixed(1e-3) if master == "gauss-seidel"
                  else cosimstep.make_controller("pc", None, 1e-4))
    opts = cosimstep.MasterOptions(master, 2)
    grid = read_run(_simulate_to(spec, controller, opts, tmp_path / "grid.db",
                                 output_interval=0.01)[1])
    result, db = _simulate_to(spec, controller, opts, tmp_path / "both.db",
                              output_interval=0.01, output_steps=True)
    both = read_run(db)
    assert np.allclose(grid.times, np.linspace(0.0, 2.0, 201), rtol=0, atol=1e-12)
    expect = np.column_stack([np.interp(grid.times, result.times, col) for col in result.values.T])
    assert np.max(np.abs(grid.values - expect)) <= 1e-12
    ref = np.column_stack([np.interp(grid.times, result.times, col) for col in result.reference.T])
    assert np.max(np.abs(grid.reference - ref)) <= 1e-12
    # with every point too: the union, in time order
    assert np.array_equal(both.times, np.union1d(grid.times, result.times))
    # the step history at the grid's resolution: the first accepted attempt of each interval
    # (per sub-model under multirate), every rejected one; all of them with every point
    accepted = grid.attempts[:, 2] == 1
    assert (~accepted).sum() == (both.attempts[:, 2] == 0).sum()
    if master == "gauss-seidel":  # 1 ms steps: every interval has 10, one is kept
        assert accepted.sum() == 200
        assert len(both.attempts) == result.steps_accepted + result.steps_rejected
    else:  # steps mostly over 10 ms: at most one per interval and sub-model, some dropped
        assert 0 < accepted.sum() < (both.attempts[:, 2] == 1).sum()
        assert accepted.sum() <= 2 * 200


def _simulate_to(spec, controller, opts, db, **output):
    import cosimstep

    result = cosimstep.simulate(spec.system, 2.0, controller, opts, reference=spec.reference,
                                store=db, **output)
    assert result.success, result.message
    return result, db


def test_points_are_read_from_blocks_and_from_a_store_written_before_them(tmp_path):
    """A store from before the blocks (a row per value) still reads; a resumed run's blocks
    are cut at its checkpoint."""
    import sqlite3

    from cosimstep.store import Store, _read_points, _truncate, read_run

    db = tmp_path / "old.db"
    store = Store(db)
    rid = store.begin("old", {}, ["a", "b"], ["1", "1"])
    with sqlite3.connect(db) as con:  # what the row-per-value store wrote
        con.executemany("INSERT INTO point VALUES (?, ?, ?)", [(rid, s, 0.5 * s) for s in range(3)])
        con.executemany("INSERT INTO sample VALUES (?, ?, ?, ?)",
                        [(rid, s, v, 10.0 * s + v) for s in range(3) for v in range(2)])
    store.add_points(3, [1.5, 2.0], np.array([[30.0, 31.0], [40.0, 41.0]]))  # and on, blocks
    store.add_point(5, 2.5, np.array([50.0, 51.0]))
    store.finish("ok", "", 2.5, 0.0, {}, {}, {})
    stored = read_run(db)
    assert np.array_equal(stored.times, 0.5 * np.arange(6))
    assert np.array_equal(stored.values, 10.0 * np.arange(6)[:, None] + [0.0, 1.0])
    _truncate(store._db, "point_block", "first_step", rid, 4, 3)  # keep the points 0 … 3
    times, values = _read_points(store._db, rid, 2)
    assert np.array_equal(times, [0.0, 0.5, 1.0, 1.5]) and values[-1].tolist() == [30.0, 31.0]
    store.close()

"""Parameter sweeps on Dask (issue 16): designs, one task per run on a local cluster of two
worker processes, one SQLite table of summaries, resumable, failures recorded."""

from __future__ import annotations

import sqlite3

import numpy as np
import pytest

from cosimstep import sweep
from cosimstep.sweep import Axis, design, parse_axis


def test_designs() -> None:
    full = design([parse_axis("l2=0.5,1,2"), parse_axis("step=0.01,0.005")])
    assert len(full) == 6 and full[0] == {"l2": 0.5, "step": 0.01}
    assert full[-1] == {"l2": 2.0, "step": 0.005}
    for kind in ("lhs", "sobol"):
        axes = [Axis("l1", low=0.1, high=10.0), Axis("l2", low=1.0, high=2.0)]
        points = design(axes, kind, samples=16, seed=3)
        values = np.array([[p["l1"], p["l2"]] for p in points])
        assert values.shape == (16, 2)
        assert np.all((values[:, 0] >= 0.1) & (values[:, 0] <= 10.0))
        assert np.all((values[:, 1] >= 1.0) & (values[:, 1] <= 2.0))
        # stratified: each of 16 equal slices of every range holds exactly one point
        for j, (low, high) in enumerate(((0.1, 10.0), (1.0, 2.0))):
            bins = np.floor((values[:, j] - low) / (high - low) * 16).astype(int)
            assert sorted(bins.tolist()) == list(range(16))
        assert design(axes, kind, samples=16, seed=3) == points  # reproducible
    with pytest.raises(ValueError, match="needs ranges"):
        design([parse_axis("l2=1,2")], "lhs", samples=4)
    with pytest.raises(ValueError, match="needs listed values"):
        design([parse_axis("l2=1:2")])
    with pytest.raises(ValueError, match="LOW < HIGH"):
        parse_axis("l2=2:1")


def test_a_sweep_runs_resumes_and_records_failures(tmp_path, examples) -> None:
    system = examples / "double_pendulum_slow.toml"
    out = tmp_path / "sweep.db"
    # first an interrupted sweep: only half of the steps
    first = sweep(system, ["l2=0.5,1", "step=0.01"], out=out, workers=2, until=2.0,
                  progress=False)
    assert list(first["status"]) == ["ok", "ok"]
    with sqlite3.connect(out) as db:
        before = dict(db.execute("SELECT point_json, finished FROM sweep_run").fetchall())
    frame = sweep(system, ["l2=0.5,1", "step=0.01,0.005,-1"], out=out, workers=2, until=2.0,
                  progress=False)
    with sqlite3.connect(out) as db:
        after = dict(db.execute("SELECT point_json, finished FROM sweep_run").fetchall())
    assert len(after) == 6 and all(after[p] == t for p, t in before.items())  # not run again
    ok = frame[frame["status"] == "ok"]
    failed = frame[frame["status"] == "failed"]
    assert len(ok) == 4 and len(failed) == 2 and set(failed["step"]) == {-1.0}
    assert all("step" in m for m in failed["message"])
    # real runs: Gauss-Seidel with quadratic extrapolation converges at order 3 in the step
    for l2 in (0.5, 1.0):
        rows = ok[ok["l2"] == l2].set_index("step")
        assert rows.loc[0.01, "calls_total"] == 400 and rows.loc[0.005, "calls_total"] == 800
        order = np.log2(rows.loc[0.01, "error"] / rows.loc[0.005, "error"])
        assert 2.5 < order < 3.5, order
    assert {"calls.bar1", "calls.bar2", "wall_s", "error_estimate"} <= set(frame.columns)


def test_the_command_line_reports_bad_names_before_running(tmp_path, examples) -> None:
    from click.testing import CliRunner

    from cosimstep.cli import main

    system = str(examples / "double_pendulum_slow.toml")
    out = str(tmp_path / "s.db")
    res = CliRunner().invoke(main, ["sweep", system, "--param", "l9=1,2", "--out", out])
    assert res.exit_code == 2 and "--param l9: no model uses this parameter" in res.output
    res = CliRunner().invoke(main, ["sweep", system, "--param", "l2=1:2", "--out", out])
    assert res.exit_code == 2 and "needs listed values" in res.output
    res = CliRunner().invoke(main, ["sweep", system, "--param", "l2=2:1", "--out", out])
    assert res.exit_code == 2 and "LOW < HIGH" in res.output
    res = CliRunner().invoke(main, ["sweep", system, "--param", "l2=", "--out", out])
    assert res.exit_code == 2 and "NAME=V1,V2" in res.output
    res = CliRunner().invoke(main, ["sweep", system, "--param", "l2=1", "--out", out,
                                    "--tol", "1e-3", "--master", "multirate",
                                    "--estimate", "richardson"])
    assert res.exit_code == 2 and "one step sequence for every sub-model" in res.output
    for args in (["--param", "l2=1,2", "--until", "-3"], ["--param", "until=0.1,-1"]):
        res = CliRunner().invoke(main, ["sweep", system, *args, "--out", out])
        assert res.exit_code == 2 and "`until` must be a positive number" in res.output
    import socket

    with socket.socket() as free:  # a port nobody listens on
        free.bind(("127.0.0.1", 0))
        port = free.getsockname()[1]
    res = CliRunner().invoke(main, ["sweep", system, "--param", "l2=1", "--out", out,
                                    "--scheduler", f"tcp://127.0.0.1:{port}"])
    assert res.exit_code == 2 and f"no Dask scheduler answers at tcp://127.0.0.1:{port}" \
        in res.output, res.output
    assert not (tmp_path / "s.db").exists()  # nothing started, nothing written


def test_each_run_of_a_sweep_can_estimate_its_error_by_a_companion(tmp_path, examples) -> None:
    system = examples / "double_pendulum_slow.toml"
    frame = sweep(system, ["tol=1e-3,1e-4"], out=tmp_path / "e.db", workers=1, until=2.0,
                  estimate="richardson", progress=False)
    assert list(frame["status"]) == ["ok", "ok"]
    ratio = frame["error_estimate"] / frame["error"]  # measured 0.61, 0.52
    assert ratio.between(0.2, 5.0).all(), list(ratio)


def test_a_worker_killed_mid_sweep_loses_no_run(tmp_path, examples) -> None:
    """A worker process is killed (SIGKILL) while the sweep is under way; the scheduler hands
    its task to another worker and every run ends up recorded, ok."""
    import threading
    import time

    import psutil

    out = tmp_path / "sweep.db"
    killed: list[int] = []

    def kill_a_worker() -> None:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not killed:
            time.sleep(0.2)
            if not out.exists():
                continue
            with sqlite3.connect(out) as db:
                try:
                    done = db.execute("SELECT COUNT(*) FROM sweep_run").fetchone()[0]
                except sqlite3.OperationalError:
                    continue
            workers = [p for p in psutil.Process().children(recursive=True)
                       if "spawn_main" in " ".join(p.cmdline())]  # the worker processes
            if done >= 1 and workers:
                victim = max(workers, key=lambda p: p.create_time())
                victim.kill()
                killed.append(victim.pid)

    thread = threading.Thread(target=kill_a_worker, daemon=True)
    thread.start()
    frame = sweep(examples / "double_pendulum_slow.toml",
                  ["l2=0.5,0.75,1,1.25,1.5,1.75,2,2.25"], out=out, workers=2, until=3.0,
                  step=0.0005, progress=False)
    thread.join(timeout=5)
    assert killed, "no worker was killed: the test did not test anything"
    assert len(frame) == 8 and set(frame["status"]) == {"ok"}, frame[["l2", "status", "message"]]
    assert all(frame["calls_total"] == 2 * 6000)


def test_plot_sweep_draws_contours_and_lines(tmp_path) -> None:
    """Contours over two swept names (thesis figs. 68-70) and lines over one, from a sweep
    table; a name that is not a column is a configuration error (exit 2)."""
    from click.testing import CliRunner

    from cosimstep.cli import main
    from cosimstep.sweep import SweepTable, run_key

    db = tmp_path / "s.db"
    table = SweepTable(db)
    for l1 in (0.1, 1.0, 10.0):
        for l2 in (0.1, 1.0, 10.0):
            point = {"l1": l1, "l2": l2}
            table.add(run_key("x.toml", point, {}), "x.toml", {},
                      {"point": point, "status": "ok" if l1 * l2 < 50 else "failed",
                       "message": "", "calls": {"a": 10}, "calls_total": int(100 * l1 / l2),
                       "steps": 10, "error": 1e-3 * l1 * l2, "error_estimate": None,
                       "wall_s": 0.1})
    table.close()
    for args in (["--x", "l1", "--y", "l2", "--z", "error"], ["--x", "l1", "--z", "calls_total"]):
        figure = tmp_path / f"{len(args)}.png"
        res = CliRunner().invoke(main, ["plot-sweep", str(db), *args, "-o", str(figure)])
        assert res.exit_code == 0, res.output
        assert figure.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and figure.stat().st_size > 10_000
    res = CliRunner().invoke(main, ["plot-sweep", str(db), "--x", "l9", "-o", str(figure)])
    assert res.exit_code == 2 and "'l9' is not a column" in res.output


def test_traces_are_kept_one_store_per_run(tmp_path, examples) -> None:
    """--keep traces: every run's trajectory in its own store, the sweep table naming it; a
    sweep recorded without traces runs again when they are asked for."""
    import cosimstep

    out = tmp_path / "sweep.db"
    args = (examples / "double_pendulum_slow.toml", ["l2=0.5,1"])
    sweep(*args, out=out, workers=1, until=1.0, step=0.01, progress=False)
    frame = sweep(*args, out=out, workers=1, until=1.0, step=0.01, progress=False,
                  keep="traces")
    assert len(frame) == 2 and set(frame["status"]) == {"ok"}
    for _, row in frame.iterrows():
        stored = cosimstep.read_run(row["store"])
        assert len(stored.times) == 101 and stored.times[-1] == pytest.approx(1.0)
        assert "bar2.theta" in stored.names
        # the summary's extremes are those of the stored trajectory
        theta = stored.values[:, stored.names.index("bar2.theta")]
        assert (row["min.bar2.theta"], row["max.bar2.theta"]) == (theta.min(), theta.max())
    theta2 = {}
    for _, row in frame.iterrows():
        stored = cosimstep.read_run(row["store"])
        theta2[row["l2"]] = stored.values[:, stored.names.index("bar2.theta")]
    assert not np.allclose(theta2[0.5], theta2[1.0])  # two different pendulums


def test_work_precision_plot_across_run_options(tmp_path) -> None:
    """Two sweeps of tol with other masters in one file: one line each, labelled by the run
    options; the frame carries them as `options`."""
    from click.testing import CliRunner

    from cosimstep.cli import main
    from cosimstep.sweep import SweepTable, run_key

    db = tmp_path / "wp.db"
    table = SweepTable(db)
    for master, cost in (("gauss-seidel", 1.0), ("multirate", 0.6)):
        for tol in (1e-3, 1e-4, 1e-5):
            point, options = {"tol": tol}, {"master": master}
            table.add(run_key("x.toml", point, options), "x.toml", options,
                      {"point": point, "status": "ok", "message": "", "calls": {},
                       "calls_total": int(cost * 100 * tol ** -0.25), "steps": 1,
                       "error": tol / 3, "error_estimate": None, "wall_s": 0.1})
    assert sorted(set(table.frame()["options"])) == ["master=gauss-seidel", "master=multirate"]
    table.close()
    figure = tmp_path / "wp.png"
    res = CliRunner().invoke(main, ["plot-sweep", str(db), "--work-precision", "-o",
                                    str(figure)])
    assert res.exit_code == 0, res.output
    assert figure.read_bytes()[:4] == b"\x89PNG" and figure.stat().st_size > 10_000
    res = CliRunner().invoke(main, ["plot-sweep", str(db), "-o", str(figure)])
    assert res.exit_code == 2 and "--work-precision" in res.output


def test_points_written_out_each_with_its_own_step_and_end(tmp_path, examples) -> None:
    """A study whose points are not a product of axes: the end time tied to the length."""
    system = examples / "double_pendulum_slow.toml"
    points = [{"l2": 1.0, "step": 0.01, "until": 1.0}, {"l2": 0.5, "step": 0.005, "until": 0.5}]
    frame = sweep(system, points=points, out=tmp_path / "s.db", workers=1, progress=False)
    assert list(frame["status"]) == ["ok", "ok"]
    assert list(frame["calls_total"]) == [2 * 100, 2 * 100]
    assert frame["step_min"].tolist() == pytest.approx([0.01, 0.005])
    assert (frame["rmse"] > 0).all() and (frame["rmse"] <= frame["error"] * 2).all()
    # an adaptive run's smallest step is one it took, below its largest
    adaptive = sweep(system, points=[{"tol": 1e-4}], out=tmp_path / "a.db", workers=1,
                     progress=False, until=2.0, controller="pc")
    assert 0 < adaptive["step_min"].iloc[0] < 2.0 / adaptive["steps"].iloc[0]
    with pytest.raises(ValueError, match="not both"):
        sweep(system, ["l2=1"], points=points, out=tmp_path / "x.db")
    with pytest.raises(ValueError, match="empty"):
        sweep(system, points=[], out=tmp_path / "x.db")
    with pytest.raises(Exception, match="l9"):
        sweep(system, points=[{"l2": 1.0}, {"l9": 2.0}], out=tmp_path / "x.db")
    assert not (tmp_path / "x.db").exists()


def test_a_point_repeated_at_a_tighter_tol_counts_both_runs_calls(monkeypatch) -> None:
    """A run the default repeated (cosimstep.tighten) cost its pair's calls: a work-precision
    study reads ``calls_total`` as the point's work."""
    import importlib

    from cosimstep.result import SimulationResult

    module = importlib.import_module("cosimstep.sweep")  # (the package exports a function so)
    kept = SimulationResult(status="ok", message="completed; repeated at tol 3e-05: ...",
                            t_end=1.0, names=[], units=[], times=np.array([0.0, 1.0]),
                            values=np.zeros((2, 0)), calls={"a": 500, "b": 500},
                            steps_accepted=200, steps_rejected=0,
                            step_sizes=np.array([0.5, 0.5]), wall_s=0.1, time_in_models={},
                            error_estimate=6e-5, tightened={"run": "first", "calls": 752})
    monkeypatch.setattr(module, "_simulate", lambda *args: kept)
    summary = module.run_point("x.toml", {}, {})
    assert summary["status"] == "ok", summary["message"]
    assert summary["calls_total"] == 1752 and summary["calls"] == {"a": 500, "b": 500}
    kept.tightened = None
    assert module.run_point("x.toml", {}, {})["calls_total"] == 1000


def test_the_line_plot_of_one_swept_name_is_one_line(tmp_path) -> None:
    """The summary's extremes (``min.NAME``, ``max.NAME``) are no swept names: a sweep of one
    name is one line (each run was its own dot, labelled by its extremes), and a sweep of
    tol and a parameter draws one work-precision curve per parameter value."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from cosimstep.plotting import _lines, _swept
    from cosimstep.sweep import SweepTable, run_key

    table = SweepTable(tmp_path / "s.db")
    for l2 in (0.5, 1.0):
        for tol in (1e-2, 1e-3, 1e-4):
            point = {"tol": tol, "l2": l2}
            table.add(run_key("x.toml", point, {}), "x.toml", {},
                      {"point": point, "status": "ok", "message": "", "calls": {"a": 10},
                       "calls_total": int(10 / tol), "steps": 10, "error": tol / 3,
                       "error_estimate": None, "wall_s": 0.1,
                       "extremes": {"a.x": (-tol, l2), "b.y": (0.0, tol)}})
    frame = table.frame()
    table.close()
    assert sorted(_swept(frame)) == ["l2", "tol"]
    assert {"min.a.x", "max.b.y"} <= set(frame.columns)
    one = frame[frame["l2"] == 0.5].drop(columns="l2")
    one.attrs = {"swept": ["tol"]}
    _, ax = plt.subplots()
    _lines(ax, one, one, "tol", "calls_total", True)
    assert len(ax.lines) == 1 and len(ax.lines[0].get_xdata()) == 3
    _, ax = plt.subplots()
    _lines(ax, frame, frame, "tol", "calls_total", True)
    assert len(ax.lines) == 2  # one per l2
    plt.close("all")

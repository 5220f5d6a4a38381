"""Checkpoints and ``--resume`` (issue 19, item 4): a fixed-step run killed with -9 and resumed
from its last checkpoint stores what the uninterrupted run stores, bit for bit; a run that cannot
be resumed says why, with exit code 2."""

from __future__ import annotations

import json
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from click.testing import CliRunner

import cosimstep
from cosimstep.cli import main
from cosimstep.store import read_run, run_table


def _same_store(a: Path, b: Path) -> None:
    x, y = read_run(a), read_run(b)
    assert y.status == x.status == "ok"
    assert np.array_equal(x.times, y.times) and np.array_equal(x.values, y.values)
    assert np.array_equal(x.attempts, y.attempts)
    assert x.summary["calls"] == y.summary["calls"]
    assert x.summary["steps_accepted"] == y.summary["steps_accepted"]


def _checkpoint(db: Path) -> tuple[float, int] | None:
    try:
        with sqlite3.connect(db) as con:
            return con.execute("SELECT t, point FROM checkpoint WHERE state IS NOT NULL"
                               ).fetchone()
    except sqlite3.OperationalError:
        return None  # not created yet


def test_a_killed_fmu_run_resumes_bit_for_bit(examples: Path, tmp_path: Path) -> None:
    """Two C FMUs (their states serialized by the FMUs), Jacobi with quadratic extrapolation,
    100,000 steps: killed with -9 after a checkpoint, resumed, equal to the uninterrupted run."""
    system = examples / "fmu" / "double_pendulum_fmu.toml"
    killed, whole = tmp_path / "killed.db", tmp_path / "whole.db"
    proc = subprocess.Popen([sys.executable, "-m", "cosimstep", "run", str(system), "-q",
                             "--out", str(killed), "--checkpoint-every", "0.2"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline, checkpoint = time.monotonic() + 120, None
    while time.monotonic() < deadline and checkpoint is None and proc.poll() is None:
        time.sleep(0.05)
        checkpoint = _checkpoint(killed)
    proc.send_signal(signal.SIGKILL)
    proc.communicate()
    assert checkpoint is not None and 0 < checkpoint[0] < 10.0
    assert [r["status"] for r in run_table(killed)] == ["abandoned"]

    res = CliRunner().invoke(main, ["run", str(system), "--resume", str(killed), "--json"])
    assert res.exit_code == 0, res.output
    out = json.loads(res.output)
    assert "resumed from its checkpoint at t = " in out["message"]
    assert out["calls"] == {"bar1": 100_000, "bar2": 100_000}
    CliRunner().invoke(main, ["run", str(system), "--out", str(whole), "-q"])
    _same_store(whole, killed)
    again = CliRunner().invoke(main, ["run", str(system), "--resume", str(killed)])
    assert again.exit_code == 2 and "completed: nothing to resume" in again.output


@pytest.mark.parametrize("controller, order", [("fixed", 0), ("fixed", 2), ("pc", 2),
                                               ("rkf45", 2), ("random", 1)])
def test_python_sub_models_resume_from_their_pickled_states(examples: Path, tmp_path: Path,
                                                            controller: str,
                                                            order: int) -> None:
    """The mixed double pendulum of Python sub-models (RK4 and solve_ivp inside), stopped by
    a call budget halfway and resumed in-process: the same store as the uninterrupted run —
    fixed step, and adaptive controllers whose state (proposed step, error budget, error
    memory, random generator) the checkpoint pickles."""
    from cosimstep.controllers import make_controller

    def run(db: Path, **kw: Any) -> cosimstep.SimulationResult:
        spec = cosimstep.load_system(examples / "double_pendulum_mixed.toml")
        ctrl = {"fixed": lambda: make_controller("fixed", 1e-3, None),
                "random": lambda: make_controller("random", 1e-3, None, seed=3)}.get(
                    controller, lambda: make_controller(controller, None, 1e-4))()
        return cosimstep.simulate(spec.system, 2.0, ctrl,
                                  cosimstep.MasterOptions("gauss-seidel", order), store=db,
                                  reference=spec.reference, **kw)

    whole = run(tmp_path / "whole.db")
    part = run(tmp_path / "part.db", checkpoint_steps=7, max_calls=whole.calls_total // 2)
    assert part.status == "timed_out"
    resumed = run(tmp_path / "part.db", resume=1)
    assert resumed.success and resumed.calls == whole.calls
    assert resumed.error_estimate == whole.error_estimate
    assert np.array_equal(resumed.times, whole.times)  # the whole run, not only its end
    _same_store(tmp_path / "whole.db", tmp_path / "part.db")
    assert np.array_equal(read_run(tmp_path / "whole.db").reference,
                          read_run(tmp_path / "part.db").reference)


def test_a_run_stored_with_its_measured_state_in_the_settings_resumes(examples: Path,
                                                                     tmp_path: Path) -> None:
    """An earlier version recorded what a run had measured into the controller (pc's error
    memory, noise floor, error estimate) among its settings; such a run still resumes, and
    one stored with another setting is still refused."""
    from cosimstep.controllers import make_controller

    def run(**kw: Any) -> cosimstep.SimulationResult:
        spec = cosimstep.load_system(examples / "double_pendulum_mixed.toml")
        return cosimstep.simulate(spec.system, 1.0, make_controller("pc", None, 1e-4),
                                  cosimstep.MasterOptions("gauss-seidel", 2),
                                  store=tmp_path / "old.db", **kw)

    assert run(checkpoint_steps=7, max_calls=100).status == "timed_out"
    with sqlite3.connect(tmp_path / "old.db") as db:
        config = json.loads(db.execute("SELECT config_json FROM run").fetchone()[0])
        controller = config["controller"]
        controller["error_estimate"] = 3e-5
        controller["policy"].update(memory=0.4, floor=0.0, noise_steps=0, propagation=1.0,
                                    safety=0.9)  # the last is a setting: refused
        db.execute("UPDATE run SET config_json=?", (json.dumps(config),))
    with pytest.raises(ValueError, match=r"other settings \(controller: "
                                         r"controller\.policy\.safety 0\.9 stored, 0\.85 now\)"):
        run(resume=1)
    with sqlite3.connect(tmp_path / "old.db") as db:
        controller["policy"]["safety"] = 0.85  # pc's own: only the measured state differs
        db.execute("UPDATE run SET config_json=?", (json.dumps(config),))
    assert run(resume=1).success


def test_a_wrapping_controller_s_run_stored_without_its_inner_settings_resumes(
        examples: Path, tmp_path: Path) -> None:
    """An earlier version did not record the options of the controller `switching` wraps;
    such a run resumes (the record cannot tell them), and one of another controller does not."""
    from cosimstep.controllers import make_controller

    def run(name: str = "switching", **kw: Any) -> cosimstep.SimulationResult:
        spec = cosimstep.load_system(examples / "double_pendulum_mixed.toml")
        return cosimstep.simulate(spec.system, 1.0, make_controller(name, None, 1e-4),
                                  cosimstep.MasterOptions("gauss-seidel", 2),
                                  store=tmp_path / "old.db", **kw)

    assert run(checkpoint_steps=7, max_calls=100).status == "timed_out"
    with sqlite3.connect(tmp_path / "old.db") as db:
        config = json.loads(db.execute("SELECT config_json FROM run").fetchone()[0])
        del config["controller"]["inner_settings"]
        db.execute("UPDATE run SET config_json=?", (json.dumps(config),))
    with pytest.raises(ValueError, match=r"other settings \(controller: controller\.name "
                                         r"'switching' stored, 'adaptive-tol' now"):
        run("adaptive-tol", resume=1)
    assert run(resume=1).success


class _Unpicklable(cosimstep.OdeSubModel):
    def serialize_state(self, token: Any) -> bytes:
        raise NotImplementedError("its solver holds an open handle")


def test_runs_that_cannot_resume_say_why(examples: Path, tmp_path: Path) -> None:
    toml = examples / "double_pendulum_slow.toml"
    db = tmp_path / "r.db"
    # a multi-rate run takes no checkpoints: --resume refuses, naming the reason
    args = ["run", str(toml), "--until", "1", "--tol", "1e-4", "--master", "multirate"]
    assert CliRunner().invoke(main, [*args, "--out", str(db),
                                     "--max-calls", "20"]).exit_code == 1  # timed_out
    res = CliRunner().invoke(main, [*args, "--resume", str(db)])
    assert res.exit_code == 2 and "has no checkpoint" in res.output
    db.unlink()
    CliRunner().invoke(main, [*args[:-2], "--out", str(db), "--max-calls", "20",
                              "--checkpoint-steps", "2"])  # pc: checkpoints
    res = CliRunner().invoke(main, [*args, "--resume", str(db)])
    assert res.exit_code == 2 and "multirate runs cannot be resumed yet" in res.output
    # a fixed-step run resumed with other options
    db2 = tmp_path / "f.db"
    fixed = ["run", str(toml), "--until", "1", "--step", "1e-3", "--controller", "fixed"]
    CliRunner().invoke(main, [*fixed, "--out", str(db2), "--max-calls", "600",
                              "--checkpoint-steps", "100"])
    res = CliRunner().invoke(main, [*fixed[:-1], "rkf45", "--tol", "1e-4",
                                    "--resume", str(db2)])
    assert res.exit_code == 2 and "other settings (controller: controller.name 'fixed' " \
        "stored, 'rkf45' now" in res.output
    res = CliRunner().invoke(main, [*fixed, "--extrapolation", "0", "--resume", str(db2)])
    assert res.exit_code == 2 and "other settings (master: master.extrapolation 2 stored, " \
        "0 now)" in res.output
    res = CliRunner().invoke(main, [*fixed, "--resume", str(db2), "--run", "7"])
    assert res.exit_code == 2 and "no run 7" in res.output
    res = CliRunner().invoke(main, [*fixed, "--resume", str(db2), "--out", "x.db"])
    assert res.exit_code == 2 and "leave out --out" in res.output
    # a sub-model that cannot serialize its state: the store says so, --resume repeats it
    spec = cosimstep.load_system(toml)
    bar = spec.system.models["bar2"]
    bar.__class__ = _Unpicklable
    db3 = tmp_path / "u.db"
    r = cosimstep.simulate(spec.system, 1.0, cosimstep.Fixed(1e-3), store=db3,
                           checkpoint_steps=100, max_calls=600)
    assert r.status == "timed_out"
    with pytest.raises(ValueError, match=r"'bar2' cannot serialize its state.*open handle"):
        cosimstep.simulate(spec.system, 1.0, cosimstep.Fixed(1e-3), store=db3, resume=1)


@pytest.mark.parametrize("delay", [0.3, 0.9])
def test_ctrl_c_during_an_fmu_run_keeps_every_point_once(examples: Path, tmp_path: Path,
                                                         delay: float) -> None:
    """SIGINT to a run of two C FMUs (unpacking, stepping or writing; benchmarks/interrupts.py
    does this 50 times at random): exit 1, no traceback, status interrupted, points whole,
    no unpacked FMU folder left."""
    import os

    system = examples / "fmu" / "double_pendulum_fmu.toml"
    db, tmp = tmp_path / "int.db", tmp_path / "tmp"
    tmp.mkdir()
    proc = subprocess.Popen([sys.executable, "-m", "cosimstep", "run", str(system), "-q",
                             "--until", "30", "--out", str(db)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "TMPDIR": str(tmp)},
                            # a shell starting the suite in the background (`cmd &`) ignores
                            # SIGINT for it, and an ignored signal is inherited: Ctrl-C must
                            # reach this run as it reaches one started from a terminal
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and not run_table_has_run(db):
        time.sleep(0.01)
    time.sleep(delay)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 1 and "Traceback" not in err, err
    stored = read_run(db)
    assert stored.status == "interrupted" and "interrupted by the user" in stored.message
    with sqlite3.connect(db) as con:
        steps = [s for first, n in con.execute("SELECT first_step, n FROM point_block "
                                               "ORDER BY first_step")
                 for s in range(first, first + n)]
        accepted = con.execute("SELECT COUNT(*) FROM attempt WHERE accepted=1").fetchone()[0] \
            + con.execute("SELECT COALESCE(SUM(n), 0) FROM step_block").fetchone()[0]
    assert steps == list(range(len(steps))) and accepted == len(steps) - 1
    assert stored.summary["t_end"] == stored.times[-1] < 30.0
    assert not [p for p in tmp.iterdir() if p.name.startswith("cosimstep-")]


def run_table_has_run(db: Path) -> bool:
    try:
        with sqlite3.connect(db) as con:
            return con.execute("SELECT COUNT(*) FROM run").fetchone()[0] > 0
    except sqlite3.OperationalError:
        return False

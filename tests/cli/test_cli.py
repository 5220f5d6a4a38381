"""The command line: run --json, validate, plot, demo, exit codes."""

from __future__ import annotations

import json
import subprocess
import sys
import time

import numpy as np
import pytest
from click.testing import CliRunner

from cosimstep.cli import main

KEYS = {"status", "message", "t_end", "calls", "calls_total", "steps_accepted", "steps_rejected",
        "h_min", "h_max", "wall_s", "store", "error"}


def test_run_json_reports_error_against_reference(examples, tmp_path):
    db = tmp_path / "slow.db"
    res = CliRunner().invoke(main, ["run", str(examples / "double_pendulum_slow.toml"),
                                    "--until", "2", "--step", "0.002", "--json", "--out", str(db)])
    assert res.exit_code == 0, res.output
    out = json.loads(res.output)
    assert set(out) >= KEYS
    assert out["status"] == "ok" and out["t_end"] == 2.0
    assert out["calls"] == {"bar1": 1000, "bar2": 1000} and out["calls_total"] == 2000
    assert out["h_min"] == pytest.approx(0.002) and out["h_max"] == pytest.approx(0.002)
    assert 0 < out["error"]["max_abs"] < 1e-5 and out["error"]["rmse"] <= out["error"]["max_abs"]
    assert db.exists()


def test_run_options_override_file(examples, tmp_path):
    res = CliRunner().invoke(main, [
        "run", str(examples / "double_pendulum_slow.toml"), "--until", "1", "--master", "jacobi",
        "--extrapolation", "0", "--controller", "random", "--seed", "3", "--json",
        "--out", str(tmp_path / "r.db")])
    out = json.loads(res.output)
    assert res.exit_code == 0 and out["status"] == "ok"
    assert 0.001 <= out["h_max"] <= 0.01 and out["steps_accepted"] < 1000


BROKEN = """
name = "broken"
[parameters]
l1 = 1.0
[models.bar1]
type = "double_pendulum.bar1"
[models.bar2]
type = "double_pendulum.barX"
[[connections]]
from = "bar1.theta"
to = "bar1.omega2"
[[connections]]
from = "bar1.omega"
to = "bar1.omega2"
[controller]
name = "fixed"
step = "fast"
"""


def test_validate_reports_three_mistakes_at_once(tmp_path):
    path = tmp_path / "broken.toml"
    path.write_text(BROKEN)
    res = CliRunner().invoke(main, ["validate", str(path)])
    assert res.exit_code == 2
    text = res.output
    assert "models.bar2.type" in text and "unknown model type 'double_pendulum.barX'" in text
    assert "connections[0]" in text and "unit mismatch" in text
    assert "connections[1]" in text and "already has a source" in text
    assert "controller.step" in text
    assert str(path) in text


def test_validate_accepts_every_example(examples):
    for path in sorted(examples.glob("*.toml")):
        res = CliRunner().invoke(main, ["validate", str(path)])
        assert res.exit_code == 0, (path, res.output)


def _helper_models(folder):
    """A models.py a system file can name, re-exporting the test helpers' sub-models."""
    (folder / "models.py").write_text(
        "import sys\n"
        f"sys.path.insert(0, {str(__import__('pathlib').Path(__file__).parents[1])!r})\n"
        "from helpers import Clock, Gain, Integrator\n")


def test_failed_run_exits_1(tmp_path):
    _helper_models(tmp_path)
    (tmp_path / "s.toml").write_text(
        'until = 1.0\n[models.clock]\ntype = "python"\nclass = "models.py:Clock"\n'
        'parameters = { fail_at = 0.3 }\n[models.sink]\ntype = "python"\n'
        'class = "models.py:Integrator"\nparameters = { unit = "s" }\n'
        '[[connections]]\nfrom = "clock.time"\nto = "sink.u"\n'
        '[controller]\nname = "fixed"\nstep = 0.1\n')
    res = CliRunner().invoke(main, ["run", str(tmp_path / "s.toml"), "--json",
                                    "--out", str(tmp_path / "s.db")])
    out = json.loads(res.output)
    assert res.exit_code == 1
    assert out["status"] == "failed" and "'clock'" in out["message"]
    assert out["steps_accepted"] == 3


def test_verbose_prints_the_sub_models_traceback_and_quiet_one_line(tmp_path):
    _helper_models(tmp_path)
    (tmp_path / "s.toml").write_text(
        'until = 1.0\n[models.clock]\ntype = "python"\nclass = "models.py:Clock"\n'
        'parameters = { fail_at = 0.3 }\n[controller]\nname = "fixed"\nstep = 0.1\n')
    args = ["run", str(tmp_path / "s.toml"), "--no-store"]
    plain = CliRunner().invoke(main, args)
    verbose = CliRunner().invoke(main, [*args, "-v"])
    quiet = CliRunner().invoke(main, [*args, "-q"])
    assert plain.exit_code == verbose.exit_code == quiet.exit_code == 1
    assert "Traceback" not in plain.output
    # the sub-model's own frame (helpers.py, where Clock raises) and the master's summary line
    assert "Traceback" in verbose.output and "helpers.py" in verbose.output
    assert "status: failed" in verbose.output
    assert quiet.output.count("\n") == 1 and quiet.output.startswith("status: failed — ")


def test_call_timeout_from_the_command_line(tmp_path):
    _helper_models(tmp_path)
    (tmp_path / "s.toml").write_text(
        'until = 1.0\n[models.clock]\ntype = "python"\nclass = "models.py:Clock"\n'
        'parameters = { fail_at = 0.3, mode = "hang" }\n'
        '[controller]\nname = "fixed"\nstep = 0.1\n')
    args = ["run", str(tmp_path / "s.toml"), "--json", "--out", str(tmp_path / "s.db")]
    started = time.perf_counter()
    res = CliRunner().invoke(main, [*args, "--call-timeout", "0.5"])
    assert time.perf_counter() - started < 10.0  # the sub-model sleeps 30 s
    out = json.loads(res.output)
    assert res.exit_code == 1 and out["status"] == "failed"
    assert "no answer within 0.5 s" in out["message"] and out["steps_accepted"] == 3
    bad = CliRunner().invoke(main, [*args, "--call-timeout", "-1"])
    assert bad.exit_code == 2 and "--call-timeout" in bad.output


def test_plot_writes_figure(examples, tmp_path):
    db = tmp_path / "t.db"
    runner = CliRunner()
    runner.invoke(main, ["run", str(examples / "double_pendulum_toggled.toml"), "--until", "3",
                         "--step", "0.01", "--out", str(db)])
    res = runner.invoke(main, ["plot", str(db), "-o", str(tmp_path / "fig.png")])
    assert res.exit_code == 0, res.output
    assert (tmp_path / "fig.png").stat().st_size > 10_000


def test_plot_chooses_variables_and_says_which_exist(examples, tmp_path):
    db = tmp_path / "t.db"
    runner = CliRunner()
    runner.invoke(main, ["run", str(examples / "double_pendulum_toggled.toml"), "--until", "1",
                         "--step", "0.01", "--out", str(db)])
    res = runner.invoke(main, ["plot", str(db), "-o", str(tmp_path / "one.png"),
                               "--variables", "bar1.theta"])
    assert res.exit_code == 0, res.output
    bad = runner.invoke(main, ["plot", str(db), "-o", str(tmp_path / "x.png"),
                               "--variables", "bar1.theta,bar9.x"])
    assert bad.exit_code == 2 and "bar9.x" in bad.output and "bar2.omega" in bad.output


def test_a_crowded_panel_says_so_and_the_last_step_is_drawn():
    """A legend of 200 outputs covered the figure; the step panel's line stopped where the
    last step began."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from cosimstep.plotting import LEGEND_MAX, _legend, _through_last

    fig, ax = plt.subplots()
    for i in range(LEGEND_MAX + 1):
        ax.plot([0, 1], [i, i], label=f"y{i}")
    _legend(ax)
    assert ax.get_legend() is None and "17 lines" in ax.texts[0].get_text()
    ax.lines[0].remove()
    _legend(ax)
    assert ax.get_legend() is not None
    plt.close(fig)
    x, y = _through_last(np.array([0.0, 0.1, 0.3]), np.array([0.1, 0.2, 0.05]))
    assert x[-1] == pytest.approx(0.35) and y[-1] == 0.05


def test_plot_missing_store_exits_2(tmp_path):
    res = CliRunner().invoke(main, ["plot", str(tmp_path / "none.db"), "-o", "x.png"])
    assert res.exit_code == 2 and "no results store" in res.output


def test_console_script_demo(tmp_path):
    """The installed entry point runs the embedded demo and writes results and a figure."""
    proc = subprocess.run([sys.executable, "-m", "cosimstep", "demo", "--out", str(tmp_path)],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "demo.png").stat().st_size > 20_000
    assert "status: ok" in proc.stdout
    from cosimstep.store import runs

    stored = runs(tmp_path / "demo.db")
    assert [s for _, _, s in stored] == ["ok"] * 3
    # the adaptive runs within their tolerance 1e-4, with fewer calls and less error than the
    # fixed step (measured: fixed 4000 calls, 2.1e-4; pc 2856, 1.2e-4; multirate 2162, 5.7e-5)
    rows = {line.split()[0]: line.split() for line in proc.stdout.splitlines()[1:4]}
    calls = {k: int(v[-3]) for k, v in rows.items()}
    errors = {k: float(v[-2]) for k, v in rows.items()}
    for adaptive in ("adaptive", "multirate,"):
        assert calls[adaptive] < calls["fixed"] and errors[adaptive] < errors["fixed"]
        assert 1e-5 < errors[adaptive] < 2e-4


def test_tolerance_with_fixed_controller_is_a_configuration_error(examples):
    res = CliRunner().invoke(main, ["run", str(examples / "double_pendulum_slow.toml"),
                                    "--controller", "fixed", "--tol", "1e-4"])
    assert res.exit_code == 2 and "does not use a tolerance" in res.output


def test_tol_alone_runs_the_default_adaptive_controller(examples, tmp_path):
    res = CliRunner().invoke(main, ["run", str(examples / "double_pendulum_slow.toml"),
                                    "--until", "2", "--tol", "1e-4", "--json",
                                    "--out", str(tmp_path / "r.db")])
    assert res.exit_code == 0, res.output
    summary = json.loads(res.output)
    assert summary["status"] == "ok" and summary["h_min"] < summary["h_max"]
    assert summary["error"]["max_abs"] < 1e-3


def test_controller_options_from_the_command_line(examples, tmp_path):
    base = ["run", str(examples / "double_pendulum_slow.toml"), "--until", "1",
            "--controller", "rkf23", "--tol", "1e-4", "--json", "--out", str(tmp_path / "r.db")]
    res = CliRunner().invoke(main, [*base, "--opt", "mode=reference", "--opt", "hmax=0.01"])
    assert res.exit_code == 0, res.output
    assert json.loads(res.output)["h_max"] <= 0.01
    bad = CliRunner().invoke(main, [*base, "--opt", "mode=everything"])
    assert bad.exit_code == 2 and "`mode` must be one of" in bad.output


def test_export_command_writes_an_fmu_and_refuses_bad_input(tmp_path):
    pytest.importorskip("pythonfmu")
    out = tmp_path / "bar1.fmu"
    res = CliRunner().invoke(main, ["export", "double_pendulum.bar1", "-o", str(out),
                                    "--param", "l1=0.5", "--start", "theta1=0.25"])
    assert res.exit_code == 0, res.output
    info = CliRunner().invoke(main, ["info", str(out), "--json"])
    assert info.exit_code == 0
    described = json.loads(info.output)
    names = {v["name"] for v in described["variables"]}
    assert {"theta", "omega", "theta2", "omega2", "l1"} <= names
    bad = CliRunner().invoke(main, ["export", "no_such_model", "-o", str(tmp_path / "x.fmu")])
    assert bad.exit_code == 2 and "known kinds" in bad.output
    bad = CliRunner().invoke(main, ["export", "double_pendulum.bar1", "-o", str(out),
                                    "--param", "l1=long"])
    assert bad.exit_code == 2 and "NAME=NUMBER" in bad.output


def test_rollback_without_state_saving_is_a_configuration_error(tmp_path):
    # Clock cannot save its state (like an FMU without canGetAndSetFMUstate)
    _helper_models(tmp_path)
    (tmp_path / "s.toml").write_text(
        'until = 1.0\n[models.clock]\ntype = "python"\nclass = "models.py:Clock"\n'
        '[models.sink]\ntype = "python"\nclass = "models.py:Integrator"\n'
        'parameters = { unit = "s" }\n[[connections]]\nfrom = "clock.time"\nto = "sink.u"\n')
    for extra in (["--tol", "1e-4"], ["--master", "multirate", "--tol", "1e-4"]):
        res = CliRunner().invoke(main, ["run", str(tmp_path / "s.toml"), *extra])
        assert res.exit_code == 2, res.output
        assert "clock cannot save and restore its state" in res.output
        assert "--controller fixed" in res.output


def test_keys_a_python_class_never_reads_are_refused(tmp_path):
    """`start`, `solver`, `path` on a type = "python" model were ignored without a word (the
    run started from the class's own state): each is named now, together, exit 2."""
    _helper_models(tmp_path)
    (tmp_path / "s.toml").write_text(
        'until = 1.0\n[models.clock]\ntype = "python"\nclass = "models.py:Clock"\n'
        'start = { time = 5.0 }\nsolver = { method = "RK45" }\npath = "x.fmu"\n'
        '[models.sink]\ntype = "python"\nclass = "models.py:Integrator"\n'
        'parameters = { unit = "s" }\n[[connections]]\nfrom = "clock.time"\nto = "sink.u"\n'
        '[controller]\nstep = 0.1\n')
    res = CliRunner().invoke(main, ["validate", str(tmp_path / "s.toml")])
    assert res.exit_code == 2, res.output
    for key in ("models.clock.start", "models.clock.solver", "models.clock.path"):
        assert f"{key}: not used by type 'python'" in res.output


def test_multirate_with_direct_feedthrough_is_a_configuration_error(tmp_path):
    # a sub-model whose output depends on its input at the same instant has no trajectory of
    # its own: refused with exit 2 and every reason, not a traceback from the master
    _helper_models(tmp_path)
    (tmp_path / "s.toml").write_text(
        'until = 1.0\n[models.sink]\ntype = "python"\nclass = "models.py:Integrator"\n'
        '[models.gain]\ntype = "python"\nclass = "models.py:Gain"\n'
        '[[connections]]\nfrom = "sink.x"\nto = "gain.u"\n'
        '[[connections]]\nfrom = "gain.y"\nto = "sink.u"\n')
    res = CliRunner().invoke(main, ["run", str(tmp_path / "s.toml"), "--master", "multirate",
                                    "--tol", "1e-4", "--interpolation", "hermite"])
    assert res.exit_code == 2, res.output
    assert "Traceback" not in res.output
    assert "'gain' has direct feedthrough" in res.output
    assert "'gain' gives no output derivatives" in res.output  # both listed at once
    assert "--master gauss-seidel" in res.output


def test_run_estimate_rerun_reports_its_estimate_and_cost(examples, tmp_path):
    res = CliRunner().invoke(main, ["run", str(examples / "linear_coupled.toml"), "--json",
                                    "--tol", "1e-3", "--until", "0.5", "--estimate", "rerun",
                                    "--out", str(tmp_path / "r.db")])
    assert res.exit_code == 0, res.output
    summary = json.loads(res.output)
    assert summary["error_estimate"] > 0 and summary["error"]["max_scaled"] > 0
    assert 0 < summary["error_estimate_calls"] < summary["calls_total"]
    slow = str(examples / "double_pendulum_slow.toml")
    bad = CliRunner().invoke(main, ["run", slow, "--controller", "fixed", "--step", "0.01",
                                    "--estimate", "rerun", "--out",
                                    str(tmp_path / "f.db")])
    assert bad.exit_code == 2 and "--estimate" in bad.output and "give --tol" in bad.output


def test_run_estimate_richardson_reports_the_companion_and_refuses_what_it_cannot_follow(
        examples, tmp_path):
    linear = str(examples / "linear_coupled.toml")
    res = CliRunner().invoke(main, ["run", linear, "--json", "--tol", "1e-3", "--until", "0.5",
                                    "--master", "gauss-seidel", "--estimate", "richardson",
                                    "--out", str(tmp_path / "r.db")])
    assert res.exit_code == 0, res.output
    summary = json.loads(res.output)
    assert summary["error_estimate"] > 0
    assert 0 < summary["error_estimate_calls"] < summary["calls_total"]
    bad = CliRunner().invoke(main, ["run", linear, "--tol", "1e-3", "--controller", "doubling",
                                    "--master", "multirate", "--estimate", "richardson",
                                    "--out", str(tmp_path / "b.db")])
    assert bad.exit_code == 2, bad.output
    assert "not pc" in bad.output and "one step sequence" in bad.output


def test_user_errors_are_configuration_errors_not_tracebacks(examples, tmp_path):
    runner = CliRunner()
    linear = str(examples / "linear_coupled.toml")
    cases = [
        (["run", linear, "--until", "-1"], "--until: must be a positive number"),
        (["run", linear, "--tol", "1e-3", "--opt", "foo=bar"],
         "unknown option 'foo' (fix: its options: tol, h0, probe_every, atol, rtol, hmin, hmax"),
    ]
    (tmp_path / "neg.toml").write_text(
        'until = 1.0\n[models.a]\ntype = "linear_coupled.slow"\n'
        '[controller]\nname = "fixed"\nstep = -0.1\n')
    cases.append((["validate", str(tmp_path / "neg.toml")],
                  "controller.step: must be a positive number, got -0.1"))
    # values the run once took without a word (a new user's trial, issue 13's standards)
    cases += [
        (["run", linear, "--tol", "inf"], "`tol` must be a positive finite number, got inf"),
        (["run", linear, "--tol", "1e-3", "--opt", "predictive=maybe"],
         "`predictive` must be true or false, got 'maybe'"),
        (["run", linear, "--tol", "1e-3", "--opt", "hmax=abc"], "`hmax` must be a number"),
        (["run", linear, "--start", "theta9=0.3"], "--start theta9: no model reads this start"),
        (["run", linear, "--master", "gauss-seidel", "--resync", "complete"],
         "this run's master is 'gauss-seidel'"),
        (["run", linear, "--out", str(tmp_path / "o.db"), "--no-store"],
         "--out: names the results store, --no-store keeps none"),
        (["run", linear, "-v", "-q"], "ask for more and for less output at once"),
        (["run", linear, "--resume", str(tmp_path / "nope.db")], "no results store"),
    ]
    (tmp_path / "solver.toml").write_text(
        'until = 1.0\nsolver = { method = "rk4", max_dtt = 0.01, substeps = -3 }\n'
        '[models.a]\ntype = "linear_coupled.slow"\n[models.b]\ntype = "linear_coupled.slow"\n'
        '[controller]\nname = "pc"\ntol = -1\n')
    cases.append((["validate", str(tmp_path / "solver.toml")],
                  "[top level].solver: rk4: no option 'max_dtt' (its options: substeps, max_dt); "
                  "'substeps' must be a whole number >= 1, got -3"))
    db = tmp_path / "r.db"
    runner.invoke(main, ["run", linear, "--until", "0.05", "--step", "0.01", "--out", str(db)])
    cases.append((["plot", str(db), "-o", str(tmp_path / "x.jpg2")],
                  "not a figure format matplotlib writes"))
    for args, expected in cases:
        res = runner.invoke(main, args)
        assert res.exit_code == 2, (args, res.output)
        assert expected in res.output and "Traceback" not in res.output, res.output
    assert not (tmp_path / "nope.db").exists()  # a refused --resume leaves no empty store
    # the shared solver is reported once, not once per model, beside the [controller] problem
    res = runner.invoke(main, ["validate", str(tmp_path / "solver.toml")])
    assert "2 problem(s)" in res.output and res.output.count("max_dtt") == 1
    assert "controller.tol: must be a positive number" in res.output


def test_one_bad_model_causes_no_follow_on_errors(tmp_path):
    (tmp_path / "bad.toml").write_text(
        'until = 1.0\n[models.bar1]\ntype = "double_pendulum.bar1"\n'
        'parameters = { l1 = "long" }\n[models.bar2]\ntype = "double_pendulum.bar2"\n'
        '[[connections]]\nfrom = "bar1.theta"\nto = "bar2.theta1"\n'
        '[[connections]]\nfrom = "bar2.theta"\nto = "bar1.theta2"\n')
    res = CliRunner().invoke(main, ["validate", str(tmp_path / "bad.toml")])
    assert res.exit_code == 2
    assert "1 problem(s)" in res.output and "models.bar1.parameters.l1" in res.output
    assert "unknown model" not in res.output


def test_param_and_start_change_a_run_without_editing_the_file(examples, tmp_path):
    runner = CliRunner()
    slow = str(examples / "double_pendulum_slow.toml")

    def run(*extra):
        res = runner.invoke(main, ["run", slow, "--until", "1", "--json", "--no-store", *extra])
        assert res.exit_code == 0, res.output
        return json.loads(res.output)

    base, shorter = run(), run("--param", "l2=0.4", "--start", "theta1=0.3")
    assert base["store"] is None and shorter["store"] is None and not list(tmp_path.iterdir())
    # the shared values reach the split models and the reference alike: still a small error
    assert shorter["error"]["max_scaled"] < 1e-5
    assert shorter["error"]["per_variable"] != base["error"]["per_variable"]
    res = runner.invoke(main, ["run", slow, "--param", "l9=0.4", "--param", "barX.l1=1",
                               "--no-store"])
    assert res.exit_code == 2
    assert "--param barX.l1: no model 'barX'" in res.output
    assert "--param l9: no model uses" in res.output


def test_budgets_end_a_run_timed_out_with_its_results_stored(examples, tmp_path):
    from cosimstep.multirate import MAX_PIECES
    from cosimstep.store import read_run

    slow = str(examples / "double_pendulum_slow.toml")
    cases = [(["--max-calls", "5000"], 5000, 512 + 2),  # fixed: checked every <= 256 steps
             (["--tol", "1e-6", "--max-calls", "800"], 800, 8),  # checked every attempt
             # multirate: checked every turn, and one turn can re-run a pending step in up
             # to MAX_PIECES pieces besides its own trial steps
             (["--master", "multirate", "--tol", "1e-6", "--max-calls", "800"], 800,
              MAX_PIECES + 16)]
    for i, (extra, budget, slack) in enumerate(cases):
        db = tmp_path / f"b{i}.db"
        res = CliRunner().invoke(main, ["run", slow, "--json", "--out", str(db), *extra])
        out = json.loads(res.output)
        assert res.exit_code == 1 and out["status"] == "timed_out", res.output
        assert "calls is spent" in out["message"]
        assert budget <= out["calls_total"] <= budget + slack, (extra, out["calls_total"])
        stored = read_run(db)
        assert stored.status == "timed_out" and 0 < stored.times[-1] < 10.0
        assert stored.times[-1] == pytest.approx(out["t_end"])  # every step so far is stored
    res = CliRunner().invoke(main, ["run", slow, "--tol", "1e-6", "--max-wall", "0.3", "--json",
                                    "--no-store"])
    out = json.loads(res.output)
    assert out["status"] == "timed_out" and "wall-time budget of 0.3 s" in out["message"]
    assert out["wall_s"] < 3.0


def test_misspelt_keys_are_named_with_a_suggestion_and_no_follow_on_errors(tmp_path):
    """A misspelt key, an unknown parameter of an event kind and an unknown controller option
    are each named once, with what was meant; the reference's map entry for the model that
    could not be built is not reported again."""
    (tmp_path / "typos.toml").write_text(
        'until = 1.0\n[models.a]\ntype = "linear_coupled.slow"\n'
        '[models.b]\ntpye = "linear_coupled.fast"\n'
        '[models.h]\ntype = "failure"\nparameters = { law = "weibull", sclae = 3.0 }\n'
        '[controller]\nname = "fixed"\nstepp = 0.001\n'
        '[reference]\ntype = "linear_coupled"\nmap = { "b.u" = "u" }\n')
    res = CliRunner().invoke(main, ["validate", str(tmp_path / "typos.toml")])
    assert res.exit_code == 2 and "Traceback" not in res.output, res.output
    assert "models.b.tpye: unknown key (fix: did you mean 'type'?)" in res.output
    assert "models.h.parameters.sclae: type 'failure' has no parameter 'sclae'" in res.output
    assert "controller.stepp: unknown option of 'fixed' (fix: did you mean 'step'?)" \
        in res.output
    assert "reference.map" not in res.output
    assert res.output.startswith("4 problem(s)"), res.output  # b.type missing is the fourth


def test_controllers_that_pass_options_on_load_with_them(tmp_path):
    """``switching`` and ``adaptive-tol`` hand options to the controller inside them: a file's
    [controller] with such options is valid (the check builds the controller, as a run does)."""
    for table in ('name = "switching"\ntol = 1e-4\nprobe_every = 10\n',
                  'name = "adaptive-tol"\ninner = "rkf45"\nmode = "all"\n'):
        (tmp_path / "c.toml").write_text(
            'until = 1.0\n[models.a]\ntype = "linear_coupled.slow"\n'
            '[models.b]\ntype = "linear_coupled.fast"\n'
            '[[connections]]\nfrom = "b.u"\nto = "a.u"\n'
            '[[connections]]\nfrom = "a.w"\nto = "b.w"\n'
            f'[controller]\n{table}')
        res = CliRunner().invoke(main, ["validate", str(tmp_path / "c.toml")])
        assert res.exit_code == 0 and "ok —" in res.output, res.output


def test_an_output_path_that_cannot_be_written_is_refused_before_any_work(examples, tmp_path):
    """A file where a folder must be, or an existing file that is no results store: exit 2
    naming the option, every command alike, and the user's file untouched (these ended in
    an SQLite or OS traceback, exit 1; sweep exited 0 with nothing run)."""
    system = str(examples / "double_pendulum_slow.toml")
    mine = tmp_path / "notes.txt"
    mine.write_text("keep me")
    db = tmp_path / "r.db"
    assert CliRunner().invoke(main, ["run", system, "--until", "0.1", "--out", str(db)]) \
        .exit_code == 0
    cases = [
        (["run", system, "--until", "0.1", "--out", str(mine / "x.db")], "--out", "not a folder"),
        (["run", system, "--until", "0.1", "--out", str(mine)], "--out", "not a results store"),
        (["sweep", system, "--param", "l2=1,2", "--out", str(mine)], "--out",
         "not a results store"),
        (["results", str(db), "-o", str(mine / "x.csv")], "-o", "not a folder"),
        (["plot", str(db), "-o", str(mine / "x.png")], "-o", "not a folder"),
        (["export", "pendulum_bar", "-o", str(mine / "e.fmu")], "-o", "not a folder"),
    ]
    for args, option, words in cases:
        res = CliRunner().invoke(main, args)
        assert res.exit_code == 2, (args, res.output)
        assert f"{option}:" in res.output and words in res.output, res.output
        assert "Traceback" not in res.output
    assert mine.read_text() == "keep me"


def test_every_problem_of_a_table_is_listed_and_true_is_no_number(tmp_path):
    """An unknown key in [master] no longer hides the bad values beside it, nor a bad step
    the unknown option beside it in [controller]; a model named twice in `order` is
    refused; a later [[parameter_changes]] entry is named by its own index when an earlier
    one was refused; `true` and quoted digits are no numbers (until = true ran to t = 1)."""
    path = tmp_path / "many.toml"
    path.write_text(
        'until = true\n[parameters]\nscale = "2"\n'
        '[models.a]\ntype = "linear_coupled.slow"\n[models.b]\ntype = "linear_coupled.fast"\n'
        '[[connections]]\nfrom = "a.v"\nto = "b.v"\n[[connections]]\nfrom = "b.u"\nto = "a.u"\n'
        'gain = true\n'
        '[master]\nextra_key = 1\ncoupling_tol = -1e-3\nmax_iterations = 0\n'
        'order = ["a", "a"]\n'
        '[controller]\nname = "fixed"\nstep = -0.001\nstepp = 3\n'
        '[[parameter_changes]]\nt = -1.0\nset = { lam = 50.0 }\n'
        '[[parameter_changes]]\nt = 1.0\nset = { lam = 60.0, lamb = 3.0 }\n')
    res = CliRunner().invoke(main, ["validate", str(path)])
    assert res.exit_code == 2 and "Traceback" not in res.output, res.output
    for words in ("[top level].until: must be a number, got true",
                  "[top level].parameters.scale: must be a number, got '2'",
                  "connections[1].gain: must be a number, got true",
                  "master.extra_key: unknown key",
                  "coupling_tol must be a positive number, got -0.001",
                  "max_iterations must be a whole number >= 1, got 0",
                  "master.order: names a more than once",
                  "controller.step: must be a positive number, got -0.001",
                  "controller.stepp: unknown option of 'fixed' (fix: did you mean 'step'?)",
                  "parameter_changes[0].t: -1 is before the run starts",
                  "parameter_changes[1].set.lamb: no model uses this parameter"):
        assert words in res.output, (words, res.output)


def test_a_python_model_file_imports_the_modules_beside_it(tmp_path):
    """``class = "plant.py:Plant"`` where plant.py does ``from parts import ...`` with
    parts.py beside it: found, as a script run from that folder finds it (it was not, unless
    another model had loaded parts.py first)."""
    (tmp_path / "s31parts.py").write_text(
        "import numpy as np\nfrom cosimstep import Port, SubModel\n"
        "class Source(SubModel):\n"
        "    inputs = ()\n    outputs = (Port('y', '1', 1.0),)\n"
        "    def set_inputs(self, values): pass\n"
        "    def do_step(self, t, h): pass\n"
        "    def get_outputs(self): return np.array([1.0])\n")
    (tmp_path / "s31plant.py").write_text("from s31parts import Source\n"
                                          "class Plant(Source):\n    pass\n")
    (tmp_path / "s.toml").write_text('until = 0.1\n[models.p]\ntype = "python"\n'
                                     'class = "s31plant.py:Plant"\n')
    res = CliRunner().invoke(main, ["run", str(tmp_path / "s.toml"), "--step", "0.05",
                                    "--no-store", "-q"])
    assert res.exit_code == 0, res.output


def test_options_that_would_change_nothing_are_refused(examples, tmp_path):
    """An option the run would ignore is refused like --resync without multirate: the
    iteration's settings with explicit coupling, checkpoints without a store or on a grid,
    a sample size with a full design; and a store of the other kind is named as such (a
    sweep table given to `runs`, a results store to `plot-sweep`, which is left as it was)."""
    system = str(examples / "double_pendulum_slow.toml")
    run = ["run", system, "--until", "0.1"]
    cases = [([*run, "--coupling-tol", "1e-6", "--no-store"], "--coupling-tol: sets the "
              "iteration of strong coupling"),
             ([*run, "--no-store", "--checkpoint-steps", "10"], "--checkpoint-steps: writes "
              "checkpoints, but --no-store"),
             ([*run, "--out", str(tmp_path / "g.db"), "--output-interval", "0.05",
               "--checkpoint-every", "5"], "--checkpoint-every: writes checkpoints, but a run "
              "stored on a grid"),
             (["sweep", system, "--param", "l2=1,2", "--samples", "5", "--out",
               str(tmp_path / "s.db")], "--samples: sets a sampled design; --design is full")]
    for args, words in cases:
        res = CliRunner().invoke(main, args)
        assert res.exit_code == 2 and words in res.output, (args, res.output)
    # but algebraic loops are solved to --coupling-tol; a number is read as Python reads it;
    # a start value stays a number
    _helper_models(tmp_path)
    (tmp_path / "loop.toml").write_text(
        'until = 0.1\n[models.a]\ntype = "python"\nclass = "models.py:Gain"\n'
        'parameters = { k = 0.5 }\n[models.b]\ntype = "python"\nclass = "models.py:Gain"\n'
        'parameters = { k = 0.5 }\n[[connections]]\nfrom = "a.y"\nto = "b.u"\noffset = 1.0\n'
        '[[connections]]\nfrom = "b.y"\nto = "a.u"\n')
    loop = ["run", str(tmp_path / "loop.toml"), "--step", "0.05", "--no-store", "-q"]
    res = CliRunner().invoke(main, [*loop, "--max-iterations", "3"])
    assert "--max-iterations: sets" in res.output  # only an iteration reads it
    for args in ([*loop, "--coupling-tol", "1e-12"],
                 [*run, "--param", "l2=.5", "--no-store", "-q"]):
        res = CliRunner().invoke(main, args)
        assert res.exit_code == 0, (args, res.output)
    res = CliRunner().invoke(main, [*run, "--start", "bar1.theta=true", "--no-store"])
    assert res.exit_code == 2 and "--start bar1.theta=true" in res.output
    db = tmp_path / "r.db"
    assert CliRunner().invoke(main, [*run, "--out", str(db)]).exit_code == 0
    before = db.read_bytes()
    res = CliRunner().invoke(main, ["plot-sweep", str(db), "--x", "l2", "-o",
                                    str(tmp_path / "p.png")])
    assert res.exit_code == 2 and "holds no sweep table (it is a results store" in res.output
    assert db.read_bytes() == before
    sweep_db = tmp_path / "sw.db"
    assert CliRunner().invoke(main, ["sweep", system, "--param", "l2=1", "--until", "0.1",
                                     "--step", "0.01", "--workers", "1", "-q", "--out",
                                     str(sweep_db)]).exit_code == 0
    res = CliRunner().invoke(main, ["runs", str(sweep_db)])
    assert res.exit_code == 2 and "it is a sweep table" in res.output


def test_a_refused_configuration_is_json_on_stdout_with_json(examples):
    """`run --json` whose command line or file is refused prints the problems as one JSON
    object on stdout (it printed nothing there), exit 2 as ever."""
    res = CliRunner().invoke(main, ["run", str(examples / "double_pendulum_slow.toml"),
                                    "--until", "-1", "--step", "0", "--json"])
    assert res.exit_code == 2
    out = json.loads(res.stdout[res.stdout.index("{"):])
    assert out["status"] == "invalid"
    assert {p["where"] for p in out["problems"]} >= {"--until"}
    assert all(p["what"] and p["fix"] for p in out["problems"])


def test_one_sub_models_text_parameter_from_the_command_line(tmp_path):
    """``--param 'MODEL.NAME="text"'`` sets a Python sub-model's string parameter (any TOML
    value, as in its table of the file); a shared value stays a number, and NaN, inf or a
    bare word are refused, each named."""
    (tmp_path / "s31modes.py").write_text(
        "import numpy as np\nfrom cosimstep import Port, SubModel\n"
        "class Mode(SubModel):\n"
        "    inputs = ()\n    outputs = (Port('y', '1', 0.0),)\n"
        "    def __init__(self, mode='off'):\n        self.mode = mode\n"
        "    def set_inputs(self, values): pass\n"
        "    def do_step(self, t, h): pass\n"
        "    def get_outputs(self): return np.array([{'off': 0.0, 'eco': 1.0}[self.mode]])\n")
    (tmp_path / "s.toml").write_text('until = 0.1\n[models.m]\ntype = "python"\n'
                                     'class = "s31modes.py:Mode"\n')
    from cosimstep import read_run

    args = ["run", str(tmp_path / "s.toml"), "--step", "0.05", "-q"]
    db = tmp_path / "r.db"
    res = CliRunner().invoke(main, [*args, "--param", 'm.mode="eco"', "--out", str(db)])
    assert res.exit_code == 0, res.output
    assert read_run(db).values[:, 0].tolist() == [1.0, 1.0, 1.0]  # 'eco', not 'off'
    res = CliRunner().invoke(main, [*args, "--param", "m.mode=eco", "--param", "x=nan",
                                    "--param", 'y="1"'])
    assert res.exit_code == 2
    assert all(f"--param {p}: expected NAME=NUMBER" in res.output
               for p in ("m.mode=eco", "x=nan", 'y="1"')), res.output


def test_rkf23_model_slopes_fall_back_to_the_fitted_cubic(examples):
    """``--opt slopes=model`` where some sub-model gives no output derivatives: the thesis's
    fitted cubic stands in (the run ended at t = 0 with KeyError 'model')."""
    res = CliRunner().invoke(main, ["run", str(examples / "pump_failure.toml"), "--until", "5",
                                    "--master", "gauss-seidel", "--controller", "rkf23",
                                    "--tol", "1e-3", "--opt", "slopes=model", "--no-store",
                                    "-q"])
    assert res.exit_code == 0 and "ok — completed" in res.output, res.output


def test_run_lists_the_command_lines_problems_with_the_files(examples):
    """A bad flag, a malformed --param, an unknown --opt, a negative --step and names no model
    reads were reported in three rounds (fix one, the next appeared): one list now, exit 2."""
    res = CliRunner().invoke(main, [
        "run", str(examples / "double_pendulum_slow.toml"), "--no-store", "--max-wall", "-1",
        "--step", "-0.01", "--tol", "1e-4", "--opt", "bogus=1", "--param", "zz=1",
        "--start", "qq=2", "--param", "broken"])
    assert res.exit_code == 2, res.output
    assert "6 problem(s)" in res.output
    for part in ("--max-wall", "--param broken", "unknown option 'bogus'",
                 "`step` (the initial step)", "--param zz", "--start qq"):
        assert part in res.output, part


def test_a_files_own_controller_problems_are_not_listed_twice(tmp_path):
    """With the file unreadable elsewhere, the command line's controller choices are checked on
    top of its [controller] table, but only where that table is sound: its own problems are
    the file's, listed once."""
    (tmp_path / "c.toml").write_text(
        'until = 1.0\n[models.a]\ntype = "linear_coupled.slow"\nsolver = { method = "rk4", '
        'substeps = 2.5 }\n[models.b]\ntype = "linear_coupled.fast"\n'
        '[[connections]]\nfrom = "b.u"\nto = "a.u"\n[[connections]]\nfrom = "a.w"\nto = "b.w"\n'
        '[controller]\ntol = 1e-4\nfoo = 1\n')
    res = CliRunner().invoke(main, ["run", str(tmp_path / "c.toml"), "--no-store",
                                    "--opt", "bar=2"])
    assert res.exit_code == 2, res.output
    assert res.output.count("foo") == 1
    assert "substeps" in res.output

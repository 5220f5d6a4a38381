"""`cosimstep run MODEL.fmu`: one FMU alone, as `fmpy simulate` runs it."""

from __future__ import annotations

import json
from pathlib import Path

import fmpy
import numpy as np
from click.testing import CliRunner

from cosimstep.cli import main
from cosimstep.store import read_run


def test_one_fmu_runs_alone_as_fmpy_runs_it(tmp_path: Path, bar_fmus: dict[int, Path]) -> None:
    db = tmp_path / "bar.db"
    res = CliRunner().invoke(main, ["run", str(bar_fmus[1]), "--until", "0.5", "--json",
                                    "--out", str(db)])
    assert res.exit_code == 0, res.output
    out = json.loads(res.output)
    # the default experiment's step (1 ms) over 0.5 s
    assert out["status"] == "ok" and out["calls_total"] == 500
    run = read_run(db)
    names = [n.split(".", 1)[1] for n in run.names]
    ref = fmpy.simulate_fmu(str(bar_fmus[1]), stop_time=0.5, step_size=1e-3, output=names)
    ours = run.values[-1]
    theirs = np.array([ref[n][-1] for n in names])
    assert np.max(np.abs(ours - theirs)) <= 1e-12, (ours, theirs)


def test_a_file_that_is_not_an_fmu_is_a_configuration_error(tmp_path: Path) -> None:
    bad = tmp_path / "bad.fmu"
    bad.write_text("not a zip")
    res = CliRunner().invoke(main, ["run", str(bad)])
    assert res.exit_code == 2 and "cannot read the FMU" in res.output
    assert "Traceback" not in res.output


def _write(path: Path, rows: str) -> Path:
    path.write_text("time,theta2,omega2\n" + rows)
    return path


def _final(spec, step: float, master=None) -> np.ndarray:
    import cosimstep

    r = cosimstep.simulate(spec.system, spec.until, cosimstep.make_controller(None, step),
                           master or spec.master)
    assert r.success, r.message
    return r.values[-1, [r.names.index(f"{spec.name}.theta"), r.names.index(f"{spec.name}.omega")]]


def test_inputs_from_a_csv(tmp_path: Path, bar_fmus: dict[int, Path]) -> None:
    import cosimstep
    from cosimstep.config import load_system

    # constant inputs other than the start values: as fmpy.simulate_fmu, to rounding
    const = _write(tmp_path / "const.csv", "0,0.1,0\n1,0.1,0\n")
    spec = load_system(bar_fmus[1], 1.0, inputs=const)
    data = np.genfromtxt(const, delimiter=",", names=True)
    ref = fmpy.simulate_fmu(str(bar_fmus[1]), stop_time=1.0, step_size=1e-3, input=data,
                            output=["theta", "omega"])
    assert np.max(np.abs(_final(spec, 1e-3) - [ref["theta"][-1], ref["omega"][-1]])) <= 1e-12
    # a ramp with a kink at 0.5 s: the bar follows each linear piece exactly (the table steps
    # first and lands on its rows), so the result does not depend on the step; it agrees with
    # held inputs, whose error is O(h), Richardson-extrapolated from 0.2 and 0.1 ms steps
    # (fmpy.simulate_fmu's result lies 8e-5 away from both on a single ramp)
    ramp = _write(tmp_path / "ramp.csv", "0,0,0\n0.5,0.2,0.4\n1,0.2,0\n")
    spec = load_system(bar_fmus[1], 1.0, inputs=ramp)
    coarse, fine = _final(spec, 0.0123), _final(spec, 1e-3)
    assert np.max(np.abs(coarse - fine)) <= 1e-9
    hold = cosimstep.MasterOptions("gauss-seidel", 0, spec.master.order)
    held = 2 * _final(spec, 1e-4, hold) - _final(spec, 2e-4, hold)
    assert np.max(np.abs(fine - held)) <= 1e-7, np.abs(fine - held)  # measured 2.4e-9


def test_csv_problems_are_listed_at_once(tmp_path: Path, bar_fmus: dict[int, Path]) -> None:
    bad = tmp_path / "bad.csv"
    bad.write_text("time,theta2,speed\n0,0.1,0\n0,x,0\n")
    res = CliRunner().invoke(main, ["run", str(bar_fmus[1]), "--inputs", str(bad)])
    assert res.exit_code == 2 and "Traceback" not in res.output
    assert "line 3" in res.output  # not a number
    res = CliRunner().invoke(main, ["run", str(bar_fmus[1]), "--inputs", str(
        _write(tmp_path / "names.csv", "0,0.1,0\n1,0.1,0\n").with_name("names.csv"))])
    assert res.exit_code == 0, res.output
    wrong = tmp_path / "wrong.csv"
    wrong.write_text("time,theta2,speed\n0,0.1,0\n1,0.2,0\n")
    res = CliRunner().invoke(main, ["run", str(bar_fmus[1]), "--inputs", str(wrong)])
    assert res.exit_code == 2 and "has no input 'speed'" in res.output
    assert "theta2, omega2" in res.output


def test_a_repeated_time_in_the_csv_is_a_step_change(tmp_path: Path) -> None:
    """Two rows with one time are a step change there (FMPy's input files write them so):
    the first row's value before it, the second's from it on; it was refused as "times must
    increase strictly". An integrator fed 0 then 1 from t = 0.5 holds exactly 0.5 at t = 1,
    with a fixed step that does not land on 0.5 by itself and under `pc`."""
    import cosimstep
    from cosimstep.adapters.table import InputTable
    from helpers import Integrator

    csv = tmp_path / "step.csv"
    csv.write_text("time,u\n0,0\n0.5,0\n0.5,1\n1,1\n")
    for controller in (cosimstep.Fixed(0.03), cosimstep.make_controller("pc", None, 1e-6)):
        table = InputTable.from_csv(csv)
        assert table.time_events() == [0.5]
        system = cosimstep.System().add("table", table).add("int", Integrator())
        system.connect(f"table.{table.outputs[0].name}", "int.u")
        r = cosimstep.simulate(system, 1.0, controller, cosimstep.MasterOptions("gauss-seidel"))
        assert r.status == "ok", r.message
        assert abs(r["int.x"][-1] - 0.5) < 1e-12


def test_csv_cells_that_are_not_finite_and_bad_time_orders_are_refused(tmp_path: Path) -> None:
    """A NaN cell was found only where the run read it (at t = 0, or as a failed run later)."""
    import pytest

    from cosimstep import ConfigurationError
    from cosimstep.adapters.table import InputTable

    cases = {"time,u\n0,1\n1,nan\n2,inf\n": ["line 3", "line 4", "not a finite number in u"],
             "time,u\n0,1\n1,2\n1,3\n1,4\n": ["more than two rows"],
             "time,u\n0,1\n2,2\n1,3\n": ["must not decrease"]}
    for i, (text, words) in enumerate(cases.items()):
        path = tmp_path / f"t{i}.csv"
        path.write_text(text)
        with pytest.raises(ConfigurationError) as info:
            InputTable.from_csv(path)
        message = str(info.value)
        assert all(w in message for w in words), message

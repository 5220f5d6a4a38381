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

"""`cosimstep info MODEL.fmu` on an FMU built from the repository's C sources."""

from __future__ import annotations

import json
from pathlib import Path

from click.testing import CliRunner

from cosimstep.cli import main


def test_info_lists_capabilities_and_variables(bar_fmus: dict[int, Path]) -> None:
    res = CliRunner().invoke(main, ["info", str(bar_fmus[2])])
    assert res.exit_code == 0, res.output
    text = res.output
    for expected in ("FMI version      2.0", "kind             CS", "pendulum_bar2 (CS)",
                     "generation tool  cosimstep", "canGetAndSetFMUstate", "canSerializeFMUstate",
                     "maxOutputDerivativeOrder                 1", "stopTime = 10.0"):
        assert expected in text, text
    rows = {line.split()[0]: line.split() for line in text.splitlines()[-10:]}
    assert rows["theta1"] == ["theta1", "input", "continuous", "Real", "0.4", "rad"]
    assert rows["omega"] == ["omega", "output", "continuous", "Real", "0", "rad/s"]
    assert rows["g"] == ["g", "parameter", "fixed", "Real", "9.81", "m/s2"]


def test_info_json(bar_fmus: dict[int, Path]) -> None:
    res = CliRunner().invoke(main, ["info", str(bar_fmus[1]), "--json"])
    assert res.exit_code == 0, res.output
    info = json.loads(res.output)
    assert info["fmiVersion"] == "2.0" and info["kind"] == ["CS"]
    assert info["modelIdentifier"] == {"CS": "pendulum_bar1"}
    caps = info["capabilities"]["CS"]
    assert caps["canGetAndSetFMUstate"] is True and caps["canInterpolateInputs"] is True
    assert caps["canHandleVariableCommunicationStepSize"] is True
    assert caps["maxOutputDerivativeOrder"] == 1
    assert info["defaultExperiment"]["stopTime"] == 10.0
    names = [v["name"] for v in info["variables"]]
    assert names == ["theta", "omega", "theta2", "omega2", "m1", "m2", "l1", "l2", "g", "max_dt"]
    assert info["variables"][2] == {"name": "theta2", "causality": "input",
                                    "variability": "continuous", "type": "Real", "start": -0.3,
                                    "unit": "rad", "description": "angle of bar 2"}


def test_info_refuses_bad_files(tmp_path: Path) -> None:
    junk = tmp_path / "junk.fmu"
    junk.write_bytes(b"\x00not a zip")
    res = CliRunner().invoke(main, ["info", str(junk)])
    assert res.exit_code == 2 and "not a zip archive" in res.output
    res = CliRunner().invoke(main, ["info", str(tmp_path / "none.fmu")])
    assert res.exit_code == 2 and "no such file" in res.output

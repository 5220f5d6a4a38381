"""TOML system files with `type = "fmu"` models: the split double pendulum made of two C FMUs
(built from a recipe on first use, or given by path) runs and agrees with the pure-Python split
pendulum of examples/double_pendulum_slow.toml; wrong FMU sections list every problem."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import cosimstep
from cosimstep.cli import main

UNTIL = 2.0
TOLERANCE = 1e-9

SHARED = """
until = 2.0
[parameters]
m1 = 1.0
m2 = 1.0
l1 = 1.0
l2 = 1.0
g = 9.81
[start]
theta1 = 0.4
theta2 = -0.3
omega1 = 0.0
omega2 = 0.0
[[connections]]
from = "bar1.theta"
to = "bar2.theta1"
[[connections]]
from = "bar1.omega"
to = "bar2.omega1"
[[connections]]
from = "bar2.theta"
to = "bar1.theta2"
[[connections]]
from = "bar2.omega"
to = "bar1.omega2"
[controller]
name = "fixed"
step = 0.001
[reference]
type = "double_pendulum"
map = { "bar1.theta" = "theta1", "bar1.omega" = "omega1", "bar2.theta" = "theta2", \
"bar2.omega" = "omega2" }
"""


def bars(source1: str, source2: str) -> str:
    return f"""
[models.bar1]
type = "fmu"
{source1}
start = {{ theta = 0.4, omega = 0.0, theta2 = -0.3, omega2 = 0.0 }}
[models.bar2]
type = "fmu"
{source2}
start = {{ theta = -0.3, omega = 0.0, theta1 = 0.4, omega1 = 0.0 }}
"""


@pytest.mark.parametrize("how", ["recipe", "path"])
def test_fmu_toml_matches_python_pendulum(tmp_path: Path, examples: Path,
                                          bar_fmus: dict[int, Path], how: str) -> None:
    if how == "recipe":
        models = bars('recipe = "pendulum_bar1"', 'recipe = "pendulum_bar2"')
    else:
        (tmp_path / "fmus").mkdir()
        for bar, fmu in bar_fmus.items():
            shutil.copy(fmu, tmp_path / "fmus" / f"bar{bar}.fmu")
        models = bars('path = "fmus/bar1.fmu"', 'path = "fmus/bar2.fmu"')
    file = tmp_path / "dp_fmu.toml"
    file.write_text(SHARED + models)

    spec = cosimstep.load_system(file)
    master = cosimstep.MasterOptions("gauss-seidel", 2)
    fmu = cosimstep.simulate(spec.system, UNTIL, cosimstep.Fixed(0.001), master,
                             reference=spec.reference)
    py_spec = cosimstep.load_system(examples / "double_pendulum_slow.toml")
    py = cosimstep.simulate(py_spec.system, UNTIL, cosimstep.Fixed(0.001), master,
                            reference=py_spec.reference)
    assert fmu.success and py.success
    assert fmu.names == py.names and fmu.times.shape == py.times.shape
    assert np.max(np.abs(fmu.values - py.values)) <= TOLERANCE
    assert fmu.error.max_abs == pytest.approx(py.error.max_abs, rel=1e-6)
    assert fmu.error.max_abs < 1e-6


def test_fmu_sections_list_every_problem(tmp_path: Path, bar_fmus: dict[int, Path]) -> None:
    shutil.copy(bar_fmus[1], tmp_path / "bar1.fmu")
    (tmp_path / "notes.fmu").write_text("not a zip")
    file = tmp_path / "bad.toml"
    file.write_text("""
[models.a]
type = "fmu"
path = "missing.fmu"
[models.b]
type = "fmu"
path = "bar1.fmu"
parameters = { lenght = 1.0, theta = 0.1 }
start = { thetaa = 0.2 }
[models.c]
type = "fmu"
path = "notes.fmu"
[models.d]
type = "fmu"
recipe = "pendulum_bar9"
[models.e]
type = "fmu"
""")
    res = CliRunner().invoke(main, ["validate", str(file)])
    assert res.exit_code == 2
    text = res.output
    for expected in ("models.a.path: no such file", "models.b.parameters.lenght",
                     "its parameters: g, l1, l2, m1, m2, max_dt",
                     "models.b.parameters.theta: 'theta' has causality output",
                     "models.b.start.thetaa", "models.c: cannot use FMU",
                     "not a zip archive", "unknown built-in FMU recipe 'pendulum_bar9'",
                     "models.e: type 'fmu' needs exactly one of `path`, `recipe` and `export`"):
        assert expected in text, text
    assert "7 problem(s)" in text

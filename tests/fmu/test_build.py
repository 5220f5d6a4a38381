"""Building the C pendulum-bar FMUs: archive layout, model description, build reuse."""

from __future__ import annotations

import zipfile
from pathlib import Path

import fmpy
import pytest

from cosimstep.fmu.build import FmuBuildError, build_fmu


@pytest.mark.parametrize("bar,other", [(1, 2), (2, 1)])
def test_model_description(bar_fmus: dict[int, Path], bar: int, other: int) -> None:
    path = bar_fmus[bar]
    with zipfile.ZipFile(path) as zf:
        names = set(zf.namelist())
    assert {"modelDescription.xml", f"binaries/linux64/pendulum_bar{bar}.so",
            "sources/pendulum_bar.c", "sources/fmi2.h", f"sources/pendulum_bar{bar}.c"} <= names
    md = fmpy.read_model_description(str(path), validate=True)
    cs = md.coSimulation
    assert md.fmiVersion == "2.0" and md.modelExchange is None
    assert cs.modelIdentifier == f"pendulum_bar{bar}"
    assert cs.canGetAndSetFMUstate and cs.canSerializeFMUstate and cs.canInterpolateInputs
    assert cs.maxOutputDerivativeOrder == 1
    variables = {v.name: v for v in md.modelVariables}
    for name, unit, causality in (("theta", "rad", "output"), ("omega", "rad/s", "output"),
                                  (f"theta{other}", "rad", "input"),
                                  (f"omega{other}", "rad/s", "input")):
        assert (variables[name].unit, variables[name].causality) == (unit, causality)
    assert variables["theta"].initial == "exact"
    for name in ("m1", "m2", "l1", "l2", "g", "max_dt"):
        assert (variables[name].causality, variables[name].variability) == ("parameter", "fixed")
    assert [u.variable.name for u in md.outputs] == ["theta", "omega"]
    assert all(u.dependencies == [] for u in md.outputs)  # no direct feedthrough


def test_build_is_reused(bar_fmus: dict[int, Path], fmu_cache: Path) -> None:
    before = bar_fmus[1].stat().st_mtime_ns
    assert build_fmu("pendulum_bar1", cache=fmu_cache) == bar_fmus[1]
    assert bar_fmus[1].stat().st_mtime_ns == before


def test_explicit_output_and_missing_compiler(tmp_path: Path) -> None:
    with pytest.raises(FmuBuildError, match="C compiler `no-such-cc` not found"):
        build_fmu("pendulum_bar2", tmp_path, compiler="no-such-cc")
    with pytest.raises(FmuBuildError, match="neither a built-in FMU"):
        build_fmu("pendulum_bar3", tmp_path)


def test_rebuild_from_shipped_sources(bar_fmus: dict[int, Path], tmp_path: Path) -> None:
    """The archive's sources/ plus its model description build the same FMU again."""
    folder = tmp_path / "src"
    folder.mkdir()
    with zipfile.ZipFile(bar_fmus[2]) as zf:
        for name in zf.namelist():
            if name.startswith("sources/") or name == "modelDescription.xml":
                (folder / Path(name).name).write_bytes(zf.read(name))
    rebuilt = build_fmu(folder, tmp_path / "out.fmu")
    with zipfile.ZipFile(rebuilt) as zf:
        assert "binaries/linux64/pendulum_bar2.so" in zf.namelist()
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(FmuBuildError, match=r"no modelDescription\.xml and no \*\.c files"):
        build_fmu(empty, tmp_path)

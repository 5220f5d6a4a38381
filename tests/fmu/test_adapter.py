"""FmuSubModel on the pendulum-bar FMU: ports, capabilities, exact save/restore, agreement with
the Python bar step by step, errors naming the FMU and call, cleanup, and refused archives."""

from __future__ import annotations

import re
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest

from cosimstep import RK4, ParameterSchedule
from cosimstep.adapters.fmu import FmuError, FmuSubModel
from cosimstep.models.pendulum import bar, default_parameters

START = {"theta1": 0.4, "theta2": -0.3, "omega1": 0.0, "omega2": 0.0}


def python_bar(i: int):
    return bar(2, i, ParameterSchedule(default_parameters(2)), START, RK4(max_dt=1e-3))


def test_ports_and_capabilities(bar_fmus: dict[int, Path]) -> None:
    model = FmuSubModel(bar_fmus[2], {"theta": -0.3, "m1": 2.0})
    assert [(p.name, p.unit, p.start) for p in model.outputs] == [
        ("theta", "rad", -0.3), ("omega", "rad/s", 0.0)]
    assert [(p.name, p.unit, p.start) for p in model.inputs] == [
        ("theta1", "rad", 0.4), ("omega1", "rad/s", 0.0)]
    caps = model.capabilities
    assert caps.can_save_state and caps.provides_derivatives
    assert caps.max_input_derivative_order == 3
    assert not caps.has_direct_feedthrough
    with pytest.raises(ValueError, match="'mass' is not a variable"):
        FmuSubModel(bar_fmus[2], {"mass": 2.0})


def drive(model, steps: int, t: float = 0.0, h: float = 0.0123) -> tuple[list, float]:
    """Steps with a cubic input polynomial each time (the FMU's Taylor path)."""
    out = []
    for k in range(steps):
        model.set_inputs(np.array([0.4 - 0.01 * k, 0.1 * k]))
        model.set_input_derivatives(np.array([[0.3, -0.2], [0.05, 1.5], [-2.0, 0.7]])[: 1 + k % 3])
        model.do_step(t, h)
        out.append((model.get_outputs().copy(), model.get_output_derivatives().copy()))
        t += h
    return out, t


@pytest.mark.parametrize("i", [1, 2])
def test_fmu_matches_python_bar_bit_for_bit(bar_fmus: dict[int, Path], i: int) -> None:
    fmu, py = FmuSubModel(bar_fmus[i], {"theta": START[f"theta{i}"]}), python_bar(i)
    fmu.initialize(0.0)
    py.initialize(0.0)
    try:
        a, _ = drive(fmu, 12)
        b, _ = drive(py, 12)
    finally:
        fmu.terminate()
    for (ya, da), (yb, db) in zip(a, b):
        assert np.array_equal(ya, yb) and np.array_equal(da, db)


def test_restore_reproduces_a_step_exactly(bar_fmus: dict[int, Path]) -> None:
    model = FmuSubModel(bar_fmus[1])
    model.initialize(0.0)
    try:
        _, t = drive(model, 5)
        token = model.save_state()
        first, _ = drive(model, 3, t)
        for _ in range(3):  # tokens dropped and states reused must not disturb the saved one
            model.save_state()
        model.restore_state(token)
        again, _ = drive(model, 3, t)
        model.restore_state(token)
        model.set_inputs(np.array([0.4, 0.0]))  # values alone: inputs held, derivatives cleared
        model.do_step(t, 0.0123)
        held = model.get_outputs()
    finally:
        model.terminate()
    for (ya, da), (yb, db) in zip(first, again):
        assert np.array_equal(ya, yb) and np.array_equal(da, db)
    py = python_bar(1)
    py.initialize(0.0)
    _, t = drive(py, 5)
    py.set_inputs(np.array([0.4, 0.0]))
    py.do_step(t, 0.0123)
    assert np.array_equal(held, py.get_outputs())
    with pytest.raises(ValueError, match="did not save"):
        model.restore_state(token)


def test_failed_call_names_fmu_and_call_and_cleans_up(bar_fmus: dict[int, Path]) -> None:
    model = FmuSubModel(bar_fmus[1], instance_name="upper")
    model.initialize(0.0)
    folder = model._unzipped
    assert folder is not None and folder.is_dir()
    with pytest.raises(FmuError, match=r"FMU 'upper' .*fmi2DoStep returned error.*differs from "
                                       "the FMU time"):
        model.do_step(5.0, 0.01)
    model.terminate()
    assert model._fmu is None
    assert folder.is_dir()  # with the loaded library, until the process exits

    bad = FmuSubModel(bar_fmus[1], {"max_dt": -1.0})
    with pytest.raises(FmuError, match=r"fmi2ExitInitializationMode returned error.*max_dt must be "
                                       r"positive"):
        bad.initialize(0.0)
    assert bad._unzipped is None and bad._fmu is None


def _rewrite(source: Path, target: Path, *, drop: str | None = None,
             add: dict[str, bytes] | None = None, md=None) -> Path:
    with zipfile.ZipFile(source) as zin, zipfile.ZipFile(target, "w") as zout:
        for item in zin.infolist():
            if drop and item.filename.startswith(drop):
                continue
            data = zin.read(item)
            if md is not None and item.filename == "modelDescription.xml":
                data = md(data.decode()).encode()
            zout.writestr(item, data)
        for name, data in (add or {}).items():
            zout.writestr(name, data)
    return target


def test_refusals(bar_fmus: dict[int, Path], tmp_path: Path) -> None:
    good = bar_fmus[1]
    corrupt = tmp_path / "corrupt.fmu"
    corrupt.write_bytes(b"PK\x03\x04 this is not really a zip archive")
    no_md = _rewrite(good, tmp_path / "no_md.fmu", drop="modelDescription.xml")
    traversal = _rewrite(good, tmp_path / "traversal.fmu", add={"../../evil.txt": b"x"})
    absolute = _rewrite(good, tmp_path / "absolute.fmu", add={"/tmp/evil.txt": b"x"})
    windows_only = _rewrite(good, tmp_path / "windows.fmu", drop="binaries/linux64",
                            add={"binaries/win64/pendulum_bar1.dll": b"MZ"})
    me_only = _rewrite(good, tmp_path / "me.fmu", md=lambda xml: re.sub(
        r"<CoSimulation.*</CoSimulation>", '<ModelExchange modelIdentifier="pendulum_bar1"/>',
        xml, flags=re.S))
    cases = [(corrupt, "not a zip archive"),
             (no_md, "no modelDescription.xml"),
             (traversal, r"entry '\.\./\.\./evil\.txt' would unpack outside"),
             (absolute, r"entry '/tmp/evil\.txt' would unpack outside"),
             (windows_only, r"no binary for this platform \(binaries/linux64/pendulum_bar1\.so is "
                            r"missing; it has binaries for: win64\)"),
             (me_only, "model exchange only"),
             (tmp_path / "missing.fmu", "no such file")]
    for path, message in cases:
        with pytest.raises(ValueError, match=message) as info:
            FmuSubModel(path)
        assert str(path) in str(info.value)
    assert not (tmp_path.parent / "evil.txt").exists()
    shutil.rmtree(tmp_path)


def test_serialized_state_round_trip(bar_fmus: dict[int, Path]) -> None:
    model = FmuSubModel(bar_fmus[2])
    model.initialize(0.0)
    try:
        _, t = drive(model, 4)
        fmu = model._fmu
        state = fmu.getFMUstate()
        data = fmu.serializeFMUstate(state)
        fmu.freeFMUstate(state)
        first, _ = drive(model, 2, t)
        copy = fmu.deSerializeFMUstate(data)
        fmu.setFMUstate(copy)
        fmu.freeFMUstate(copy)
        again, _ = drive(model, 2, t)
        with pytest.raises(Exception, match="fmi2DeSerializeFMUstate"):
            fmu.deSerializeFMUstate(data[:-1])
    finally:
        model.terminate()
    for (ya, da), (yb, db) in zip(first, again):
        assert np.array_equal(ya, yb) and np.array_equal(da, db)

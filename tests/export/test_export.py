"""Built-in sub-models exported as FMI 2.0 co-simulation FMUs with pythonfmu (issue 5, item 5):
the model description mirrors the ports, a step runs the same Python sub-model bit for bit, FMU
state save/restore (also serialized) reproduces a step exactly, and the split double pendulum of
examples/double_pendulum_slow.toml made of two exported FMUs agrees with the pure-Python one.

pythonfmu's runtime refuses ``fmi2SetRealInputDerivatives``, so the exported FMUs hold inputs over
a step: the comparison with the Python bars is made at extrapolation order 0."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import fmpy
import numpy as np
import pytest
from fmpy.fmi2 import FMU2Slave

import cosimstep
from cosimstep import RK4, ParameterSchedule
from cosimstep.adapters.fmu import FmuSubModel
from cosimstep.controllers import make_controller
from cosimstep.models.pendulum import bar, default_parameters

from .conftest import START

UNTIL = 2.0


class CountingFmu(FmuSubModel):
    restores = 0

    def restore_state(self, token: Any) -> None:
        self.restores += 1
        super().restore_state(token)


def fmu_pendulum(bars: dict[int, Path]) -> cosimstep.System:
    system = cosimstep.System()
    system.add("bar1", CountingFmu(bars[1]))
    system.add("bar2", CountingFmu(bars[2]))
    system.connect("bar1.theta", "bar2.theta1").connect("bar1.omega", "bar2.omega1")
    system.connect("bar2.theta", "bar1.theta2").connect("bar2.omega", "bar1.omega2")
    return system


def python_pendulum(examples: Path) -> cosimstep.System:
    return cosimstep.load_system(examples / "double_pendulum_slow.toml").system


def test_model_description_mirrors_the_ports(exported_bars: dict[int, Path]) -> None:
    model = FmuSubModel(exported_bars[2], {"theta": -0.25, "m1": 2.0})
    assert [(p.name, p.unit, p.start) for p in model.outputs] == [
        ("theta", "rad", -0.25), ("omega", "rad/s", 0.0)]
    assert [(p.name, p.unit, p.start) for p in model.inputs] == [
        ("theta1", "rad", 0.4), ("omega1", "rad/s", 0.0)]
    caps = model.capabilities
    assert caps.can_save_state and not caps.has_direct_feedthrough
    # pythonfmu's runtime implements neither input nor output derivatives
    assert caps.max_input_derivative_order == 0 and not caps.provides_derivatives
    md = model.model_description
    assert md.coSimulation.canSerializeFMUstate and not md.coSimulation.canInterpolateInputs
    assert sorted(u.name for u in md.unitDefinitions) == ["rad", "rad/s"]
    params = {v.name: float(v.start) for v in md.modelVariables if v.causality == "parameter"}
    assert params == default_parameters(2)


def test_refusals(exported_bars: dict[int, Path], tmp_path: Path) -> None:
    from cosimstep.fmu.export import export_fmu

    with pytest.raises(ValueError, match=r"'pendulum' is not a built-in.*double_pendulum\.bar1"):
        export_fmu("pendulum", tmp_path)
    with pytest.raises(ValueError, match=r"`parameters`.*'mass' is not one of its parameters"):
        export_fmu("double_pendulum.bar1", tmp_path, parameters={"mass": 2.0})
    with pytest.raises(ValueError, match=r"`start`.*'theta3' is not one of its start"):
        export_fmu("double_pendulum.bar1", tmp_path, start={"theta3": 0.1})
    with pytest.raises(ValueError, match="'g' must be a finite number"):
        export_fmu("double_pendulum.bar1", tmp_path, parameters={"g": "9.81"})
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("i", [1, 2])
def test_step_matches_python_bar_bit_for_bit(exported_bars: dict[int, Path], i: int) -> None:
    """Parameters and start values set on the FMU reach the sub-model it runs."""
    params = {**default_parameters(2), "m2": 2.0, "l1": 0.8}
    start = {**START, f"theta{i}": 0.25}
    fmu = FmuSubModel(exported_bars[i], {"m2": 2.0, "l1": 0.8, "theta": 0.25})
    py = bar(2, i, ParameterSchedule(params), start, RK4(max_dt=1e-3))
    fmu.initialize(0.0)
    py.initialize(0.0)
    try:
        t, h = 0.0, 0.0123
        for k in range(10):
            u = np.array([0.4 - 0.01 * k, 0.1 * k])
            for model in (fmu, py):
                model.set_inputs(u)
                model.do_step(t, h)
            assert np.array_equal(fmu.get_outputs(), py.get_outputs())
            t += h
    finally:
        fmu.terminate()


def test_restore_reproduces_a_step_exactly(exported_bars: dict[int, Path]) -> None:
    model = FmuSubModel(exported_bars[1])
    model.initialize(0.0)
    try:
        model.set_inputs(np.array([-0.3, 0.1]))
        model.do_step(0.0, 0.01)
        token = model.save_state()
        model.set_inputs(np.array([-0.2, 0.3]))
        model.do_step(0.01, 0.02)
        first = model.get_outputs()
        for _ in range(3):  # later saves must not disturb the earlier state
            model.save_state()
        model.restore_state(token)
        model.set_inputs(np.array([-0.2, 0.3]))
        model.do_step(0.01, 0.02)
        assert np.array_equal(model.get_outputs(), first)
    finally:
        model.terminate()


def test_serialized_state_round_trip_through_fmpy(exported_bars: dict[int, Path],
                                                  tmp_path: Path) -> None:
    md = fmpy.read_model_description(str(exported_bars[2]))
    fmpy.extract(str(exported_bars[2]), unzipdir=str(tmp_path))
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=str(tmp_path),
                    modelIdentifier=md.coSimulation.modelIdentifier, instanceName="bar2")
    fmu.instantiate()
    try:
        fmu.setupExperiment(startTime=0.0)
        fmu.enterInitializationMode()
        fmu.exitInitializationMode()
        vr = {v.name: v.valueReference for v in md.modelVariables}
        outs, ins = [vr["theta"], vr["omega"]], [vr["theta1"], vr["omega1"]]
        fmu.setReal(ins, [0.4, 0.0])
        fmu.doStep(0.0, 0.05)
        blob = fmu.serializeFMUstate(fmu.getFMUstate())
        fmu.setReal(ins, [0.35, -0.2])
        fmu.doStep(0.05, 0.05)
        first = fmu.getReal(outs)
        fmu.doStep(0.1, 0.05)  # move on, then come back from the bytes
        state = fmu.deSerializeFMUstate(blob)
        fmu.setFMUstate(state)
        fmu.freeFMUstate(state)
        assert fmu.getReal(ins) == [0.4, 0.0]  # the inputs held then are part of the state
        fmu.setReal(ins, [0.35, -0.2])
        fmu.doStep(0.05, 0.05)
        assert fmu.getReal(outs) == first
        fmu.terminate()
    finally:
        fmu.freeInstance()


def test_split_pendulum_matches_python_at_order_0(exported_bars: dict[int, Path],
                                                  examples: Path) -> None:
    """Gauss–Seidel, h = 0.001, inputs held (order 0): the same arithmetic, so the same numbers."""
    master = cosimstep.MasterOptions("gauss-seidel", 0)
    fmu = cosimstep.simulate(fmu_pendulum(exported_bars), UNTIL, cosimstep.Fixed(0.001), master)
    py = cosimstep.simulate(python_pendulum(examples), UNTIL, cosimstep.Fixed(0.001), master)
    assert fmu.success and py.success, (fmu.message, py.message)
    assert fmu.names == py.names and fmu.values.shape == py.values.shape == (2001, 4)
    assert np.max(np.abs(fmu.times - py.times)) <= 1e-12
    assert np.max(np.abs(fmu.values - py.values)) <= 1e-12  # measured: 0.0


def test_adaptive_run_with_rollback(exported_bars: dict[int, Path], examples: Path) -> None:
    """The predictor–corrector controller re-runs every step from a restored FMU state.

    Inputs held without slopes (pythonfmu takes no input derivatives) leave a first-order
    coupling error, so tol 1e-4 costs small steps: about 2,500 to 0.3 s (the whole 2 s took
    790,000 calls and two minutes)."""
    until = 0.3
    spec = cosimstep.load_system(examples / "double_pendulum_slow.toml")
    system = fmu_pendulum(exported_bars)
    result = cosimstep.simulate(system, until, make_controller("pc", None, 1e-4),
                                cosimstep.MasterOptions("gauss-seidel", 0))
    assert result.success, result.message
    assert result.times[-1] == pytest.approx(until)
    restores = [m.restores for m in system.models.values()]
    assert restores[0] == restores[1] >= result.steps_accepted > 100
    spec.reference.solve(0.0, until)
    error = np.max(np.abs(result.values - spec.reference.values(result.times, result.names)))
    assert error < 1e-4  # measured 4.6e-5 in 2467 steps


def test_exported_fmus_run_on_one_copy_of_the_runtime(exported_bars: dict[int, Path]) -> None:
    """Every pythonfmu FMU ships the same runtime library; unpacked, the two bars' binaries are
    one file, so the loader maps one copy of it (two copies share process-wide C++ objects and
    both destroy them at exit: docs/reliability.md)."""
    import os

    bars = [FmuSubModel(exported_bars[i]) for i in (1, 2)]
    for model in bars:
        model.initialize(0.0)
    try:
        libraries = [Path(m._fmu.dll._name) for m in bars]
        assert libraries[0] != libraries[1]  # each FMU's own name and folder
        assert os.stat(libraries[0]).st_ino == os.stat(libraries[1]).st_ino
        assert bars[0]._fmu.dll._handle == bars[1]._fmu.dll._handle
    finally:
        for model in bars:
            model.terminate()

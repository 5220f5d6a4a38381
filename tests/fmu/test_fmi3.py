"""FMI 3.0 co-simulation (issue 5): the pendulum-bar FMU built from pendulum_bar_fmi3.c through
Fmu3SubModel. FMI 3.0 has no input derivatives, so the FMU holds its inputs over a step; the
Python bars it is compared with are made to hold theirs too (max_input_derivative_order = 0), so
the master hands both the same mid-step extrapolated inputs and the numbers must agree."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import cosimstep
import helpers
from cosimstep import RK4, ParameterSchedule
from cosimstep.adapters.fmu import FmuError, FmuSubModel
from cosimstep.adapters.fmu3 import Fmu3SubModel
from cosimstep.adapters.fmu_open import open_fmu
from cosimstep.controllers import make_controller
from cosimstep.fmu.build import build_fmu
from cosimstep.models.pendulum import bar, default_parameters

START = {"theta1": 0.4, "theta2": -0.3, "omega1": 0.0, "omega2": 0.0}
TOLERANCE = 1e-9


@pytest.fixture(scope="module")
def fmi3_bars(fmu_cache: Path) -> dict[int, Path]:
    return {i: build_fmu(f"pendulum_bar{i}_fmi3", cache=fmu_cache) for i in (1, 2)}


class CountingFmu3(Fmu3SubModel):
    restores = 0

    def restore_state(self, token: Any) -> None:
        self.restores += 1
        super().restore_state(token)


def hold_only(model: cosimstep.SubModel) -> cosimstep.SubModel:
    model.capabilities = dataclasses.replace(model.capabilities, max_input_derivative_order=0)
    return model


def python_pendulum() -> cosimstep.System:
    """The Python split pendulum with bars that hold their inputs, like the FMI 3.0 bars."""
    system = cosimstep.System()
    for i in (1, 2):
        system.add(f"bar{i}", hold_only(bar(2, i, ParameterSchedule(default_parameters(2)),
                                            START, RK4(max_dt=1e-3))))
    system.connect("bar1.theta", "bar2.theta1").connect("bar1.omega", "bar2.omega1")
    system.connect("bar2.theta", "bar1.theta2").connect("bar2.omega", "bar1.omega2")
    return system


def test_ports_capabilities_and_exact_restore(fmi3_bars: dict[int, Path]) -> None:
    model = Fmu3SubModel(fmi3_bars[2], {"theta": -0.3, "m1": 1.0}, instance_name="lower")
    assert [(p.name, p.unit, p.start) for p in model.outputs] == [
        ("theta", "rad", -0.3), ("omega", "rad/s", 0.0)]
    assert [p.name for p in model.inputs] == ["theta1", "omega1"]
    caps = model.capabilities
    assert caps.can_save_state and caps.provides_derivatives and not caps.has_direct_feedthrough
    assert caps.max_input_derivative_order == 0
    with pytest.raises(ValueError, match="'time' \\(independent, continuous\\) cannot be set"):
        Fmu3SubModel(fmi3_bars[2], {"time": 1.0})

    py = bar(2, 2, ParameterSchedule(default_parameters(2)), START, RK4(max_dt=1e-3))
    model.initialize(0.0)
    py.initialize(0.0)
    folder = model._unzipped
    try:
        t, h = 0.0, 0.0123
        for k in range(6):  # held inputs: bit for bit with the Python bar
            for m in (model, py):
                m.set_inputs(np.array([0.4 - 0.01 * k, 0.1 * k]))
                m.do_step(t, h)
            assert np.array_equal(model.get_outputs(), py.get_outputs())
            assert np.array_equal(model.get_output_derivatives(), py.get_output_derivatives())
            t += h
        token = model.save_state()
        model.do_step(t, h)
        first = model.get_outputs()
        model.restore_state(token)
        model.do_step(t, h)
        assert np.array_equal(model.get_outputs(), first)
        with pytest.raises(FmuError, match=r"FMU 'lower' .*fmi3DoStep returned error.*differs "
                                           "from the FMU time"):
            model.do_step(7.0, h)
    finally:
        model.terminate()
    assert folder is not None and folder.is_dir()  # with its library, until exit
    bad = Fmu3SubModel(fmi3_bars[1], {"max_dt": -1.0})
    with pytest.raises(FmuError, match=r"fmi3ExitInitializationMode returned error.*max_dt"):
        bad.initialize(0.0)
    assert bad._unzipped is None and bad._fmu is None


def fmu3_pendulum(fmi3_bars: dict[int, Path]) -> cosimstep.System:
    return helpers.fmu_pendulum(fmi3_bars, CountingFmu3)


@pytest.mark.parametrize("controller", ["fixed 0.001", "pc tol 1e-4"])
def test_fmi3_pendulum_matches_python(fmi3_bars: dict[int, Path], controller: str) -> None:
    until = 2.0

    def make() -> cosimstep.Controller:
        if controller == "fixed 0.001":
            return cosimstep.Fixed(0.001)
        return make_controller("pc", None, 1e-4)

    master = cosimstep.MasterOptions("gauss-seidel", 2)
    fmu_system = fmu3_pendulum(fmi3_bars)
    fmu = cosimstep.simulate(fmu_system, until, make(), master)
    py = cosimstep.simulate(python_pendulum(), until, make(), master)
    assert fmu.success and py.success, (fmu.message, py.message)
    assert fmu.names == py.names and fmu.times.shape == py.times.shape
    assert fmu.times[-1] == pytest.approx(until)
    assert np.max(np.abs(fmu.times - py.times)) <= TOLERANCE
    assert np.max(np.abs(fmu.values - py.values)) <= TOLERANCE  # measured: 0.0
    assert (fmu.calls, fmu.steps_accepted, fmu.steps_rejected) == \
        (py.calls, py.steps_accepted, py.steps_rejected)
    restores = [m.restores for m in fmu_system.models.values()]
    if controller == "fixed 0.001":
        assert restores == [0, 0]
    else:  # hold-only receivers: pc re-runs every step (step doubling) from a restored state
        assert restores[0] == restores[1] >= fmu.steps_accepted


def test_multirate_master_on_fmi3_matches_python(fmi3_bars: dict[int, Path]) -> None:
    master = cosimstep.MasterOptions("multirate", 2)
    fmu = cosimstep.simulate(fmu3_pendulum(fmi3_bars), 1.0, make_controller("pc", None, 1e-4),
                             master)
    py = cosimstep.simulate(python_pendulum(), 1.0, make_controller("pc", None, 1e-4), master)
    assert fmu.success and py.success, (fmu.message, py.message)
    assert fmu.calls == py.calls
    assert {n: m.corrections for n, m in fmu.models.items()} == \
        {n: m.corrections for n, m in py.models.items()}
    assert sum(m.corrections for m in fmu.models.values()) > 0  # rollbacks happened
    assert np.max(np.abs(fmu.values - py.values)) <= TOLERANCE


def test_open_fmu_picks_the_adapter(fmi3_bars: dict[int, Path], bar_fmus: dict[int, Path]) -> None:
    assert type(open_fmu(fmi3_bars[1])) is Fmu3SubModel
    assert type(open_fmu(bar_fmus[1])) is FmuSubModel
    with pytest.raises(ValueError, match=r"FMI 3\.0 co-simulation only; this adapter runs FMI 2\.0 "
                                         r"co-simulation"):
        FmuSubModel(fmi3_bars[1])
    with pytest.raises(ValueError, match="`solver` is only for model-exchange FMUs"):
        open_fmu(fmi3_bars[1], solver={"method": "RK45"})
    with pytest.raises(ValueError, match=r"FMI 3\.0 co-simulation only; this adapter runs FMI 2\.0 "
                                         r"model exchange"):
        open_fmu(fmi3_bars[1], kind="ME")


def test_a_fixed_step_run_of_fmi3_fmus_resumes_bit_for_bit(fmi3_bars: dict[int, Path],
                                                          tmp_path: Path) -> None:
    """Checkpoints hold the FMI 3 FMUs' states as fmi3SerializeFMUState bytes: a run stopped
    by a call budget and resumed stores what the uninterrupted run stores."""
    from cosimstep.store import read_run

    def run(db: Path, **kw: Any) -> cosimstep.SimulationResult:
        return cosimstep.simulate(fmu3_pendulum(fmi3_bars), 2.0, cosimstep.Fixed(1e-3),
                                  cosimstep.MasterOptions("jacobi", 2), store=db, **kw)

    run(tmp_path / "whole.db")
    assert run(tmp_path / "part.db", checkpoint_steps=300, max_calls=2500).status == "timed_out"
    assert run(tmp_path / "part.db", resume=1).success
    whole, part = read_run(tmp_path / "whole.db"), read_run(tmp_path / "part.db")
    assert np.array_equal(whole.times, part.times) and np.array_equal(whole.values, part.values)
    assert whole.summary["calls"] == part.summary["calls"] == {"bar1": 2000, "bar2": 2000}

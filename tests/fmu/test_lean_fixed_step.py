"""The lean fixed-step loop on the two C FMUs, with the FMUs' raw C calls fed from and into the
result table, gives the general loop's run bit for bit with inputs held (Jacobi and
Gauss–Seidel), also when a subclass overrides a step method (then its methods are called). With
inputs extrapolated, the lean loop's extrapolating kernel gives the same run up to rounding, for
the FMUs as built (they interpolate their inputs: input derivatives, sent by the kernel through
``fmi2SetRealInputDerivatives``) and for the same FMUs taking no input derivatives."""

from __future__ import annotations

import functools
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import cosimstep
import helpers
from cosimstep.adapters.fmu import FmuSubModel
from cosimstep.masters import Master


class GeneralFixed(cosimstep.Fixed):
    """Not ``Fixed`` itself: ``simulate`` takes the general controller loop."""


class CountingFmu(FmuSubModel):
    steps = 0

    def do_step(self, t: float, h: float) -> None:
        self.steps += 1
        super().do_step(t, h)


@pytest.mark.parametrize("master", ["jacobi", "gauss-seidel"])
@pytest.mark.parametrize("model_class", [FmuSubModel, CountingFmu])
def test_fmu_pendulum_same_run_both_loops(bar_fmus: dict[int, Path], master: str,
                                          model_class: Any) -> None:
    options = cosimstep.MasterOptions(master, 0)
    runs = {label: cosimstep.simulate(helpers.fmu_pendulum(bar_fmus, model_class), 1.0,
                                      controller(0.001), options)
            for label, controller in (("lean", cosimstep.Fixed), ("general", GeneralFixed))}
    lean, general = runs["lean"], runs["general"]
    assert lean.success and general.success, (lean.message, general.message)
    assert np.array_equal(lean.times, general.times)
    assert np.array_equal(lean.values, general.values)
    assert lean.calls == general.calls == {"bar1": 1000, "bar2": 1000}
    assert np.array_equal(lean.step_sizes, general.step_sizes)


def test_held_kernel_calls_fmus_directly_unless_a_method_is_overridden(
        bar_fmus: dict[int, Path]) -> None:
    for model_class, direct in ((FmuSubModel, True), (CountingFmu, False)):
        compiled = helpers.fmu_pendulum(bar_fmus, model_class).compile()
        runner = Master(compiled, cosimstep.MasterOptions("jacobi", 0))
        runner.initialize(0.0)
        try:
            kernel = runner.held_kernel()
            assert kernel is not None
            assert [entry[2] is not None for entry in kernel.plan] == [direct, direct]
        finally:
            runner.terminate()


class CountingHeldFmu(CountingFmu):
    def __init__(self, path: Path, start: dict) -> None:
        super().__init__(path, start, input_derivative_order=0)


# Measured over 1 s (1000 steps of 0.001): without input derivatives at most 4.4e-16 after
# 0.5 s and 8.9e-16 after 1 s (angles and rates of order 1; about 1e-14 after 10 s, the pendulum
# being chaotic); with input derivatives at most 4.4e-16 after 0.5 s and 1.3e-15 after 1 s
# (Jacobi order 2; the others 4.4e-16 to 8.9e-16), the same with the FMUs' methods called.
AGREE = 1e-13


@pytest.mark.parametrize("master", ["jacobi", "gauss-seidel"])
@pytest.mark.parametrize("order", [1, 2])
@pytest.mark.parametrize("model_class", [
    FmuSubModel, CountingFmu, functools.partial(FmuSubModel, input_derivative_order=0),
    CountingHeldFmu], ids=["derivatives-direct", "derivatives-methods", "held-direct",
                           "held-methods"])
def test_extrapolating_fmus_agree_in_both_loops(
        bar_fmus: dict[int, Path], master: str, order: int, model_class: Any) -> None:
    # with and without input derivatives (the C bars can interpolate inputs; order 0 hides it)
    options = cosimstep.MasterOptions(master, order)
    runs = {label: cosimstep.simulate(helpers.fmu_pendulum(bar_fmus, model_class), 1.0,
                                      controller(0.001), options)
            for label, controller in (("lean", cosimstep.Fixed), ("general", GeneralFixed))}
    lean, general = runs["lean"], runs["general"]
    assert lean.success and general.success, (lean.message, general.message)
    assert np.array_equal(lean.times, general.times)
    assert lean.values.shape == general.values.shape
    assert not np.array_equal(lean.values, general.values)  # the kernel ran
    assert np.max(np.abs(lean.values - general.values)) <= AGREE
    assert lean.calls == general.calls == {"bar1": 1000, "bar2": 1000}
    assert np.array_equal(lean.step_sizes, general.step_sizes)


def test_extrapolating_kernel_calls_fmus_directly_unless_a_method_is_overridden(
        bar_fmus: dict[int, Path]) -> None:
    held = functools.partial(FmuSubModel, input_derivative_order=0)
    for model_class, direct in ((held, True), (CountingHeldFmu, False)):
        compiled = helpers.fmu_pendulum(bar_fmus, model_class).compile()
        runner = Master(compiled, cosimstep.MasterOptions("gauss-seidel", 2))
        runner.initialize(0.0)
        try:
            kernel = runner.extrapolating_kernel()
            assert kernel is not None
            assert [entry[2] is not None for entry in kernel.plan] == [direct, direct]
        finally:
            runner.terminate()
    # the FMUs as built interpolate their inputs: the kernel sends their input derivatives
    for model_class, direct in ((FmuSubModel, True), (CountingFmu, False)):
        compiled = helpers.fmu_pendulum(bar_fmus, model_class).compile()
        runner = Master(compiled, cosimstep.MasterOptions("gauss-seidel", 2))
        runner.initialize(0.0)
        try:
            kernel = runner.extrapolating_kernel()
            assert kernel is not None
            assert [entry[2] is not None for entry in kernel.plan] == [direct, direct]
            assert all(entry[6] is not None for entry in kernel.plan)  # derivatives: q = 2
        finally:
            runner.terminate()


def test_kernel_keeps_the_fmus_input_derivative_bookkeeping(bar_fmus: dict[int, Path]) -> None:
    """After kernel steps the FMU counts as holding input derivatives: a plain ``_direct_io``
    refuses, and inputs set without derivatives clear them before the next step — the same
    state as after the general step's ``set_input_derivatives``."""
    states = {}
    for lean in (True, False):
        compiled = helpers.fmu_pendulum(bar_fmus).compile()
        runner = Master(compiled, cosimstep.MasterOptions("jacobi", 1))
        table = np.zeros((4, compiled.n_outputs))
        table[0] = runner.initialize(0.0)
        try:
            kernel = runner.extrapolating_kernel()
            times = [0.0]
            for n in range(3):
                t = n * 0.001
                if lean and n >= 1:
                    kernel.step(t, 0.001, n, table.reshape(-1), table.ctypes.data)
                else:
                    table[n + 1] = runner.step(t, 0.001, times, table[:n + 1].copy())
                times.append(t + 0.001)
            bar1 = compiled.models[0]
            assert bar1._derivatives_set and not bar1._derivatives_stale
            assert bar1._direct_io() is None and bar1._direct_io(derivatives=True) is not None
            bar1.set_inputs(table[3, [2, 3]])  # held inputs: the derivatives go
            bar1.do_step(0.003, 0.001)
            assert not bar1._derivatives_set and bar1._direct_io() is not None
            states[lean] = (table.copy(), bar1.get_outputs())
        finally:
            runner.terminate()
    assert np.max(np.abs(states[True][0] - states[False][0])) <= AGREE
    assert np.max(np.abs(states[True][1] - states[False][1])) <= AGREE


class HangingFmu(FmuSubModel):
    """Its raw ``fmi2DoStep`` (the lean kernels' C path) hangs from t = 0.05 on."""

    raw_steps = 0

    def _direct_io(self, derivatives: bool = False) -> Any:
        io = super()._direct_io(derivatives)
        if io is None:
            return None
        do_step = io[4]

        def hanging(component: Any, t: float, h: float, flag: int) -> int:
            type(self).raw_steps += 1
            if t >= 0.05 - 1e-12:
                time.sleep(30)
            return do_step(component, t, h, flag)

        return (*io[:4], hanging, *io[5:])


@pytest.mark.parametrize("order", [0, 2])
def test_a_hang_in_the_raw_c_path_times_out(bar_fmus: dict[int, Path], order: int) -> None:
    """The watchdog's stamps are inlined in the kernels' C paths (held inputs: order 0;
    extrapolated with input derivatives: order 2), so a call there that never returns ends
    the run as one through ``Master._guard`` does, with the steps before it."""
    HangingFmu.raw_steps = 0
    started = time.perf_counter()
    result = cosimstep.simulate(helpers.fmu_pendulum(bar_fmus, HangingFmu), 1.0,
                                cosimstep.Fixed(0.01),
                                cosimstep.MasterOptions("jacobi", order, call_timeout=0.3))
    assert time.perf_counter() - started < 10.0  # the call sleeps 30 s
    assert result.status == "failed" and "no answer within 0.3 s" in result.message
    assert "t = 0.05" in result.message and result.steps_accepted == 5
    assert HangingFmu.raw_steps > 0  # the C path ran (the general step for the first `order`)

"""The lean fixed-step loop on the two C FMUs, with the FMUs' raw C calls fed from and into the
result table, gives the general loop's run bit for bit (Jacobi and Gauss–Seidel, inputs held or
extrapolated), also when a subclass overrides a step method (then its methods are called). With
FMUs that take no input derivatives and inputs extrapolated, the lean loop's extrapolating kernel
gives the same run up to rounding."""

from __future__ import annotations

import functools
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


@pytest.mark.parametrize("master, order", [("jacobi", 0), ("gauss-seidel", 0),
                                           ("gauss-seidel", 2)])
@pytest.mark.parametrize("model_class", [FmuSubModel, CountingFmu])
def test_fmu_pendulum_same_run_both_loops(bar_fmus: dict[int, Path], master: str, order: int,
                                          model_class: Any) -> None:
    options = cosimstep.MasterOptions(master, order)
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


# Measured over 1 s (1000 steps of 0.001): at most 4.4e-16 after 0.5 s and 8.9e-16 after 1 s
# (angles and rates of order 1; about 1e-14 after 10 s, the pendulum being chaotic).
AGREE = 1e-13


@pytest.mark.parametrize("master", ["jacobi", "gauss-seidel"])
@pytest.mark.parametrize("order", [1, 2])
@pytest.mark.parametrize("model_class", [functools.partial(FmuSubModel, input_derivative_order=0),
                                         CountingHeldFmu], ids=["direct", "methods"])
def test_fmus_without_input_derivatives_agree_in_both_loops(
        bar_fmus: dict[int, Path], master: str, order: int, model_class: Any) -> None:
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
    # the FMUs as built interpolate their inputs (input derivatives): the general step
    compiled = helpers.fmu_pendulum(bar_fmus).compile()
    assert Master(compiled, cosimstep.MasterOptions("gauss-seidel", 2)).extrapolating_kernel() \
        is None

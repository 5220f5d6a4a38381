"""Acceptance (issue 5): cosimstep's Jacobi master with inputs held gives the same values as
libcosim's fixed-step execution (through libcosimpy) on the same two C FMUs of the split double
pendulum, at every communication point. Skipped when libcosimpy is not installed."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import cosimstep
from helpers import fmu_pendulum

libcosim_execution = pytest.importorskip("libcosimpy.CosimExecution")
libcosim_slave = pytest.importorskip("libcosimpy.CosimSlave")
libcosim_observer = pytest.importorskip("libcosimpy.CosimObserver")
libcosim_logging = pytest.importorskip("libcosimpy.CosimLogging")

H = 0.001
UNTIL = 0.5
STEPS = round(UNTIL / H)
OUT_VR, IN_VR = [0, 1], [2, 3]  # theta, omega; the other bar's theta, omega
START_VR = {1: {0: 0.4, 1: 0.0, 2: -0.3, 3: 0.0}, 2: {0: -0.3, 1: 0.0, 2: 0.4, 3: 0.0}}


def libcosim_values(bar_fmus: dict[int, Path]) -> np.ndarray:
    libcosim_logging.log_output_level(libcosim_logging.CosimLogLevel.ERROR)
    execution = libcosim_execution.CosimExecution.from_step_size(round(H * 1e9))  # ns
    index = {bar: execution.add_local_slave(libcosim_slave.CosimLocalSlave(str(path),
                                                                           f"bar{bar}"))
             for bar, path in bar_fmus.items()}
    for bar, values in START_VR.items():
        for vr, value in values.items():
            execution.real_initial_value(index[bar], vr, value)
    for a in (1, 2):
        for out_vr, in_vr in zip(OUT_VR, IN_VR):
            execution.connect_real_variables(index[a], out_vr, index[3 - a], in_vr)
    observer = libcosim_observer.CosimObserver.create_last_value()
    execution.add_observer(observer)
    rows = []
    for _ in range(STEPS):
        assert execution.step(1)
        rows.append([*observer.last_real_values(index[1], OUT_VR),
                     *observer.last_real_values(index[2], OUT_VR)])
    assert execution.status().current_time == round(UNTIL * 1e9)
    return np.array(rows)


def test_jacobi_hold_matches_libcosim(bar_fmus: dict[int, Path]) -> None:
    system = fmu_pendulum(bar_fmus)
    ours = cosimstep.simulate(system, UNTIL, cosimstep.Fixed(H),
                              cosimstep.MasterOptions("jacobi", 0))
    assert ours.success, ours.message
    assert ours.names == ["bar1.theta", "bar1.omega", "bar2.theta", "bar2.omega"]
    assert ours.values.shape == (STEPS + 1, 4)
    theirs = libcosim_values(bar_fmus)
    difference = np.max(np.abs(ours.values[1:] - theirs))
    print(f"max |cosimstep - libcosim| over {STEPS} steps: {difference:.3e}")
    assert difference <= 1e-12

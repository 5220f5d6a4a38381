"""Acceptance (issue 5): the split double pendulum made of two C FMUs agrees with the pure-Python
split double pendulum (examples/double_pendulum_slow.toml) at every exchanged value and every
point — fixed step under Gauss–Seidel with quadratic extrapolation, and the adaptive
predictor–corrector controller, whose corrector re-runs each step from a restored FMU state."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

import cosimstep
import helpers
from cosimstep.adapters.fmu import FmuSubModel
from cosimstep.controllers import make_controller

UNTIL = 10.0
TOLERANCE = 1e-9


class CountingFmu(FmuSubModel):
    restores = 0

    def restore_state(self, token: Any) -> None:
        self.restores += 1
        super().restore_state(token)


def fmu_pendulum(bar_fmus: dict[int, Path]) -> cosimstep.System:
    return helpers.fmu_pendulum(bar_fmus, CountingFmu)


@pytest.mark.parametrize("controller", ["fixed 0.001", "pc tol 1e-4"])
def test_fmu_pendulum_matches_python(bar_fmus: dict[int, Path], examples: Path,
                                     controller: str) -> None:
    def make() -> cosimstep.Controller:
        if controller == "fixed 0.001":
            return cosimstep.Fixed(0.001)
        return make_controller("pc", None, 1e-4)

    master = cosimstep.MasterOptions("gauss-seidel", 2)
    fmu_system = fmu_pendulum(bar_fmus)
    fmu = cosimstep.simulate(fmu_system, UNTIL, make(), master)
    python_system = cosimstep.load_system(examples / "double_pendulum_slow.toml").system
    py = cosimstep.simulate(python_system, UNTIL, make(), master)

    assert fmu.success and py.success, (fmu.message, py.message)
    assert fmu.names == py.names
    assert fmu.times.shape == py.times.shape and fmu.times[-1] == pytest.approx(UNTIL)
    assert np.max(np.abs(fmu.times - py.times)) <= TOLERANCE
    assert np.max(np.abs(fmu.values - py.values)) <= TOLERANCE
    assert fmu.steps_accepted == py.steps_accepted
    assert fmu.steps_rejected == py.steps_rejected
    assert fmu.calls == py.calls
    restores = [m.restores for m in fmu_system.models.values()]
    if controller == "fixed 0.001":
        assert restores == [0, 0]
    else:  # every step is predicted, rolled back and corrected
        assert restores[0] == restores[1] >= fmu.steps_accepted


def test_multirate_master_on_fmus_matches_python(bar_fmus: dict[int, Path],
                                                  examples: Path) -> None:
    """Each FMU with its own step, rollback of one step per FMU on failed verification."""
    master = cosimstep.MasterOptions("multirate", 2)
    fmu_system = fmu_pendulum(bar_fmus)
    fmu = cosimstep.simulate(fmu_system, 1.0, make_controller("pc", None, 1e-4), master)
    python_system = cosimstep.load_system(examples / "double_pendulum_slow.toml").system
    py = cosimstep.simulate(python_system, 1.0, make_controller("pc", None, 1e-4), master)
    assert fmu.success and py.success, (fmu.message, py.message)
    assert fmu.calls == py.calls
    assert {n: m.corrections for n, m in fmu.models.items()} == \
        {n: m.corrections for n, m in py.models.items()}
    assert sum(m.corrections for m in fmu.models.values()) > 0  # rollbacks happened
    assert np.max(np.abs(fmu.values - py.values)) <= TOLERANCE

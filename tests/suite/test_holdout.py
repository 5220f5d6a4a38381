"""The systems ``benchmarks/holdout.py`` keeps apart from the suite: each split is the
monolithic model it is measured against (a fixed step converges to it at third order, as the
suite's problems do), so that what the holdout table reports is the coupling's error."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

import cosimstep as cs

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
holdout = pytest.importorskip("holdout")


@pytest.mark.parametrize("name", list(holdout.SYSTEMS))
def test_each_split_converges_to_its_monolithic_model(name: str) -> None:
    _, source, build, until = holdout.SYSTEMS[name]
    assert source
    horizon = min(until, 3.0)  # the thermal pair's heater (2 s) included
    errors = []
    for steps in (150, 300):
        system, reference = build()
        result = cs.simulate(system, horizon, cs.Fixed(horizon / steps),
                             cs.MasterOptions("gauss-seidel", 2), reference=reference)
        assert result.status == "ok", result.message
        errors.append(result.error.max_scaled)
    # Gauss-Seidel with quadratic extrapolation: third order, 8 x per halving; a split that
    # differed from its monolithic model would stall at the difference instead
    assert errors[0] / errors[1] > 5.0, errors

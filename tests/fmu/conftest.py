from __future__ import annotations

from pathlib import Path

import pytest

from cosimstep.fmu.build import build_fmu


@pytest.fixture(scope="session")
def fmu_cache(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("fmu-cache")


@pytest.fixture(scope="session")
def bar_fmus(fmu_cache: Path) -> dict[int, Path]:
    """The two bars of the split double pendulum, compiled once per test session."""
    return {bar: build_fmu(f"pendulum_bar{bar}", cache=fmu_cache) for bar in (1, 2)}

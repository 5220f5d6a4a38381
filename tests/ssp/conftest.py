from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import pytest

from cosimstep.fmu.build import build_fmu


@pytest.fixture(scope="session", autouse=True)
def recipe_cache(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """Recipes named by system files (`recipe = ...`, `cosimstep:recipe:...`) build into the
    cache folder; point it at a fresh folder so a test exercises the first-use build."""
    folder = tmp_path_factory.mktemp("recipe-cache")
    old = os.environ.get("COSIMSTEP_CACHE_DIR")
    os.environ["COSIMSTEP_CACHE_DIR"] = str(folder)
    yield folder
    if old is None:
        os.environ.pop("COSIMSTEP_CACHE_DIR", None)
    else:
        os.environ["COSIMSTEP_CACHE_DIR"] = old


@pytest.fixture(scope="session")
def bar_fmus(recipe_cache: Path) -> dict[int, Path]:
    return {bar: build_fmu(f"pendulum_bar{bar}") for bar in (1, 2)}

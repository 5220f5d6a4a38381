from __future__ import annotations

from pathlib import Path

import pytest

START = {"theta1": 0.4, "theta2": -0.3, "omega1": 0.0, "omega2": 0.0}  # double_pendulum_slow.toml


@pytest.fixture(scope="session")
def exported_bars(tmp_path_factory: pytest.TempPathFactory) -> dict[int, Path]:
    """Both bars of the split double pendulum exported with pythonfmu, once per test session."""
    pythonfmu = pytest.importorskip("pythonfmu", reason="pythonfmu is not installed "
                                    "(pip install 'cosimstep[export]')")
    if not pythonfmu.FmuBuilder.has_binary():
        pytest.skip("pythonfmu ships no runtime binary for this platform")
    from cosimstep.fmu.export import export_fmu

    out = tmp_path_factory.mktemp("exported")
    return {i: export_fmu(f"double_pendulum.bar{i}", out, start=START) for i in (1, 2)}

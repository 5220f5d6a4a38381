"""`run --fmu-logging`: FMUs instantiated with logging on, their messages echoed as they come."""

from __future__ import annotations

from pathlib import Path

from click.testing import CliRunner

from cosimstep.adapters.fmu_base import fmu_logging, set_fmu_logging
from cosimstep.cli import main


def _system(tmp_path: Path, bar_fmus: dict[int, Path]) -> Path:
    toml = tmp_path / "bar.toml"
    toml.write_text(f'until = 0.1\n[models.upper]\ntype = "fmu"\npath = "{bar_fmus[1]}"\n'
                    '[controller]\nname = "fixed"\nstep = 0.01\n')
    return toml


def test_fmu_logging_echoes_what_the_fmu_logs(tmp_path: Path, bar_fmus: dict[int, Path]) -> None:
    toml = _system(tmp_path, bar_fmus)
    try:
        quiet = CliRunner().invoke(main, ["run", str(toml), "--no-store"])
        loud = CliRunner().invoke(main, ["run", str(toml), "--no-store", "--fmu-logging"])
    finally:
        set_fmu_logging(False)
    assert quiet.exit_code == loud.exit_code == 0, (quiet.output, loud.output)
    # the bar logs its instantiation only when instantiated with loggingOn
    assert "instantiated, GUID" not in quiet.output
    assert "upper: [ok] instantiated, GUID" in loud.output
    assert not fmu_logging()

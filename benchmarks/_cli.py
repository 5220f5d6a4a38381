"""The command-line options the error-control benchmarks (``suite.py``, ``holdout.py``) share."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_shared(ap: argparse.ArgumentParser, results: Path) -> None:
    """``--masters``, ``--opt KEY=VALUE`` (repeatable; implies not writing the docs),
    ``--no-write`` and ``--results`` (where the raw rows go, default ``results``)."""
    ap.add_argument("--masters", help="comma-separated: pc, multirate (default: both)")
    ap.add_argument("--opt", action="append", default=[], metavar="KEY=VALUE",
                    help="a controller option for the adaptive runs (e.g. predictive=true); "
                         "implies --no-write")
    ap.add_argument("--no-write", action="store_true", help="do not touch docs/benchmarks.md")
    ap.add_argument("--results", type=Path, default=results, help="where the raw results go")


def option(text: str) -> tuple[str, object]:
    """``KEY=VALUE`` with a TOML-like value (true/false, a number, else the text)."""
    key, _, value = text.partition("=")
    lowered = value.strip().lower()
    if lowered in ("true", "false"):
        return key.strip(), lowered == "true"
    try:
        return key.strip(), float(value)
    except ValueError:
        return key.strip(), value.strip()

"""Results out of the store: CSV, Parquet or MATLAB files, one column per exchanged output.

``cosimstep results DB -o OUT.csv|.parquet|.mat [--run ID] [--variables a,b]``. CSV needs
nothing beyond Python; Parquet goes through pandas and pyarrow (``pip install
"cosimstep[parquet]"``); ``.mat`` through SciPy (``t`` and one array per output, names made
MATLAB-safe: ``bar1.theta`` becomes ``bar1_theta``).
"""

from __future__ import annotations

import csv
import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from cosimstep.store import StoredRun

FORMATS = (".csv", ".parquet", ".mat")


def select(run: StoredRun, variables: Sequence[str] | None) -> tuple[list[str], np.ndarray]:
    """The chosen outputs' names and columns (all by default); ``KeyError`` naming the unknown
    ones and the known ones."""
    if not variables:
        return list(run.names), run.values
    unknown = [v for v in variables if v not in run.names]
    if unknown:
        raise KeyError(f"no output(s) {', '.join(unknown)} in the run; its outputs: "
                       f"{', '.join(run.names)}")
    cols = [run.names.index(v) for v in variables]
    return list(variables), run.values[:, cols]


def write(run: StoredRun, path: str | Path, variables: Sequence[str] | None = None) -> Path:
    """Write the run's values to ``path``; the format follows the suffix (:data:`FORMATS`)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in FORMATS:
        raise ValueError(f"'{path}': unknown format; end the name in one of {', '.join(FORMATS)}")
    names, values = select(run, variables)
    path.parent.mkdir(parents=True, exist_ok=True)
    if suffix == ".csv":
        with path.open("w", newline="") as f:
            out = csv.writer(f)
            out.writerow(["t", *names])
            out.writerows([repr(float(t)), *map(repr, row.tolist())]
                          for t, row in zip(run.times, values))
    elif suffix == ".parquet":
        import pandas as pd  # optional: cosimstep[parquet]

        frame = pd.DataFrame(values, index=pd.Index(run.times, name="t"), columns=names)
        frame.to_parquet(path)
    else:
        from scipy.io import savemat

        savemat(path, {"t": run.times, **{_matlab(n): values[:, i] for i, n in enumerate(names)}})
    return path


def _matlab(name: str) -> str:
    return re.sub(r"\W", "_", name)


__all__ = ["FORMATS", "select", "write"]

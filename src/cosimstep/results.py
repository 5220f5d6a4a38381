"""Results out of the store: CSV, Parquet or MATLAB files, one column per exchanged output.

``cosimstep results DB -o OUT.csv|.parquet|.mat [--run ID] [--variables a,b]``. CSV needs
nothing beyond Python; Parquet goes through pandas and pyarrow (``pip install
"cosimstep[parquet]"``); ``.mat`` through SciPy (``t`` and one array per output, names made
MATLAB-safe: ``bar1.theta`` becomes ``bar1_theta``). String and Binary ports are written as
their values, as :meth:`~cosimstep.store.StoredRun.to_pandas` reads them, not as the codes the
store keeps (:mod:`cosimstep.symbols`): text as it is (CSV: bytes in hexadecimal; MATLAB: a cell
array).
"""

from __future__ import annotations

import csv
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from cosimstep.store import StoredRun
from cosimstep.symbols import TEXT_UNITS

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
    # String and Binary ports: their values, not the codes (a code the store lacks, as after a
    # kill before its symbols were written, stays the number)
    text = [i for i, name in enumerate(names) if run.units[run.names.index(name)] in TEXT_UNITS]
    columns: list[Any] = [values[:, i] for i in range(len(names))]
    for i in text:
        columns[i] = [run.symbols.get(int(c), c) for c in values[:, i].tolist()]
    path.parent.mkdir(parents=True, exist_ok=True)
    if suffix == ".csv":
        with path.open("w", newline="") as f:
            out = csv.writer(f)
            out.writerow(["t", *names])
            for n, (t, row) in enumerate(zip(run.times, values)):  # a row at a time
                cells = list(map(repr, row.tolist()))
                for i in text:
                    cells[i] = _cell(columns[i][n])
                out.writerow([repr(float(t)), *cells])
    elif suffix == ".parquet":
        import pandas as pd  # optional: cosimstep[parquet]

        frame = pd.DataFrame(dict(zip(names, columns, strict=True)),
                             index=pd.Index(run.times, name="t"))
        frame.to_parquet(path)
    else:
        from scipy.io import savemat

        savemat(path, {"t": run.times, **{_matlab(n): _matlab_column(c)
                                          for n, c in zip(names, columns, strict=True)}})
    return path


def _cell(value: str | bytes | float) -> str:
    """A String value as it is, a Binary one in hexadecimal (CSV holds text), a code the
    store lacks as its number."""
    if isinstance(value, bytes):
        return value.hex()
    return value if isinstance(value, str) else repr(value)


def _matlab_column(column: Any) -> Any:
    """Numbers as a vector; text as a cell array of strings, bytes as one of uint8 vectors."""
    if not isinstance(column, list):
        return column
    cells = np.empty(len(column), dtype=object)
    cells[:] = [np.frombuffer(v, dtype=np.uint8) if isinstance(v, bytes) else v
                for v in column]
    return cells


def _matlab(name: str) -> str:
    return re.sub(r"\W", "_", name)


__all__ = ["FORMATS", "select", "write"]

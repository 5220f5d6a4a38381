"""Input signals from a table (a CSV file): piecewise-linear in time, as `fmpy simulate` feeds
a single FMU's continuous inputs.

The first column is time (increasing), the others are signals named by their header.
Between rows a signal is linear, before the first row and after the last it is held. Two rows
with the same time are a step change there, as in FMPy's input files: the first row's values
up to that time, the second's from it on (a time event, so steps land on it). The sub-model
gives its slope as the output derivative, so a receiver that follows input derivatives sees
each segment exactly.
"""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any

import numpy as np

from cosimstep.errors import ConfigurationError, Problem
from cosimstep.submodel import Capabilities, Port, SubModel


class InputTable(SubModel):
    """Piecewise-linear signals of time from rows ``(t, v1, v2, …)``."""

    def __init__(self, times: np.ndarray, values: np.ndarray, names: list[str]) -> None:
        self.times = np.asarray(times, dtype=float)
        self.values = np.asarray(values, dtype=float).reshape(len(self.times), len(names))
        self.outputs = tuple(Port(n, "1", float(v)) for n, v in zip(names, self.values[0]))
        self.inputs = ()
        self.capabilities = Capabilities(can_save_state=True, provides_derivatives=True)
        self._t = float(self.times[0])

    @classmethod
    def from_csv(cls, path: str | Path) -> InputTable:
        """Read ``path``; every problem (header, numbers, time order) is listed at once."""
        path = Path(path)
        problems: list[Problem] = []
        try:
            with path.open(newline="") as f:
                rows = [r for r in csv.reader(f) if r and any(c.strip() for c in r)]
        except OSError as exc:
            raise ConfigurationError([Problem(str(path), f"cannot read: {exc.strerror}",
                                              "give the path of a CSV file")], str(path)) from exc
        header = [c.strip() for c in rows[0]] if rows else []
        if len(header) < 2:
            problems.append(Problem(f"{path}: header", "needs a time column and at least one "
                                    "signal", "e.g. time,u1,u2"))
        data = []
        for i, row in enumerate(rows[1:], start=2):
            try:
                numbers = [float(c) for c in row]
            except ValueError:
                problems.append(Problem(f"{path}: line {i}", f"not all numbers: {row}",
                                        "write one number per column"))
                continue
            if len(numbers) != len(header):
                problems.append(Problem(f"{path}: line {i}", f"{len(numbers)} values for "
                                        f"{len(header)} columns", "one value per column"))
                continue
            bad = [name for name, v in zip(header, numbers) if not np.isfinite(v)]
            if bad:
                problems.append(Problem(f"{path}: line {i}", f"not a finite number in "
                                        f"{', '.join(bad)}: {row}", "give every cell a value"))
                continue
            data.append(numbers)
        table = np.array(data, dtype=float).reshape(-1, max(len(header), 1))
        if not problems and len(table) == 0:
            problems.append(Problem(str(path), "no rows", "add rows below the header"))
        problems += _time_problems(path, header, table[:, 0] if table.size else table)
        if problems:
            raise ConfigurationError(problems, str(path))
        return cls(table[:, 0], table[:, 1:], header[1:])

    def initialize(self, t0: float) -> None:
        self._t = t0

    def set_inputs(self, values: np.ndarray) -> None:
        """No inputs."""

    def do_step(self, t: float, h: float) -> None:
        self._t = t + h

    def get_outputs(self) -> np.ndarray:
        """The values now: on the segment that starts at or before now (from a step change's
        time on, its second row's), held outside the table."""
        i = self._segment()
        if i < 0:
            return self.values[0].copy()
        if i >= len(self.times) - 1:
            return self.values[-1].copy()
        return self.values[i] + (self._t - self.times[i]) * self._slope(i)

    def get_output_derivatives(self) -> np.ndarray:
        """The slope of the segment the current time starts (0 outside the table)."""
        i = self._segment()
        if i < 0 or i >= len(self.times) - 1:
            return np.zeros(self.values.shape[1])
        return self._slope(i)

    def _segment(self) -> int:
        """The last row at or before now (-1: before the table)."""
        return int(np.searchsorted(self.times, self._t, side="right")) - 1

    def _slope(self, i: int) -> np.ndarray:
        return (self.values[i + 1] - self.values[i]) / (self.times[i + 1] - self.times[i])

    def time_events(self) -> list[float]:
        """The times inside the table (a step change's once): the slope changes or the value
        jumps there, steps land on them."""
        return sorted({float(t) for t in self.times[1:-1]})

    def save_state(self) -> Any:
        return self._t

    def restore_state(self, token: Any) -> None:
        self._t = float(token)


def _time_problems(path: Path, header: list[str], times: np.ndarray) -> list[Problem]:
    """The time column must not decrease; a time may appear twice (a step change), not three
    times (which value would hold there?)."""
    where = f"{path}: {header[0] if header else 'time'}"
    if len(times) < 2:
        return []
    steps = np.diff(times)
    if np.any(steps < 0):
        return [Problem(where, "times must not decrease", "sort the rows by time")]
    if np.any((steps[:-1] == 0) & (steps[1:] == 0)):
        return [Problem(where, "a time appears in more than two rows", "keep two rows at "
                        "a step change: the value before it and the value from it on")]
    return []

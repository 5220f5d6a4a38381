"""Input signals from a table (a CSV file): piecewise-linear in time, as `fmpy simulate` feeds
a single FMU's continuous inputs.

The first column is time (strictly increasing), the others are signals named by their header.
Between rows a signal is linear, before the first row and after the last it is held. The
sub-model gives its slope as the output derivative, so a receiver that follows input
derivatives sees each segment exactly.
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
            data.append(numbers)
        table = np.array(data, dtype=float).reshape(-1, max(len(header), 1))
        if not problems and len(table) == 0:
            problems.append(Problem(str(path), "no rows", "add rows below the header"))
        if len(table) > 1 and not np.all(np.diff(table[:, 0]) > 0):
            problems.append(Problem(f"{path}: {header[0] if header else 'time'}",
                                    "times must increase strictly", "sort the rows by time"))
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
        return np.array([np.interp(self._t, self.times, col) for col in self.values.T])

    def get_output_derivatives(self) -> np.ndarray:
        """The slope of the segment the current time starts (0 outside the table)."""
        i = int(np.searchsorted(self.times, self._t, side="right")) - 1
        if i < 0 or i >= len(self.times) - 1:
            return np.zeros(self.values.shape[1])
        return (self.values[i + 1] - self.values[i]) / (self.times[i + 1] - self.times[i])

    def time_events(self) -> list[float]:
        """The rows inside the table: the slope changes there, steps land on them."""
        return [float(t) for t in self.times[1:-1]]

    def save_state(self) -> Any:
        return self._t

    def restore_state(self, token: Any) -> None:
        self._t = float(token)

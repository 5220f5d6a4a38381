"""Text and bytes through numeric ports: FMI String and Binary variables (issue 20).

Everything a master moves, extrapolates, stores and checkpoints is a vector of floats, and a
String or Binary variable is only ever held (it is discrete), never interpolated. So such a port
carries a *code*: the index of its value in a process-wide table, :data:`SYMBOLS`. An FMU
adapter turns what it reads into codes and the codes it is given back into values; a result
decodes its text columns (:meth:`~cosimstep.result.SimulationResult.text`), and the results
store keeps the values of the codes a run used (table ``symbol``), so a stored run reads back
the same text.

Codes are stable within a process, so two runs in one process share them; a run read from a
store uses the codes stored with it. The value of code 0 is the empty string.
"""

from __future__ import annotations

import threading
from collections.abc import Iterable, Mapping
from typing import Any

TEXT_UNITS = ("text", "bytes")
"""The units of String (``"text"``) and Binary (``"bytes"``) ports; they mark coded columns."""


class Symbols:
    """A table of interned strings and byte strings, each with a float code."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._values: list[str | bytes] = [""]
        self._codes: dict[tuple[type, str | bytes], int] = {(str, ""): 0}

    def code(self, value: str | bytes | None) -> float:
        """The code of ``value`` (``None``, as an FMU may return, is the empty string)."""
        if value is None:
            value = ""
        key = (type(value), value)
        with self._lock:
            index = self._codes.get(key)
            if index is None:
                index = self._codes[key] = len(self._values)
                self._values.append(value)
        return float(index)

    def value(self, code: float) -> str | bytes:
        """The value of a code; ``KeyError`` for a number that is not one."""
        index = int(code)
        if index != code or not 0 <= index < len(self._values):
            raise KeyError(f"{code!r} is not the code of a text or bytes value")
        return self._values[index]

    def text(self, code: float) -> str:
        value = self.value(code)
        return value.decode("utf-8", "replace") if isinstance(value, bytes) else value

    def binary(self, code: float) -> bytes:
        value = self.value(code)
        return value.encode("utf-8") if isinstance(value, str) else value

    def table(self, codes: Iterable[float]) -> dict[int, str | bytes]:
        """Code → value for the distinct ``codes`` (what a store keeps for one run)."""
        return {int(c): self.value(c) for c in set(codes)}


SYMBOLS = Symbols()


def decoded_frame(values: Any, times: Any, names: list[str], units: list[str],
                  table: Mapping[int, str | bytes] | None = None) -> Any:
    """A DataFrame of a run's values indexed by time, text and bytes columns decoded (through
    ``table``, a stored run's codes, or :data:`SYMBOLS`)."""
    import pandas as pd

    frame = pd.DataFrame(values, index=pd.Index(times, name="t"), columns=names)
    lookup = (lambda c: table[int(c)]) if table is not None else SYMBOLS.value
    for name, unit in zip(names, units, strict=True):
        if unit in TEXT_UNITS:
            frame[name] = [lookup(c) for c in frame[name]]
    return frame

__all__ = ["SYMBOLS", "TEXT_UNITS", "Symbols", "decoded_frame"]

"""Text and bytes through numeric ports: FMI String and Binary variables (issue 20).

Everything a master moves, extrapolates, stores and checkpoints is a vector of floats, and a
String or Binary variable is only ever held (it is discrete), never interpolated. So such a port
carries a *code* for its value, kept in a process-wide table, :data:`SYMBOLS`. An FMU adapter
turns what it reads into codes and the codes it is given back into values; a result decodes its
text columns (:meth:`~cosimstep.result.SimulationResult.text`), and the results store keeps the
values of the codes a run used (table ``symbol``, also at every checkpoint), so a stored run
reads back the same text.

A code is a 48-bit hash of the value (and whether it is text or bytes), exact as a float: the
same value has the same code in every process, so a run resumed from a checkpoint by another
process, or one run of a sweep on another worker, agrees on the codes. Two values with one
code would be refused (a chance of about n^2 / 2^49 for n distinct values).
"""

from __future__ import annotations

import hashlib
import threading
from collections.abc import Iterable, Mapping
from typing import Any

TEXT_UNITS = ("text", "bytes")
"""The units of String (``"text"``) and Binary (``"bytes"``) ports; they mark coded columns."""


class Symbols:
    """A table of interned strings and byte strings, each with a float code."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._values: dict[int, str | bytes] = {}

    def code(self, value: str | bytes | None) -> float:
        """The code of ``value`` (``None``, as an FMU may return, is the empty string)."""
        if value is None:
            value = ""
        data = b"b" + value if isinstance(value, bytes) else b"s" + value.encode("utf-8")
        code = int.from_bytes(hashlib.blake2b(data, digest_size=6).digest(), "little")
        with self._lock:
            known = self._values.setdefault(code, value)
        if known != value or type(known) is not type(value):
            raise ValueError(f"{value!r} and {known!r} have the same code")
        return float(code)

    def value(self, code: float) -> str | bytes:
        """The value of a code; ``KeyError`` for a number that is not the code of a value
        seen in this process (or loaded from a store)."""
        try:
            return self._values[int(code)]
        except (KeyError, ValueError, OverflowError):
            raise KeyError(f"{code!r} is not the code of a known text or bytes value") from None

    def text(self, code: float) -> str:
        value = self.value(code)
        return value.decode("utf-8", "replace") if isinstance(value, bytes) else value

    def binary(self, code: float) -> bytes:
        value = self.value(code)
        return value.encode("utf-8") if isinstance(value, str) else value

    def known(self) -> dict[int, str | bytes]:
        """Every code seen in this process, with its value."""
        with self._lock:
            return dict(self._values)

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

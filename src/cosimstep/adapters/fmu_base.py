"""What the FMI 3.0 co-simulation and the model-exchange adapters share (issue 5).

:class:`FmuBase` reads and checks the model description (:func:`~cosimstep.adapters.fmu.check_fmu`
with the version and kind the subclass runs), turns its Float64/Real inputs and outputs into
ports, checks start-value overrides, formats failed FMI calls as :class:`FmuError` naming the FMU,
the call and what the FMU logged, unpacks the archive into a temporary folder and removes it again,
and keeps FMU-state pointers for reuse until :meth:`FmuBase.terminate` frees them.

The FMI 2.0 co-simulation adapter (:class:`~cosimstep.adapters.fmu.FmuSubModel`) predates this
module and keeps its own copies of these helpers.
"""

from __future__ import annotations

import contextlib
import shutil
import tempfile
import weakref
from collections import deque
from collections.abc import Mapping, Sequence
from ctypes import byref, c_void_p
from pathlib import Path
from typing import Any

import fmpy
from fmpy.fmi1 import FMICallException
from fmpy.model_description import ModelDescription, ModelVariable

from cosimstep.adapters.fmu import FmuError, check_fmu, fmu_interface
from cosimstep.submodel import Port, SubModel

STATUS = ("ok", "warning", "discard", "error", "fatal", "pending")
REAL_TYPES = ("Real", "Float64", "Float32")  # exchanged through ports
_SETTABLE_TYPES = (*REAL_TYPES, "Integer", "Enumeration", "Boolean", "Int8", "UInt8", "Int16",
                   "UInt16", "Int32", "UInt32", "Int64", "UInt64")
_SETTABLE_BEFORE_INIT = ("exact", "approx")

__all__ = ["STATUS", "FmuBase", "FmuError"]


class _SavedState:
    """A token for one saved FMU state. When the master drops it, its memory is kept for reuse
    (getting an FMU state into a given pointer overwrites it in place); :meth:`FmuBase.terminate`
    frees it in the FMU."""

    __slots__ = ("__weakref__", "owner", "pointer")

    def __init__(self, owner: FmuBase, pointer: c_void_p) -> None:
        self.owner: FmuBase | None = owner
        self.pointer = pointer

    def __del__(self) -> None:
        if self.owner is not None:
            self.owner._spare_states.append(self.pointer)


class FmuBase(SubModel):
    """Model description, ports, start values, errors, unpacking and FMU states of one FMU.

    Subclasses set :attr:`SUPPORTED` and :attr:`CALL_PREFIX`, create the FMPy object in
    ``initialize`` (after :meth:`_unpack`) and implement the step, state and value calls.
    """

    SUPPORTED: tuple[tuple[str, str], ...] = ()
    CALL_PREFIX = "fmi"  # "fmi2" or "fmi3", for call names in messages

    def __init__(self, path: str | Path, start: Mapping[str, float] | None = None, *,
                 instance_name: str | None = None) -> None:
        self.path = Path(path)
        md = check_fmu(self.path, self.SUPPORTED)
        self.model_description: ModelDescription = md
        chosen = fmu_interface(md, self.SUPPORTED)
        assert chosen is not None  # check_fmu refused it otherwise
        self.fmi_version, self.kind = chosen
        self.interface = md.coSimulation if self.kind == "CS" else md.modelExchange
        self.name = instance_name or md.modelName
        by_name = {v.name: v for v in md.modelVariables}
        self.start = self._check_start(dict(start or {}), by_name)
        self._in_vars = [v for v in md.modelVariables
                         if v.causality == "input" and v.type in REAL_TYPES]
        self._out_vars = [v for v in md.modelVariables
                          if v.causality == "output" and v.type in REAL_TYPES]
        self.inputs = tuple(self._port(v) for v in self._in_vars)
        self.outputs = tuple(self._port(v) for v in self._out_vars)
        self._in_vr = [v.valueReference for v in self._in_vars]
        self._out_vr = [v.valueReference for v in self._out_vars]
        self._fmu: Any = None
        self._unzipped: Path | None = None
        self._initialized = False
        self._states: weakref.WeakSet[_SavedState] = weakref.WeakSet()
        self._spare_states: list[c_void_p] = []
        self._log: deque[str] = deque(maxlen=20)

    # -- construction helpers ------------------------------------------------------------------
    def _check_start(self, start: dict[str, Any],
                     by_name: Mapping[str, ModelVariable]) -> dict[str, tuple[ModelVariable, Any]]:
        problems = []
        for name in start:
            v = by_name.get(name)
            if v is None:
                problems.append(f"'{name}' is not a variable of the FMU")
            elif v.variability == "constant" or v.causality in ("independent", "local") or (
                    v.causality in ("output", "calculatedParameter")
                    and v.initial not in _SETTABLE_BEFORE_INIT):
                problems.append(f"'{name}' ({v.causality}, {v.variability}) cannot be set")
            elif v.type not in _SETTABLE_TYPES or v.dimensions:
                problems.append(f"'{name}' is of type {v.type}"
                                f"{' (an array)' if v.dimensions else ''}, which cannot be set "
                                "here")
        if problems:
            raise ValueError(f"`start` for FMU {self.path}: {'; '.join(problems)}")
        return {name: (by_name[name], value) for name, value in start.items()}

    def _port(self, v: ModelVariable) -> Port:
        value = self.start[v.name][1] if v.name in self.start else v.start
        unit = v.unit or (v.declaredType.unit if v.declaredType is not None else None) or "1"
        return Port(v.name, unit, None if value is None else float(value), v.description or "")

    def _feedthrough(self) -> dict[str, tuple[str, ...]]:
        """Per output, the inputs it depends on at the same instant (ModelStructure/Outputs)."""
        inputs = {id(v) for v in self._in_vars}
        declared = {id(u.variable): u for u in self.model_description.outputs}
        result: dict[str, tuple[str, ...]] = {}
        for v in self._out_vars:
            unknown = declared.get(id(v))
            if unknown is None or unknown.dependencies is None:
                deps = tuple(i.name for i in self._in_vars)  # undeclared: depends on all
            else:
                deps = tuple(d.name for d in unknown.dependencies if id(d) in inputs)
            result[v.name] = deps
        return result

    # -- errors ----------------------------------------------------------------------------------
    def _logger(self, status: int, message: bytes | str | None) -> None:
        label = STATUS[status] if 0 <= status < len(STATUS) else str(status)
        text = message.decode("utf-8", "replace") if isinstance(message, bytes) else str(message)
        self._log.append(f"[{label}] {text}")

    def _error(self, call: str, exc: BaseException | None = None) -> FmuError:
        if isinstance(exc, FMICallException):
            status = STATUS[exc.status] if 0 <= exc.status < len(STATUS) else str(exc.status)
            what = f"{exc.function} returned {status}"
        elif exc is None:
            what = call
        else:
            what = f"{call} failed: {exc}"
        logged = "; ".join(self._log)
        self._log.clear()
        return FmuError(f"FMU '{self.name}' ({self.path.name}): {what}"
                        + (f" — FMU log: {logged}" if logged else ""))

    def _live(self) -> Any:
        if self._fmu is None:
            raise FmuError(f"FMU '{self.name}' ({self.path.name}) is not initialized")
        return self._fmu

    # -- lifecycle ------------------------------------------------------------------------------
    def _unpack(self) -> str:
        self._unzipped = Path(tempfile.mkdtemp(prefix=f"cosimstep-{self.name}-"))
        fmpy.extract(str(self.path), unzipdir=str(self._unzipped))
        return str(self._unzipped)

    def _start_values(self, inputs: bool) -> list[tuple[ModelVariable, Any]]:
        """Overrides to set before initialization (``inputs=False``) or inside it (inputs)."""
        return [vv for vv in self.start.values() if (vv[0].causality == "input") == inputs]

    def _fail_initialization(self, exc: BaseException) -> FmuError:
        error = exc if isinstance(exc, FmuError) else self._error("initialization", exc)
        with contextlib.suppress(Exception):
            self.terminate()
        return error

    # -- FMU state -------------------------------------------------------------------------------
    def _get_state(self, pointer: c_void_p) -> None:
        fmu = self._live()
        getattr(fmu, f"{self.CALL_PREFIX}Get{self._state_word}")(fmu.component, byref(pointer))

    def _set_state(self, pointer: c_void_p) -> None:
        fmu = self._live()
        getattr(fmu, f"{self.CALL_PREFIX}Set{self._state_word}")(fmu.component, pointer)

    @property
    def _state_word(self) -> str:
        return "FMUState" if self.fmi_version == "3.0" else "FMUstate"

    def _save_fmu_state(self) -> _SavedState:
        pointer = self._spare_states.pop() if self._spare_states else c_void_p()
        try:
            self._get_state(pointer)
        except FMICallException as exc:
            raise self._error(f"{self.CALL_PREFIX}Get{self._state_word}", exc) from None
        token = _SavedState(self, pointer)
        self._states.add(token)
        return token

    def _restore_fmu_state(self, saved: Any) -> None:
        if not isinstance(saved, _SavedState) or saved.owner is not self:
            raise ValueError(f"FMU '{self.name}': restore_state got a state this instance did "
                             "not save, or one freed by terminate()")
        try:
            self._set_state(saved.pointer)
        except FMICallException as exc:
            raise self._error(f"{self.CALL_PREFIX}Set{self._state_word}", exc) from None

    def terminate(self) -> None:
        """Terminate and free the instance, free saved states, remove the unpacked files.

        Every part runs even if an earlier one failed; the first failure is raised at the end.
        """
        fmu, self._fmu = self._fmu, None
        first: Exception | None = None
        if fmu is not None:
            if self._initialized:
                try:
                    fmu.terminate()
                except Exception as exc:
                    first = self._error(f"{self.CALL_PREFIX}Terminate", exc)
            for saved in list(self._states):
                saved.owner = None
                self._spare_states.append(saved.pointer)
            self._states = weakref.WeakSet()
            free = getattr(fmu, f"{self.CALL_PREFIX}Free{self._state_word}")
            for pointer in self._spare_states:
                if pointer:
                    with contextlib.suppress(Exception):
                        free(fmu.component, byref(pointer))
            self._spare_states = []
            if fmu.component is not None:
                try:
                    fmu.freeInstance()
                except Exception as exc:
                    first = first or self._error(f"{self.CALL_PREFIX}FreeInstance", exc)
            else:
                with contextlib.suppress(Exception):
                    fmu.freeLibrary()
        self._initialized = False
        if self._unzipped is not None:
            shutil.rmtree(self._unzipped, ignore_errors=True)
            self._unzipped = None
        if first is not None:
            raise first


def setter_name(v: ModelVariable, version: str) -> tuple[str, type]:
    """FMPy's setter for a variable's type (``setReal``/``setFloat64``...) and the Python type."""
    if v.type in ("Real", "Float64", "Float32"):
        return ("setReal" if version == "2.0" else f"set{v.type}"), float
    if v.type == "Boolean":
        return "setBoolean", bool
    if version == "2.0":
        return "setInteger", int
    return f"set{'Int64' if v.type == 'Enumeration' else v.type}", int


def set_values(fmu: Any, values: Sequence[tuple[ModelVariable, Any]], version: str) -> None:
    """Set start values one by one with the setter of each variable's type."""
    for v, value in values:
        name, kind = setter_name(v, version)
        getattr(fmu, name)([v.valueReference], [kind(value)])

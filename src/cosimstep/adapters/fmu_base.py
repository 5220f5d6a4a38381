"""What every FMU adapter shares (issue 5): checking an archive and one FMU's bookkeeping.

:func:`check_fmu` reads and checks an FMU without unpacking it and :func:`fmu_interface` picks the
FMI version and kind to run. :class:`FmuBase` reads the model description (checked for the
version and kind the subclass runs), turns its Float64/Real inputs and outputs into ports, checks
start-value overrides, formats failed FMI calls as :class:`FmuError` naming the FMU, the call and
what the FMU logged, unpacks the archive into a temporary folder shared by every instance of the
same file (:class:`_Unpacked`: kept, with the loaded library, until the process exits), and keeps
FMU-state pointers for reuse until :meth:`FmuBase.terminate` frees them. The adapters are
:class:`~cosimstep.adapters.fmu.FmuSubModel` (FMI 2.0 co-simulation),
:class:`~cosimstep.adapters.fmu3.Fmu3SubModel` (FMI 3.0 co-simulation) and
:class:`~cosimstep.adapters.fmu_me.MeSubModel` (FMI 2.0 and 3.0 model exchange).
"""

from __future__ import annotations

import atexit
import contextlib
import dataclasses
import functools
import os
import shutil
import sys
import threading
import weakref
import zipfile
from collections import deque
from collections.abc import Mapping, Sequence
from ctypes import byref, c_void_p
from pathlib import Path
from typing import Any

import fmpy
import numpy as np
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import (
    fmi2CallbackAllocateMemoryTYPE,
    fmi2CallbackFreeMemoryTYPE,
    fmi2CallbackFunctions,
    fmi2CallbackLoggerTYPE,
)
from fmpy.model_description import ModelDescription, ModelVariable, ValidationError

from cosimstep.archive import escapes, mark, new_folder, size_problems
from cosimstep.errors import EndOfSimulation
from cosimstep.submodel import ELEMENT, Port, SubModel
from cosimstep.symbols import SYMBOLS

STATUS = ("ok", "warning", "discard", "error", "fatal", "pending")
REAL_TYPES = ("Real", "Float64", "Float32")  # exchanged through ports
_SETTABLE_TYPES = (*REAL_TYPES, "Integer", "Enumeration", "Boolean", "Int8", "UInt8", "Int16",
                   "UInt16", "Int32", "UInt32", "Int64", "UInt64", "String", "Binary")
_CODED = {"String": ("string", "text"), "Binary": ("binary", "bytes")}  # kind, unit
_SETTABLE_BEFORE_INIT = ("exact", "approx")

__all__ = ["FMI2_CS", "FMI2_ME", "FMI3_CS", "FMI3_ME", "STATUS", "SUPPORTED", "FmuBase", "FmuError",
           "check_fmu", "fmu_interface"]


class FmuError(RuntimeError):
    """An FMI call failed; the message names the FMU, the call and what the FMU logged."""


FMI2_CS = ("2.0", "CS")
FMI2_ME = ("2.0", "ME")
FMI3_CS = ("3.0", "CS")
FMI3_ME = ("3.0", "ME")
SUPPORTED = (FMI2_CS, FMI3_CS, FMI2_ME, FMI3_ME)
"""FMI versions and kinds cosimstep runs, in the order :func:`fmu_interface` prefers them (an
FMU's own co-simulation solver before cosimstep's wrapper around model exchange)."""
_KIND_NAMES = {"CS": "co-simulation", "ME": "model exchange", "SE": "scheduled execution"}


def fmu_interface(md: ModelDescription,
                  supported: Sequence[tuple[str, str]] = SUPPORTED) -> tuple[str, str] | None:
    """The first of ``supported`` (``(version, "CS" | "ME")``) that the FMU offers, or ``None``."""
    offered = _offered(md)
    return next((pair for pair in supported if pair in offered), None)


def _offered(md: ModelDescription) -> list[tuple[str, str]]:
    version = "3.0" if str(md.fmiVersion).startswith("3.") else str(md.fmiVersion)
    parts = (("CS", md.coSimulation), ("ME", md.modelExchange),
             ("SE", getattr(md, "scheduledExecution", None)))
    return [(version, kind) for kind, part in parts if part is not None]


def _describe(pairs: Sequence[tuple[str, str]]) -> str:
    return " and ".join(f"FMI {v} {_KIND_NAMES[k]}" for v, k in pairs) or "no interface"


def check_fmu(path: str | Path,
              supported: Sequence[tuple[str, str]] = (FMI2_CS,)) -> ModelDescription:
    """Read and check an FMU without unpacking it; raise ``ValueError`` saying why it is refused.

    ``supported`` lists the ``(version, kind)`` pairs the caller can run (default: what
    :class:`~cosimstep.adapters.fmu.FmuSubModel` runs); the FMU must offer one of them, with a
    binary for this platform.
    """
    path = Path(path)
    info = path.stat() if path.is_file() else None
    if info is None:
        return _check(path, tuple(supported))
    return _checked(str(path), info.st_mtime_ns, info.st_size, tuple(supported))


@functools.lru_cache(maxsize=64)
def _checked(path: str, mtime_ns: int, size: int,
             supported: tuple[tuple[str, str], ...]) -> ModelDescription:
    """:func:`_check` once per version of a file: the further instances of an FMU skip reading
    and validating its model description (about 1 ms each), which nothing changes afterwards.
    A file changed on disk has another modification time or size, so it is read again."""
    return _check(Path(path), supported)


def _check(path: Path, supported: Sequence[tuple[str, str]]) -> ModelDescription:
    names, xml = _read_archive(path)
    try:
        _validate(xml)
        md = fmpy.read_model_description(str(path), validate=False)
    except Exception as exc:  # FMPy raises plain Exceptions for invalid descriptions
        raise _refuse(path, f"invalid modelDescription.xml: {exc}") from exc
    if md.fmiVersion == "1.0":
        raise _refuse(path, f"FMI 1.0 is not supported (cosimstep runs {_describe(SUPPORTED)} "
                      "FMUs)")
    chosen = fmu_interface(md, supported)
    if chosen is None:
        raise _refuse(path, _unsupported(md, supported))
    _check_binary(path, md, chosen, names)
    return md


def _refuse(path: Path, reason: str) -> ValueError:
    """The error :func:`check_fmu` raises, naming the file so a system's many FMUs are told
    apart."""
    return ValueError(f"cannot use FMU {path}: {reason}")


def _read_archive(path: Path) -> tuple[list[str], bytes]:
    """The entry names and ``modelDescription.xml`` of a zip that is safe to unpack; checked
    before any XML is parsed, so a broken or hostile archive is refused with a clear reason."""
    if not path.is_file():
        raise _refuse(path, "no such file")
    if not zipfile.is_zipfile(path):
        raise _refuse(path, "not a zip archive (an FMU is a zip file)")
    try:
        with zipfile.ZipFile(path) as zf:
            infos = zf.infolist()
            names = [i.filename for i in infos]
            xml = zf.read("modelDescription.xml") if "modelDescription.xml" in names else None
    except (OSError, zipfile.BadZipFile) as exc:
        raise _refuse(path, f"corrupt zip archive ({exc})") from exc
    too_big = size_problems(infos, _needed)
    if too_big:
        raise _refuse(path, "; ".join(too_big))
    for name in names:
        if escapes(name):
            raise _refuse(path, f"archive entry '{name}' would unpack outside the FMU's folder "
                          "(absolute path or '..'); refusing to unpack it")
    if xml is None:
        raise _refuse(path, "no modelDescription.xml at the top of the archive")
    return names, xml


def _unsupported(md: ModelDescription, supported: Sequence[tuple[str, str]]) -> str:
    """Why none of the FMU's interfaces is in ``supported``: cosimstep cannot run it at all, or
    only another adapter can (then :func:`~cosimstep.adapters.fmu_open.open_fmu` is the fix)."""
    offered = _offered(md)
    only = " only" if len(offered) == 1 else ""
    if not any(pair in SUPPORTED for pair in offered):
        return (f"{_describe(offered)}{only} is not supported (cosimstep runs "
                f"{_describe(SUPPORTED)} FMUs)")
    return (f"{_describe(offered)}{only}; this adapter runs {_describe(supported)} "
            "(cosimstep.adapters.fmu_open.open_fmu picks the adapter for any supported FMU)")


def _check_binary(path: Path, md: ModelDescription, chosen: tuple[str, str],
                  names: list[str]) -> None:
    """Refuse an FMU without a shared library for this platform in the chosen interface."""
    version, kind = chosen
    part = md.coSimulation if kind == "CS" else md.modelExchange
    folder = fmpy.platform_tuple if version == "3.0" else fmpy.platform
    binary = f"binaries/{folder}/{part.modelIdentifier}{fmpy.sharedLibraryExtension}"
    if binary not in names:
        found = sorted({n.split("/")[1] for n in names
                        if n.startswith("binaries/") and n.count("/") >= 2})
        raise _refuse(path, f"no binary for this platform ({binary} is missing; it has binaries "
                      f"for: {', '.join(found) or 'none'})")


_SCHEMAS: dict[str, Any] = {}
_SCHEMA_LOCK = threading.Lock()


def _validate(xml: bytes) -> None:
    """Validate a model description against FMPy's XML schema of its FMI version.

    What ``fmpy.read_model_description(validate=True)`` does, with each schema compiled once per
    process instead of on every call (about 2–3 ms of the 4 ms it took per FMU). Raises FMPy's
    ``ValidationError`` listing the problems; versions FMPy does not know are left to its reader.
    """
    from lxml import etree

    root = etree.fromstring(xml)
    version = root.get("fmiVersion") or ""
    file = {"1.0": ("fmi1", "fmiModelDescription.xsd"),
            "2.0": ("fmi2", "fmi2ModelDescription.xsd")}.get(
        version, ("fmi3", "fmi3ModelDescription.xsd") if version.startswith("3.") else None)
    if file is None:
        return
    # a schema's error log belongs to the schema object: one validation at a time
    with _SCHEMA_LOCK:
        schema = _SCHEMAS.get(file[0])
        if schema is None:
            schema = _SCHEMAS[file[0]] = etree.XMLSchema(
                file=str(Path(fmpy.__file__).parent / "schema" / file[0] / file[1]))
        if not schema.validate(root):
            problems = [f"{e.level_name} (line {e.line}, column {e.column}): {e.message}"
                        for e in schema.error_log]
            raise ValidationError(problems)


def _needed(name: str) -> bool:
    """Whether an archive entry is unpacked to run the FMU (everything but sources and docs)."""
    return not name.startswith(("sources/", "documentation/"))


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

    Subclasses set :attr:`SUPPORTED` and :attr:`CALL_PREFIX`, create the library object (FMPy's, or
    :class:`~cosimstep.adapters.fmi2_library.Fmi2Slave`) in
    ``initialize`` (:meth:`_load`; on failure ``raise self._fail_initialization(exc)``)
    and implement the step, state and value calls.
    """

    SUPPORTED: tuple[tuple[str, str], ...] = ()
    CALL_PREFIX = "fmi"  # "fmi2" or "fmi3", for call names in messages
    DISCRETE_TYPES: tuple[str, ...] = ()  # non-real variable types exchanged through ports
    ARRAYS = False  # array variables (FMI 3.0) as one port per element, ``name[i]``

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
        self._in_vars, self._in_disc = self._port_variables(md, "input")
        self._out_vars, self._out_disc = self._port_variables(md, "output")
        self.inputs = tuple(p for v in (*self._in_vars, *self._in_disc) for p in self._ports(v))
        self.outputs = tuple(p for v in (*self._out_vars, *self._out_disc)
                             for p in self._ports(v))
        self._in_vr = [v.valueReference for v in self._in_vars]
        self._out_vr = [v.valueReference for v in self._out_vars]
        self._fmu: Any = None
        self._unzipped: Path | None = None
        self._once_key: tuple | None = None  # see _OncePerProcess
        self._initialized = False
        self._states: weakref.WeakSet[_SavedState] = weakref.WeakSet()
        self._spare_states: list[c_void_p] = []
        self._log: deque[str] = deque(maxlen=20)

    # -- construction helpers ------------------------------------------------------------------
    def _port_variables(self, md: ModelDescription,
                        causality: str) -> tuple[list[ModelVariable], list[ModelVariable]]:
        """The real variables of a causality, and the integer, boolean and enumeration ones
        the adapter exchanges too (:attr:`DISCRETE_TYPES`; their ports come after the real
        ones, in the model description's order)."""
        of = [v for v in md.modelVariables if v.causality == causality]
        arrays = self.ARRAYS  # of numbers; String and Binary arrays are not ports
        return ([v for v in of if v.type in REAL_TYPES and (arrays or not v.dimensions)],
                [v for v in of if v.type in self.DISCRETE_TYPES and (
                    not v.dimensions or (arrays and v.type not in _CODED))])

    def shape(self, v: ModelVariable) -> list[int]:
        """An array variable's extent per dimension (``[]`` for a scalar): fixed, or given by
        a structural parameter (its start value, or the value set)."""
        given = getattr(self, "start", {})
        out = []
        for d in v.dimensions:
            if d.start is not None:
                out.append(int(d.start))
            else:
                ref = d.variable
                value = given[ref.name][1] if ref.name in given else ref.start
                out.append(int(_as_number(value)))
        return out

    def size(self, v: ModelVariable) -> int:
        """How many values variable ``v`` holds: 1, or its array's element count."""
        return int(np.prod(self.shape(v))) if v.dimensions else 1

    def _check_start(self, start: dict[str, Any],
                     by_name: Mapping[str, ModelVariable]) -> dict[str, tuple[ModelVariable, Any]]:
        """The overrides by variable, every problem reported at once. ``name[i]`` or
        ``name[i,j]`` (1-based, FMI's structured names) sets one element of an array variable
        on top of its start value or of the whole array given — the way an SSP, whose
        parameter values are scalars, sets an array."""
        problems, elements, whole = [], [], {}
        for name, value in start.items():
            match = ELEMENT.match(name)
            if name not in by_name and match and match.group(1) in by_name:
                elements.append((name, match.group(1), match.group(2), value))
                continue
            v = by_name.get(name)
            why = "is not a variable of the FMU" if v is None else self._unsettable(v)
            if why:
                problems.append(f"'{name}' {why}")
            else:
                whole[name] = (v, value)
        for name, base, index, value in elements:
            v = by_name[base]
            why = self._unsettable(v) or ("" if v.dimensions else "is not an array")
            at = None if why else _flat_index(index, self.shape(v))
            if why or at is None:
                why = why or f"is not an element of an array of shape {self.shape(v)}"
                problems.append(f"'{name}' {why}")
                continue
            values = array_values(whole.get(base, (v, v.start))[1], self.size(v))
            values[at] = float(value)
            whole[base] = (v, values)
        if problems:
            raise ValueError(f"`start` for FMU {self.path}: {'; '.join(problems)}")
        return whole

    def _unsettable(self, v: ModelVariable) -> str:
        """Why ``v`` cannot be given a start value here ("" if it can)."""
        if v.variability == "constant" or v.causality == "independent" or (
                # FMI: outputs and locals (states) only with a start value that is used
                v.causality in ("output", "calculatedParameter", "local")
                and v.initial not in _SETTABLE_BEFORE_INIT):
            return f"({v.causality}, {v.variability}) cannot be set"
        if v.type not in _SETTABLE_TYPES or (v.dimensions and not self.ARRAYS):
            return (f"is of type {v.type}{' (an array)' if v.dimensions else ''}, which cannot "
                    "be set here")
        return ""

    def _ports(self, v: ModelVariable) -> list[Port]:
        """The port of a scalar variable; one per element of an array, ``name[1]`` …
        ``name[n]`` in the FMU's (row-major) order, each with its start value and the
        array's kind, unit and discreteness."""
        if not v.dimensions:
            return [self._port(v)]
        n = self.size(v)
        value = self.start[v.name][1] if v.name in self.start else v.start
        starts = array_values(value, n, numbers=v.type not in REAL_TYPES) \
            if value is not None else [None] * n
        like = self._port(v, scalar=False)
        return [dataclasses.replace(like, name=f"{v.name}[{i + 1}]", start=x)
                for i, x in enumerate(starts)]

    def _port(self, v: ModelVariable, scalar: bool = True) -> Port:
        """The port of variable ``v`` (with ``scalar=False``: its kind, unit and discreteness,
        for the elements of an array)."""
        value = self.start[v.name][1] if v.name in self.start else v.start
        if not scalar:
            value = None
        if v.type in _CODED:  # text and bytes: a code into cosimstep.symbols.SYMBOLS
            kind, unit = _CODED[v.type]
            start = SYMBOLS.code(_as_binary(value) if v.type == "Binary" else value)
            return Port(v.name, unit, start, v.description or "", discrete=True, kind=kind)
        if v.type not in REAL_TYPES:
            # integers, booleans, enumerations: discrete by nature, dimensionless
            kind = "boolean" if v.type == "Boolean" else "integer"
            start = None if value is None else float(_as_number(value))
            return Port(v.name, "1", start, v.description or "", discrete=True, kind=kind)
        unit = v.unit or (v.declaredType.unit if v.declaredType is not None else None) or "1"
        # a discrete output changes only at the FMU's own events: the master holds it and
        # lands on its changes (Port.discrete)
        return Port(v.name, unit, None if value is None else float(value), v.description or "",
                    discrete=v.causality == "output" and v.variability == "discrete")

    def _feedthrough(self) -> dict[str, tuple[str, ...]]:
        """Per output, the inputs it depends on at the same instant (ModelStructure/Outputs)."""
        in_vars = [*self._in_vars, *self._in_disc]
        inputs = {id(v) for v in in_vars}
        declared = {id(u.variable): u for u in self.model_description.outputs}
        result: dict[str, tuple[str, ...]] = {}
        for v in (*self._out_vars, *self._out_disc):
            unknown = declared.get(id(v))
            if unknown is None or unknown.dependencies is None:
                deps = in_vars  # undeclared: depends on all
            else:
                deps = [d for d in unknown.dependencies if id(d) in inputs]
            # ports: an array's every element depends on every element of its inputs
            names = tuple(p.name for d in deps for p in self._ports(d))
            for port in self._ports(v):
                result[port.name] = names
        return result

    # -- integer, boolean and enumeration ports -------------------------------------------------
    def _write_discrete(self, values: Sequence[float]) -> None:
        """Set the integer, enumeration, boolean, string and binary inputs (:attr:`_in_disc`)
        from the master's floats: rounded to the nearest integer (a boolean: nonzero), codes
        decoded (:mod:`cosimstep.symbols`); one call per FMI type."""
        groups: dict[str, tuple[list[int], list[Any]]] = {}
        at = 0
        for v in self._in_disc:
            name, kind = setter_name(v, self.fmi_version)
            vrs, xs = groups.setdefault(name, ([], []))
            vrs.append(v.valueReference)
            n = self.size(v)  # an array's elements, flattened
            xs.extend(SYMBOLS.text(x) if v.type == "String" else SYMBOLS.binary(x)
                      if v.type == "Binary" else kind(round(float(x))) for x in values[at:at + n])
            at += n
        fmu = self._live()
        for name, (vrs, xs) in groups.items():
            try:
                getattr(fmu, name)(vrs, xs)
            except FMICallException as exc:
                raise self._error(exc.function, exc) from None

    def _read_discrete(self) -> np.ndarray:
        """The integer, enumeration, boolean, string and binary outputs (:attr:`_out_disc`) as
        floats (text and bytes as codes), in port order; one call per FMI type."""
        groups: dict[str, tuple[list[int], list[int]]] = {}  # getter: value refs, ports
        at = 0
        for v in self._out_disc:
            vrs, index = groups.setdefault(getter_name(v, self.fmi_version), ([], []))
            vrs.append(v.valueReference)
            n = self.size(v)  # an array's elements, flattened
            index.extend(range(at, at + n))
            at += n
        fmu = self._live()
        out = np.empty(at)
        for name, (vrs, index) in groups.items():
            try:  # FMI 2.0 has no arrays, and its getters no value count
                got = getattr(fmu, name)(*((vrs,) if len(index) == len(vrs) else
                                           (vrs, len(index))))
            except FMICallException as exc:
                raise self._error(exc.function, exc) from None
            coded = name in ("getString", "getBinary")
            out[index] = [SYMBOLS.code(x) if coded else float(x) for x in got]
        return out

    # -- errors ----------------------------------------------------------------------------------
    def _logger(self, status: int, message: bytes | str | None) -> None:
        self._log.append(_log_line(status, message))
        _echo(self.name, self._log[-1])

    def _fmi2_callbacks(self) -> fmi2CallbackFunctions:
        """FMI 2.0 callbacks whose logger keeps the FMU's messages for :meth:`_error`.

        The logger holds the log, not the instance, so the sub-model is not part of a reference
        cycle through its own callbacks.
        """
        log, name = self._log, self.name

        def logger(env: Any, instance: bytes, status: int, category: bytes,
                   message: bytes) -> None:
            log.append(_log_line(status, message))
            _echo(name, log[-1])

        callbacks = fmi2CallbackFunctions()
        callbacks.logger = fmi2CallbackLoggerTYPE(logger)
        callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(fmpy.calloc)
        callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(fmpy.free)
        with contextlib.suppress(Exception):  # formats the C logger's variadic arguments
            from fmpy.logging import addLoggerProxy

            addLoggerProxy(byref(callbacks))
        return callbacks

    def _error(self, call: str, exc: BaseException | None = None) -> FmuError:
        """The error for ``call``: failed with ``exc``, or (no ``exc``) ``call`` says what went
        wrong."""
        if isinstance(exc, FMICallException):
            return self._failed(exc.function, exc.status)
        return self._report(call if exc is None else f"{call} failed: {exc}")

    def _failed(self, function: str, status: int) -> Exception:
        """The error for an FMI call that returned ``status`` (> warning) — or, for a step
        the FMU discarded because it ends the simulation (FMI 2.0 ``fmi2Terminated``), the
        :class:`~cosimstep.errors.EndOfSimulation` that ends the run normally."""
        label = STATUS[status] if 0 <= status < len(STATUS) else str(status)
        if (function.endswith("DoStep") and label == "discard" and self._fmu is not None
                and getattr(self._fmu, "terminated", lambda: False)()):
            logged = "; ".join(self._log)
            self._log.clear()
            return EndOfSimulation(self.name, "terminateSimulation during a step"
                                   + (f" (FMU log: {logged})" if logged else ""))
        return self._report(f"{function} returned {label}")

    def _report(self, what: str) -> FmuError:
        logged = "; ".join(self._log)
        self._log.clear()
        return FmuError(f"FMU '{self.name}' ({self.path.name}): {what}"
                        + (f" — FMU log: {logged}" if logged else ""))

    def _not_live(self) -> FmuError:
        return FmuError(f"FMU '{self.name}' ({self.path.name}) is not initialized")

    def _live(self) -> Any:
        if self._fmu is None:
            raise self._not_live()
        return self._fmu

    # -- lifecycle ------------------------------------------------------------------------------
    def _unpack(self) -> str:
        # an FMU that runs once per process gets a library of its own, to unload (see _load)
        self._unzipped = _UNPACKED.acquire(self.path, share=not self._once)
        return str(self._unzipped)

    @property
    def _once(self) -> bool:
        """The FMU declares ``canBeInstantiatedOnlyOncePerProcess``."""
        return bool(getattr(self.interface, "canBeInstantiatedOnlyOncePerProcess", False))

    def _load(self, fmu_class: type) -> Any:
        """Unpack the archive and load the FMU's library: the ``fmu_class`` object, not
        instantiated.

        The library stays loaded with its folder (:class:`_Unpacked`), marked so before the
        load: a load that fails after the library was mapped must not leave it mapped from a
        folder that goes. An FMU that can be instantiated only once per process is the
        exception: a second live instance is refused, and its library is unloaded with its
        instance as before, the only way to a fresh one in the same process."""
        folder = self._unpack()
        if self._once:
            _ONCE.enter(self)
        else:
            _UNPACKED.keep(Path(folder))
        try:
            self._fmu = fmu_class(guid=self.model_description.guid, unzipDirectory=folder,
                                  modelIdentifier=self.interface.modelIdentifier,
                                  instanceName=self.name)
        except BaseException:
            _ONCE.leave(self)
            raise
        return self._fmu

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

    def _serialize_fmu_state(self, saved: Any) -> bytes:
        """The FMU's own bytes of a saved state (``fmi2SerializeFMUstate`` / FMI 3's)."""
        if not getattr(self.interface, "canSerializeFMUstate", False):
            raise NotImplementedError(f"FMU '{self.name}' cannot serialize its state "
                                      "(canSerializeFMUstate is false in its model description)")
        if not isinstance(saved, _SavedState) or saved.owner is not self:
            raise ValueError(f"FMU '{self.name}': serialize_state got a state this instance "
                             "did not save")
        fmu = self._live()
        try:
            if self.fmi_version == "3.0":
                return bytes(fmu.serializeFMUState(saved.pointer))
            return bytes(fmu.serializeFMUstate(saved.pointer))
        except FMICallException as exc:
            raise self._error(f"{self.CALL_PREFIX}Serialize{self._state_word}", exc) from None

    def _deserialize_fmu_state(self, data: bytes) -> _SavedState:
        """A saved state of this instance from :meth:`_serialize_fmu_state`'s bytes."""
        fmu = self._live()
        pointer = self._spare_states.pop() if self._spare_states else c_void_p()
        try:
            if self.fmi_version == "3.0":
                fmu.deserializeFMUState(data, pointer)
            else:
                fmu.deSerializeFMUstate(data, pointer)
        except FMICallException as exc:
            raise self._error(f"{self.CALL_PREFIX}DeSerialize{self._state_word}", exc) from None
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
        """Terminate and free the instance, free saved states, release the unpacked files (the
        library and its folder stay for later instances, see :class:`_Unpacked`; an FMU that
        can be instantiated only once per process is unloaded, see :meth:`_load`).

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
            if self._once:  # the instance and the library, as the library object does
                try:
                    if fmu.component is not None:
                        fmu.freeInstance()
                    else:
                        fmu.freeLibrary()
                except Exception as exc:
                    first = first or self._error(f"{self.CALL_PREFIX}FreeInstance", exc)
                _ONCE.leave(self)
            elif fmu.component is not None:
                # the instance only: the library stays loaded (``_Unpacked``), where the
                # library objects' own ``freeInstance`` would unload it too
                try:
                    getattr(fmu, f"{self.CALL_PREFIX}FreeInstance")(fmu.component)
                except Exception as exc:
                    first = first or self._error(f"{self.CALL_PREFIX}FreeInstance", exc)
                fmu.component = None
        self._initialized = False
        if self._unzipped is not None:
            _UNPACKED.release(self._unzipped)
            self._unzipped = None
        if first is not None:
            raise first


class _Unpacked:
    """One unpacked folder per FMU file, shared by every instance of it.

    An FMU's files are read-only to its instances (FMI: the resource location is for reading),
    so instances of one FMU need one copy: a system of ten instances of one FMU unpacked ten
    times before. Files are told apart by their content (each member's name, CRC and size):
    the same FMU at another path (an SSP archive unpacked again for every run of a sweep)
    shares the folder, a file rebuilt in place gets a fresh one.

    A folder whose shared library has been loaded (:meth:`keep`) stays, and the library with it,
    until the process exits; any other goes when the last instance using it is terminated. Why:
    a library must not be loaded a second time from a second folder, and it cannot always be
    unloaded in between. pythonfmu's runtime exports C++ symbols of which the loader keeps one
    per process, which makes ``dlclose`` a no-op for it; a second copy loaded from another
    folder shares those objects with the first, and both destroy them at exit. The ship plant
    with its pythonfmu zone (``examples/ship_plant_fmu.toml``), whose run is repeated at a
    tighter tolerance after the first run had removed the folder, ended in 8 of 10 runs with
    ``free(): corrupted unsorted chunks`` and exit code 134 after writing its results; with
    folders kept and shared, in 0 of 12 (docs/reliability.md). A later instance of the same
    file also skips the unpacking, and the library is already mapped. A folder that vanished
    meanwhile (a cleaner of the temporary directory) is unpacked again at the same place.
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        # key -> [folder, users, kept: whether its library was loaded]
        self._folders: dict[tuple, list] = {}
        self._binaries: dict[tuple[int, int], Path] = {}  # (CRC, size) -> the first unpacked
        self._cleanup = False

    def acquire(self, path: Path, share: bool = True) -> Path:
        """The folder of ``path``'s content, unpacked if needed; ``share``: its binaries may be
        the same files as identical ones unpacked before (:meth:`_share_binaries`)."""
        key = content_of(path)
        with self._lock:
            entry = self._folders.get(key)
            if entry is None:
                entry = self._folders[key] = [self._extract(path, new_folder(path.stem)), 0,
                                              False]
            elif not entry[0].is_dir():
                self._extract(path, mark(entry[0]))
            else:
                share = False  # unpacked before, and shared then if it could be
            if share:
                self._share_binaries(key, entry[0])
            entry[1] += 1
            return entry[0]

    def _share_binaries(self, key: tuple, folder: Path) -> None:
        """Each binary made the same file as an identical one (same CRC and size) unpacked
        before. The loader (glibc's) maps a file once per process, telling files apart by device
        and inode, so FMUs that ship the same runtime — every pythonfmu FMU ships one — run on one
        copy of it: two copies of pythonfmu's runtime share its process-wide C++ objects and
        both destroy them at exit (see the class docstring). Where a link cannot be made (another
        file system, no hard links) the binary stays a copy of its own."""
        for name, crc, size in key:
            if not name.startswith("binaries/") or name.endswith("/"):
                continue
            mine = folder / name
            first = self._binaries.get((crc, size))
            if first is None or not first.is_file():
                self._binaries[(crc, size)] = mine
                continue
            if first == mine:
                continue
            link = mine.with_name(mine.name + ".link")
            try:
                os.link(first, link)
                os.replace(link, mine)
            except OSError:
                with contextlib.suppress(OSError):
                    link.unlink()

    @staticmethod
    def _extract(path: Path, folder: Path) -> Path:
        try:
            # sources/ and documentation/ are not needed to run the binary; without them the
            # test FMUs unpacked in 1.7 instead of 3.1 ms
            fmpy.extract(str(path), unzipdir=str(folder), include=_needed)
        except BaseException:
            shutil.rmtree(folder, ignore_errors=True)
            raise
        return folder

    def keep(self, folder: Path) -> None:
        """``folder``'s library has been loaded: keep both until the process exits."""
        with self._lock:
            for entry in self._folders.values():
                if entry[0] == folder:
                    entry[2] = True
            if not self._cleanup:
                self._cleanup = True
                atexit.register(self._remove_kept)

    def release(self, folder: Path) -> None:
        with self._lock:
            for key, entry in list(self._folders.items()):
                if entry[0] == folder:
                    entry[1] -= 1
                    if entry[1] <= 0 and not entry[2]:
                        del self._folders[key]
                        shutil.rmtree(folder, ignore_errors=True)
                    return
        shutil.rmtree(folder, ignore_errors=True)  # not ours: remove it as before

    def _remove_kept(self) -> None:
        """At exit: the kept folders go (a loaded library's file can be removed on POSIX; where
        it cannot, the next process's sweep of dead processes' folders takes it)."""
        with self._lock:
            for folder, _, kept in self._folders.values():
                if kept:
                    shutil.rmtree(folder, ignore_errors=True)


_UNPACKED = _Unpacked()


def content_of(path: Path) -> tuple:
    """:func:`_content` of the file at ``path`` as it is on disk now."""
    info = path.stat()
    return _content(str(path.resolve()), info.st_size, info.st_mtime_ns, info.st_ctime_ns,
                    info.st_ino)


@functools.lru_cache(maxsize=256)
def _content(path: str, size: int, mtime_ns: int, ctime_ns: int, inode: int) -> tuple:
    """What tells one FMU file's content from another's: its members' names, CRCs and sizes
    (read from the archive's directory once per version of the file on disk)."""
    with zipfile.ZipFile(path) as archive:
        return tuple(sorted((i.filename, i.CRC, i.file_size) for i in archive.infolist()))


class _OncePerProcess:
    """The live instances of FMUs that declare ``canBeInstantiatedOnlyOncePerProcess``: a
    second one of the same file is refused with the reason, instead of sharing a library that
    says it cannot serve two."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._live: dict[tuple, str] = {}  # content key -> the live instance's name

    def enter(self, model: FmuBase) -> None:
        key = content_of(model.path)
        with self._lock:
            other = self._live.get(key)
            if other is not None:
                raise model._report(f"it can be instantiated only once per process "
                                    f"(canBeInstantiatedOnlyOncePerProcess), and instance "
                                    f"'{other}' is alive: use it once per system, or run the "
                                    f"systems that need it in separate processes")
            self._live[key] = model.name
            model._once_key = key

    def leave(self, model: FmuBase) -> None:
        key = getattr(model, "_once_key", None)
        with self._lock:
            if key is not None and self._live.get(key) == model.name:
                del self._live[key]
        model._once_key = None


_ONCE = _OncePerProcess()


def once_per_process_problems(models: Mapping[str, Any]) -> list[str]:
    """Why ``models`` (by name) cannot run in one process: several instances of one FMU that
    declares ``canBeInstantiatedOnlyOncePerProcess`` — found before the run, where
    :class:`_OncePerProcess` would refuse the second instance when it starts."""
    groups: dict[tuple, list[str]] = {}
    for name, model in models.items():
        if isinstance(model, FmuBase) and model._once:
            groups.setdefault(content_of(model.path), []).append(name)
    return [f"{', '.join(names)} are instances of one FMU that can be instantiated only once "
            "per process (canBeInstantiatedOnlyOncePerProcess)"
            for names in groups.values() if len(names) > 1]


_LOGGING = [False]


def set_fmu_logging(on: bool) -> None:
    """Instantiate FMUs from now on with ``loggingOn`` and echo each message they log to
    stderr as it comes, prefixed by the instance name (``run --fmu-logging``). Off by default:
    the messages are kept either way and quoted when a call fails."""
    _LOGGING[0] = bool(on)


def fmu_logging() -> bool:
    """Whether FMUs are instantiated with ``loggingOn`` (:func:`set_fmu_logging`)."""
    return _LOGGING[0]


def _echo(name: str, line: str) -> None:
    if _LOGGING[0]:
        print(f"{name}: {line}", file=sys.stderr, flush=True)


def _as_bool(value: Any) -> bool:
    """A boolean start value: ``true``/``false`` (TOML), or a number (nonzero is true)."""
    return bool(_as_number(value)) if isinstance(value, str) else bool(value)


def _as_binary(value: Any) -> bytes:
    """A Binary value: bytes as they are, a model description's hexadecimal start text, or
    text (TOML) as UTF-8."""
    if value is None:
        return b""
    if isinstance(value, bytes | bytearray):
        return bytes(value)
    text = str(value)
    try:
        return bytes.fromhex(text)
    except ValueError:
        return text.encode("utf-8")


def _as_number(value: Any) -> int:
    """A start value of an integer, boolean or enumeration variable as a number (FMPy gives
    ``"true"``/``"false"`` or numbers as text for some)."""
    if isinstance(value, str):
        text = value.strip().lower()
        if text in ("true", "false"):
            return int(text == "true")
        return int(float(text))
    return int(value)


def _log_line(status: int, message: bytes | str | None) -> str:
    label = STATUS[status] if 0 <= status < len(STATUS) else str(status)
    text = message.decode("utf-8", "replace") if isinstance(message, bytes) else str(message)
    return f"[{label}] {text}"


def setter_name(v: ModelVariable, version: str) -> tuple[str, type]:
    """FMPy's setter for a variable's type (``setReal``/``setFloat64``...) and the Python type."""
    if v.type in ("Real", "Float64", "Float32"):
        return ("setReal" if version == "2.0" else f"set{v.type}"), float
    if v.type == "Boolean":
        return "setBoolean", _as_bool
    if v.type == "String":
        return "setString", str
    if v.type == "Binary":
        return "setBinary", _as_binary
    if version == "2.0":
        return "setInteger", int
    return f"set{'Int64' if v.type == 'Enumeration' else v.type}", int


def getter_name(v: ModelVariable, version: str) -> str:
    """FMPy's getter for a non-real variable's type (``getInteger``, ``getInt32``...)."""
    if v.type in ("Boolean", "String", "Binary"):
        return f"get{v.type}"
    if version == "2.0":
        return "getInteger"
    return f"get{'Int64' if v.type == 'Enumeration' else v.type}"


def set_values(fmu: Any, values: Sequence[tuple[ModelVariable, Any]], version: str) -> None:
    """Set start values one by one with the setter of each variable's type (an array's
    values at once, flattened)."""
    for v, value in values:
        name, kind = setter_name(v, version)
        if v.dimensions:
            getattr(fmu, name)([v.valueReference], [kind(x) for x in array_values(value)])
        else:
            getattr(fmu, name)([v.valueReference], [kind(value)])


def _flat_index(index: str, shape: Sequence[int]) -> int | None:
    """The row-major position of the 1-based ``"i,j"`` in an array of ``shape``, or ``None``
    if it is not one of its elements."""
    idx = [int(i) - 1 for i in index.split(",")]
    if len(idx) != len(shape) or any(not 0 <= i < n for i, n in zip(idx, shape, strict=True)):
        return None
    return int(np.ravel_multi_index(idx, shape))


def array_values(value: Any, n: int | None = None, numbers: bool = False) -> list[float]:
    """An array's values flattened (row-major): from nested lists (TOML), a number, or a
    model description's start text ``"1 0 0 1"`` (with ``numbers``: integers, booleans
    ``"true false"``); a single value fills ``n`` elements."""
    if isinstance(value, str):
        flat = [float(_as_number(x) if numbers else x) for x in value.split()]
    elif isinstance(value, list | tuple | np.ndarray):
        flat = [float(x) for x in np.asarray(value, dtype=float).ravel()]
    else:
        flat = [float(value)]
    if n is not None and len(flat) == 1 and n > 1:
        flat = flat * n
    if n is not None and len(flat) != n:
        raise ValueError(f"{len(flat)} values for an array of {n}")
    return flat

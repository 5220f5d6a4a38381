"""FMI co-simulation FMUs as sub-models, through FMPy (issue 5).

:class:`FmuSubModel` runs an FMI 2.0 co-simulation FMU: its Real inputs and outputs become ports
(names, units and start values from ``modelDescription.xml``), start values and parameters can be
overridden by name, and the capabilities come from the model description — state save/restore
from ``canGetAndSetFMUstate``, output derivatives (grey box) from ``maxOutputDerivativeOrder``,
input derivatives from ``canInterpolateInputs``.

An FMU is checked before anything is unpacked (:func:`check_fmu`): a file that is not a zip
archive, has no ``modelDescription.xml``, has no binary for this platform, is not of a version and
kind the adapter runs, or holds an entry that would unpack outside its folder is refused with a
``ValueError`` naming the file and the reason. FMI 3.0 co-simulation FMUs run in
:mod:`cosimstep.adapters.fmu3`, model-exchange FMUs in :mod:`cosimstep.adapters.fmu_me`;
:func:`cosimstep.adapters.fmu_open.open_fmu` picks the adapter. The archive is unpacked into a
temporary folder by :meth:`initialize` and the folder is removed by :meth:`terminate`, also when a
call failed.
"""

from __future__ import annotations

import contextlib
import posixpath
import shutil
import tempfile
import weakref
import zipfile
from collections import deque
from collections.abc import Mapping, Sequence
from ctypes import byref, c_double, c_int, c_size_t, c_void_p
from pathlib import Path
from typing import Any

import fmpy
import numpy as np
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import (
    FMU2Slave,
    fmi2CallbackAllocateMemoryTYPE,
    fmi2CallbackFreeMemoryTYPE,
    fmi2CallbackFunctions,
    fmi2CallbackLoggerTYPE,
    fmi2FMUstate,
)
from fmpy.model_description import ModelDescription, ModelVariable

from cosimstep.submodel import Capabilities, Port, SubModel

INPUT_DERIVATIVE_ORDER = 3  # offered to masters when an FMU can interpolate inputs
_STATUS = ("ok", "warning", "discard", "error", "fatal", "pending")
_SETTABLE_BEFORE_INIT = ("exact", "approx")


class FmuError(RuntimeError):
    """An FMI call failed; the message names the FMU, the call and what the FMU logged."""


FMI2_CS = ("2.0", "CS")
FMI2_ME = ("2.0", "ME")
FMI3_CS = ("3.0", "CS")
SUPPORTED = (FMI2_CS, FMI3_CS, FMI2_ME)
"""FMI versions and kinds cosimstep runs, in the order :func:`fmu_interface` prefers them (an
FMU's own co-simulation solver before cosimstep's wrapper around model exchange)."""
_KIND_NAMES = {"CS": "co-simulation", "ME": "model exchange"}


def fmu_interface(md: ModelDescription,
                  supported: Sequence[tuple[str, str]] = SUPPORTED) -> tuple[str, str] | None:
    """The first of ``supported`` (``(version, "CS" | "ME")``) that the FMU offers, or ``None``."""
    offered = _offered(md)
    return next((pair for pair in supported if pair in offered), None)


def _offered(md: ModelDescription) -> list[tuple[str, str]]:
    version = "3.0" if str(md.fmiVersion).startswith("3.") else str(md.fmiVersion)
    return [(version, kind) for kind, part in (("CS", md.coSimulation), ("ME", md.modelExchange))
            if part is not None]


def _describe(pairs: Sequence[tuple[str, str]]) -> str:
    return " and ".join(f"FMI {v} {_KIND_NAMES[k]}" for v, k in pairs) or "no interface"


def check_fmu(path: str | Path,
              supported: Sequence[tuple[str, str]] = (FMI2_CS,)) -> ModelDescription:
    """Read and check an FMU without unpacking it; raise ``ValueError`` saying why it is refused.

    ``supported`` lists the ``(version, kind)`` pairs the caller can run (default: what
    :class:`FmuSubModel` runs); the FMU must offer one of them, with a binary for this platform.
    """
    path = Path(path)

    def refuse(reason: str) -> ValueError:
        return ValueError(f"cannot use FMU {path}: {reason}")

    if not path.is_file():
        raise refuse("no such file")
    if not zipfile.is_zipfile(path):
        raise refuse("not a zip archive (an FMU is a zip file)")
    try:
        with zipfile.ZipFile(path) as zf:
            names = zf.namelist()
    except (OSError, zipfile.BadZipFile) as exc:
        raise refuse(f"corrupt zip archive ({exc})") from exc
    for name in names:
        if _escapes(name):
            raise refuse(f"archive entry '{name}' would unpack outside the FMU's folder "
                         "(absolute path or '..'); refusing to unpack it")
    if "modelDescription.xml" not in names:
        raise refuse("no modelDescription.xml at the top of the archive")
    try:
        md = fmpy.read_model_description(str(path), validate=True)
    except Exception as exc:  # FMPy raises plain Exceptions for invalid descriptions
        raise refuse(f"invalid modelDescription.xml: {exc}") from exc
    if md.fmiVersion == "1.0":
        raise refuse(f"FMI 1.0 is not supported (cosimstep runs {_describe(SUPPORTED)} FMUs)")
    chosen = fmu_interface(md, supported)
    if chosen is None:
        offered = _offered(md)
        only = " only" if len(offered) == 1 else ""
        if not any(pair in SUPPORTED for pair in offered):
            raise refuse(f"{_describe(offered)}{only} is not supported (cosimstep runs "
                         f"{_describe(SUPPORTED)} FMUs)")
        raise refuse(f"{_describe(offered)}{only}; this adapter runs {_describe(supported)} "
                     "(cosimstep.adapters.fmu_open.open_fmu picks the adapter for any supported "
                     "FMU)")
    version, kind = chosen
    part = md.coSimulation if kind == "CS" else md.modelExchange
    folder = fmpy.platform_tuple if version == "3.0" else fmpy.platform
    binary = f"binaries/{folder}/{part.modelIdentifier}{fmpy.sharedLibraryExtension}"
    if binary not in names:
        found = sorted({n.split("/")[1] for n in names
                        if n.startswith("binaries/") and n.count("/") >= 2})
        raise refuse(f"no binary for this platform ({binary} is missing; it has binaries for: "
                     f"{', '.join(found) or 'none'})")
    return md


def _needed(name: str) -> bool:
    """Whether an archive entry is unpacked to run the FMU (everything but sources and docs)."""
    return not name.startswith(("sources/", "documentation/"))


def _escapes(name: str) -> bool:
    """Whether a zip entry name points outside the folder it is unpacked into."""
    if "\\" in name or name.startswith("/") or (len(name) > 1 and name[1] == ":"):
        return True
    return ".." in posixpath.normpath(name).split("/")


class _SavedState:
    """A token for one saved FMU state. When the master drops it, its memory is kept for reuse
    (``fmi2GetFMUstate`` overwrites a given state in place); :meth:`FmuSubModel.terminate` frees
    it in the FMU."""

    __slots__ = ("__weakref__", "owner", "pointer")

    def __init__(self, owner: FmuSubModel, pointer: fmi2FMUstate) -> None:
        self.owner: FmuSubModel | None = owner
        self.pointer = pointer

    def __del__(self) -> None:
        if self.owner is not None:
            self.owner._spare_states.append(self.pointer)


class DirectIO(tuple):
    """The raw C entry points of one initialized FMU instance, for a master's hot loop.

    ``(component, set_real, in_vr, n_in, do_step, get_real, out_vr, n_out, fail)``: ``set_real``
    and ``get_real`` take ``(component, in_vr / out_vr, n_in / n_out, address of n doubles)``,
    ``do_step`` takes ``(component, t, h, 1)``; each returns the FMI status, and a status above
    1 (warning) is a failure, for which ``fail(function_name, status)`` builds the exception the
    sub-model's own methods would raise. Addresses are plain integers; the caller keeps the
    memory alive.
    """

    __slots__ = ()


class FmuSubModel(SubModel):
    """An FMI 2.0 co-simulation FMU as a sub-model.

    Parameters
    ----------
    path:
        The ``.fmu`` file.
    start:
        Start values and parameters by variable name (``{"theta": 0.4, "m1": 2.0}``); they are set
        before initialization and replace the model description's start values.
    instance_name:
        Name of the FMU instance (in messages and the FMU's log); default the model name.
    input_derivative_order:
        Highest input derivative offered to masters when the FMU can interpolate inputs
        (``canInterpolateInputs``); FMI 2.0 does not declare a limit.
    tolerance:
        Passed to ``fmi2SetupExperiment`` for the FMU's internal solver, if given.
    """

    def __init__(self, path: str | Path, start: Mapping[str, float] | None = None, *,
                 instance_name: str | None = None,
                 input_derivative_order: int = INPUT_DERIVATIVE_ORDER,
                 tolerance: float | None = None) -> None:
        self.path = Path(path)
        md = check_fmu(self.path)
        self.model_description = md
        self.name = instance_name or md.modelName
        self.tolerance = tolerance
        cs = md.coSimulation
        by_name = {v.name: v for v in md.modelVariables}
        self.start = self._check_start(dict(start or {}), by_name)
        ins = [v for v in md.modelVariables if v.causality == "input" and v.type == "Real"]
        outs = [v for v in md.modelVariables if v.causality == "output" and v.type == "Real"]
        self.inputs = tuple(self._port(v) for v in ins)
        self.outputs = tuple(self._port(v) for v in outs)
        self._in_vr = [v.valueReference for v in ins]
        self._out_vr = [v.valueReference for v in outs]
        order = input_derivative_order if cs.canInterpolateInputs else 0
        self.capabilities = Capabilities(
            can_save_state=bool(cs.canGetAndSetFMUstate),
            provides_derivatives=cs.maxOutputDerivativeOrder >= 1,
            max_input_derivative_order=order,
            feedthrough=self._feedthrough(md, ins, outs),
        )
        # Input derivatives for every order at once: orders 1..q for each input, in one call.
        self._deriv_vr = self._in_vr * order
        self._deriv_order = [k for k in range(1, order + 1) for _ in self._in_vr]
        self._fmu: FMU2Slave | None = None
        self._component: int | None = None  # the instance pointer while initialized
        self._c: dict[str, Any] = {}  # our own prototypes of the FMI functions called per step
        # Value references and value buffers as C arrays, made once: a step passes addresses.
        self._in_vr_c = np.array(self._in_vr, dtype=np.uint32)
        self._out_vr_c = np.array(self._out_vr, dtype=np.uint32)
        self._u = np.zeros(len(self._in_vr))
        self._y = np.zeros(len(self._out_vr))
        self._dy = np.zeros(len(self._out_vr))
        self._d = np.zeros((order, len(self._in_vr)))
        self._deriv_vr_c = np.array(self._deriv_vr, dtype=np.uint32)
        self._deriv_order_c = np.array(self._deriv_order, dtype=np.int32)
        self._ones_c = np.ones(len(self._out_vr), dtype=np.int32)
        self._unzipped: Path | None = None
        self._initialized = False
        self._derivatives_set = False  # the FMU holds nonzero input derivatives
        self._derivatives_stale = False  # ...which the next step must not use
        self._states: weakref.WeakSet[_SavedState] = weakref.WeakSet()
        self._spare_states: list[fmi2FMUstate] = []
        self._log: deque[str] = deque(maxlen=20)
        self._callbacks = self._make_callbacks()

    # -- construction helpers ------------------------------------------------------------------
    def _check_start(self, start: dict[str, Any],
                     by_name: Mapping[str, ModelVariable]) -> dict[str, Any]:
        problems = []
        for name in start:
            v = by_name.get(name)
            if v is None:
                problems.append(f"'{name}' is not a variable of the FMU")
            elif v.variability == "constant" or v.causality in ("independent", "local") or (
                    v.causality in ("output", "calculatedParameter")
                    and v.initial not in _SETTABLE_BEFORE_INIT):
                problems.append(f"'{name}' ({v.causality}, {v.variability}) cannot be set")
            elif v.type not in ("Real", "Integer", "Enumeration", "Boolean"):
                problems.append(f"'{name}' is of type {v.type}, which cannot be set here")
        if problems:
            raise ValueError(f"`start` for FMU {self.path}: {'; '.join(problems)}")
        return {name: (by_name[name], value) for name, value in start.items()}

    def _port(self, v: ModelVariable) -> Port:
        value = self.start[v.name][1] if v.name in self.start else v.start
        unit = v.unit or (v.declaredType.unit if v.declaredType is not None else None) or "1"
        return Port(v.name, unit, None if value is None else float(value), v.description or "")

    @staticmethod
    def _feedthrough(md: ModelDescription, ins: list[ModelVariable],
                     outs: list[ModelVariable]) -> dict[str, tuple[str, ...]]:
        inputs = {id(v) for v in ins}
        declared = {id(u.variable): u for u in md.outputs}
        result: dict[str, tuple[str, ...]] = {}
        for v in outs:
            unknown = declared.get(id(v))
            if unknown is None or unknown.dependencies is None:
                deps = tuple(i.name for i in ins)  # undeclared: FMI says "depends on all"
            else:
                deps = tuple(d.name for d in unknown.dependencies if id(d) in inputs)
            result[v.name] = deps
        return result

    def _make_callbacks(self) -> fmi2CallbackFunctions:
        log = self._log

        def logger(env: Any, instance: bytes, status: int, category: bytes,
                   message: bytes) -> None:
            label = _STATUS[status] if 0 <= status < len(_STATUS) else str(status)
            log.append(f"[{label}] {message.decode('utf-8', 'replace')}")

        callbacks = fmi2CallbackFunctions()
        callbacks.logger = fmi2CallbackLoggerTYPE(logger)
        callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(fmpy.calloc)
        callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(fmpy.free)
        with contextlib.suppress(Exception):  # formats the C logger's variadic arguments
            from fmpy.logging import addLoggerProxy

            addLoggerProxy(byref(callbacks))
        return callbacks

    def _error(self, call: str, exc: BaseException) -> FmuError:
        if isinstance(exc, FMICallException):
            return self._failed(exc.function, exc.status)
        return self._report(f"{call} failed: {exc}")

    def _failed(self, function: str, status: int) -> FmuError:
        """The error for an FMI call that returned ``status`` (> warning)."""
        label = _STATUS[status] if 0 <= status < len(_STATUS) else str(status)
        return self._report(f"{function} returned {label}")

    def _report(self, what: str) -> FmuError:
        logged = "; ".join(self._log)
        self._log.clear()
        return FmuError(f"FMU '{self.name}' ({self.path.name}): {what}"
                        + (f" — FMU log: {logged}" if logged else ""))

    # -- SubModel API ----------------------------------------------------------------------------
    def initialize(self, t0: float) -> None:
        if self._fmu is not None:
            self.terminate()
        md = self.model_description
        try:
            self._unzipped = Path(tempfile.mkdtemp(prefix=f"cosimstep-{self.name}-"))
            # sources/ and documentation/ are not needed to run the binary; without them the
            # test FMUs unpacked in 1.7 instead of 3.1 ms (and there is less to remove)
            fmpy.extract(str(self.path), unzipdir=str(self._unzipped), include=_needed)
            self._fmu = FMU2Slave(guid=md.guid, unzipDirectory=str(self._unzipped),
                                  modelIdentifier=md.coSimulation.modelIdentifier,
                                  instanceName=self.name)
            fmu = self._fmu
            fmu.instantiate(callbacks=self._callbacks)
            fmu.setupExperiment(tolerance=self.tolerance, startTime=t0)
            early = {n: vv for n, vv in self.start.items() if vv[0].causality != "input"}
            late = {n: vv for n, vv in self.start.items() if vv[0].causality == "input"}
            self._set_values(early)
            fmu.enterInitializationMode()
            self._set_values(late)
            fmu.exitInitializationMode()
            self._bind(fmu)
        except Exception as exc:
            error = self._error("initialization", exc)
            with contextlib.suppress(Exception):
                self.terminate()
            raise error from exc
        self._initialized = True
        self._derivatives_set = self._derivatives_stale = False

    def _bind(self, fmu: FMU2Slave) -> None:
        """Our own ctypes prototypes of the FMI functions a step calls.

        FMPy's methods convert Python lists to new C arrays and check the status in Python on
        every call (about 10 µs per step of two FMUs, more than the FMUs' own work here); these
        take the addresses of the preallocated arrays above and return the status, which is
        checked with one comparison. ``dll[name]`` gives a new function object, so FMPy's own
        prototypes of the same functions stay as they were.
        """
        vp, size = c_void_p, c_size_t
        signatures = {"fmi2SetReal": (vp, vp, size, vp), "fmi2GetReal": (vp, vp, size, vp),
                      "fmi2DoStep": (vp, c_double, c_double, c_int)}
        if self.capabilities.max_input_derivative_order:
            signatures["fmi2SetRealInputDerivatives"] = (vp, vp, size, vp, vp)
        if self.capabilities.provides_derivatives:
            signatures["fmi2GetRealOutputDerivatives"] = (vp, vp, size, vp, vp)
        functions = {}
        for name, argtypes in signatures.items():
            f = fmu.dll[name]
            f.argtypes, f.restype = argtypes, c_int
            functions[name] = f
        self._c = functions
        self._component = fmu.component.value if isinstance(fmu.component, c_void_p) \
            else fmu.component
        self._addr = {name: array.ctypes.data for name, array in (
            ("in_vr", self._in_vr_c), ("out_vr", self._out_vr_c), ("u", self._u),
            ("y", self._y), ("dy", self._dy), ("d", self._d), ("deriv_vr", self._deriv_vr_c),
            ("deriv_order", self._deriv_order_c), ("ones", self._ones_c))}

    def _direct_io(self) -> DirectIO | None:
        """The raw calls of a step for a master that passes addresses (see :class:`DirectIO`).

        ``None`` when a subclass overrides a step method (the master must call it), when the
        instance is not initialized, or when it holds input derivatives (a plain ``set_inputs``
        would have to clear them first).
        """
        cls = type(self)
        if (self._component is None or self._derivatives_set
                or cls.set_inputs is not FmuSubModel.set_inputs
                or cls.do_step is not FmuSubModel.do_step
                or cls.get_outputs is not FmuSubModel.get_outputs):
            return None
        c, addr = self._c, self._addr
        return DirectIO((self._component, c["fmi2SetReal"], addr["in_vr"], len(self._in_vr),
                         c["fmi2DoStep"], c["fmi2GetReal"], addr["out_vr"], len(self._out_vr),
                         self._failed))

    def _set_values(self, values: Mapping[str, tuple[ModelVariable, Any]]) -> None:
        fmu = self._fmu
        assert fmu is not None
        for v, value in values.values():
            if v.type == "Real":
                fmu.setReal([v.valueReference], [float(value)])
            elif v.type == "Boolean":
                fmu.setBoolean([v.valueReference], [bool(value)])
            else:
                fmu.setInteger([v.valueReference], [int(value)])

    def _live(self) -> FMU2Slave:
        if self._fmu is None:
            raise self._not_live()
        return self._fmu

    def _not_live(self) -> FmuError:
        return FmuError(f"FMU '{self.name}' ({self.path.name}) is not initialized")

    def set_inputs(self, values: np.ndarray) -> None:
        if self._component is None:
            raise self._not_live()
        self._u[:] = values
        status = self._c["fmi2SetReal"](self._component, self._addr["in_vr"], self._u.size,
                                        self._addr["u"])
        if status > 1:
            raise self._failed("fmi2SetReal", status)
        # Like OdeSubModel: new values alone mean inputs held over the step.
        self._derivatives_stale = self._derivatives_set

    def set_input_derivatives(self, derivatives: np.ndarray) -> None:
        order = self.capabilities.max_input_derivative_order
        if order == 0:
            super().set_input_derivatives(derivatives)
        d = np.zeros((order, len(self._in_vr)))
        given = np.asarray(derivatives, dtype=float)[:order]
        d[: given.shape[0]] = given
        self._send_derivatives(d)

    def _send_derivatives(self, d: np.ndarray) -> None:
        if self._component is None:
            raise self._not_live()
        self._d[:] = d
        addr = self._addr
        status = self._c["fmi2SetRealInputDerivatives"](
            self._component, addr["deriv_vr"], self._deriv_vr_c.size, addr["deriv_order"],
            addr["d"])
        if status > 1:
            raise self._failed("fmi2SetRealInputDerivatives", status)
        self._derivatives_set = bool(d.any())
        self._derivatives_stale = False

    def do_step(self, t: float, h: float) -> None:
        if self._component is None:
            raise self._not_live()
        if self._derivatives_stale:
            self._send_derivatives(np.zeros((self.capabilities.max_input_derivative_order,
                                             len(self._in_vr))))
        status = self._c["fmi2DoStep"](self._component, t, h, 1)
        if status > 1:
            raise self._failed("fmi2DoStep", status)

    def get_outputs(self) -> np.ndarray:
        if self._component is None:
            raise self._not_live()
        status = self._c["fmi2GetReal"](self._component, self._addr["out_vr"], self._y.size,
                                        self._addr["y"])
        if status > 1:
            raise self._failed("fmi2GetReal", status)
        return self._y.copy()

    def get_output_derivatives(self) -> np.ndarray:
        if not self.capabilities.provides_derivatives:
            return super().get_output_derivatives()
        if self._component is None:
            raise self._not_live()
        addr = self._addr
        status = self._c["fmi2GetRealOutputDerivatives"](
            self._component, addr["out_vr"], self._dy.size, addr["ones"], addr["dy"])
        if status > 1:
            raise self._failed("fmi2GetRealOutputDerivatives", status)
        return self._dy.copy()

    def save_state(self) -> Any:
        if not self.capabilities.can_save_state:
            return super().save_state()
        fmu = self._live()
        pointer = self._spare_states.pop() if self._spare_states else fmi2FMUstate()
        try:
            fmu.fmi2GetFMUstate(fmu.component, byref(pointer))
        except FMICallException as exc:
            raise self._error("fmi2GetFMUstate", exc) from None
        token = _SavedState(self, pointer)
        self._states.add(token)
        # The input-derivative bookkeeping is part of the state the FMU now holds.
        return token, self._derivatives_set, self._derivatives_stale

    def restore_state(self, token: Any) -> None:
        saved, derivatives_set, derivatives_stale = token
        if not isinstance(saved, _SavedState) or saved.owner is not self:
            raise ValueError(f"FMU '{self.name}': restore_state got a state this instance did "
                             "not save, or one freed by terminate()")
        try:
            self._live().setFMUstate(saved.pointer)
        except FMICallException as exc:
            raise self._error("fmi2SetFMUstate", exc) from None
        self._derivatives_set, self._derivatives_stale = derivatives_set, derivatives_stale

    def terminate(self) -> None:
        """Terminate and free the instance, free saved states, remove the unpacked files.

        Every part runs even if an earlier one failed; the first failure is raised at the end.
        """
        fmu, self._fmu = self._fmu, None
        self._component, self._c = None, {}
        first: Exception | None = None
        if fmu is not None:
            if self._initialized:
                try:
                    fmu.terminate()
                except Exception as exc:
                    first = self._error("fmi2Terminate", exc)
            for saved in list(self._states):
                saved.owner = None
                self._spare_states.append(saved.pointer)
            self._states = weakref.WeakSet()
            for pointer in self._spare_states:
                with contextlib.suppress(Exception):
                    fmu.freeFMUstate(pointer)
            self._spare_states = []
            if fmu.component is not None:
                try:
                    fmu.freeInstance()
                except Exception as exc:
                    first = first or self._error("fmi2FreeInstance", exc)
            else:
                with contextlib.suppress(Exception):
                    fmu.freeLibrary()
        self._initialized = False
        if self._unzipped is not None:
            shutil.rmtree(self._unzipped, ignore_errors=True)
            self._unzipped = None
        if first is not None:
            raise first

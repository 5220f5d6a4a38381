"""The FMI 2.0 co-simulation C API of one unpacked FMU, through ctypes (issue 5).

:class:`Fmi2Slave` stands in for FMPy's ``FMU2Slave`` in
:class:`~cosimstep.adapters.fmu.FmuSubModel`, with the same constructor keywords and the methods
and ``fmi2…`` attributes :class:`~cosimstep.adapters.fmu_base.FmuBase` calls. FMPy's class builds
a prototype for every FMI function of the standard from its Python annotations
(``inspect.signature``, about 2–4 ms per FMU); a master of small FMUs pays that on every run.
Here a function gets its prototype when it is first called, from the table :data:`SIGNATURES`,
and the functions every co-simulation run needs are looked up once when the library is loaded,
so a library that lacks one is refused there, naming it.

Every call that returns an ``fmi2Status`` is checked: a status above ``fmi2Warning`` raises
FMPy's ``FMICallException`` (function name and status), which the adapters already turn into an
:class:`~cosimstep.adapters.fmu_base.FmuError` naming the FMU and what it logged. The FMU model
exchange adapter and the FMI 3.0 adapter keep using FMPy's classes.
"""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Callable, Sequence
from ctypes import (
    CDLL,
    byref,
    c_char_p,
    c_double,
    c_int,
    c_size_t,
    c_uint,
    c_void_p,
    create_string_buffer,
)
from pathlib import Path
from typing import Any

import fmpy
from fmpy.fmi1 import FMICallException

__all__ = ["REQUIRED", "SIGNATURES", "Fmi2Slave"]

_WARNING = 1  # fmi2Warning: the highest status that is not a failure
_TRUE, _FALSE = 1, 0
_CO_SIMULATION = 1  # fmi2Type
_TERMINATED = 3  # fmi2StatusKind fmi2Terminated

_vp, _size = c_void_p, c_size_t
_ARRAY_CALL = (_vp, _vp, _size, _vp)  # component, value references, count, values
SIGNATURES: dict[str, tuple[Any, tuple[Any, ...]]] = {
    # name: (restype, argtypes); c_int results are fmi2Status and are checked
    "fmi2Instantiate": (_vp, (c_char_p, c_int, c_char_p, c_char_p, _vp, c_int, c_int)),
    "fmi2FreeInstance": (None, (_vp,)),
    "fmi2SetupExperiment": (c_int, (_vp, c_int, c_double, c_double, c_int, c_double)),
    "fmi2EnterInitializationMode": (c_int, (_vp,)),
    "fmi2ExitInitializationMode": (c_int, (_vp,)),
    "fmi2Terminate": (c_int, (_vp,)),
    "fmi2Reset": (c_int, (_vp,)),
    "fmi2GetReal": (c_int, _ARRAY_CALL),
    "fmi2GetInteger": (c_int, _ARRAY_CALL),
    "fmi2GetBoolean": (c_int, _ARRAY_CALL),
    "fmi2GetString": (c_int, _ARRAY_CALL),
    "fmi2SetReal": (c_int, _ARRAY_CALL),
    "fmi2SetInteger": (c_int, _ARRAY_CALL),
    "fmi2SetBoolean": (c_int, _ARRAY_CALL),
    "fmi2SetString": (c_int, _ARRAY_CALL),
    "fmi2GetFMUstate": (c_int, (_vp, _vp)),  # component, fmi2FMUstate*
    "fmi2SetFMUstate": (c_int, (_vp, _vp)),  # component, fmi2FMUstate
    "fmi2FreeFMUstate": (c_int, (_vp, _vp)),  # component, fmi2FMUstate*
    "fmi2SerializedFMUstateSize": (c_int, (_vp, _vp, _vp)),
    "fmi2SerializeFMUstate": (c_int, (_vp, _vp, _vp, _size)),
    "fmi2DeSerializeFMUstate": (c_int, (_vp, _vp, _size, _vp)),
    "fmi2SetRealInputDerivatives": (c_int, (_vp, _vp, _size, _vp, _vp)),
    "fmi2GetRealOutputDerivatives": (c_int, (_vp, _vp, _size, _vp, _vp)),
    "fmi2DoStep": (c_int, (_vp, c_double, c_double, c_int)),
    "fmi2GetBooleanStatus": (c_int, (_vp, c_int, _vp)),  # component, kind, fmi2Boolean*
}
"""Prototypes of the FMI 2.0 functions cosimstep calls (a subset of the standard's)."""

REQUIRED = ("fmi2Instantiate", "fmi2FreeInstance", "fmi2SetupExperiment",
            "fmi2EnterInitializationMode", "fmi2ExitInitializationMode", "fmi2Terminate",
            "fmi2GetReal", "fmi2SetReal", "fmi2GetInteger", "fmi2SetInteger", "fmi2GetBoolean",
            "fmi2SetBoolean", "fmi2DoStep")
"""Functions a co-simulation run calls; a library without one of them is refused on loading."""

_VALUE_TYPES = {"Real": c_double, "Integer": c_int, "Boolean": c_int, "String": c_char_p}


class Fmi2Slave:
    """One FMI 2.0 co-simulation FMU's shared library and (after :meth:`instantiate`) instance.

    Parameters
    ----------
    guid, modelIdentifier, unzipDirectory, instanceName:
        As for FMPy's ``FMU2Slave``: the model description's GUID and model identifier, the
        folder the FMU was unpacked into, the instance name.

    Attributes ``fmi2…`` (see :data:`SIGNATURES`) are the C functions with their status checked;
    ``dll`` is the loaded library (``dll[name]`` gives an unprototyped function object of one's
    own); ``component`` is the instance pointer as an integer, ``None`` before instantiation.
    """

    def __init__(self, *, guid: str, modelIdentifier: str, unzipDirectory: str | os.PathLike,
                 instanceName: str | None = None) -> None:
        self.guid = guid
        self.modelIdentifier = modelIdentifier
        self.unzipDirectory = str(unzipDirectory)
        self.instanceName = instanceName if instanceName is not None else modelIdentifier
        library = (Path(self.unzipDirectory, "binaries", fmpy.platform).resolve()
                   / f"{modelIdentifier}{fmpy.sharedLibraryExtension}")
        if not library.is_file():
            raise FileNotFoundError(f"cannot find the FMU's shared library {library}")
        # Windows resolves a DLL's own dependencies from its folder only when told so; FMPy
        # changes the working directory instead, which is global and not restored on errors.
        add = getattr(os, "add_dll_directory", None) if sys.platform.startswith("win") else None
        with add(str(library.parent)) if add else contextlib.nullcontext():
            try:
                self.dll = CDLL(str(library))
            except OSError as exc:
                raise OSError(f"cannot load the FMU's shared library {library}: {exc}") from exc
        missing = [name for name in REQUIRED if not hasattr(self.dll, name)]
        if missing:
            self.freeLibrary()
            raise OSError(f"the FMU's shared library {library} lacks {', '.join(missing)} "
                          "(an FMI 2.0 co-simulation library exports all of them)")
        self.component: int | None = None
        self.callbacks: Any = None  # kept alive while the instance may call them

    # -- the C functions, prototyped on first use ------------------------------------------------
    def __getattr__(self, name: str) -> Callable[..., Any]:
        # only called for attributes not found otherwise: the fmi2… functions the first time
        signature = SIGNATURES.get(name)
        if signature is None:
            raise AttributeError(name)
        restype, argtypes = signature
        try:
            function = self.dll[name]
        except AttributeError:
            raise AttributeError(f"the FMU's shared library does not export {name}") from None
        function.restype, function.argtypes = restype, argtypes
        if restype is c_int:
            def checked(*args: Any) -> int:
                status = function(*args)
                if status > _WARNING:
                    raise FMICallException(function=name, status=status)
                return status
        else:
            checked = function
        setattr(self, name, checked)
        return checked

    def terminated(self) -> bool:
        """Whether the slave asks to end the simulation (``fmi2GetBooleanStatus`` with
        ``fmi2Terminated``, asked after ``fmi2DoStep`` returned ``fmi2Discard``); ``False``
        when it cannot tell."""
        value = c_int(0)
        try:
            self.fmi2GetBooleanStatus(self.component, _TERMINATED, byref(value))
        except (AttributeError, FMICallException):
            return False
        return bool(value.value)

    def freeLibrary(self) -> None:
        """Unload the shared library (after :meth:`freeInstance`, or if there is no instance)."""
        fmpy.freeLibrary(self.dll._handle)

    # -- lifecycle -------------------------------------------------------------------------------
    def instantiate(self, visible: bool = False, callbacks: Any = None,
                    loggingOn: bool = False) -> None:
        """``fmi2Instantiate`` as co-simulation with ``callbacks`` (an ``fmi2CallbackFunctions``
        structure, required: the FMU calls its logger and memory functions)."""
        if callbacks is None:
            raise ValueError("`callbacks` is required (FMI 2.0 instances call them)")
        self.callbacks = callbacks
        resources = Path(self.unzipDirectory, "resources").resolve().as_uri()
        component = self.fmi2Instantiate(
            self.instanceName.encode("utf-8"), _CO_SIMULATION, self.guid.encode("utf-8"),
            resources.encode("utf-8"), byref(callbacks), _TRUE if visible else _FALSE,
            _TRUE if loggingOn else _FALSE)
        if component is None:
            raise RuntimeError("fmi2Instantiate returned NULL (the FMU refused to instantiate)")
        self.component = component

    def setupExperiment(self, tolerance: float | None = None, startTime: float = 0.0,
                        stopTime: float | None = None) -> int:
        return self.fmi2SetupExperiment(
            self.component, _FALSE if tolerance is None else _TRUE,
            0.0 if tolerance is None else tolerance, startTime,
            _FALSE if stopTime is None else _TRUE, 0.0 if stopTime is None else stopTime)

    def enterInitializationMode(self) -> int:
        return self.fmi2EnterInitializationMode(self.component)

    def exitInitializationMode(self) -> int:
        return self.fmi2ExitInitializationMode(self.component)

    def terminate(self) -> int:
        return self.fmi2Terminate(self.component)

    def reset(self) -> int:
        return self.fmi2Reset(self.component)

    def freeInstance(self) -> None:
        """``fmi2FreeInstance``, then unload the library."""
        self.fmi2FreeInstance(self.component)
        self.component = None
        self.freeLibrary()

    # -- values ----------------------------------------------------------------------------------
    def _values(self, kind: str, vr: Sequence[int], values: Sequence[Any] | None = None) -> Any:
        refs = (c_uint * len(vr))(*vr)
        ctype = _VALUE_TYPES[kind]
        if values is None:
            buffer = (ctype * len(vr))()
            getattr(self, f"fmi2Get{kind}")(self.component, refs, len(vr), buffer)
            return buffer
        if kind == "String":
            values = [None if s is None else str(s).encode("utf-8") for s in values]
        buffer = (ctype * len(vr))(*values)
        getattr(self, f"fmi2Set{kind}")(self.component, refs, len(vr), buffer)
        return None

    def getReal(self, vr: Sequence[int]) -> list[float]:
        return list(self._values("Real", vr))

    def getInteger(self, vr: Sequence[int]) -> list[int]:
        return list(self._values("Integer", vr))

    def getBoolean(self, vr: Sequence[int]) -> list[bool]:
        return [bool(v) for v in self._values("Boolean", vr)]

    def getString(self, vr: Sequence[int]) -> list[str | None]:
        return [None if v is None else v.decode("utf-8") for v in self._values("String", vr)]

    def setReal(self, vr: Sequence[int], value: Sequence[float]) -> None:
        self._values("Real", vr, value)

    def setInteger(self, vr: Sequence[int], value: Sequence[int]) -> None:
        self._values("Integer", vr, value)

    def setBoolean(self, vr: Sequence[int], value: Sequence[bool]) -> None:
        self._values("Boolean", vr, [_TRUE if v else _FALSE for v in value])

    def setString(self, vr: Sequence[str | None], value: Sequence[str | None]) -> None:
        self._values("String", vr, value)

    def doStep(self, currentCommunicationPoint: float, communicationStepSize: float,
               noSetFMUStatePriorToCurrentPoint: bool = True) -> int:
        return self.fmi2DoStep(self.component, currentCommunicationPoint, communicationStepSize,
                               _TRUE if noSetFMUStatePriorToCurrentPoint else _FALSE)

    # -- FMU state -------------------------------------------------------------------------------
    def getFMUstate(self) -> c_void_p:
        state = c_void_p()
        self.fmi2GetFMUstate(self.component, byref(state))
        return state

    def setFMUstate(self, state: c_void_p) -> None:
        self.fmi2SetFMUstate(self.component, state)

    def freeFMUstate(self, state: c_void_p) -> None:
        self.fmi2FreeFMUstate(self.component, byref(state))

    def serializeFMUstate(self, state: c_void_p) -> bytes:
        size = c_size_t()
        self.fmi2SerializedFMUstateSize(self.component, state, byref(size))
        buffer = create_string_buffer(size.value)
        self.fmi2SerializeFMUstate(self.component, state, buffer, size)
        return buffer.raw

    def deSerializeFMUstate(self, serialized: bytes, state: c_void_p | None = None) -> c_void_p:
        state = c_void_p() if state is None else state
        buffer = create_string_buffer(serialized, size=len(serialized))
        self.fmi2DeSerializeFMUstate(self.component, buffer, len(buffer), byref(state))
        return state

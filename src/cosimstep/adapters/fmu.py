"""FMI 2.0 co-simulation FMUs as sub-models (issue 5).

:class:`FmuSubModel` runs an FMI 2.0 co-simulation FMU: its Real inputs and outputs become ports
(names, units and start values from ``modelDescription.xml``), start values and parameters can be
overridden by name, and the capabilities come from the model description — state save/restore
from ``canGetAndSetFMUstate``, output derivatives (grey box) from ``maxOutputDerivativeOrder``,
input derivatives from ``canInterpolateInputs``. What it shares with the other FMU adapters
(model description, ports, start values, errors, unpacking, FMU states) is
:class:`~cosimstep.adapters.fmu_base.FmuBase`; the calls of a step go through its own ctypes
prototypes on preallocated arrays (:meth:`FmuSubModel._bind`), and a master may call them
directly (:class:`DirectIO`). The library is loaded and instantiated by
:class:`~cosimstep.adapters.fmi2_library.Fmi2Slave` (ctypes prototypes made on first use, instead
of FMPy's ``FMU2Slave``, which builds all of them from annotations on every load); the model
description is read by FMPy.

An FMU is checked before anything is unpacked (:func:`check_fmu`): a file that is not a zip
archive, has no ``modelDescription.xml``, has no binary for this platform, is not of a version and
kind the adapter runs, or holds an entry that would unpack outside its folder is refused with a
``ValueError`` naming the file and the reason. FMI 3.0 co-simulation FMUs run in
:mod:`cosimstep.adapters.fmu3`, model-exchange FMUs in :mod:`cosimstep.adapters.fmu_me`;
:func:`cosimstep.adapters.fmu_open.open_fmu` picks the adapter. The archive is unpacked into a
temporary folder by :meth:`FmuSubModel.initialize`, shared by every instance of the same file
and kept with the loaded library until the process exits
(:class:`~cosimstep.adapters.fmu_base._Unpacked`); :meth:`FmuSubModel.terminate` frees the
instance, also when a call failed.
"""

from __future__ import annotations

import pickle
from collections.abc import Mapping
from ctypes import c_double, c_int, c_size_t, c_void_p
from pathlib import Path
from typing import Any

import numpy as np

from cosimstep.adapters.fmi2_library import Fmi2Slave
from cosimstep.adapters.fmu_base import (
    FMI2_CS,
    FMI2_ME,
    FMI3_CS,
    FMI3_ME,
    SUPPORTED,
    FmuBase,
    FmuError,
    check_fmu,
    fmu_interface,
    fmu_logging,
    set_values,
)
from cosimstep.submodel import Capabilities

# check_fmu, fmu_interface, FmuError and the version constants live in fmu_base (every adapter
# uses them) and are re-exported here, where they were first defined.
__all__ = ["FMI2_CS", "FMI2_ME", "FMI3_CS", "FMI3_ME", "INPUT_DERIVATIVE_ORDER", "SUPPORTED",
           "DirectIO", "FmuError", "FmuSubModel", "check_fmu", "fmu_interface"]

INPUT_DERIVATIVE_ORDER = 3  # offered to masters when an FMU can interpolate inputs


class DirectIO(tuple):
    """The raw C entry points of one initialized FMU instance, for a master's hot loop.

    ``(component, set_real, in_vr, n_in, do_step, get_real, out_vr, n_out, fail)``: ``set_real``
    and ``get_real`` take ``(component, in_vr / out_vr, n_in / n_out, address of n doubles)``,
    ``do_step`` takes ``(component, t, h, 1)``; each returns the FMI status, and a status above
    1 (warning) is a failure, for which ``fail(function_name, status)`` builds the exception the
    sub-model's own methods would raise. Addresses are plain integers; the caller keeps the
    memory alive. Asked for with input derivatives (:meth:`FmuSubModel._direct_io`), six more
    entries follow: the call sending them and its arguments.
    """

    __slots__ = ()


class FmuSubModel(FmuBase):
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

    SUPPORTED = (FMI2_CS,)
    CALL_PREFIX = "fmi2"
    DISCRETE_TYPES = ("Integer", "Boolean", "Enumeration", "String")

    def __init__(self, path: str | Path, start: Mapping[str, float] | None = None, *,
                 instance_name: str | None = None,
                 input_derivative_order: int = INPUT_DERIVATIVE_ORDER,
                 tolerance: float | None = None) -> None:
        super().__init__(path, start, instance_name=instance_name)
        self.tolerance = tolerance
        cs = self.interface
        order = input_derivative_order if cs.canInterpolateInputs else 0
        self.capabilities = Capabilities(
            can_save_state=bool(cs.canGetAndSetFMUstate),
            provides_derivatives=cs.maxOutputDerivativeOrder >= 1,
            max_input_derivative_order=order,
            feedthrough=self._feedthrough(),
        )
        # Input derivatives for every order at once: orders 1..q for each input, in one call.
        self._deriv_vr = self._in_vr * order
        self._deriv_order = [k for k in range(1, order + 1) for _ in self._in_vr]
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
        self._derivatives_set = False  # the FMU holds nonzero input derivatives
        self._derivatives_stale = False  # ...which the next step must not use
        self._callbacks = self._fmi2_callbacks()

    # -- SubModel API ----------------------------------------------------------------------------
    def initialize(self, t0: float) -> None:
        if self._fmu is not None:
            self.terminate()
        try:
            fmu = self._load(Fmi2Slave)
            fmu.instantiate(callbacks=self._callbacks, loggingOn=fmu_logging())
            fmu.setupExperiment(tolerance=self.tolerance, startTime=t0)
            set_values(fmu, self._start_values(inputs=False), "2.0")
            fmu.enterInitializationMode()
            set_values(fmu, self._start_values(inputs=True), "2.0")
            fmu.exitInitializationMode()
            self._bind(fmu)
        except Exception as exc:
            raise self._fail_initialization(exc) from exc
        self._initialized = True
        self._derivatives_set = self._derivatives_stale = False

    def _bind(self, fmu: Fmi2Slave) -> None:
        """Our own ctypes prototypes of the FMI functions a step calls.

        The loader's convenience methods (like FMPy's) convert Python lists to new C arrays and
        check the status in Python on every call (about 10 µs per step of two FMUs, more than the
        FMUs' own work here); these take the addresses of the preallocated arrays above and
        return the status, which is checked with one comparison. ``dll[name]`` gives a new
        function object, so the loader's own prototypes of the same functions stay as they were.
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

    def _direct_io(self, derivatives: bool = False) -> DirectIO | None:
        """The raw calls of a step for a master that passes addresses (see :class:`DirectIO`).

        ``None`` when a subclass overrides a step method (the master must call it) or when the
        instance is not initialized. Without ``derivatives`` also when it holds input
        derivatives (a plain ``set_inputs`` would have to clear them first). With
        ``derivatives`` the master sends input derivatives before every step itself: ``None``
        when the FMU takes none or a subclass overrides ``set_input_derivatives``, and the
        entries of :class:`DirectIO` are followed by ``(set_derivatives, deriv_vr, n_deriv,
        deriv_order, d, d_address)``: ``fmi2SetRealInputDerivatives`` taking ``(component,
        deriv_vr, n_deriv, deriv_order, d_address)``, which sends the array ``d`` of shape
        ``(order, n_in)`` (row ``k - 1``: the ``k``-th derivative of every input). The master
        fills ``d`` (its rows beyond the orders it sends must be zero, as
        :meth:`set_input_derivatives` makes them) and, after sending, records it as
        :meth:`set_input_derivatives` does (``_derivatives_set``, ``_derivatives_stale``).
        """
        cls = type(self)
        if (self._component is None or (self._derivatives_set and not derivatives)
                or self._in_disc or self._out_disc
                or cls.set_inputs is not FmuSubModel.set_inputs
                or cls.do_step is not FmuSubModel.do_step
                or cls.get_outputs is not FmuSubModel.get_outputs):
            return None
        c, addr = self._c, self._addr
        io = (self._component, c["fmi2SetReal"], addr["in_vr"], len(self._in_vr),
              c["fmi2DoStep"], c["fmi2GetReal"], addr["out_vr"], len(self._out_vr),
              self._failed)
        if derivatives:
            if (not self.capabilities.max_input_derivative_order
                    or cls.set_input_derivatives is not FmuSubModel.set_input_derivatives
                    or cls._send_derivatives is not FmuSubModel._send_derivatives):
                return None
            io += (c["fmi2SetRealInputDerivatives"], addr["deriv_vr"], self._deriv_vr_c.size,
                   addr["deriv_order"], self._d, addr["d"])
        return DirectIO(io)

    def set_inputs(self, values: np.ndarray) -> None:
        if self._component is None:
            raise self._not_live()
        n = self._u.size
        if self._in_disc:
            self._write_discrete(values[n:])
            values = values[:n]
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
        given = np.asarray(derivatives, dtype=float)[:order, :len(self._in_vr)]  # the reals
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
        self._derivatives_set = bool(np.count_nonzero(d))  # d.any(), without its wrapper
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
        if self._out_disc:
            return np.concatenate([self._y, self._read_discrete()])
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
        if self._out_disc:  # integers, booleans, strings: piecewise constant
            return np.concatenate([self._dy, np.zeros(len(self._out_disc))])
        return self._dy.copy()

    def save_state(self) -> Any:
        if not self.capabilities.can_save_state:
            return super().save_state()
        # The input-derivative bookkeeping is part of the state the FMU now holds.
        return self._save_fmu_state(), self._derivatives_set, self._derivatives_stale

    def restore_state(self, token: Any) -> None:
        saved, derivatives_set, derivatives_stale = token
        self._restore_fmu_state(saved)
        self._derivatives_set, self._derivatives_stale = derivatives_set, derivatives_stale

    def serialize_state(self, token: Any) -> bytes:
        saved, derivatives_set, derivatives_stale = token
        return pickle.dumps((self._serialize_fmu_state(saved), derivatives_set,
                             derivatives_stale))

    def deserialize_state(self, data: bytes) -> Any:
        raw, derivatives_set, derivatives_stale = pickle.loads(data)
        return self._deserialize_fmu_state(raw), derivatives_set, derivatives_stale

    def terminate(self) -> None:
        """Terminate and free the instance, free saved states, remove the unpacked files
        (:meth:`FmuBase.terminate`); the step calls are unbound first, so a later call raises
        "not initialized" instead of calling into a freed instance."""
        self._component, self._c = None, {}
        super().terminate()

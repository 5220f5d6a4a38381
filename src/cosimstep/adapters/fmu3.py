"""FMI 3.0 co-simulation FMUs as sub-models, through FMPy's ``FMU3Slave`` (issue 5).

:class:`Fmu3SubModel` behaves like the FMI 2.0 :class:`~cosimstep.adapters.fmu.FmuSubModel`:
Float64 (and Float32) inputs and outputs become ports with names, units and start values from
``modelDescription.xml``; start values and parameters are overridden by name; rollback uses
``fmi3GetFMUState``/``fmi3SetFMUState`` when ``canGetAndSetFMUState`` is declared; output
derivatives (grey box) come from ``fmi3GetOutputDerivatives`` when ``maxOutputDerivativeOrder``
is at least 1. FMI 3.0 has no input derivatives, so the FMU holds its inputs over a step
(``max_input_derivative_order = 0``).

Event mode: an FMU declaring ``hasEventMode`` is instantiated with ``eventModeUsed`` and
``earlyReturnAllowed``, so its internal events (state and time events inside a communication
step) are handled at their time: ``fmi3DoStep`` returns early at the event with
``eventHandlingNeeded``, the adapter runs the event (``fmi3EnterEventMode``,
``fmi3UpdateDiscreteStates`` until no update is needed, ``fmi3EnterStepMode``) and continues the
step from there, so one ``do_step`` of the master may be several FMU steps. The same happens
at the end of initialization. :attr:`Fmu3SubModel.events` lists the event times. Intermediate
updates are not used.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from fmpy.fmi1 import FMICallException
from fmpy.fmi3 import FMU3Slave

from cosimstep.adapters.fmu_base import FMI3_CS, FmuBase, fmu_logging, set_values
from cosimstep.errors import EndOfSimulation
from cosimstep.submodel import Capabilities

MAX_EVENT_ITERATIONS = 1000  # fmi3UpdateDiscreteStates calls at one event
MAX_EARLY_RETURNS = 10000  # early returns within one communication step

__all__ = ["Fmu3SubModel"]


class Fmu3SubModel(FmuBase):
    """An FMI 3.0 co-simulation FMU as a sub-model.

    Parameters
    ----------
    path:
        The ``.fmu`` file.
    start:
        Start values and parameters by variable name; set before initialization (inputs inside
        initialization mode), replacing the model description's start values.
    instance_name:
        Name of the FMU instance (in messages and the FMU's log); default the model name.
    tolerance:
        Passed to ``fmi3EnterInitializationMode`` for the FMU's internal solver, if given.
    """

    SUPPORTED = (FMI3_CS,)
    DISCRETE_TYPES = ("Int8", "UInt8", "Int16", "UInt16", "Int32", "UInt32", "Int64", "UInt64",
                      "Boolean", "Enumeration", "String", "Binary")
    CALL_PREFIX = "fmi3"
    ARRAYS = True

    def __init__(self, path: str | Path, start: Mapping[str, float] | None = None, *,
                 instance_name: str | None = None, tolerance: float | None = None) -> None:
        super().__init__(path, start, instance_name=instance_name)
        self.tolerance = tolerance
        cs = self.interface
        self._event_mode = bool(getattr(cs, "hasEventMode", False))
        self.events: list[float] = []
        self._float32_in = any(v.type == "Float32" for v in self._in_vars)
        self._float32_out = any(v.type == "Float32" for v in self._out_vars)
        # values per real input and output (arrays: their element counts)
        self._n_in = sum(self.size(v) for v in self._in_vars)
        self._n_out = sum(self.size(v) for v in self._out_vars)
        arrays = any(v.dimensions for v in (*self._in_vars, *self._out_vars))
        if arrays and (self._float32_in or self._float32_out):
            raise ValueError(f"FMU {self.path}: Float32 array ports are not supported yet")
        self.capabilities = Capabilities(
            can_save_state=bool(cs.canGetAndSetFMUstate),
            provides_derivatives=int(cs.maxOutputDerivativeOrder or 0) >= 1 and not arrays,
            max_input_derivative_order=0,
            feedthrough=self._feedthrough(),
        )

    def initialize(self, t0: float) -> None:
        if self._fmu is not None:
            self.terminate()
        try:
            fmu = self._load(FMU3Slave)
            self._instantiate(fmu)
            set_values(fmu, self._start_values(inputs=False), "3.0")
            fmu.enterInitializationMode(tolerance=self.tolerance, startTime=t0)
            set_values(fmu, self._start_values(inputs=True), "3.0")
            fmu.exitInitializationMode()
            self._initialized = True
            self.events = []
            if self._event_mode:  # initialization ends in event mode
                self._update_discrete_states(t0)
                fmu.enterStepMode()
        except EndOfSimulation:
            raise
        except Exception as exc:
            raise self._fail_initialization(exc) from exc

    def _instantiate(self, fmu: FMU3Slave) -> None:
        """Instantiate with event mode if the FMU declares it; an FMU that then refuses to be
        instantiated (the Reference FMU Roberts declares ``hasEventMode`` but answers "Event
        Mode is not supported") is instantiated again without, as importers that do not use
        event mode always do."""
        def instantiate(event_mode: bool) -> None:
            fmu.instantiate(loggingOn=fmu_logging(), eventModeUsed=event_mode,
                            earlyReturnAllowed=event_mode,
                            logMessage=lambda env, status, category, message:
                            self._logger(status, message))

        if not self._event_mode:
            instantiate(False)
            return
        try:
            instantiate(True)
        except Exception:
            instantiate(False)
            self._event_mode = False
            self._log.clear()

    def _call(self, call: str, *args: Any) -> Any:
        try:
            return getattr(self._live(), call)(*args)
        except FMICallException as exc:
            raise self._error(call, exc) from None

    def set_inputs(self, values: np.ndarray) -> None:
        n = self._n_in
        if self._in_disc:  # integers and booleans: the master's floats, rounded
            self._write_discrete(values[n:])
            values = values[:n]
        if not n:
            return
        if self._float32_in:  # mixed precisions: each input with its own setter
            set_values(self._live(), list(zip(self._in_vars, values, strict=True)), "3.0")
            return
        self._call("setFloat64", self._in_vr, [float(x) for x in values])

    def do_step(self, t: float, h: float) -> None:
        end, now = t + h, t
        for _ in range(MAX_EARLY_RETURNS):
            event, terminate, early, last = self._call("doStep", now, end - now)
            if terminate:
                raise EndOfSimulation(self.name, f"terminateSimulation in the step from "
                                      f"t = {now:.9g}")
            reached = float(last) if early else end
            if event and self._event_mode:
                self._call("enterEventMode")
                self._update_discrete_states(reached)
                self._call("enterStepMode")
                self.events.append(reached)
            if not early or reached >= end:
                return
            if not self._event_mode or reached <= now:
                raise self._error(f"fmi3DoStep from t = {now} over {end - now} returned early "
                                  f"at t = {last}" + ("" if self._event_mode else
                                                      " (early return was not allowed)"))
            now = reached
        raise self._error(f"more than {MAX_EARLY_RETURNS} early returns in the step from "
                          f"t = {t} to {end}")

    def _update_discrete_states(self, t: float) -> None:
        for _ in range(MAX_EVENT_ITERATIONS):
            needed, terminate, *_ = self._call("updateDiscreteStates")
            if terminate:
                raise EndOfSimulation(self.name, f"terminateSimulation at the event at "
                                      f"t = {t:.9g}")
            if not needed:
                return
        raise self._error(f"no end of the event iteration at t = {t!r} after "
                          f"{MAX_EVENT_ITERATIONS} calls of fmi3UpdateDiscreteStates")

    def get_outputs(self) -> np.ndarray:
        if self._float32_out:
            reals = np.array([self._call(f"get{v.type}", [v.valueReference])[0]
                              for v in self._out_vars])
        elif self._out_vr:
            reals = np.array(self._call("getFloat64", self._out_vr, self._n_out), dtype=float)
        else:
            reals = np.zeros(0)  # FMPy cannot get zero values
        if not self._out_disc:
            return reals
        return np.concatenate([reals, self._read_discrete()])

    def get_output_derivatives(self) -> np.ndarray:
        if not self.capabilities.provides_derivatives:
            return super().get_output_derivatives()
        reals = np.array(self._call("getOutputDerivatives", self._out_vr,
                                    [1] * len(self._out_vr)))
        # integers, booleans, strings: piecewise constant
        return np.concatenate([reals, np.zeros(len(self.outputs) - self._n_out)])

    def save_state(self) -> Any:
        if not self.capabilities.can_save_state:
            return super().save_state()
        return self._save_fmu_state(), len(self.events)

    def restore_state(self, token: Any) -> None:
        if not self.capabilities.can_save_state:
            super().restore_state(token)
        saved, n_events = token
        self._restore_fmu_state(saved)
        del self.events[n_events:]

    def serialize_state(self, token: Any) -> bytes:
        saved, n_events = token
        return n_events.to_bytes(8, "little") + self._serialize_fmu_state(saved)

    def deserialize_state(self, data: bytes) -> Any:
        return self._deserialize_fmu_state(data[8:]), int.from_bytes(data[:8], "little")

"""Model-exchange FMUs (FMI 2.0 and 3.0) as co-simulation sub-models: cosimstep integrates them.

A model-exchange FMU only evaluates its equations — derivatives, event indicators, outputs — for
states and a time the importer gives it; :class:`MeSubModel` is that importer, so the FMU behaves
like any other sub-model. ``do_step(t, h)`` integrates the FMU's ODE with SciPy's ``solve_ivp``
(the :class:`~cosimstep.adapters.ode.SolveIvp` settings: method, rtol, atol; by default the same
RK45, rtol = 1e-8, atol = 1e-10 as the Python sub-models, so a model written both ways gives the
same numbers). Inputs follow the polynomial the master sets (value and up to three derivatives),
exactly as :class:`~cosimstep.adapters.ode.OdeSubModel` does.

FMI 2.0 and FMI 3.0 model exchange follow the same protocol under different names
(``fmi2NewDiscreteStates`` is ``fmi3UpdateDiscreteStates``, ``fmi2GetDerivatives`` is
``fmi3GetContinuousStateDerivatives``, FMI 3.0 has no ``setupExperiment``); :class:`_Calls` binds
the raw functions of the version at hand once, so the integration below is written once.

Ports: real inputs and outputs (FMI 3.0 Float64 and Float32, arrays as one port per element),
then integer, boolean and enumeration ones. Real inputs of variability ``continuous`` go to the
FMU at every evaluation; inputs that may change only in event mode (real ones of variability
``discrete``, and every integer, boolean and enumeration input) are set there when their value
changes, and the event is iterated — a change of a discrete input is an event.

Events, following the model-exchange protocol:

* **State events.** Each event indicator ``z`` is a ``solve_ivp`` event function. An event is a
  change of ``z > 0``; the crossing is located by ``solve_ivp``'s root finding and the time is then
  moved right, by the smallest steps that do it, until the indicator is on the new side, so the
  FMU sees the condition that triggered. An indicator that starts a segment at (numerically) zero —
  typically right after its own event, e.g. a ball leaving the floor — only triggers on a crossing
  back, not on leaving zero.
* **Time events.** The next event time the FMU announces (``nextEventTime``) ends an integration
  segment; the event is handled there, inside the step when it falls inside it.
* **Step events.** ``fmi2CompletedIntegratorStep`` is called at the end of every integration
  segment (the end of a step or an event), not after every internal step of ``solve_ivp``, which
  does not expose them; an FMU asking for event mode there gets an event iteration.

At an event the FMU enters event mode, ``fmi2NewDiscreteStates`` is repeated until no new discrete
states are needed, and the continuous states are read back (they may have been re-initialized).
:attr:`MeSubModel.events` lists the times of the events handled.

Rollback: with ``canGetAndSetFMUstate`` the saved state is the FMU state plus the wrapper's own
(time, states, input polynomial, next time event). Without it, the wrapper saves the continuous
states and time and sets them back; that is the complete state of an FMU without events, so
rollback is offered for FMUs without event indicators, and refused with an :class:`FmuError` if an
event happened since the state was saved (the FMU's discrete states cannot be put back).

Output derivatives (grey box) are offered when every output is a continuous state: the derivative
of an output is then the state derivative the FMU computes at the current time, states and inputs —
the same as ``OdeSubModel.get_output_derivatives``. Other outputs have no derivative to offer.
"""

from __future__ import annotations

import math
import pickle
from collections.abc import Callable, Mapping
from ctypes import c_double, c_uint
from pathlib import Path
from typing import Any

import numpy as np
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Model, fmi2False
from fmpy.fmi3 import FMU3Model
from scipy.integrate import solve_ivp

from cosimstep.adapters.fmu_base import FMI2_ME, FMI3_ME, FmuBase, fmu_logging, set_values
from cosimstep.adapters.ode import INPUT_ORDER, SolveIvp, _taylor
from cosimstep.errors import EndOfSimulation
from cosimstep.submodel import Capabilities

__all__ = ["MeSubModel", "make_me_solver"]

MAX_EVENT_ITERATIONS = 1000  # fmi2NewDiscreteStates calls at one event
MAX_STALLED_EVENTS = 100  # events in a row without time advancing: chattering
AT_ZERO = 1e-12  # an indicator this close to zero starts a segment "at" its switching surface
SOLVE_IVP_METHODS = ("RK45", "RK23", "DOP853", "Radau", "BDF", "LSODA")


def make_me_solver(spec: Mapping[str, Any] | None) -> SolveIvp:
    """The integrator of a model-exchange FMU from a mapping like ``{"method": "RK45"}``.

    Keys ``method`` (a ``solve_ivp`` method, default RK45), ``rtol`` and ``atol``; bad keys or
    values raise ``ValueError`` naming them.
    """
    spec = dict(spec or {})
    unknown = sorted(set(spec) - {"method", "rtol", "atol"})
    if unknown:
        raise ValueError(f"unknown key(s) {', '.join(unknown)}: a model-exchange FMU's solver "
                         "takes method, rtol and atol")
    method = str(spec.pop("method", "RK45"))
    chosen = next((m for m in SOLVE_IVP_METHODS if m.lower() == method.lower()), None)
    if chosen is None:
        raise ValueError(f"`method` {method!r} is not a solve_ivp method; a model-exchange FMU is "
                         f"integrated with one of {', '.join(SOLVE_IVP_METHODS)}")
    for key in ("rtol", "atol"):
        value = spec.get(key)
        if value is not None and (isinstance(value, bool) or not isinstance(value, int | float)
                                  or not math.isfinite(value) or value <= 0):
            raise ValueError(f"`{key}` must be a positive number, got {value!r}")
    return SolveIvp(method=chosen, **{k: float(v) for k, v in spec.items()})


class _Calls:
    """The raw FMI functions the integration calls many times per step, bound to one instance.

    Each takes the buffers of :class:`MeSubModel`; FMPy's wrappers raise ``FMICallException``
    on an error status, as its high-level methods do.
    """

    __slots__ = ("get_derivatives", "get_indicators", "get_states", "set_reals",
                 "set_states", "set_time", "update_discrete")

    def __init__(self, fmu: Any, version: str, vr: Any, n_vr: int, values: Any,
                 n_values: int) -> None:
        c = fmu.component
        p = "fmi3" if version == "3.0" else "fmi2"
        derivatives = getattr(fmu, "fmi3GetContinuousStateDerivatives" if p == "fmi3"
                              else "fmi2GetDerivatives")
        time, states = getattr(fmu, f"{p}SetTime"), getattr(fmu, f"{p}SetContinuousStates")
        get_states, indicators = (getattr(fmu, f"{p}GetContinuousStates"),
                                  getattr(fmu, f"{p}GetEventIndicators"))
        self.set_time: Callable[[float], Any] = lambda t: time(c, t)
        self.set_states: Callable[[Any, int], Any] = lambda buf, n: states(c, buf, n)
        self.get_states: Callable[[Any, int], Any] = lambda buf, n: get_states(c, buf, n)
        self.get_derivatives: Callable[[Any, int], Any] = lambda buf, n: derivatives(c, buf, n)
        self.get_indicators: Callable[[Any, int], Any] = lambda buf, n: indicators(c, buf, n)
        if p == "fmi3":
            set_float = fmu.fmi3SetFloat64
            self.set_reals: Callable[[], Any] = lambda: set_float(c, vr, n_vr, values, n_values)
            self.update_discrete: Callable[[], tuple] = fmu.updateDiscreteStates
        else:
            set_real = fmu.fmi2SetReal
            self.set_reals = lambda: set_real(c, vr, n_vr, values)
            self.update_discrete = fmu.newDiscreteStates


class MeSubModel(FmuBase):
    """A model-exchange FMU (FMI 2.0 or 3.0) integrated by cosimstep, as a co-simulation
    sub-model.

    Parameters
    ----------
    path:
        The ``.fmu`` file.
    start:
        Start values and parameters by variable name, set before initialization (inputs inside
        initialization mode).
    instance_name:
        Name of the FMU instance (in messages and the FMU's log); default the model name.
    solver:
        ``solve_ivp`` settings (:class:`~cosimstep.adapters.ode.SolveIvp`); default RK45 with
        rtol = 1e-8, atol = 1e-10, as the Python sub-models.
    """

    SUPPORTED = (FMI2_ME, FMI3_ME)
    CALL_PREFIX = "fmi2"  # "fmi3" for an FMI 3.0 FMU (set per instance)
    DISCRETE_TYPES = ("Integer", "Boolean", "Enumeration", "Int8", "UInt8", "Int16", "UInt16",
                      "Int32", "UInt32", "Int64", "UInt64", "String", "Binary")  # FMI 2 and 3
    ARRAYS = True  # FMI 3.0 arrays; FMI 2.0 has none

    def __init__(self, path: str | Path, start: Mapping[str, float] | None = None, *,
                 instance_name: str | None = None, solver: SolveIvp | None = None) -> None:
        super().__init__(path, start, instance_name=instance_name)
        if solver is not None and not isinstance(solver, SolveIvp):
            raise ValueError(f"`solver` for model-exchange FMU {self.path} must be a SolveIvp "
                             f"(solve_ivp method, rtol, atol), got {solver!r}")
        self.solver = solver or SolveIvp()
        self.CALL_PREFIX = "fmi3" if self.fmi_version == "3.0" else "fmi2"
        md = self.model_description
        self._nx = int(md.numberOfContinuousStates)
        self._nz = int(md.numberOfEventIndicators or 0)
        states = [d.variable.derivative for d in md.derivatives]  # in state-vector order
        index = {id(v): i for i, v in enumerate(states)}
        scalar = not any(v.dimensions for v in (*states, *self._out_vars))
        self._out_state = [index.get(id(v)) if scalar else None for v in self._out_vars]
        self._fmu_state = bool(self.interface.canGetAndSetFMUstate)
        self.capabilities = Capabilities(
            can_save_state=self._fmu_state or self._nz == 0,
            provides_derivatives=bool(self._out_vars) and None not in self._out_state,
            max_input_derivative_order=INPUT_ORDER,
            feedthrough=self._feedthrough(),
        )
        self._setup_inputs()
        self._out_n = [self.size(v) for v in self._out_vars]
        self._float64_out = all(v.type != "Float32" for v in self._out_vars)
        self._t = 0.0
        self._x = np.zeros(self._nx)
        self._u = self._start_inputs()
        self._du = np.zeros((INPUT_ORDER, len(self.inputs)))
        self._slope = False
        self._next_event: float | None = None
        self.events: list[float] = []
        # ctypes buffers with NumPy views: the right-hand side runs inside solve_ivp's loop
        self._xbuf, self._xv = _buffer(self._nx)
        self._dxbuf, self._dxv = _buffer(self._nx)
        self._zbuf, self._zv = _buffer(self._nz)
        self._ubuf, self._uv = _buffer(len(self._cont))
        self._vrbuf = (c_uint * max(len(self._cont_vars), 1))(
            *[v.valueReference for v in self._cont_vars])
        self._sent_evt = self._u[self._evt].copy()
        self._z_key: tuple[float, bytes] | None = None
        self._z_last = np.zeros(self._nz)
        self._c: _Calls | None = None
        self._callbacks = self._fmi2_callbacks() if self.fmi_version == "2.0" else None

    def _setup_inputs(self) -> None:
        """Which input ports go to the FMU at every evaluation (``_cont``: real ports of
        variability continuous) and which only in event mode, on change (``_evt``: real ports
        of variability discrete, then the integer, boolean and enumeration ones)."""
        port_vars = [v for v in self._in_vars for _ in range(self.size(v))]
        n_real = len(port_vars)
        self._cont = np.array([i for i, v in enumerate(port_vars)
                               if v.variability != "discrete"], dtype=int)
        disc_real = [i for i, v in enumerate(port_vars) if v.variability == "discrete"]
        self._evt = np.array(disc_real + list(range(n_real, len(self.inputs))), dtype=int)
        self._n_evt_real = len(disc_real)
        self._cont_vars = [v for v in self._in_vars if v.variability != "discrete"]
        self._evt_vars = [v for v in self._in_vars if v.variability == "discrete"]
        # Float32 inputs (FMI 3.0) are set variable by variable, not through the Float64 buffer
        self._float64_cont = all(v.type != "Float32" for v in self._cont_vars)

    def _start_inputs(self) -> np.ndarray:
        return np.array([p.start if p.start is not None else 0.0 for p in self.inputs], float)

    # -- SubModel API ------------------------------------------------------------------------------
    def initialize(self, t0: float) -> None:
        if self._fmu is not None:
            self.terminate()
        try:
            fmu = self._instantiate(t0)
            self._initialized = True
            self._t = float(t0)
            self._u = self._start_inputs()
            self._du = np.zeros_like(self._du)
            self._sent_evt = self._u[self._evt].copy()  # set in initialization mode
            self.events = []
            self._iterate_discrete_states(t0)  # initialization ends in event mode
            fmu.enterContinuousTimeMode()
            self._x = self._read_states()
        except Exception as exc:
            raise self._fail_initialization(exc) from exc

    def _instantiate(self, t0: float) -> Any:
        """Load, instantiate and initialize the FMU (start values before, inputs inside
        initialization mode); it is then in event mode, as both versions leave it."""
        v = self.fmi_version
        if v == "3.0":
            fmu = self._load(FMU3Model)
            fmu.instantiate(loggingOn=fmu_logging(),
                            logMessage=lambda env, status, category, message:
                            self._logger(status, message))
            set_values(fmu, self._start_values(inputs=False), v)
            fmu.enterInitializationMode(tolerance=self.solver.rtol, startTime=t0)
        else:
            fmu = self._load(FMU2Model)
            fmu.instantiate(callbacks=self._callbacks, loggingOn=fmu_logging())
            fmu.setupExperiment(tolerance=self.solver.rtol, startTime=t0)
            set_values(fmu, self._start_values(inputs=False), v)
            fmu.enterInitializationMode()
        set_values(fmu, self._start_values(inputs=True), v)
        fmu.exitInitializationMode()
        self._c = _Calls(fmu, v, self._vrbuf, len(self._cont_vars), self._ubuf, len(self._cont))
        return fmu

    def set_inputs(self, values: np.ndarray) -> None:
        self._u = np.array(values, dtype=float)
        self._du[:] = 0.0
        self._send_inputs(self._u)

    def set_input_derivatives(self, derivatives: np.ndarray) -> None:
        d = np.asarray(derivatives, dtype=float)
        self._du[:] = 0.0
        self._du[: d.shape[0]] = d[:INPUT_ORDER]

    def do_step(self, t: float, h: float) -> None:
        self._live()
        if abs(t - self._t) > 1e-9 * max(1.0, abs(self._t)):
            raise self._error(f"do_step from t = {t!r}, but the FMU is at t = {self._t!r}")
        t_start, u0, du = self._t, self._u, self._du
        self._slope = bool(du.any())
        t_end = t + h
        x, now, stalled = self._x, t, 0  # from the master's t, as OdeSubModel
        try:
            while now < t_end:
                timed = self._next_event is not None and self._next_event <= t_end
                stop = max(now, self._next_event) if timed else t_end  # type: ignore[type-var]
                reached, x, state_event = self._integrate(now, stop, x)
                self._evaluate(reached, x)
                step_event = self._completed_integrator_step(reached)
                if state_event or step_event or (timed and reached >= stop):
                    x = self._handle_event(reached)
                    stalled = stalled + 1 if reached <= now else 0
                    if stalled > MAX_STALLED_EVENTS:
                        raise self._error(f"{stalled} events in a row at t = {reached!r} without "
                                          "time advancing (chattering)")
                now = reached
        except FMICallException as exc:
            raise self._error(exc.function, exc) from None
        self._x = np.array(x, dtype=float)
        self._t = t_end
        if self._slope:  # re-expanded around the new time, as OdeSubModel does
            dt = t_end - t_start
            self._u = _taylor(u0, du, dt)
            self._du = np.array([_taylor(du[j], du[j + 1:], dt) for j in range(len(du))])

    def get_outputs(self) -> np.ndarray:
        fmu = self._live()
        try:
            if not self._out_vr:
                reals = np.zeros(0)
            elif self.fmi_version == "2.0":
                reals = np.array(fmu.getReal(self._out_vr), dtype=float)
            elif self._float64_out:
                reals = np.array(fmu.getFloat64(self._out_vr, sum(self._out_n)), dtype=float)
            else:
                reals = np.concatenate([getattr(fmu, f"get{v.type}")([v.valueReference], n)
                                        for v, n in zip(self._out_vars, self._out_n,
                                                        strict=True)])
        except FMICallException as exc:
            raise self._error(exc.function, exc) from None
        if self._out_disc:
            return np.concatenate([reals, self._read_discrete()])
        return reals

    def get_output_derivatives(self) -> np.ndarray:
        if not self.capabilities.provides_derivatives:
            return super().get_output_derivatives()
        self._live()
        try:
            self._c.get_derivatives(self._dxbuf, self._nx)  # type: ignore[union-attr]
        except FMICallException as exc:
            raise self._error(exc.function, exc) from None
        if self._out_disc:  # integers and booleans are piecewise constant
            return np.concatenate([self._dxv[self._out_state], np.zeros(len(self._out_disc))])
        return self._dxv[self._out_state].copy()

    def save_state(self) -> Any:
        if not self.capabilities.can_save_state:
            return super().save_state()
        saved = self._save_fmu_state() if self._fmu_state else None
        return (saved, self._t, self._x.copy(), self._u.copy(), self._du.copy(),
                self._next_event, len(self.events))

    def serialize_state(self, token: Any) -> bytes:
        saved, *rest = token
        return pickle.dumps((None if saved is None else self._serialize_fmu_state(saved),
                             *rest))

    def deserialize_state(self, data: bytes) -> Any:
        raw, *rest = pickle.loads(data)
        return (None if raw is None else self._deserialize_fmu_state(raw), *rest)

    def restore_state(self, token: Any) -> None:
        if not self.capabilities.can_save_state:
            super().restore_state(token)
        saved, t, x, u, du, next_event, n_events = token
        if self._fmu_state:
            self._restore_fmu_state(saved)
        else:
            if len(self.events) > n_events:
                raise self._error(f"cannot go back to t = {t!r}: events happened since, and "
                                  "the FMU does not offer FMU state to undo them")
            self._live()
            try:
                self._c.set_time(t)  # type: ignore[union-attr]
                self._xv[:] = x
                self._c.set_states(self._xbuf, self._nx)  # type: ignore[union-attr]
                self._send_inputs(u)
            except FMICallException as exc:
                raise self._error(exc.function, exc) from None
        self._t, self._x, self._u, self._du = t, x.copy(), u.copy(), du.copy()
        self._sent_evt = self._u[self._evt].copy()  # restored with the FMU state, or re-sent
        self._next_event = next_event
        del self.events[n_events:]
        self._z_key = None

    # -- integration ---------------------------------------------------------------------------
    def _inputs_at(self, s: float) -> np.ndarray:
        return _taylor(self._u, self._du, s - self._t)

    def _send_inputs(self, u: np.ndarray) -> None:
        if not self.inputs:
            return
        self._live()
        try:
            if self._cont.size:
                self._set_continuous(u[self._cont])
            if self._evt.size and not np.array_equal(u[self._evt], self._sent_evt):
                self._set_in_event_mode(u[self._evt])
        except FMICallException as exc:
            raise self._error(exc.function, exc) from None

    def _set_continuous(self, values: np.ndarray) -> None:
        if self._float64_cont:
            self._uv[:] = values
            self._c.set_reals()  # type: ignore[union-attr]
        else:
            set_values(self._fmu, _by_variable(self._cont_vars, values, self.size), "3.0")

    def _set_in_event_mode(self, values: np.ndarray) -> None:
        """New values of inputs that may change only in event mode: set there, the event
        iterated (it may change the states), back to continuous time."""
        fmu = self._fmu
        fmu.enterEventMode()
        n = self._n_evt_real
        set_values(fmu, _by_variable(self._evt_vars, values[:n], self.size), self.fmi_version)
        if self._in_disc:
            self._write_discrete(values[n:])
        self._iterate_discrete_states(self._t)
        fmu.enterContinuousTimeMode()
        self._sent_evt = np.array(values, dtype=float)
        self._z_key = None
        self._x = self._read_states()

    def _evaluate(self, s: float, y: np.ndarray) -> None:
        """Give the FMU time ``s``, states ``y`` and the inputs at ``s``."""
        c = self._c
        c.set_time(s)  # type: ignore[union-attr]
        if self._nx:
            self._xv[:] = y
            c.set_states(self._xbuf, self._nx)  # type: ignore[union-attr]
        if self._slope and self._cont.size:
            self._set_continuous(self._inputs_at(s)[self._cont])

    def _rhs(self, s: float, y: np.ndarray) -> np.ndarray:
        self._evaluate(s, y)
        self._c.get_derivatives(self._dxbuf, self._nx)  # type: ignore[union-attr]
        return self._dxv.copy()

    def _indicators(self, s: float, y: np.ndarray) -> np.ndarray:
        key = (s, y.tobytes())
        if key != self._z_key:  # solve_ivp asks once per event function at the same point
            self._evaluate(s, y)
            self._c.get_indicators(self._zbuf, self._nz)  # type: ignore[union-attr]
            self._z_last, self._z_key = self._zv.copy(), key
        return self._z_last

    def _integrate(self, a: float, b: float,
                   x: np.ndarray) -> tuple[float, np.ndarray, bool]:
        """Integrate from ``a`` towards ``b``; stop early at a state event.

        Returns the time reached, the states there and whether a state event stopped it.
        """
        if self._nx == 0 or b <= a:
            return b, x, False
        events = self._event_functions(a, b, x) if self._nz else []
        s = self.solver
        try:
            sol = solve_ivp(self._rhs, (a, b), x, method=s.method, rtol=s.rtol, atol=s.atol,
                            events=events or None, dense_output=bool(events))
        finally:
            self._z_key = None
        if sol.status == -1:
            raise self._error(f"solve_ivp ({s.method}) failed between t = {a!r} and {b!r}: "
                              f"{sol.message}")
        if sol.status == 1:
            hit = [e for e, times in zip(events, sol.t_events, strict=True) if len(times)]
            t_event, x_event = self._past_crossing(sol.sol, hit, float(sol.t[-1]), b)
            return t_event, x_event, True
        return b, sol.y[:, -1], False

    def _event_functions(self, a: float, b: float, x: np.ndarray) -> list[Callable[..., float]]:
        """One terminal ``solve_ivp`` event per indicator, watching the crossing away from the
        side it starts on (``direction``); see the module docstring for indicators at zero."""
        z0 = self._indicators(a, x).copy()
        functions = []
        for i, value in enumerate(z0):
            if abs(value) > AT_ZERO:
                direction = -1.0 if value > 0 else 1.0
            else:
                leaving = self._leaving(a, b, x, i, value)
                if leaving == 0.0:
                    continue  # stays on the surface over the probe: nothing to watch here
                direction = -1.0 if leaving > 0 else 1.0

            def event(s: float, y: np.ndarray, i: int = i) -> float:
                return float(self._indicators(s, y)[i])

            event.terminal = True  # type: ignore[attr-defined]
            event.direction = direction  # type: ignore[attr-defined]
            event.index = i  # type: ignore[attr-defined]
            functions.append(event)
        return functions

    def _leaving(self, a: float, b: float, x: np.ndarray, i: int, z0: float) -> float:
        """Sign of the change of indicator ``i`` just after ``a`` (one explicit Euler probe)."""
        probe = 1e-6 * (b - a)
        y = x + probe * self._rhs(a, x)
        return float(np.sign(self._indicators(a + probe, y)[i] - z0))

    def _past_crossing(self, dense: Callable[[float], np.ndarray], hit: list[Any],
                       t_root: float, b: float) -> tuple[float, np.ndarray]:
        """The earliest time at or after the located root where a triggered indicator is on its
        new side, found by growing steps of one unit in the last place."""
        step = math.ulp(max(abs(t_root), abs(b)))
        t = t_root
        for _ in range(64):
            y = np.asarray(dense(t), dtype=float)
            z = self._indicators(t, y)
            if any((z[e.index] <= 0.0) if e.direction < 0 else (z[e.index] > 0.0) for e in hit):
                return t, y
            if t >= b:
                break
            t = min(t + step, b)
            step *= 2.0
        return t_root, np.asarray(dense(t_root), dtype=float)

    # -- events ----------------------------------------------------------------------------------
    def _completed_integrator_step(self, t: float) -> bool:
        if not self.interface.needsCompletedIntegratorStep:
            return False
        enter, terminate = self._fmu.completedIntegratorStep(fmi2False)
        if terminate:
            raise EndOfSimulation(self.name, f"terminateSimulation at t = {t:.9g} (after an "
                                  "integrator step)")
        return bool(enter)

    def _handle_event(self, t: float) -> np.ndarray:
        fmu = self._fmu
        fmu.enterEventMode()
        self._iterate_discrete_states(t)
        fmu.enterContinuousTimeMode()
        self.events.append(t)
        self._z_key = None
        return self._read_states()

    def _iterate_discrete_states(self, t: float) -> None:
        for _ in range(MAX_EVENT_ITERATIONS):
            needed, terminate, _, _, timed, next_time = \
                self._c.update_discrete()  # type: ignore[union-attr]
            if terminate:
                raise EndOfSimulation(self.name, f"terminateSimulation at the event at "
                                      f"t = {t:.9g}")
            self._next_event = float(next_time) if timed else None
            if not needed:
                return
        call = ("fmi3UpdateDiscreteStates" if self.fmi_version == "3.0"
                else "fmi2NewDiscreteStates")
        raise self._error(f"no end of the event iteration at t = {t!r} after "
                          f"{MAX_EVENT_ITERATIONS} calls of {call}")

    def _read_states(self) -> np.ndarray:
        if self._nx == 0:
            return np.zeros(0)
        self._c.get_states(self._xbuf, self._nx)  # type: ignore[union-attr]
        return self._xv.copy()

    def time_events(self) -> tuple[float, ...]:
        """None known in advance: an FMU announces one time event at a time, and each is handled
        inside the step it falls into."""
        return ()


def _by_variable(variables: list[Any], values: np.ndarray,
                 size: Callable[[Any], int]) -> list[tuple[Any, Any]]:
    """Port values regrouped per variable (an array's elements as one list), for
    :func:`~cosimstep.adapters.fmu_base.set_values`."""
    pairs, i = [], 0
    for v in variables:
        n = size(v)
        pairs.append((v, [float(x) for x in values[i:i + n]] if v.dimensions
                      else float(values[i])))
        i += n
    return pairs


def _buffer(n: int) -> tuple[Any, np.ndarray]:
    buf = (c_double * max(n, 1))()
    return buf, np.ctypeslib.as_array(buf)[:n]

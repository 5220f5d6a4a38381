"""FMI 2.0 model-exchange FMUs as co-simulation sub-models: cosimstep integrates them (issue 5).

A model-exchange FMU only evaluates its equations — derivatives, event indicators, outputs — for
states and a time the importer gives it; :class:`MeSubModel` is that importer, so the FMU behaves
like any other sub-model. ``do_step(t, h)`` integrates the FMU's ODE with SciPy's ``solve_ivp``
(the :class:`~cosimstep.adapters.ode.SolveIvp` settings: method, rtol, atol; by default the same
RK45, rtol = 1e-8, atol = 1e-10 as the Python sub-models, so a model written both ways gives the
same numbers). Inputs follow the polynomial the master sets (value and up to three derivatives),
exactly as :class:`~cosimstep.adapters.ode.OdeSubModel` does.

Events, following the FMI 2.0 model-exchange protocol:

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
from scipy.integrate import solve_ivp

from cosimstep.adapters.fmu_base import FMI2_ME, FmuBase, fmu_logging, set_values
from cosimstep.adapters.ode import INPUT_ORDER, SolveIvp, _taylor
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


class MeSubModel(FmuBase):
    """An FMI 2.0 model-exchange FMU integrated by cosimstep, as a co-simulation sub-model.

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

    SUPPORTED = (FMI2_ME,)
    CALL_PREFIX = "fmi2"

    def __init__(self, path: str | Path, start: Mapping[str, float] | None = None, *,
                 instance_name: str | None = None, solver: SolveIvp | None = None) -> None:
        super().__init__(path, start, instance_name=instance_name)
        if solver is not None and not isinstance(solver, SolveIvp):
            raise ValueError(f"`solver` for model-exchange FMU {self.path} must be a SolveIvp "
                             f"(solve_ivp method, rtol, atol), got {solver!r}")
        self.solver = solver or SolveIvp()
        md = self.model_description
        self._nx = int(md.numberOfContinuousStates)
        self._nz = int(md.numberOfEventIndicators or 0)
        states = [d.variable.derivative for d in md.derivatives]  # in state-vector order
        index = {id(v): i for i, v in enumerate(states)}
        self._out_state = [index.get(id(v)) for v in self._out_vars]
        self._fmu_state = bool(self.interface.canGetAndSetFMUstate)
        self.capabilities = Capabilities(
            can_save_state=self._fmu_state or self._nz == 0,
            provides_derivatives=bool(self._out_vars) and None not in self._out_state,
            max_input_derivative_order=INPUT_ORDER,
            feedthrough=self._feedthrough(),
        )
        n_in = len(self._in_vr)
        self._t = 0.0
        self._x = np.zeros(self._nx)
        self._u = np.array([p.start if p.start is not None else 0.0 for p in self.inputs], float)
        self._du = np.zeros((INPUT_ORDER, n_in))
        self._slope = False
        self._next_event: float | None = None
        self.events: list[float] = []
        # ctypes buffers with NumPy views: the right-hand side runs inside solve_ivp's loop
        self._xbuf, self._xv = _buffer(self._nx)
        self._dxbuf, self._dxv = _buffer(self._nx)
        self._zbuf, self._zv = _buffer(self._nz)
        # inputs of variability "continuous" go to the FMU at every evaluation; "discrete" ones
        # may change only in event mode, so a new value is sent there (an event)
        self._disc = np.array([i for i, v in enumerate(self._in_vars)
                               if v.variability == "discrete"], dtype=int)
        self._cont = np.array([i for i in range(n_in) if i not in set(self._disc.tolist())],
                              dtype=int)
        self._ubuf, self._uv = _buffer(len(self._cont))
        self._vrbuf = (c_uint * max(len(self._cont), 1))(*[self._in_vr[i] for i in self._cont])
        self._sent_disc = self._u[self._disc].copy()
        self._z_key: tuple[float, bytes] | None = None
        self._z_last = np.zeros(self._nz)
        self._callbacks = self._fmi2_callbacks()

    # -- SubModel API ------------------------------------------------------------------------------
    def initialize(self, t0: float) -> None:
        if self._fmu is not None:
            self.terminate()
        try:
            fmu = self._load(FMU2Model)
            fmu.instantiate(callbacks=self._callbacks, loggingOn=fmu_logging())
            fmu.setupExperiment(tolerance=self.solver.rtol, startTime=t0)
            set_values(fmu, self._start_values(inputs=False), "2.0")
            fmu.enterInitializationMode()
            set_values(fmu, self._start_values(inputs=True), "2.0")
            fmu.exitInitializationMode()
            self._initialized = True
            self._t = float(t0)
            self._u = np.array([p.start if p.start is not None else 0.0 for p in self.inputs],
                               float)
            self._du = np.zeros_like(self._du)
            self._sent_disc = self._u[self._disc].copy()  # set in initialization mode
            self.events = []
            self._iterate_discrete_states(t0)  # initialization ends in event mode
            fmu.enterContinuousTimeMode()
            self._x = self._read_states()
        except Exception as exc:
            raise self._fail_initialization(exc) from exc

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
        try:
            return np.array(self._live().getReal(self._out_vr))
        except FMICallException as exc:
            raise self._error("fmi2GetReal", exc) from None

    def get_output_derivatives(self) -> np.ndarray:
        if not self.capabilities.provides_derivatives:
            return super().get_output_derivatives()
        fmu = self._live()
        try:
            fmu.fmi2GetDerivatives(fmu.component, self._dxbuf, self._nx)
        except FMICallException as exc:
            raise self._error("fmi2GetDerivatives", exc) from None
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
            fmu = self._live()
            try:
                fmu.fmi2SetTime(fmu.component, t)
                self._xv[:] = x
                fmu.fmi2SetContinuousStates(fmu.component, self._xbuf, self._nx)
                self._send_inputs(u)
            except FMICallException as exc:
                raise self._error(exc.function, exc) from None
        self._t, self._x, self._u, self._du = t, x.copy(), u.copy(), du.copy()
        self._sent_disc = self._u[self._disc].copy()  # restored with the FMU state, or re-sent
        self._next_event = next_event
        del self.events[n_events:]
        self._z_key = None

    # -- integration ---------------------------------------------------------------------------
    def _inputs_at(self, s: float) -> np.ndarray:
        return _taylor(self._u, self._du, s - self._t)

    def _send_inputs(self, u: np.ndarray) -> None:
        if not self._in_vr:
            return
        fmu = self._live()
        self._uv[:] = u[self._cont]
        try:
            if self._cont.size:
                fmu.fmi2SetReal(fmu.component, self._vrbuf, self._cont.size, self._ubuf)
            if self._disc.size and not np.array_equal(u[self._disc], self._sent_disc):
                self._set_discrete(u[self._disc])
        except FMICallException as exc:
            raise self._error(exc.function, exc) from None

    def _set_discrete(self, values: np.ndarray) -> None:
        """New values of discrete inputs: set in event mode, the event iterated (it may change
        the states), back to continuous time."""
        fmu = self._fmu
        fmu.enterEventMode()
        fmu.setReal([self._in_vr[i] for i in self._disc], [float(x) for x in values])
        self._iterate_discrete_states(self._t)
        fmu.enterContinuousTimeMode()
        self._sent_disc = np.array(values, dtype=float)
        self._z_key = None
        self._x = self._read_states()

    def _evaluate(self, s: float, y: np.ndarray) -> None:
        """Give the FMU time ``s``, states ``y`` and the inputs at ``s``."""
        fmu = self._fmu
        fmu.fmi2SetTime(fmu.component, s)
        if self._nx:
            self._xv[:] = y
            fmu.fmi2SetContinuousStates(fmu.component, self._xbuf, self._nx)
        if self._slope and self._cont.size:
            self._uv[:] = self._inputs_at(s)[self._cont]
            fmu.fmi2SetReal(fmu.component, self._vrbuf, self._cont.size, self._ubuf)

    def _rhs(self, s: float, y: np.ndarray) -> np.ndarray:
        self._evaluate(s, y)
        fmu = self._fmu
        fmu.fmi2GetDerivatives(fmu.component, self._dxbuf, self._nx)
        return self._dxv.copy()

    def _indicators(self, s: float, y: np.ndarray) -> np.ndarray:
        key = (s, y.tobytes())
        if key != self._z_key:  # solve_ivp asks once per event function at the same point
            self._evaluate(s, y)
            fmu = self._fmu
            fmu.fmi2GetEventIndicators(fmu.component, self._zbuf, self._nz)
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
            raise self._error(f"the FMU asked to terminate the simulation at t = {t!r}")
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
            needed, terminate, _, _, timed, next_time = self._fmu.newDiscreteStates()
            if terminate:
                raise self._error(f"the FMU asked to terminate the simulation at t = {t!r}")
            self._next_event = float(next_time) if timed else None
            if not needed:
                return
        raise self._error(f"no end of the event iteration at t = {t!r} after "
                          f"{MAX_EVENT_ITERATIONS} calls of fmi2NewDiscreteStates")

    def _read_states(self) -> np.ndarray:
        if self._nx == 0:
            return np.zeros(0)
        fmu = self._fmu
        fmu.fmi2GetContinuousStates(fmu.component, self._xbuf, self._nx)
        return self._xv.copy()

    def time_events(self) -> tuple[float, ...]:
        """None known in advance: an FMU announces one time event at a time, and each is handled
        inside the step it falls into."""
        return ()


def _buffer(n: int) -> tuple[Any, np.ndarray]:
    buf = (c_double * max(n, 1))()
    return buf, np.ctypeslib.as_array(buf)[:n]

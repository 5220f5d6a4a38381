"""Coupling algorithms: how one communication step ``[t, t + h]`` is executed (thesis 3.3.2).

* **Jacobi**: every sub-model steps on its partners' values extrapolated from the history up to
  ``t`` — the sub-models are independent within a step (they could run in parallel).
* **Gauss–Seidel**: sub-models step one after another; a later one uses the fresh values of those
  already stepped (interpolated over the step instead of extrapolated).

A master executes calls and counts them; it does not decide the step size (controllers do) nor
keep the history (the orchestrator does). It can save and restore every sub-model's state, which
is what rejecting and re-running a step needs.
"""

from __future__ import annotations

import functools
import math
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, NoReturn

import numpy as np

from cosimstep.errors import EndOfSimulation, RestoreError, SubModelError, restore_problems
from cosimstep.extrapolation import (
    evaluate,
    midstep_weights,
    step_derivative_weights,
    taylor_coefficients,
)
from cosimstep.iteration import COUPLINGS, Iteration, LoopError, LoopStats
from cosimstep.system import CompiledSystem

MASTERS = ("jacobi", "gauss-seidel", "multirate")
RESYNC = ("partial", "complete")
COUPLING_INPUTS = ("polynomial", "trapezoidal")


def trapezoidal_refusal(controller: str) -> str:
    """Why an error-controlled controller is refused with ``coupling_input = "trapezoidal"``.

    Measured on examples/stiff_two_mass.toml, `pc` (step doubling) at tol 1e-2 / 1e-3 / 1e-4
    over 1 s: 31 / 185 / 259 × tol with status ok. The estimate assumes inputs of the
    extrapolation's order; the held mean is a different, lower-order input, whose error on the
    stiff mode the step doubling does not see.
    """
    return (f"coupling_input 'trapezoidal' holds the mean of the iterated end values, for "
            f"stability at large fixed steps; controller '{controller}' cannot keep its "
            "tolerance with it (pc: 31-259 x tol measured)")


DEFAULT_CALL_TIMEOUT = 60.0
"""Seconds one sub-model call may take by default: far beyond any step of a model that works
(the slowest call in the benchmarks takes about 0.1 s), short enough that a hung FMU does not
hold a batch job until its wall-time limit. Watching costs two stores per call (measured in
docs/benchmarks.md, fmu-overhead)."""

TIMED_EVERY = 4
"""The held kernel times its calls on one step in this many (see :class:`_LeanKernel`)."""


@dataclass(frozen=True)
class MasterOptions:
    """How steps are executed.

    Attributes
    ----------
    name:
        ``"jacobi"`` or ``"gauss-seidel"`` (default: measured more accurate at equal calls), or
        ``"multirate"``: one adaptive step per sub-model (:mod:`cosimstep.multirate`).
    extrapolation:
        Order of the input polynomial over a step: 0 hold, 1 linear, 2 quadratic (default: the
        accurate one; see docs/concepts.md for the measured orders).
    order:
        Gauss–Seidel execution order by model name (default: the order models were added).
    call_timeout:
        Seconds one sub-model call may take before the run ends as failed, results kept
        (default :data:`DEFAULT_CALL_TIMEOUT`; ``0`` or ``None``: no limit). The run then goes
        on in a worker thread that stamps every call, and a timed-out call is abandoned there.
    interpolation:
        Multi-rate only: how partners' stored trajectories are read (a method of
        :mod:`cosimstep.interpolation`; ``None``: the built-in local cubic, fastest).
    resync:
        Multi-rate only: who goes back when a sub-model finds an event inside a step it has
        taken while others ran past that time (thesis 4.3.5, fig. 85). ``"partial"`` (default):
        only the sub-models the event's outputs reach through the connections; ``"complete"``:
        every sub-model past the event.
    coupling:
        ``"explicit"`` (default: one pass per step), or strong coupling, every step repeated
        until the exchanged values agree: ``"fixed-point"``, ``"aitken"``, ``"iqn-ils"``
        (:mod:`cosimstep.iteration`). Jacobi and Gauss–Seidel only.
    coupling_tol:
        Iteration converged when every exchanged value's residual is within
        ``coupling_tol * (1 + |value|)`` (absolute and relative).
    max_iterations:
        Passes per step before the step counts as failed (:class:`~cosimstep.iteration.
        CouplingError`).
    coupling_input:
        Strong coupling only: what a sub-model receives over a step. ``"polynomial"``
        (default): the interpolant of order ``extrapolation`` through the stored points and the
        iterated end value. ``"trapezoidal"``: the mean of the values at the step's two ends,
        held — the trapezoidal rule on the interface, A-stable where the converged polynomial
        is only conditionally stable (a mass driven by a linear force ramp is Newmark's linear
        acceleration method, unstable beyond ω ΔT = 2√3; driven by the mean force it is the
        average acceleration method, stable at every step; see docs/concepts.md).
    """

    name: str = "gauss-seidel"
    extrapolation: int = 2
    order: tuple[str, ...] | None = None
    call_timeout: float | None = DEFAULT_CALL_TIMEOUT
    interpolation: str | None = None
    resync: str = "partial"
    coupling: str = "explicit"
    coupling_tol: float = 1e-8
    max_iterations: int = 50
    coupling_input: str = "polynomial"

    def problems(self) -> list[str]:
        out = []
        if self.name not in MASTERS:
            out.append(f"unknown master '{self.name}'; choose one of {', '.join(MASTERS)}")
        if self.extrapolation not in (0, 1, 2):
            out.append(f"extrapolation order {self.extrapolation} is not 0, 1 or 2")
        if self.call_timeout is not None and not self.call_timeout >= 0:
            out.append("call_timeout must be positive (0: no limit)")
        if self.interpolation is not None:
            from cosimstep.interpolation import INTERPOLATORS

            if self.interpolation not in INTERPOLATORS:
                out.append(f"unknown interpolation '{self.interpolation}'; choose one of "
                           f"{', '.join(INTERPOLATORS)}")
            elif self.name != "multirate":
                out.append("interpolation applies to the multirate master only")
        if self.resync not in RESYNC:
            out.append(f"unknown resync '{self.resync}'; choose one of {', '.join(RESYNC)}")
        return out + self._coupling_problems()

    def _coupling_problems(self) -> list[str]:
        out = []
        if self.coupling not in COUPLINGS:
            out.append(f"unknown coupling '{self.coupling}'; choose one of "
                       f"{', '.join(COUPLINGS)}")
        elif self.coupling != "explicit" and self.name == "multirate":
            out.append(f"coupling '{self.coupling}' iterates the steps of the jacobi and "
                       "gauss-seidel masters, not multirate")
        if not (self.coupling_tol > 0 and math.isfinite(self.coupling_tol)):
            out.append(f"coupling_tol must be a positive number, got {self.coupling_tol}")
        if not (isinstance(self.max_iterations, int) and self.max_iterations >= 1):
            out.append(f"max_iterations must be a whole number >= 1, got {self.max_iterations}")
        if self.coupling_input not in COUPLING_INPUTS:
            out.append(f"unknown coupling_input '{self.coupling_input}'; choose one of "
                       f"{', '.join(COUPLING_INPUTS)}")
        elif self.coupling_input != "polynomial" and self.coupling == "explicit":
            out.append(f"coupling_input '{self.coupling_input}' needs the end values of an "
                       "iterated step: choose a strong coupling (fixed-point, aitken, iqn-ils)")
        return out


class _Abandoned(BaseException):
    """Ends a watched worker whose call came back after the run had given up on it."""


class _Watchdog:
    """Runs a whole job (a run's kernel) in one daemon worker thread and watches its calls.

    Handing every call to a worker thread and waiting for it costs two thread switches per
    call, more than a small FMU's step. Here the worker runs the whole job and marks each
    sub-model call it makes with a token (:meth:`call`, or the same stores inlined in the lean
    kernels): :attr:`running` is the call's token while it runs, 0 between calls. The calling
    thread looks at least every quarter of the limit, and ends the run when one token has stood
    for the whole limit: that call has run at least that long, and the run ends within 1.25
    time-outs of the call's start. A token costs no clock read (the lean kernels time only a
    sample of their calls, see :class:`_LeanKernel`). A timed-out call is abandoned: its thread
    is a daemon, and if the call ever returns, the worker stops there (:class:`_Abandoned`)
    without touching anything else.

    No lock: a call's end is "``running = 0``, then read ``abandoned``", the watchdog's decision
    "``abandoned = True``, then read ``running``" (both single stores and loads under the GIL,
    so seen in one order by both threads). If the watchdog still sees the call running after
    raising the flag, the worker will read the flag when (if) the call returns and stop; if the
    call ended in between, the flag is lowered again and the worker goes on — unless it read the
    flag in that instant, in which case it stopped and the run ends timed out all the same
    (the call did take the whole limit). Either way the worker never steps a sub-model after
    the caller has reported the time-out.
    """

    def __init__(self, timeout: float) -> None:
        self.timeout = timeout
        self.running = 0  # the token of the call under way; 0: none
        self.tick = 0  # the last token handed out (tokens are never reused within a run)
        self.where: tuple[int, float, float | None] = (-1, math.nan, None)  # (k, t, h)
        # where a lean kernel's run of steps places a token (k, t, h), instead of `where`
        self.locate: Callable[[int], tuple[int, float, float | None]] | None = None
        self.abandoned = False

    def call(self, k: int, t: float, h: float | None, fn: Any, args: tuple) -> Any:
        self.where, self.locate = (k, t, h), None
        self.tick += 1
        self.running = self.tick
        try:
            return fn(*args)
        finally:
            self.running = 0
            if self.abandoned:
                raise _Abandoned

    def stamp(self, k: int, t: float, h: float | None) -> int:
        """A call of model ``k`` starts (the lean kernels' single calls): its token."""
        self.where, self.locate = (k, t, h), None
        self.tick += 1
        self.running = self.tick
        return self.tick

    def _give_up(self, token: int) -> bool:
        """Abandon the call ``token`` if it is still running (see the class)."""
        self.abandoned = True
        if self.running == token:
            return True
        self.abandoned = False
        return False

    def _timeout(self, names: Sequence[str], token: int) -> SubModelError:
        k, t, h = self.where if self.locate is None else self.locate(token)
        msg = f"no answer within {self.timeout:g} s (call abandoned)"
        error = SubModelError(names[k], t, f"TimeoutError: {msg}", h)
        error.__cause__ = TimeoutError(msg)
        return error

    def run(self, job: Any, names: Sequence[str]) -> Any:
        """``job()`` in the worker; its result or exception, or a :class:`SubModelError` for
        the call that exceeded the time-out (found within 1.25 time-outs of its start)."""
        box: list = []
        done = threading.Event()

        def work() -> None:
            try:
                box.append((True, job()))
            except _Abandoned:
                return
            except BaseException as exc:  # handed to the calling thread
                box.append((False, exc))
            finally:
                done.set()

        threading.Thread(target=work, daemon=True, name="cosimstep-run").start()
        timeout = self.timeout
        quarter = wait = 0.25 * timeout
        seen, since = 0, 0.0  # the token at the last look, and when it was first seen
        given_up = 0  # the call abandoned in vain (it ended in that instant; see the class)
        try:
            while not done.wait(wait):
                token, now = self.running, time.perf_counter()
                if token != seen:
                    seen, since = token, now
                elif token and now - since >= timeout:
                    if self._give_up(token):
                        raise self._timeout(names, token)
                    given_up = token
                # a quarter of the limit, or the deadline of the call seen if sooner
                wait = max(min(quarter, since + timeout - now) if token else quarter, 1e-3)
        except KeyboardInterrupt:
            # stop at the next call's return; wait for it as long as a call may take
            self.abandoned = True
            done.wait(timeout)
            raise
        if not box:  # it stopped on the flag raised in the instant its call ended
            raise self._timeout(names, given_up)
        ok, value = box[0]
        if not ok:
            raise value
        return value


def _untouched(gains: list[np.ndarray], offsets: list[np.ndarray]) -> list[bool]:
    """Per model: whether every input is its source's value unchanged (gain 1, offset 0; a
    model without inputs too), judged on all models' tables at once — one NumPy call per
    model cost more than the rest of a large system's set-up."""
    if not gains:
        return []
    bounds = np.cumsum([0, *map(len, gains)])
    changed = np.flatnonzero((np.concatenate(gains) != 1.0) | (np.concatenate(offsets) != 0.0))
    untouched = np.ones(len(gains), dtype=bool)
    untouched[np.searchsorted(bounds, changed, side="right") - 1] = False
    return untouched.tolist()


def _columns(n: int, sources: list[list[int]]) -> np.ndarray:
    """A mask of ``n`` columns, true for those in any of ``sources``."""
    mask = np.zeros(n, dtype=bool)
    mask[[j for src in sources for j in src]] = True
    return mask


class Master:
    """Executes communication steps over a compiled system."""

    def __init__(self, system: CompiledSystem, options: MasterOptions = MasterOptions()) -> None:
        problems = options.problems()
        if problems:
            raise ValueError("; ".join(problems))
        self.system = system
        self.options = options
        n = len(system.models)
        self.calls = np.zeros(n, dtype=np.int64)
        self.time_in_models = np.zeros(n)
        if options.order is None:
            self.sequence = list(range(n))
        else:
            unknown = [m for m in options.order if m not in system.names]
            if unknown or len(set(options.order)) != len(options.order):
                raise ValueError(f"`order` {list(options.order)} must name each model at most "
                                 f"once, from: {', '.join(system.names)}")
            self.sequence = [system.names.index(m) for m in options.order]
            self.sequence += [k for k in range(n) if k not in self.sequence]
        self._deriv_order = [m.capabilities.max_input_derivative_order for m in system.models]
        # a connection without gain, offset or unit change passes values on untouched
        self._identity = _untouched(system.a, system.b)
        self._watch: _Watchdog | None = None  # set while a watched run is under way
        self._dy0: np.ndarray | None = None
        self.correct_start = False  # set by a fixed-step run: see :meth:`step`
        self._restorable, self._integrating = _start_facts(system)
        # on Python ints: NumPy's cost per call on arrays of one or two elements would
        # dominate the set-up of a system of thousands of models
        sources = [src.tolist() for src in system.src]
        self.predicted = self._predicted_columns(sources)
        # outputs some model reads, and those read by a hold-only receiver
        self.consumed = _columns(system.n_outputs, sources)
        self.held = _columns(system.n_outputs, [src for k, src in enumerate(sources)
                                                if self._deriv_order[k] == 0])
        # piecewise-constant outputs (Port.discrete): held over every step, never extrapolated
        self.discrete = np.array([p.discrete for m in system.models for p in m.outputs],
                                 dtype=bool)
        self._hold = np.flatnonzero(self.discrete)
        self.assumed = np.zeros(system.n_outputs)
        self.last = np.zeros(system.n_outputs)
        self.iteration = _iteration(system, options)
        self.loop_stats = LoopStats()
        self._loop_of = {k: loop for loop in system.loops for k in loop}  # model -> its loop
        # the values iterated on (strong coupling): those some receiver takes extrapolated
        self._unknowns = self.predicted & ~self.discrete
        # outputs computed from the instant (direct feedthrough): at a time event already on
        # its far side (see step), and the models that have any
        self._instant, self._instant_model = _instant_outputs(system)
        # who declares which time event: at an edge its outputs may already stand on the
        # event's far side (a step source), see _jumped
        self._declared = _declared_events(system)

    def _predicted_columns(self, sources: list[list[int]]) -> np.ndarray:
        """Outputs that some receiver uses *extrapolated* over a step (not yet computed).

        Under Jacobi that is every consumed output; under Gauss–Seidel only outputs of models that
        step after (or are) a receiver — the others are interpolated through their fresh values.
        ``sources``: each model's source columns.
        """
        system = self.system
        rank = {k: i for i, k in enumerate(self.sequence)}
        owner = system.owners
        jacobi = self.options.name == "jacobi"
        mask = np.zeros(system.n_outputs, dtype=bool)
        mask[[j for k, src in enumerate(sources) for j in src
              if jacobi or rank[owner[j]] >= rank[k]]] = True
        return mask

    # -- life cycle --------------------------------------------------------------------------
    def initialize(self, t0: float) -> np.ndarray:
        """Initialize every sub-model and return the exchanged values at ``t0``."""
        for k, model in enumerate(self.system.models):
            self._guard(k, t0, model.initialize, t0)
        y = np.empty(self.system.n_outputs)
        for k in range(len(self.system.models)):
            y[self.system.output_slices[k]] = self._outputs(k, t0, None)
        self._settle_feedthrough(t0, y)
        self._check_finite(range(len(self.system.models)), t0, y)
        self._dy0 = None
        if all(m.capabilities.provides_derivatives for m in self.system.models):
            system = self.system
            for k, m in enumerate(system.models):  # slopes at t0 need the inputs at t0
                self._guard(k, t0, m.set_inputs, self._route(k, y[system.src[k]]))
            self._dy0 = np.concatenate([self._guard(k, t0, m.get_output_derivatives)
                                        for k, m in enumerate(system.models)])
        return y

    def _outputs(self, k: int, t: float, h: float | None) -> np.ndarray:
        """Outputs of model ``k``, checked to be one float per declared output."""
        return self._checked_outputs(k, t, h,
                                     self._guard(k, t, self.system.models[k].get_outputs, h=h))

    def _checked_outputs(self, k: int, t: float, h: float | None, values: Any) -> np.ndarray:
        """``values`` from model ``k``'s ``get_outputs`` as one float per declared output, or
        a :class:`SubModelError` saying what came back instead."""
        try:
            arr = np.asarray(values, dtype=float)
        except (TypeError, ValueError):
            arr = None
        n = len(self.system.models[k].outputs)
        if arr is None or arr.shape != (n,):
            raise SubModelError(self.system.names[k], t, f"get_outputs returned {values!r}; "
                                f"expected {n} float(s), one per declared output", h)
        return arr

    def terminate(self, spare: set[str] | frozenset[str] = frozenset()) -> None:
        """Terminate every sub-model but those named in ``spare`` (their calls hung)."""
        for name, model in zip(self.system.names, self.system.models):
            if name not in spare:
                # a model that fails to end frees what it can; not contextlib.suppress, whose
                # object per model cost more than the call in a system of thousands
                try:  # noqa: SIM105
                    model.terminate()
                except Exception:
                    pass

    def save(self) -> list[Any]:
        return [m.save_state() for m in self.system.models]

    def restore(self, tokens: Sequence[Any]) -> None:
        for m, token in zip(self.system.models, tokens):
            m.restore_state(token)

    # -- one communication step --------------------------------------------------------------
    def step(self, t: float, h: float, times: Sequence[float], history: np.ndarray, *,
             order: int | None = None, end: np.ndarray | None = None,
             edge: bool = False) -> np.ndarray:
        """Advance every sub-model from ``t`` to ``t + h``; return the new exchanged values.

        ``times``/``history`` are the stored points (the last row belongs to ``t``). ``order``
        overrides the extrapolation order for this step. ``end`` (values at ``t + h`` from an
        earlier attempt of the same step) turns extrapolation into interpolation: the corrector
        of a predictor–corrector step. After the step, :attr:`assumed` holds the value at
        ``t + h`` of the input polynomial each output was assumed to follow (see
        :attr:`predicted` for which outputs were actually extrapolated). With strong coupling
        the step is repeated until its end values agree (:mod:`cosimstep.iteration`).

        ``edge``: the step ends on a time event. An output computed from the instant (direct
        feedthrough) is then already the event's right-hand value at ``t + h`` (a spring whose
        stiffness changes there gives the new force), so no receiver follows a curve through
        it over the step: those outputs are extrapolated from the step's own side, as a
        discrete output is held, and the step returns that extrapolation for them, the
        step's own end, which the controller judges; :meth:`right_limits` gives the values
        the next segment starts from. Interpolated through the new value, a jump of size
        ``ΔF`` was smeared over the step, an ``O(ΔF·h)`` input error that no shorter step
        reduces relative to its share of the tolerance, and every controller that judged the
        end values saw the jump whatever the step: `pc`, `rkf45` and an iterated coupling on
        problem 7 with k changed at 5 s rejected steps down to 1e-10 s there and ended
        ``failed``.
        """
        if self.iteration is None:
            if self._start_without_slopes(times, order, end):
                # A segment's first step without grey-box slopes can only hold the inputs, an
                # O(h²) error that outweighed the rest of a fixed-step run (problem 7: 88–96 %
                # of its error). Run it again once, its inputs interpolated through its own
                # end values: O(h³), the order of the steps after it.
                token = self.save()
                y = self._pass(t, h, times, history, order, end, edge)
                self.restore(token)
                return self._pass(t, h, times, history, 1, y, edge)
            return self._pass(t, h, times, history, order, end, edge)
        return self.iteration.run(
            lambda x: self._pass(t, h, times, history, order, end if x is None else x, edge),
            self.save, self.restore, lambda: self.assumed, self._unknowns, t, h)

    def _start_without_slopes(self, times: Sequence[float], order: int | None,
                              end: np.ndarray | None) -> bool:
        """Whether :meth:`step` corrects this step: a fixed-step run (``correct_start``), the
        first step of a segment (one stored point), no grey-box slopes to extrapolate with,
        inputs otherwise extrapolated, sub-models that can go back, and one that integrates
        its inputs (a loop of feedthrough models is settled at the points whatever the
        inputs did between them). An adaptive controller's own estimate judges its first
        step instead."""
        return (self.correct_start and end is None and order is None and len(times) == 1
                and self.options.extrapolation > 0 and self._dy0 is None and self._restorable
                and self._integrating)

    def _pass(self, t: float, h: float, times: Sequence[float], history: np.ndarray,
              order: int | None, end: np.ndarray | None, edge: bool = False) -> np.ndarray:
        """One pass of the step: every sub-model once (see :meth:`step`)."""
        p = self.options.extrapolation if order is None else order
        coef = self._polynomial(t, h, times, history, p, end, edge)
        y_new = history[-1].copy()
        gauss_seidel = self.options.name == "gauss-seidel"
        if end is None and len(times) == 1 and p > 0 and self._dy0 is not None:
            coef[1] = self._dy0  # start-up: grey-box slopes instead of a first-order hold
        self._held_discrete(coef, y_new)
        self.assumed = evaluate(coef, h)
        poly, coef = coef, self._as_input(coef, h)  # the same array unless trapezoidal
        # an extrapolation of order 0 foresees no change to tell a jump from (see _jumped)
        owners = self._owners(t + h) if edge and p > 0 else ()
        jumped: list[int] = []
        for k in self.sequence:
            self._step_model(k, t, h, coef)
            out = self.system.output_slices[k]
            model = self.system.models[k]
            if gauss_seidel and model.capabilities.has_direct_feedthrough:
                # its outputs must reflect inputs at t + h before later models interpolate them
                src = self.system.src[k]
                self._guard(k, t, model.set_inputs, self._route(k, evaluate(poly[:, src], h)),
                            h=h)
            y_new[out] = self._outputs(k, t, h)
            own = self._jumped(out, y_new, history[-1]) if k in owners else []
            jumped += own
            if gauss_seidel and not (edge and self._instant_model[k]):
                self._read_fresh(out, own, poly, coef, t, h, times, history, y_new, p)
        self._settle_feedthrough(t + h, y_new)
        self._check_finite(range(len(self.system.models)), t, y_new, h)
        if edge:
            y_new[self._instant] = self.assumed[self._instant]
            y_new[jumped] = self.assumed[jumped]
        self.last = y_new
        return y_new

    def _read_fresh(self, out: slice, own: list[int], poly: np.ndarray, coef: np.ndarray,
                    t: float, h: float, times: Sequence[float], history: np.ndarray,
                    y_new: np.ndarray, p: int) -> None:
        """Gauss–Seidel: the models after this one see its fresh values ``y_new[out]``,
        interpolated through ``t + h`` — but the columns ``own``, which jumped at the time
        event the step ends on (:meth:`_jumped`), keep their own side."""
        kept = poly[:, own].copy() if own else None
        pts = [*times[-p:], t + h] if p > 0 else [t + h]
        poly[:, out] = taylor_coefficients(pts, _stacked(history[-p:, out], y_new[out])
                                           if p > 0 else y_new[None, out], t, p)
        if kept is not None:
            poly[:, own] = kept
        self._held_discrete(poly, history[-1])
        if coef is not poly:
            coef[:, out] = self._as_input(poly[:, out], h)

    def _polynomial(self, t: float, h: float, times: Sequence[float], history: np.ndarray,
                    p: int, end: np.ndarray | None, edge: bool) -> np.ndarray:
        """The inputs' polynomial over the step (Taylor coefficients at ``t``): extrapolated
        from the history, or interpolated through ``end`` — but at an edge not through the
        right-hand values of the outputs computed from the instant (see :meth:`step`)."""
        if end is None:
            return taylor_coefficients(times, history, t, p)
        pts = [*times[-p:], t + h] if p > 0 else [t + h]
        vals = _stacked(history[-p:], end) if p > 0 else end[None, :]
        coef = taylor_coefficients(pts, vals, t, p)
        if edge and self._instant.any():
            own_side = taylor_coefficients(times, history, t, p)
            coef[:, self._instant] = own_side[:, self._instant]
        return coef

    def right_limits(self, t: float, y: np.ndarray) -> np.ndarray:
        """``y`` at a time event ``t`` reached by an edge step (:meth:`step`), with the outputs
        computed from the instant read again there: the event's right-hand values, where the
        next segment starts and what the results show at ``t``."""
        owners = self._owners(t)
        if not self._instant.any() and not owners:
            return y
        y = y.copy()
        for k in owners:  # what jumped there was kept on the step's own side (_jumped)
            y[self.system.output_slices[k]] = self._outputs(k, t, None)
        self._settle_feedthrough(t, y)
        self._check_finite(range(len(self.system.models)), t, y, None)
        return y

    def check_restored(self, t: float, stored: Sequence[np.ndarray],
                       models: Sequence[int] | None = None) -> None:
        """After a rejected step, the sub-models ``models`` (default: all) restored to ``t``:
        raise :class:`~cosimstep.errors.RestoreError` if an output that comes from a
        sub-model's state differs from ``stored`` (each one's outputs stored at ``t``;
        :func:`restore_problems`). The multi-rate master checks its tracks one at a time."""
        system = self.system
        ks = range(len(system.models)) if models is None else models
        slices = [system.output_slices[k] for k in ks]
        state = ~self._instant & ~self.discrete
        try:
            now = [self._outputs(k, t, None) for k in ks]
        except SubModelError:
            return  # that is the failure's business (the step is retried), not the restore's
        why = restore_problems([system.names[k] for k in ks], list(stored), now,
                               [state[out] for out in slices])
        if why is not None:
            raise RestoreError(why)

    def _owners(self, t: float) -> tuple[int, ...]:
        """The models that declared the time event an edge step ends on (the declared time
        nearest ``t``: the run lands on it to within ulps)."""
        times, owners = self._declared
        if not times.size:
            return ()
        i = int(np.searchsorted(times, t))
        if i == times.size or (i > 0 and t - times[i - 1] < times[i] - t):
            i -= 1
        return owners[i]

    def _jumped(self, out: slice, y_new: np.ndarray, start: np.ndarray) -> list[int]:
        """The columns of ``out`` (outputs of a model that declared the time event this edge
        step ends on) whose new value is the event's right-hand one: it missed the step's own
        extrapolation by more than the whole change that extrapolation foresaw over the step.

        The API reads one value at the event, and a model that changes abruptly there may give
        either side: an output computed from its own clock (a step source, ``1 if t >= 1``)
        already gives the new one. Interpolated through it, a receiver met the jump over the
        whole step, an error no shorter step reduces, and ``pc`` (Gauss–Seidel and Jacobi
        alike, through its corrector) ended at ``hmin`` on the event. A continuous output
        misses its extrapolation by the extrapolation's error, of a higher order in ``h`` than
        the change; where steps are too long for that to hold, taking it as jumped costs only
        this step's interpolation. Such a column is met on the step's own side, as a direct
        feedthrough output is (:meth:`step`), and read again at the event for its right-hand
        value (:meth:`right_limits`). Discrete outputs are held in any case. Not judged where
        the step's extrapolation has order 0 (it foresees no change, so every output that
        moves would count as jumped): there the new value is still interpolated through."""
        cols = np.arange(out.start, out.stop)
        jump = jumped(y_new[cols], self.assumed[cols], start[cols])
        jump &= ~self.discrete[cols] & ~self._instant[cols]
        return cols[jump].tolist()

    def _as_input(self, coef: np.ndarray, h: float) -> np.ndarray:
        """The input polynomial over the step as the sub-models receive it: as is, or under
        ``coupling_input = "trapezoidal"`` the mean of its two end values, held (one row, so
        every sub-model, whatever input derivatives it takes, sees the same constant)."""
        if self.options.coupling_input != "trapezoidal":
            return coef
        mean = 0.5 * (coef[0] + evaluate(coef, h))
        out = np.zeros_like(coef)
        out[0] = mean
        return out

    def _held_discrete(self, coef: np.ndarray, row: np.ndarray) -> None:
        """Discrete outputs keep their value at the step's start (``row``) over the step: a
        curve through a jump would smear it over the steps around it, and a step that ends on
        a change must not see the new value before its end."""
        if self._hold.size:
            coef[0, self._hold] = row[self._hold]
            coef[1:, self._hold] = 0.0

    def restart(self) -> None:
        """After a time event: grey-box slopes (if any) for the first step of the new segment."""
        self._dy0 = self.derivatives()

    def derivatives(self) -> np.ndarray | None:
        """Grey-box output derivatives of every model now, or ``None`` if one cannot tell."""
        if not all(m.capabilities.provides_derivatives for m in self.system.models):
            return None
        return np.concatenate([np.asarray(self._guard(k, math.nan, m.get_output_derivatives),
                                          dtype=float)
                               for k, m in enumerate(self.system.models)])

    def _step_model(self, k: int, t: float, h: float, coef: np.ndarray) -> None:
        system = self.system
        model = system.models[k]
        src, a = system.src[k], system.a[k]
        q = min(self._deriv_order[k], coef.shape[0] - 1)
        if q > 0 or coef.shape[0] == 1:
            u = self._route(k, coef[0, src])
        else:
            # The sub-model holds inputs constant: give it the extrapolated mid-step value,
            # which is second-order accurate over the step where the start value is first-order.
            u = self._route(k, evaluate(coef[:, src], 0.5 * h))
        start = time.perf_counter()
        self.calls[k] += 1
        watch = self._watch
        try:  # the step's calls under one guard; watched, each has its own time-out
            if watch is None:
                model.set_inputs(u)
                if q > 0:
                    model.set_input_derivatives(a * coef[1:q + 1, src])
                model.do_step(t, h)
            else:
                watch.call(k, t, h, model.set_inputs, (u,))
                if q > 0:
                    watch.call(k, t, h, model.set_input_derivatives, (a * coef[1:q + 1, src],))
                watch.call(k, t, h, model.do_step, (t, h))
        except (Exception, SystemExit) as exc:
            self._reraise(k, t, exc, h)
        self.time_in_models[k] += time.perf_counter() - start

    def held_kernel(self) -> _HeldKernel | None:
        """The lean form of :meth:`step` for runs of many plain steps, or ``None``.

        It applies when inputs are held over the step (extrapolation order 0) and no sub-model
        has direct feedthrough: each step is then "inputs from one stored row, step, outputs into
        the next row", with nothing to extrapolate or settle (see :class:`_HeldKernel`).
        """
        if self.options.extrapolation != 0 or self.options.name not in ("jacobi",
                                                                         "gauss-seidel"):
            return None
        if self.iteration is not None or any(self._instant_model):
            return None
        return _HeldKernel(self)

    def extrapolating_kernel(self) -> _ExtrapolatingKernel | None:
        """The lean form of :meth:`step` at extrapolation order 1 or 2 on uniform steps, or
        ``None``.

        It applies when no sub-model has direct feedthrough: every input is then the input
        polynomial's value at mid-step, or (for a sub-model taking input derivatives) its value
        and derivatives at the step's start, which on uniform steps are fixed linear
        combinations of the last stored rows (and, under Gauss–Seidel, of the new one; see
        :func:`~cosimstep.extrapolation.midstep_weights` and
        :func:`~cosimstep.extrapolation.step_derivative_weights`). The caller uses it only for
        steps as long as the ``order`` steps before them, within one segment (see
        :class:`_ExtrapolatingKernel`).
        """
        if self.options.extrapolation == 0 or self.options.name not in ("jacobi",
                                                                         "gauss-seidel"):
            return None
        if self.iteration is not None or any(self._instant_model):
            return None
        return _ExtrapolatingKernel(self)

    def _settle_feedthrough(self, t: float, y: np.ndarray) -> None:
        """Refresh direct-feedthrough outputs from inputs at ``t`` (no step, no call); the
        models of an algebraic loop together (:meth:`_solve_loop`)."""
        system = self.system
        for k in system.feedthrough_order:
            loop = self._loop_of.get(k)
            if loop is not None:
                if k == loop[0]:  # a loop's models are solved together, at its first
                    self._solve_loop(loop, t, y)
            else:
                u = self._route(k, y[system.src[k]])
                self._guard(k, t, system.models[k].set_inputs, u)
                y[system.output_slices[k]] = self._outputs(k, t, None)

    def _solve_loop(self, models: tuple[int, ...], t: float, y: np.ndarray) -> None:
        """The outputs of an algebraic loop's models at ``t``: the values ``z`` that the models
        give back when their inputs are taken from ``z`` (and the other values in ``y``),
        solved by SciPy's ``root`` (MINPACK's hybrid Powell method, a finite-difference
        Jacobian) from the values the outputs have now. Plain substitution, the explicit
        masters' one pass, diverges or stalls on a loop whose gain exceeds one."""
        from scipy.optimize import root

        system = self.system
        cols = np.concatenate([np.arange(system.output_slices[k].start,
                                         system.output_slices[k].stop) for k in models])
        trial = y.copy()
        stats = self.loop_stats

        def through(z: np.ndarray) -> np.ndarray:
            trial[cols] = z
            stats.evaluations += 1
            for k in models:
                self._guard(k, t, system.models[k].set_inputs,
                            self._route(k, trial[system.src[k]]))
            return np.concatenate([self._outputs(k, t, None) for k in models])

        tol = self.options.coupling_tol
        solution = root(lambda z: through(z) - z, y[cols], method="hybr",
                        options={"xtol": tol})
        out = through(solution.x)  # the models' inputs left at the solution
        residual = np.abs(out - solution.x) / (tol * (1.0 + np.abs(out)))
        worst = float(np.max(residual)) if residual.size else 0.0
        if not worst <= 1.0:
            i = int(np.nanargmax(residual)) if np.isfinite(residual).any() else 0
            raise LoopError(t, [system.output_names[j] for j in cols], worst * tol,
                            str(solution.message), (system.output_names[cols[i]],
                                                    float(out[i]),
                                                    float(abs(out[i] - solution.x[i]))))
        y[cols] = out
        stats.solves += 1
        stats.residual_max = max(stats.residual_max, worst * tol)

    def _check_finite(self, models: Any, t: float, y: np.ndarray,
                      h: float | None = None) -> None:
        if np.isfinite(y).all():
            return
        for k in models:
            block = y[self.system.output_slices[k]]
            if not np.all(np.isfinite(block)):
                bad = [self.system.output_names[self.system.output_slices[k].start + i]
                       for i in np.flatnonzero(~np.isfinite(block))]
                raise SubModelError(self.system.names[k], t,
                                    f"returned non-finite output(s) {', '.join(bad)}", h)

    def _route(self, k: int, x: np.ndarray) -> np.ndarray:
        """Model ``k``'s inputs from its sources' values ``x`` (gain, offset, unit change)."""
        if self._identity[k]:
            return x
        return self.system.a[k] * x + self.system.b[k]

    def _guard(self, k: int, t: float, fn: Any, *args: Any, h: float | None = None) -> Any:
        try:
            if self._watch is not None:
                return self._watch.call(k, t, h, fn, args)
            return fn(*args)
        except (Exception, SystemExit) as exc:  # a sub-model's sys.exit() ends only its run
            self._reraise(k, t, exc, h)

    def _reraise(self, k: int, t: float, exc: BaseException, h: float | None) -> NoReturn:
        """Raise what model ``k``'s call at ``t`` raised as the run reports it: named after
        the model, with the time and step."""
        if isinstance(exc, SubModelError):
            raise exc
        if isinstance(exc, EndOfSimulation):  # named as in the system
            raise EndOfSimulation(self.system.names[k], exc.reason) from None
        raise SubModelError(self.system.names[k], t, f"{type(exc).__name__}: {exc}", h) from exc

    @property
    def max_step(self) -> float:
        return min((m.capabilities.max_step for m in self.system.models), default=math.inf)


def _stacked(rows: np.ndarray, row: np.ndarray) -> np.ndarray:
    """``np.vstack([rows, row])`` (the same C-ordered array) without its generality, which
    cost more than the copy on the few values a step stacks."""
    out = np.empty((rows.shape[0] + 1, rows.shape[1]))
    out[:-1] = rows
    out[-1] = row
    return out


def _iteration(system: CompiledSystem, options: MasterOptions) -> Iteration | None:
    """Strong coupling's iteration, or ``None`` for explicit coupling; ``ValueError`` if a
    sub-model cannot go back to the step's start."""
    if options.coupling == "explicit":
        return None
    unable = [n for n, m in zip(system.names, system.models) if not m.capabilities.can_save_state]
    if unable:
        raise ValueError(f"coupling '{options.coupling}' repeats every step from the saved "
                         f"states, but {', '.join(unable)} cannot save and restore its state")
    return Iteration(options.coupling, options.coupling_tol, options.max_iterations,
                     system.output_names)


class _LeanKernel:
    """What the two lean kernels share: counts kept locally and added to the master's at the
    end, failures named as :meth:`Master._guard` names them, and runs of steps.

    The held kernel times its sub-models' calls on one step in :data:`TIMED_EVERY` (the first
    of every run of steps, then every fourth), not on every one: two clock reads per call were
    a sixth of a cheap Python model's whole step. :meth:`sync` scales each model's sampled time
    by its calls over its timed calls, so ``time_in_models`` is an estimate there — unbiased
    for sub-models whose cost does not follow the step's number — and exact elsewhere.
    """

    master: Master
    names: list[str]
    calls: list[int]
    timed: list[int]  # calls timed (the sample :attr:`time` holds)
    time: list[float]
    done: int

    def step(self, t: float, h: float, n: int, flat: np.ndarray, base: int) -> None:
        raise NotImplementedError

    def steps(self, times: Sequence[float], h: float, n: int, flat: np.ndarray,
              base: int) -> None:
        """:meth:`step` from each of ``times`` in turn (rows ``n`` on); :attr:`done` counts the
        steps completed."""
        self.done = 0
        for i, t in enumerate(times):
            self.step(t, h, n + i, flat, base)
            self.done = i + 1

    def sync(self) -> None:
        """Add the counts so far to the master's (once, when the run ends), and the time
        spent in each model, scaled up from the calls timed."""
        spent = [s if timed == calls or timed == 0 else s * calls / timed
                 for s, calls, timed in zip(self.time, self.calls, self.timed)]
        self.master.calls += np.array(self.calls, dtype=np.int64)
        self.master.time_in_models += np.array(spent)
        self.calls = [0] * len(self.calls)
        self.timed = [0] * len(self.calls)
        self.time = [0.0] * len(self.time)

    def _c_step(self, k: int, t: float, h: float, raw: tuple, in_address: int,
                out_address: int, derivatives: tuple | None = None, token: int = 0,
                timed: bool = True) -> None:
        """One FMU's step through its raw C calls (``raw[:9]``: the instance, setReal and its
        value references, doStep, getReal and its, the error maker): inputs from
        ``in_address``, input derivatives first if given (``(setRealInputDerivatives, value
        references, count, orders, address, model)``), outputs to ``out_address``. Counted,
        timed (if ``timed``) and watched (under the watchdog's ``token``, handed out by the
        caller) as :meth:`Master._guard` would."""
        component, set_real, in_vr, n_in, do_step, get_real, out_vr, n_out, fail = raw[:9]
        self.calls[k] += 1
        watch = self.master._watch
        if watch is not None:  # Master._guard's stamp, inlined
            watch.running = token
        if timed:  # counted before the call: a call that fails is counted and timed as one
            start = time.perf_counter()
            self.timed[k] += 1
        status = set_real(component, in_vr, n_in, in_address)
        if status > 1:
            self._fail(k, t, h, fail("fmi2SetReal", status))
        if derivatives is not None:
            set_derivatives, deriv_vr, n_deriv, deriv_order, d_address, model = derivatives
            status = set_derivatives(component, deriv_vr, n_deriv, deriv_order, d_address)
            if status > 1:
                self._fail(k, t, h, fail("fmi2SetRealInputDerivatives", status))
            # as after set_input_derivatives (conservatively: "may be nonzero")
            model._derivatives_set, model._derivatives_stale = True, False
        status = do_step(component, t, h, 1)
        if status > 1:
            self._fail(k, t, h, fail("fmi2DoStep", status))
        if timed:
            self.time[k] += time.perf_counter() - start
        status = get_real(component, out_vr, n_out, out_address)
        if status > 1:
            self._fail(k, t, h, fail("fmi2GetReal", status))
        if watch is not None:
            watch.running = 0
            if watch.abandoned:
                raise _Abandoned

    def _fail(self, k: int, t: float, h: float, exc: BaseException) -> None:
        if self.master._watch is not None:
            self.master._watch.running = 0
        if isinstance(exc, SubModelError):
            raise exc
        if isinstance(exc, EndOfSimulation):
            raise EndOfSimulation(self.names[k], exc.reason) from None
        raise SubModelError(self.names[k], t, f"{type(exc).__name__}: {exc}", h) from exc


def _instant_outputs(system: CompiledSystem) -> tuple[np.ndarray, list[bool]]:
    """Which outputs a model computes from its inputs at the same instant (a feedthrough entry
    that names inputs), as a column mask, and which models have any."""
    mask = np.zeros(system.n_outputs, dtype=bool)
    models = []
    for m, columns in zip(system.models, system.output_slices):
        feedthrough = m.capabilities.feedthrough
        models.append(bool(feedthrough) and any(feedthrough.values()))
        if models[-1]:  # (most models have none: their ports need no look)
            mask[columns] = [bool(feedthrough.get(port.name)) for port in m.outputs]
    return mask, models


def jumped(new: np.ndarray, own: np.ndarray, start: np.ndarray) -> np.ndarray:
    """Which outputs read at a time event their sub-model declared are already on its far
    side: those that missed their own extrapolation ``own`` by more than the whole change it
    foresaw from ``start`` (a continuous output misses by the extrapolation's error, of higher
    order in the step than the change). The one rule of :meth:`Master._jumped` and
    :meth:`cosimstep.multirate.Multirate._left_of_jump`."""
    return np.abs(new - own) > np.abs(own - start)


def _declared_events(system: CompiledSystem) -> tuple[np.ndarray, list[tuple[int, ...]]]:
    """The distinct time events the models declare, sorted, and the models declaring each."""
    owners: dict[float, list[int]] = {}
    for k, model in enumerate(system.models):
        for e in model.time_events():
            owners.setdefault(float(e), []).append(k)
    times = sorted(owners)
    return np.array(times, dtype=float), [tuple(owners[e]) for e in times]


def _start_facts(system: CompiledSystem) -> tuple[bool, bool]:
    """For :meth:`Master._start_without_slopes`: whether every model can go back, and whether
    some model carries its inputs' path over a step into an output (one it computes, not one
    settled from its inputs at the step's end) — only then can re-running a start help."""
    restorable = all(m.capabilities.can_save_state for m in system.models)
    integrating = any(
        len(src) > 0 and any(p.name not in m.capabilities.feedthrough for p in m.outputs)
        for m, src in zip(system.models, system.src))
    return restorable, integrating


class _HeldKernel(_LeanKernel):
    """:meth:`Master.step` at extrapolation order 0 without feedthrough, for a row-major table.

    The values live in one preallocated table (one row per communication point). A step reads
    model ``k``'s inputs from row ``n`` (Jacobi, or Gauss–Seidel sources that step later) or row
    ``n + 1`` (Gauss–Seidel sources already stepped) through integer index arrays fixed once, and
    writes its outputs into row ``n + 1``. A sub-model that offers its raw C calls
    (``_direct_io``, an FMU) is called with addresses: the inputs' address is the source row's
    when its inputs are one contiguous run of columns passed on unchanged, otherwise a gathered
    copy; the outputs go straight into the table. Nothing is allocated per step for such a
    model. The calls, their order, the values, the counts and the errors are those of
    :meth:`Master.step` (compared in tests/orchestration/test_lean_fixed_step.py).
    """

    def __init__(self, master: Master) -> None:
        self.master = master
        system = master.system
        self.names = system.names
        m = system.n_outputs
        self.m = m
        rank = {k: i for i, k in enumerate(master.sequence)}
        gauss_seidel = master.options.name == "gauss-seidel"
        self.calls = [0] * len(system.models)  # added to the master's counts by :meth:`sync`
        self.timed = [0] * len(system.models)
        self.time = [0.0] * len(system.models)
        self.done = 0  # steps completed by the last call of :meth:`steps`
        self._flat: np.ndarray | None = None
        self._read_only = np.empty(0)
        # stands in for the watchdog when there is none: its stores cost less than the tests
        self._unwatched = _Watchdog(math.inf)
        self.plan = []
        # a row holding values no Python float passed through (an FMU's, a model's several)
        # is checked as a whole; the others' sum is checked as it is made
        self._whole_rows = False
        # built on Python ints: a system of thousands of models builds its plan once per run,
        # and NumPy's calls on arrays of one or two elements cost more than the lists'
        owner = system.owners
        for k in master.sequence:
            src = system.src[k].tolist()
            # 1 where model k reads a fresh value (a Gauss–Seidel source stepped before it)
            fresh = [int(rank[owner[j]] < rank[k]) for j in src] if gauss_seidel \
                else [0] * len(src)
            self.plan.append(self._entry(k, src, fresh))

    def _entry(self, k: int, src: list[int], fresh: list[int]) -> tuple:
        """Model ``k``'s entry of :attr:`plan`; ``src``: its inputs' columns, ``fresh``: 1
        for each input read from row ``n + 1``."""
        master, system, m = self.master, self.master.system, self.m
        model = system.models[k]
        out = system.output_slices[k]
        direct = getattr(model, "_direct_io", None)
        raw = direct() if direct is not None else None
        contiguous = bool(src) and (len(src) == 1
                                    or src == list(range(src[0], src[0] + len(src))))
        in_offset = None  # where the inputs start in the table from row n, when they are
        buffer = None     # one run of columns passed on unchanged (no gather needed)
        if contiguous and len(set(fresh)) == 1:
            in_offset = src[0] + m * fresh[0]
        if raw is not None:
            if in_offset is not None and master._identity[k]:
                in_offset *= 8  # a byte offset for the C call
            else:
                in_offset, buffer = None, np.zeros(len(src))
            raw = (*raw, 8 * out.start, buffer, buffer.ctypes.data if buffer is not None else 0)
        lo = hi = None  # the inputs' columns from row n's start, read as one slice
        if raw is None and in_offset is not None:
            lo, hi = in_offset, in_offset + len(src)
        gather = None  # flat indices of the inputs from row n, where not read as a block
        if in_offset is None:
            gather = np.array([j + m * f for j, f in zip(src, fresh)], dtype=int)
        single = raw is None and out.stop - out.start == 1
        self._whole_rows |= raw is not None or out.stop - out.start > 1
        return (k, model, raw, in_offset, lo, hi, gather, master._identity[k], system.a[k],
                system.b[k], m + out.start, m + out.stop, (out.stop - out.start,), single)

    def step(self, t: float, h: float, n: int, flat: np.ndarray, base: int) -> None:
        """Step every model from row ``n`` to row ``n + 1`` of the table.

        ``flat`` is the table as one flat array, ``base`` its address; a sub-model failure
        raises :class:`SubModelError` as :meth:`Master.step` does.
        """
        self.steps((t,), h, n, flat, base)

    def steps(self, times: Sequence[float], h: float, n: int, flat: np.ndarray,
              base: int) -> None:
        """Steps of ``h`` from each of ``times`` in turn, rows ``n`` to ``n + len(times)``.

        One call for a run of equal steps saves the loop's bookkeeping per step; :attr:`done`
        counts the steps completed, so a failure part-way keeps the rows before it.
        """
        m = self.m
        calls, timed_calls, spent, clock = self.calls, self.timed, self.time, time.perf_counter
        read_only, whole_rows = self._begin(flat), self._whole_rows
        watch = self.master._watch or self._unwatched
        tick = watch.tick  # the tokens from here on are placed by _locate
        watch.locate = functools.partial(self._locate, tuple(times), h, tick)
        try:
            for i, t in enumerate(times):
                self.done = i  # the steps before this one (read also after a hung call)
                row = (n + i) * m
                timed = not i % TIMED_EVERY  # the calls timed (see _LeanKernel)
                total = 0.0  # of the single outputs: not finite if one of them is not
                odd = False  # a single output that was no float: the row is checked whole
                for k, model, raw, in_offset, lo, hi, gather, identity, a, b, o0, o1, shape, \
                        single in self.plan:
                    tick += 1
                    if raw is not None:
                        self._fmu_step(k, t, h, row, flat, base, raw, in_offset, gather,
                                       identity, a, b, tick, timed)
                        continue
                    # one block of columns: a read-only view (no copy, and the stored values
                    # cannot be altered through it); else gathered
                    x = read_only[row + lo:row + hi] if lo is not None else flat[gather + row]
                    u = x if identity else a * x + b
                    calls[k] += 1
                    watch.running = tick  # one token for the model's three calls
                    if timed:  # counted before the call, as in _c_step
                        start = clock()
                        timed_calls[k] += 1
                    try:
                        model.set_inputs(u)
                        model.do_step(t, h)
                        y = model.get_outputs()
                    except (Exception, SystemExit) as exc:
                        self._fail(k, t, h, exc)
                    if timed:
                        spent[k] += clock() - start
                    watch.running = 0
                    if watch.abandoned:
                        raise _Abandoned
                    if type(y) is not np.ndarray or y.shape != shape:
                        y = self.master._checked_outputs(k, t, h, y)
                    if single:  # a float stored as an item: a third of a slice's assignment
                        value = y.item()
                        if type(value) is float:
                            flat[row + o0] = value
                            total += value
                            continue
                        odd = True  # (an int, a long double, a complex …: stored as before)
                    flat[row + o0:row + o1] = y
                # NaN or inf somewhere (or a sum that overflowed: then nothing is found)
                if total - total != 0.0 or ((whole_rows or odd) and not math.isfinite(
                        sum(flat[row + m:row + 2 * m].tolist()))):
                    self.master._check_finite(range(len(self.plan)), t,
                                              flat[row + m:row + 2 * m], h)
        finally:
            watch.tick = tick
        self.done = len(times)

    def _begin(self, flat: np.ndarray) -> np.ndarray:
        """A read-only view of ``flat``, for the Python sub-models' inputs (made once)."""
        if flat is not self._flat:
            self._flat, self._read_only = flat, flat.view()
            self._read_only.flags.writeable = False
        return self._read_only

    def _locate(self, times: tuple[float, ...], h: float, first: int,
                token: int) -> tuple[int, float, float]:
        """The model, time and step of the call given ``token`` in a run of :meth:`steps`
        (the tokens after ``first``, one per model of the plan and step)."""
        i, j = divmod(token - first - 1, len(self.plan))
        return self.plan[j][0], times[i], h

    def _fmu_step(self, k: int, t: float, h: float, row: int, flat: np.ndarray, base: int,
                  raw: tuple, in_offset: int | None, gather: np.ndarray, identity: bool,
                  a: np.ndarray, b: np.ndarray, token: int, timed: bool) -> None:
        """One FMU's step through its raw C calls, inputs from row ``row`` (a flat index),
        outputs straight into the next row."""
        out_offset, buffer, buffer_address = raw[9:]
        if in_offset is not None:
            address = base + 8 * row + in_offset
        else:
            x = flat[gather + row]
            buffer[:] = x if identity else a * x + b
            address = buffer_address
        self._c_step(k, t, h, raw, address, base + 8 * (row + self.m) + out_offset,
                     token=token, timed=timed)


class _ExtrapolatingKernel(_LeanKernel):
    """:meth:`Master.step` at extrapolation order ``p`` = 1 or 2 on uniform steps, without
    feedthrough, for a row-major table.

    Under those conditions :meth:`Master.step` gives a model without input derivatives the
    value at ``t + h/2`` of a polynomial through the last ``p + 1`` stored rows (Jacobi, and
    Gauss–Seidel sources that step later) or through the last ``p`` rows and the new one
    (Gauss–Seidel sources already stepped). With equal steps that value is a fixed weighted sum
    of those rows (:func:`~cosimstep.extrapolation.midstep_weights`), so the step needs no Taylor
    coefficients: the weights and the routing are fixed once here. A model reading one
    contiguous run of columns with one kind of source takes a dot product of the weights with
    that block of the table; otherwise its inputs are gathered by integer index arrays.

    A model that takes input derivatives (order ``r > 0``) gets, as from :meth:`Master.step`,
    the polynomial's value at ``t`` — row ``n`` itself, whichever the polynomial — and its
    derivatives ``1 … q`` at ``t`` (``q = min(r, p)``; the ``k``-th derivative, not the Taylor
    coefficient), times the connections' gains. With equal steps derivative ``k`` is again a
    fixed weighted sum of the same rows, the weights of unit spacing
    (:func:`~cosimstep.extrapolation.step_derivative_weights`) divided by ``h**k`` (redone
    when ``h`` changes). An FMU offering its raw calls gets them through
    ``fmi2SetRealInputDerivatives`` on its own derivative buffer: the kernel sends them before
    every step, as the general step does through ``set_input_derivatives``.

    The caller uses it only where :meth:`Master.step` would see ``p + 1`` equally spaced points:
    from the ``p``-th step of a segment (the general step does the first ``p``, where the order
    drops and grey-box slopes may enter), and for steps as long as the ones before. The calls,
    their order, the counts, the stored rows and the errors are those of :meth:`Master.step`;
    the values agree to rounding (the sums are taken in another order, and the general step
    takes the spacing from the stored times; tests/orchestration/test_lean_fixed_step.py and
    tests/fmu/test_lean_fixed_step.py measure the difference).
    """

    def __init__(self, master: Master) -> None:
        self.master = master
        system = master.system
        self.names = system.names
        self.order = p = master.options.extrapolation
        m = self.m = system.n_outputs
        owner = system.owners
        rank = {k: i for i, k in enumerate(master.sequence)}
        gauss_seidel = master.options.name == "gauss-seidel"
        weights = (np.array(midstep_weights(p, False)), np.array(midstep_weights(p, True)))
        # derivatives 1..p at t for unit spacing, per kind of source: (p, p + 1)
        unit = (np.array(step_derivative_weights(p, False)),
                np.array(step_derivative_weights(p, True)))
        self.calls = [0] * len(system.models)  # added to the master's counts by :meth:`sync`
        self.timed = [0] * len(system.models)
        self.time = [0.0] * len(system.models)
        self._flat: np.ndarray | None = None  # the table as given, and as rows
        self._rows = np.empty((0, m))
        self._h: float | None = None  # the step the derivative weights are scaled for
        self._scaled: list[tuple[np.ndarray, np.ndarray]] = []  # (unit weights, scaled ones)
        self.done = 0  # steps completed by the last call of :meth:`steps`
        self.plan = []
        # a row holding values no Python float passed through (an FMU's, a model's several)
        # is checked as a whole; the others' sum is checked as it is made
        self._whole_rows = False
        for k in master.sequence:
            model = system.models[k]
            src = np.asarray(system.src[k], dtype=int)
            fresh = np.array([gauss_seidel and rank[owner[j]] < rank[k] for j in src], dtype=int)
            # input j uses rows n - p + fresh_j ... n + fresh_j: flat indices relative to row n
            gather = (np.arange(-p, 1)[:, None] + fresh[None, :]) * m + src[None, :]
            contiguous = src.size > 0 and np.array_equal(src, np.arange(src[0],
                                                                        src[0] + src.size))
            one_kind = contiguous and len(set(fresh.tolist())) == 1
            q = min(master._deriv_order[k], p)
            block = None  # (first row offset, end row offset, first column, end column, weights)
            deriv = None
            if q == 0:
                w = np.where(fresh[None, :] == 1, weights[1][:, None], weights[0][:, None])
                if one_kind:
                    f = int(fresh[0])
                    block = (f - p, f + 1, int(src[0]), int(src[0]) + src.size, weights[f])
            else:
                w = None
                if one_kind:
                    f = int(fresh[0])
                    wd_unit = unit[f][:q]
                    block = (f - p, f + 1, int(src[0]), int(src[0]) + src.size, None)
                else:  # per input: (q, p + 1, inputs)
                    wd_unit = np.where(fresh[None, None, :] == 1, unit[1][:q, :, None],
                                       unit[0][:q, :, None])
                wd = wd_unit.copy()
                self._scaled.append((wd_unit, wd))
                deriv = (q, wd, src, np.zeros((q, src.size)))
            raw = None
            direct = getattr(model, "_direct_io", None)
            if direct is not None:
                raw = direct(derivatives=True) if q else direct()
            buffer = np.zeros(src.size)
            if raw is not None:
                out = system.output_slices[k]
                raw = (*raw, 8 * out.start, buffer.ctypes.data)
                if q:
                    # the inputs straight from row n when passed on unchanged in one block
                    direct_in = master._identity[k] and contiguous
                    raw = (*raw, 8 * int(src[0]) if direct_in else None)
            self.plan.append((k, model, raw, block, gather, w, deriv, master._identity[k],
                              system.a[k], system.b[k], system.output_slices[k], buffer))

    def _scale(self, h: float) -> None:
        """Derivative weights for steps of ``h``: derivative ``k`` scales like ``h**-k``."""
        for wd_unit, wd in self._scaled:
            for i in range(wd.shape[0]):
                wd[i] = wd_unit[i] / h ** (i + 1)
        self._h = h

    def step(self, t: float, h: float, n: int, flat: np.ndarray, base: int) -> None:
        """Step every model from row ``n`` to row ``n + 1`` of the table (``n >= p``, rows
        ``n - p`` to ``n`` one step ``h`` apart).

        ``flat`` is the table as one flat array, ``base`` its address; a sub-model failure
        raises :class:`SubModelError` as :meth:`Master.step` does.
        """
        m = self.m
        row = n * m
        if flat is not self._flat:
            self._flat, self._rows = flat, flat.reshape(-1, m)
        if h != self._h:
            self._scale(h)
        rows, dot = self._rows, np.dot
        for k, model, raw, block, gather, w, deriv, identity, a, b, out, buffer in self.plan:
            if deriv is not None:
                _, wd, _, d = deriv
                # derivatives 1..q at t: fixed weights (scaled for h) of the rows, times gains
                if block is not None:
                    r0, r1, c0, c1, _ = block
                    dot(wd, rows[n + r0:n + r1, c0:c1], out=d)
                else:
                    np.sum(wd * flat[gather + row], axis=1, out=d)
                if not identity:
                    d *= a
            if raw is not None:
                self._fmu_step(k, t, h, n, flat, base, raw, block, gather, w, deriv, identity,
                               a, b, buffer, model)
            else:
                self._python_step(k, t, h, n, flat, model, block, gather, w, deriv, identity,
                                  a, b, out)
        new = flat[row + m:row + 2 * m]
        if not math.isfinite(sum(new.tolist())):  # NaN or inf somewhere (or a sum overflow)
            self.master._check_finite(range(len(self.plan)), t, new, h)

    def _fmu_step(self, k: int, t: float, h: float, n: int, flat: np.ndarray, base: int,
                  raw: tuple, block: Any, gather: Any, w: Any, deriv: Any, identity: bool,
                  a: Any, b: Any, buffer: np.ndarray, model: Any) -> None:
        """One FMU's step through its C functions: inputs (and derivatives) from the table's
        rows, outputs straight into row ``n + 1``."""
        m, row = self.m, n * self.m
        rows, dot = self._rows, np.dot
        derivatives = None
        if deriv is None:
            out_offset, buffer_address = raw[9:]
            if block is not None:
                r0, r1, c0, c1, wb = block
                dot(wb, rows[n + r0:n + r1, c0:c1], out=buffer)
                if not identity:
                    buffer[:] = a * buffer + b
            else:
                x = (w * flat[gather + row]).sum(axis=0)
                buffer[:] = x if identity else a * x + b
        else:
            (set_derivatives, deriv_vr, n_deriv, deriv_order, d_model, d_address,
             out_offset, buffer_address, in_offset) = raw[9:]
            q, _, src, d = deriv
            if in_offset is None:
                x = flat[src + row]
                buffer[:] = x if identity else a * x + b
            else:
                buffer_address = base + 8 * row + in_offset  # row n, unchanged
            d_model[:q] = d
            d_model[q:] = 0.0
            derivatives = (set_derivatives, deriv_vr, n_deriv, deriv_order, d_address, model)
        watch = self.master._watch
        self._c_step(k, t, h, raw, buffer_address, base + 8 * (row + m) + out_offset,
                     derivatives, 0 if watch is None else watch.stamp(k, t, h))

    def _python_step(self, k: int, t: float, h: float, n: int, flat: np.ndarray, model: Any,
                     block: Any, gather: Any, w: Any, deriv: Any, identity: bool, a: Any,
                     b: Any, out: slice) -> None:
        """One Python sub-model's step: its calls under one guard (errors named, time-outs)."""
        m, row = self.m, n * self.m
        rows, dot = self._rows, np.dot
        calls, spent, clock = self.calls, self.time, time.perf_counter
        master = self.master
        if deriv is not None:
            x = flat[deriv[2] + row]  # the value at t: row n
        elif block is not None:
            r0, r1, c0, c1, wb = block
            x = dot(wb, rows[n + r0:n + r1, c0:c1])
        else:
            x = (w * flat[gather + row]).sum(axis=0)
        u = x if identity else a * x + b
        calls[k] += 1
        self.timed[k] += 1
        watch = master._watch
        if watch is not None:  # one stamp for the model's calls
            watch.stamp(k, t, h)
        start = clock()
        try:
            model.set_inputs(u)
            if deriv is not None:
                model.set_input_derivatives(deriv[3].copy())
            model.do_step(t, h)
            y = model.get_outputs()
        except (Exception, SystemExit) as exc:
            self._fail(k, t, h, exc)
        spent[k] += clock() - start
        if watch is not None:
            watch.running = 0
            if watch.abandoned:
                raise _Abandoned
        if type(y) is not np.ndarray or y.shape != (out.stop - out.start,):
            y = master._checked_outputs(k, t, h, y)
        flat[row + m + out.start:row + m + out.stop] = y


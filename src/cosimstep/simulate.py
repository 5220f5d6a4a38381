"""Orchestration: the loop that advances a coupled system in time.

The loop asks the controller for an attempt at each step, lands steps on the sub-models' time
events and the end time, records every attempt and every accepted point in the store, and turns
sub-model failures, step-size failures and Ctrl-C into a result with a status and the values
computed so far — never into a lost run.
"""

from __future__ import annotations

import bisect
import contextlib
import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from cosimstep.controllers import Controller, Fixed
from cosimstep.controllers.base import Attempt
from cosimstep.errors import StepSizeError, SubModelError
from cosimstep.masters import Master, MasterOptions, _Watchdog
from cosimstep.reference import ErrorReport, Reference, error_report
from cosimstep.store import Store
from cosimstep.system import System

HISTORY_ROWS = 4  # stored points handed to controllers/masters for extrapolation
FAILED_TRIAL_SHRINK = 0.25  # step factor after a trial step a sub-model failed on


@dataclass
class ModelStats:
    """One sub-model's share of a run (for multi-rate runs each has its own steps)."""

    calls: int
    accepted: int
    rejected: int
    corrections: int  # multi-rate: steps re-run after a failed verification of extrapolated input
    step_sizes: np.ndarray = field(repr=False)
    times: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    """The sub-model's own communication points (multi-rate: its own steps; synchronous: the
    common grid)."""
    values: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)), repr=False)
    """Its outputs there, as it computed them (one column per output, in declaration order)."""
    replaced: int = 0
    """Multi-rate: accepted steps later dropped by a rollback or re-run in several pieces, net
    (the attempts log holds ``accepted + replaced`` accepted attempts)."""

    def to_dict(self) -> dict[str, Any]:
        s = self.step_sizes
        return {"calls": self.calls, "accepted": self.accepted, "rejected": self.rejected,
                "corrections": self.corrections,
                "h_min": float(s.min()) if s.size else None,
                "h_max": float(s.max()) if s.size else None}


@dataclass
class SimulationResult:
    """What a run produced. ``status`` is ``"ok"``, ``"failed"`` or ``"interrupted"``."""

    status: str
    message: str
    t_end: float
    names: list[str]
    units: list[str]
    times: np.ndarray
    values: np.ndarray
    calls: dict[str, int]
    steps_accepted: int
    steps_rejected: int
    step_sizes: np.ndarray
    wall_s: float
    time_in_models: dict[str, float]
    store: str | None = None
    error: ErrorReport | None = None
    reference: np.ndarray | None = field(default=None, repr=False)
    models: dict[str, ModelStats] = field(default_factory=dict)
    error_estimate: float | None = None
    """The global error the run estimates it delivered, without a reference, in the norm
    ``tol`` bounds (``max |e| / (1 + |y|)`` for the default ``atol = rtol = tol``); ``None``
    for controllers without error control. Compare with ``error.max_scaled``."""
    estimate_calls: int = 0
    """Calls the estimate cost (the looser run of ``estimate="rerun"``), not in ``calls``."""

    @property
    def success(self) -> bool:
        return self.status == "ok"

    @property
    def calls_total(self) -> int:
        return int(sum(self.calls.values()))

    def __getitem__(self, name: str) -> np.ndarray:
        """Trajectory of an exchanged output, e.g. ``result["bar1.theta"]``."""
        try:
            return self.values[:, self.names.index(name)]
        except ValueError:
            raise KeyError(f"no output '{name}'; outputs: {', '.join(self.names)}") from None

    def summary(self) -> dict[str, Any]:
        """The JSON summary the CLI prints with ``--json``."""
        steps = self.step_sizes
        out: dict[str, Any] = {
            "status": self.status,
            "message": self.message,
            "t_end": self.t_end,
            "calls": dict(self.calls),
            "calls_total": self.calls_total,
            "steps_accepted": self.steps_accepted,
            "steps_rejected": self.steps_rejected,
            "h_min": float(steps.min()) if steps.size else None,
            "h_max": float(steps.max()) if steps.size else None,
            "wall_s": self.wall_s,
            "master_overhead_s": max(self.wall_s - sum(self.time_in_models.values()), 0.0),
            "store": self.store,
        }
        out["error_estimate"] = self.error_estimate
        out["error_estimate_calls"] = self.estimate_calls
        if self.error is not None:
            out["error"] = self.error.to_dict()
        out["models"] = {n: m.to_dict() for n, m in self.models.items()}
        return out

    def to_pandas(self):
        import pandas as pd

        return pd.DataFrame(self.values, index=pd.Index(self.times, name="t"), columns=self.names)


class _Context:
    """The :class:`~cosimstep.controllers.StepContext` the loop hands to controllers."""

    def __init__(self, master: Master) -> None:
        self.master = master
        self.all_times: list[float] = []
        self.rows: list[np.ndarray] = []
        self.times: list[float] = []  # the points extrapolation may use (rows of ``history``)
        self.history = np.empty((0, 0))
        self.order = master.options.extrapolation
        self.names = master.system.output_names
        self.predicted = master.predicted
        self.consumed = master.consumed
        self.held = master.held
        self._segment = 0  # index of the first point after the last time event
        self.first_token: Any = None  # the first state saved during the current attempt

    def push(self, t: float, y: np.ndarray) -> None:
        self.all_times.append(t)
        self.rows.append(y)
        first = max(self._segment, len(self.rows) - HISTORY_ROWS)
        self.history = np.array(self.rows[first:])
        self.times = self.all_times[first:]

    def restart(self) -> None:
        """A time event at the last point: extrapolate only from points at or after it."""
        self._segment = len(self.rows) - 1
        self.history = np.array(self.rows[self._segment:])
        self.times = self.all_times[self._segment:]
        self.master.restart()

    def step(self, t: float, h: float, *, order: int | None = None,
             end: np.ndarray | None = None,
             extra: tuple[tuple[float, np.ndarray], ...] = ()) -> np.ndarray:
        times, history = self.times, self.history
        if extra:
            times = [*times, *(e[0] for e in extra)]
            history = np.vstack([history, *(e[1] for e in extra)])[-HISTORY_ROWS:]
        return self.master.step(t, h, times, history, order=order, end=end)

    def defect(self) -> tuple[np.ndarray, np.ndarray]:
        y = self.master.last
        return y - self.master.assumed, self.master.predicted

    def derivatives(self) -> np.ndarray | None:
        return self.master.derivatives()

    def save(self) -> Any:
        token = self.master.save()
        if self.first_token is None:
            self.first_token = token
        return token

    def restore(self, token: Any) -> None:
        self.master.restore(token)


class _ControllerLoop:
    """The time loop for any controller: attempts, rejections, the step context."""

    def __init__(self, runner: Master, controller: Controller, t0: float, until: float,
                 events: list[float], sink: Store | None, bar: Any) -> None:
        self.runner, self.controller = runner, controller
        self.t0, self.until, self.events = t0, until, events
        self.sink, self.bar = sink, bar
        self.ctx = _Context(runner)
        self.t = t0
        self.steps: list[float] = []
        self.rejected = 0
        self.failed_trials = 0  # rejected because a sub-model failed on the trial step

    def run(self) -> None:
        runner, controller, ctx, sink, bar = (self.runner, self.controller, self.ctx,
                                              self.sink, self.bar)
        until, events, steps = self.until, self.events, self.steps
        t = self.t0
        clock = _Clock(t)
        y0 = runner.initialize(t)
        ctx.push(t, y0)
        if sink is not None:
            sink.add_point(0, t, y0)
        h = controller.initial_step(t, until)
        hmax_models = runner.max_step
        while t < until:
            landing = _next_landing(events, t, until)
            h = min(h, hmax_models)
            if h >= (landing - t) * (1 - 1e-9) or (landing - t) - h < 1e-6 * h:
                h = landing - t  # land exactly on the event / end time
            ctx.first_token = None
            try:
                attempt = controller.attempt(ctx, t, h)
            except SubModelError as exc:
                attempt = self._failed_trial(exc, t, h)
            if sink is not None:
                sink.add_attempt(None, t, h, attempt.accepted, attempt.error)
            if attempt.accepted:
                clock.add(h)
                t = landing if abs(clock.value - landing) <= 1e-9 * h else clock.value
                self.t = t
                if t == landing and t < until:
                    controller.event(t)
                ctx.push(t, attempt.y)
                if t == landing and t < until:
                    ctx.restart()
                steps.append(h)
                if sink is not None:
                    sink.add_point(len(steps), t, attempt.y)
                if bar is not None:
                    bar.update(h)
            else:
                self.rejected += 1
            h = attempt.h_next

    def _failed_trial(self, exc: SubModelError, t: float, h: float) -> Attempt:
        """A trial step a sub-model could not take (it raised, or returned NaN or inf) is a
        rejected step: the sub-models go back to ``t`` and the step is retried at a quarter of
        its length (the factor SUNDIALS' integrators apply after a failed nonlinear solve).

        An adaptive controller proposes steps the sub-models have never seen; extrapolated
        inputs over a long step can leave a sub-model's domain (a singularity, a solver that
        gives up) although the true inputs never do. Only a failure that persists down to the
        controller's ``hmin``, a call that hung (its thread may still hold the model), or a
        controller that cannot roll back ends the run.
        """
        policy = getattr(self.controller, "policy", None)
        token = self.ctx.first_token
        if exc.hung or token is None or policy is None:
            raise exc
        h_next = FAILED_TRIAL_SHRINK * h
        if h_next < policy.hmin:
            raise SubModelError(exc.model, exc.t, f"{exc.reason} (still after retrying with "
                                f"steps down to {h:.3g} s; hmin = {policy.hmin:.3g} s)",
                                exc.h) from exc
        self.ctx.restore(token)
        self.failed_trials += 1
        return Attempt(np.empty(0), False, h_next, math.inf)

    def finish(self) -> None:
        """Nothing to hand on: every point went to the store as it was accepted."""

    def results(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        ctx = self.ctx
        values = np.array(ctx.rows) if ctx.rows else np.empty((0, self.runner.system.n_outputs))
        return np.array(ctx.all_times), values, np.array(self.steps)


class _FixedLoop:
    """The fixed-step time loop without per-step objects: the same run as
    :class:`_ControllerLoop` with :class:`~cosimstep.controllers.Fixed` (same calls, values,
    counts, stored rows and errors; tests/orchestration/test_lean_fixed_step.py).

    Points go into a preallocated table (grown in chunks if time events add steps), the clock's
    compensated sum is inlined, and the store and the progress bar receive the new steps in
    batches: at most :attr:`BATCH` steps, and as many as took about :attr:`PUBLISH_SECONDS`
    when steps are slow, so rows still reach the store's commit (every 0.5 s) while a run of
    slow sub-models goes on — what a crash keeps — without a clock read per step. With inputs
    held and no feedthrough, :class:`~cosimstep.masters._HeldKernel` does the master's step;
    with inputs extrapolated (order 1 or 2) and no feedthrough (input derivatives or not),
    :class:`~cosimstep.masters._ExtrapolatingKernel` does the steps after the first ``order``
    of each segment that are as long as the ones before (values equal to rounding);
    otherwise :meth:`Master.step` is called with the history the controller loop would pass.
    """

    BATCH = 256  # at most this many steps between store writes and progress updates
    PUBLISH_SECONDS = 0.1  # batch size: the steps that took about this long

    def __init__(self, runner: Master, step: float, t0: float, until: float,
                 events: list[float], sink: Store | None, bar: Any) -> None:
        self.runner, self.h_step = runner, step
        self.t0, self.until, self.events = t0, until, events
        self.sink, self.bar = sink, bar
        self.t = t0
        self.n = -1  # index of the newest point in the table
        self.rejected = 0
        m = runner.system.n_outputs
        # room for the whole run if it is small, else grown by doubling (at most ~32 MB first)
        rows = int(min((until - t0) / step, max(1024, 4_000_000 // max(m, 1)))) \
            + len(events) + 2
        self.times = np.empty(rows)
        self.table = np.empty((rows, m))
        self.hs = np.empty(rows)
        self.kernel = None
        self._stored = 0  # points handed to the store so far
        self._shown = 0  # steps shown on the progress bar so far
        self._published = (0, time.perf_counter())  # (n, time) of the last publication

    def _grow(self) -> None:
        rows = 2 * self.times.shape[0]
        for name in ("times", "table", "hs"):
            old = getattr(self, name)
            new = np.empty((rows, *old.shape[1:]))
            new[:old.shape[0]] = old
            setattr(self, name, new)

    def run(self) -> None:
        runner = self.runner
        until, events, h_step = self.until, self.events, self.h_step
        t = self.t0
        y0 = runner.initialize(t)
        self.times[0], self.table[0], self.n = t, y0, 0
        kernel = self.kernel = runner.held_kernel() or runner.extrapolating_kernel()
        # An extrapolating kernel needs `order` equal steps before the step in its segment: the
        # general step does the first `order` steps of each segment (where it lowers the order
        # and may use grey-box slopes). Within a segment every step is h_plain except the one
        # landing on the event or end time, so "h == h_plain" after them means equal spacing.
        lean_after = getattr(kernel, "order", 0)
        hmax_models = runner.max_step
        clock, carry = t, 0.0  # _Clock, inlined
        segment = 0  # first point extrapolation may use (the last time event's)
        n = 0
        table = self.table
        flat, base = table.reshape(-1), table.ctypes.data
        h_plain = min(h_step, hmax_models)
        landing = until
        self._published = (0, time.perf_counter())
        due = 1  # the next step to publish after (then as _publish says)
        while t < until:
            if events:  # without events the landing is always the end time
                landing = _next_landing(events, t, until)
            h = h_plain
            if h >= (landing - t) * (1 - 1e-9) or (landing - t) - h < 1e-6 * h:
                h = landing - t  # land exactly on the event / end time
            if n + 1 == table.shape[0]:
                self._grow()
                table = self.table
                flat, base = table.reshape(-1), table.ctypes.data
            if kernel is not None and (not lean_after or (n - segment >= lean_after
                                                          and h == h_plain)):
                kernel.step(t, h, n, flat, base)
            else:
                first = max(segment, n + 1 - HISTORY_ROWS)
                table[n + 1] = runner.step(t, h, self.times[first:n + 1].tolist(),
                                           table[first:n + 1].copy())
            s = clock + h
            if abs(clock) >= abs(h):
                carry += (clock - s) + h
            else:
                carry += (h - s) + clock
            clock = s
            value = clock + carry
            t = landing if abs(value - landing) <= 1e-9 * h else value
            n += 1
            self.times[n], self.hs[n - 1] = t, h
            self.n, self.t = n, t
            if t == landing and t < until:
                segment = n
                runner.restart()
            if n == due:
                due = n + self._publish()

    def _publish(self) -> int:
        """Hand the points not yet stored to the store, and the steps to the progress bar;
        return how many steps to run until the next publication."""
        n = self.n
        if self.sink is not None and n >= self._stored:
            first = self._stored
            self.sink.add_points(first, self.times[first:n + 1].tolist(),
                                 self.table[first:n + 1].tolist())
            if first == 0:
                first = 1
            self.sink.add_accepted_attempts(self.times[first - 1:n].tolist(),
                                            self.hs[first - 1:n].tolist())
            self._stored = n + 1
        if self.bar is not None and n > self._shown:
            self.bar.update(float(np.sum(self.hs[self._shown:n])))
            self._shown = n
        last_n, last_time = self._published
        now = time.perf_counter()
        self._published = (n, now)
        per_step = (now - last_time) / max(n - last_n, 1)
        return max(1, min(self.BATCH, int(self.PUBLISH_SECONDS / per_step))) if per_step > 0 \
            else self.BATCH

    def finish(self) -> None:
        if self.kernel is not None:
            self.kernel.sync()
            self.kernel = None
        self.runner._watch = None
        self._publish()

    def results(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        n = self.n
        return (self.times[:n + 1].copy(), self.table[:n + 1].copy(), self.hs[:max(n, 0)].copy())


class _Clock:
    """Compensated (Neumaier) sum of the steps: 10^4 steps of 0.001 end at 10.0, not 10 - 1e-12."""

    def __init__(self, t0: float) -> None:
        self._sum, self._carry = t0, 0.0

    def add(self, h: float) -> None:
        s = self._sum + h
        if abs(self._sum) >= abs(h):
            self._carry += (self._sum - s) + h
        else:
            self._carry += (h - s) + self._sum
        self._sum = s

    @property
    def value(self) -> float:
        return self._sum + self._carry


def _next_landing(events: list[float], t: float, t_end: float) -> float:
    i = bisect.bisect_right(events, t + 1e-12 * max(1.0, abs(t)))
    return min(events[i], t_end) if i < len(events) else t_end


def simulate(
    system: System,
    until: float,
    controller: Controller,
    master: MasterOptions | None = None,
    *,
    t0: float = 0.0,
    reference: Reference | None = None,
    store: str | Path | None = None,
    name: str = "system",
    config: dict[str, Any] | None = None,
    progress: bool | None = False,
    raise_on_failure: bool = False,
    estimate: str = "sum",
) -> SimulationResult:
    """Co-simulate ``system`` from ``t0`` to ``until``.

    Parameters
    ----------
    system:
        The coupled system (validated here; configuration problems raise
        :class:`~cosimstep.errors.ConfigurationError`).
    controller:
        Decides the communication steps, e.g. ``Fixed(0.001)``.
    master:
        Coupling scheme and input extrapolation (default: Jacobi, quadratic extrapolation).
    reference:
        Monolithic reference; when given the result carries the error against it.
    store:
        SQLite file to write (appended to if it exists); ``None`` keeps results in memory only.
    progress:
        Show a progress bar on stderr (``None``: only when stderr is a terminal); it appears only
        after two seconds, so short runs stay quiet.
    raise_on_failure:
        Raise the failure instead of returning a result with ``status = "failed"``.
    estimate:
        How an adaptive run estimates the global error it delivered
        (``SimulationResult.error_estimate``), without a reference: ``"sum"`` (free) adds up
        the controller's local estimates, as if no error decayed; ``"rerun"`` runs the system
        again at 10× the tolerance first and takes a ninth of the difference
        (:mod:`cosimstep.estimate`; about 50 % more calls, counted in
        ``estimate_calls``), which also sees errors that decay, cancel or grow.
    """
    if estimate not in ("sum", "rerun"):
        raise ValueError(f"`estimate` must be 'sum' or 'rerun', got {estimate!r}")
    looser = None
    if estimate == "rerun":
        policy = getattr(controller, "policy", None)
        if policy is None:
            raise ValueError(f"estimate='rerun' needs an error-controlled controller; "
                             f"'{controller.name}' has no tolerance")
        looser = _simulate(system, until, _loosened(controller), master, t0, None, None, name,
                           None, False, False, None)
    return _simulate(system, until, controller, master, t0, reference, store, name, config,
                     progress, raise_on_failure, looser)


def _loosened(controller: Controller) -> Controller:
    """A fresh copy of ``controller`` at :data:`~cosimstep.estimate.FACTOR` × its tolerance."""
    import copy

    from cosimstep.estimate import FACTOR

    twin = copy.deepcopy(controller)
    policy = twin.policy  # type: ignore[attr-defined]
    policy.tol *= FACTOR
    policy.atol = None if policy.atol is None else policy.atol * FACTOR
    policy.rtol = None if policy.rtol is None else policy.rtol * FACTOR
    return twin


def _simulate(system: System, until: float, controller: Controller,
              master: MasterOptions | None, t0: float, reference: Reference | None,
              store: str | Path | None, name: str, config: dict[str, Any] | None,
              progress: bool | None, raise_on_failure: bool,
              looser: SimulationResult | None) -> SimulationResult:
    """:func:`simulate` once; ``looser`` is the run at 10× the tolerance for ``"rerun"``."""
    if not (math.isfinite(until) and until > t0):
        raise ValueError(f"`until` ({until}) must be finite and after t0 ({t0})")
    master = master or MasterOptions()
    compiled = system.compile()
    if controller.needs_rollback:
        unable = [n for n, m in zip(compiled.names, compiled.models)
                  if not m.capabilities.can_save_state]
        if unable:
            raise ValueError(f"controller '{controller.name}' rejects and re-runs steps, but "
                             f"{', '.join(unable)} cannot save/restore state; choose a "
                             "controller without rollback (e.g. fixed)")
    events = sorted({float(e) for m in compiled.models for e in m.time_events() if t0 < e < until})
    if master.name == "multirate":
        return _simulate_multirate(compiled, until, controller, master, t0=t0,
                                   reference=reference, store=store, name=name, config=config,
                                   progress=progress, raise_on_failure=raise_on_failure,
                                   events=events, looser=looser)
    runner = Master(compiled, master)
    sink = Store(store) if store is not None else None
    settings = {"t0": t0, "until": until, "master": vars(master),
                "controller": controller.describe(), **(config or {})}
    if sink is not None:
        sink.begin(name, settings, compiled.output_names,
                   compiled.output_units)
    status, message = "ok", "completed"
    wall0 = time.perf_counter()
    bar = _progress(progress, t0, until)
    failure: BaseException | None = None
    # The fixed step needs no controller, context or attempt per step: a lean loop gives the
    # same run (a subclass of Fixed may change attempt(), so only Fixed itself qualifies).
    loop: _FixedLoop | _ControllerLoop
    if type(controller) is Fixed:
        loop = _FixedLoop(runner, controller.step, t0, until, events, sink, bar)
    else:
        loop = _ControllerLoop(runner, controller, t0, until, events, sink, bar)
    try:
        if isinstance(loop, _FixedLoop) and master.call_timeout:
            runner._watch = _Watchdog(master.call_timeout)
            runner._watch.run(loop.run, compiled.names)
        else:
            loop.run()
    except SubModelError as exc:
        status, message, failure = "failed", str(exc), exc
    except StepSizeError as exc:
        status, message, failure = "failed", f"at t = {loop.t:.9g}: {exc}", exc
    except Exception as exc:
        status, message, failure = \
            "failed", f"at t = {loop.t:.9g}: {type(exc).__name__}: {exc}", exc
    except KeyboardInterrupt as exc:
        status, message, failure = \
            "interrupted", f"interrupted by the user at t = {loop.t:.9g}", exc
    finally:
        try:
            loop.finish()  # hands the last rows to the store, which may fail (disk full)
        finally:
            if bar is not None:
                bar.close()
            runner.terminate()  # frees FMU instances and their unpacked folders in any case
    wall = time.perf_counter() - wall0
    t = loop.t
    times, values, steps = loop.results()
    rejected = loop.rejected
    err, ref_values = None, None
    if reference is not None and len(times) > 1:
        names = [n for n in compiled.output_names if n in reference.mapping]
        cols = [compiled.output_names.index(n) for n in names]
        reference.solve(t0, float(t))  # only as far as the run got
        ref_values = reference.values(times, names)
        err = error_report(times, values[:, cols], ref_values, names)
        if sink is not None:
            sink.add_reference(ref_values, cols)
    models = {n: ModelStats(int(c), len(steps), rejected, 0, steps.copy(), times,
                            values[:, compiled.output_slices[k]])
              for k, (n, c) in enumerate(zip(compiled.names, runner.calls))}
    result = SimulationResult(
        status=status, message=message, t_end=float(t), names=compiled.output_names,
        units=compiled.output_units, times=times, values=values,
        calls={n: int(c) for n, c in zip(compiled.names, runner.calls)},
        steps_accepted=len(steps), steps_rejected=rejected, step_sizes=steps,
        wall_s=wall, time_in_models={n: float(s) for n, s in
                                     zip(compiled.names, runner.time_in_models)},
        store=str(store) if store is not None else None, error=err, reference=ref_values,
        models=models, error_estimate=getattr(controller, "error_estimate", None))
    _rerun_estimate(result, looser, controller, events)
    return _finish(result, sink, failure, raise_on_failure)


def _rerun_estimate(result: SimulationResult, looser: SimulationResult | None,
                    controller: Controller, events: list[float]) -> None:
    """Replace the summed estimate by the re-run's (when there is one that got anywhere)."""
    if looser is None:
        return
    from cosimstep.estimate import rerun_estimate

    policy = controller.policy  # type: ignore[attr-defined]
    result.estimate_calls = looser.calls_total
    if len(looser.times) > 1:
        result.error_estimate = rerun_estimate(result, looser,
                                               lambda y: policy.scale(y) / policy.tol, events)


def _finish(result: SimulationResult, sink: Store | None, failure: BaseException | None,
            raise_on_failure: bool) -> SimulationResult:
    """Close the store with the run's summary; raise the failure if asked to."""
    if sink is not None:
        sink.finish(result.status, result.message, result.t_end, result.wall_s,
                    result.summary(), result.calls, result.time_in_models)
        sink.close()
    if failure is not None and raise_on_failure:
        raise failure
    return result


def _simulate_multirate(compiled: Any, until: float, controller: Controller,
                        master: MasterOptions, *, t0: float, reference: Reference | None,
                        store: str | Path | None, name: str, config: dict[str, Any] | None,
                        progress: bool | None, raise_on_failure: bool,
                        events: list[float],
                        looser: SimulationResult | None = None) -> SimulationResult:
    """:func:`simulate` with one adaptive step per sub-model (:mod:`cosimstep.multirate`).

    The controller lends its error policy (tolerance, limits, global budget) to every
    sub-model's own step control. Results: every sub-model's own points, and on the union of all
    points each trajectory evaluated by its local cubic; the error against the reference is
    taken at each sub-model's own points (no interpolation error enters it).
    """
    from cosimstep.multirate import Multirate

    policy = getattr(controller, "policy", None)
    if policy is None:
        raise ValueError(f"the multirate master needs an error-controlled controller (e.g. "
                         f"--tol 1e-4 or --controller pc); '{controller.name}' has no tolerance")
    h0 = getattr(controller, "h0", None) or 1e-4 * (until - t0)
    race = Multirate(compiled, policy, min(max(h0, policy.hmin), policy.hmax),
                     order=master.extrapolation, interpolation=master.interpolation,
                     call_timeout=master.call_timeout)
    sink = Store(store) if store is not None else None
    settings = {"t0": t0, "until": until, "master": vars(master),
                "controller": controller.describe(), **(config or {})}
    if sink is not None:
        sink.begin(name, settings, compiled.output_names, compiled.output_units)
    status, message, failure = "ok", "completed", None
    wall0 = time.perf_counter()
    bar = _progress(progress, t0, until)
    behind = [t0]

    if sink is not None:
        race.on_attempt = lambda name, t, h, ok: sink.add_attempt(name, t, h, ok, None)

    def on_step(track: Any) -> None:
        if bar is not None:
            t_min = min(tr.t for tr in race.tracks)
            bar.update(t_min - behind[0])
            behind[0] = t_min

    try:
        race.initialize(t0, until, events)
        race.run(until, on_step)
    except SubModelError as exc:
        status, message, failure = "failed", str(exc), exc
    except StepSizeError as exc:
        status, message, failure = "failed", str(exc), exc
    except Exception as exc:
        status, message, failure = "failed", f"{type(exc).__name__}: {exc}", exc
    except KeyboardInterrupt as exc:
        status, message, failure = "interrupted", "interrupted by the user", exc
    finally:
        if bar is not None:
            bar.close()
        for m in compiled.models:
            with contextlib.suppress(Exception):
                m.terminate()
    wall = time.perf_counter() - wall0
    tracks = race.tracks
    started = all(tr.times for tr in tracks)
    t_end = min(tr.t for tr in tracks) if started else t0
    # the union of all points up to where every trajectory reaches
    grid = np.unique(np.concatenate([np.asarray(tr.times) for tr in tracks])) if started \
        else np.array([t0])
    grid = grid[grid <= t_end * (1 + 1e-14) + 1e-15] if started else grid
    values = np.hstack([race.values_at(tr.index, grid) for tr in tracks]) if started \
        else np.empty((0, compiled.n_outputs))
    err, ref_values = None, None
    if reference is not None and started and t_end > t0:
        reference.solve(t0, float(max(tr.t for tr in tracks)))
        names = [n for n in compiled.output_names if n in reference.mapping]
        err = _own_point_error(compiled, tracks, reference, names)
        ref_values = reference.values(grid, names)
    if sink is not None:
        for i, (t, y) in enumerate(zip(grid, values)):
            sink.add_point(i, float(t), y)
        if ref_values is not None:
            names = [n for n in compiled.output_names if n in reference.mapping]
            sink.add_reference(ref_values, [compiled.output_names.index(n) for n in names])
        for tr in tracks:
            sl = compiled.output_slices[tr.index]
            sink.add_own_points(list(range(sl.start, sl.stop)), np.asarray(tr.times),
                                np.array(tr.rows).reshape(len(tr.times), -1))
    models = {tr.name: ModelStats(tr.calls, tr.accepted, tr.rejected, tr.corrections,
                                  np.array(tr.steps), np.asarray(tr.times),
                                  np.array(tr.rows).reshape(len(tr.times), -1), tr.replaced)
              for tr in tracks}
    all_steps = np.concatenate([np.array(tr.steps) for tr in tracks]) if tracks else np.zeros(0)
    result = SimulationResult(
        status=status, message=message, t_end=float(t_end), names=compiled.output_names,
        units=compiled.output_units, times=grid, values=values,
        calls={tr.name: tr.calls for tr in tracks},
        steps_accepted=sum(tr.accepted for tr in tracks),
        steps_rejected=sum(tr.rejected for tr in tracks), step_sizes=all_steps, wall_s=wall,
        time_in_models={tr.name: tr.time_in_model for tr in tracks},
        store=str(store) if store is not None else None, error=err, reference=ref_values,
        models=models, error_estimate=race.error_estimate())
    _rerun_estimate(result, looser, controller, events)
    return _finish(result, sink, failure, raise_on_failure)


def _own_point_error(compiled: Any, tracks: list, reference: Reference,
                     names: list[str]) -> ErrorReport:
    """The error against the reference at each sub-model's own points (no interpolation)."""
    diffs, scaled, per = [], [], {}
    for tr in tracks:
        sl = compiled.output_slices[tr.index]
        own = [n for n in compiled.output_names[sl] if n in reference.mapping]
        if not own:
            continue
        cols = [compiled.output_names[sl].index(n) for n in own]
        ref_own = reference.values(np.asarray(tr.times), own)
        d = np.abs(np.array(tr.rows)[:, cols] - ref_own)
        diffs.append(d.ravel())
        scaled.append((d / (1.0 + np.abs(ref_own))).ravel())
        per.update({n: float(d[:, c].max()) for c, n in enumerate(own)})
    all_d = np.concatenate(diffs) if diffs else np.zeros(0)
    return ErrorReport(float(all_d.max()) if all_d.size else 0.0,
                       float(np.sqrt(np.mean(all_d**2))) if all_d.size else 0.0,
                       {n: per[n] for n in names if n in per},
                       int(sum(len(tr.times) for tr in tracks)),
                       float(np.concatenate(scaled).max()) if all_d.size else 0.0)


def _progress(progress: bool | None, t0: float, until: float) -> Any:
    if progress is False:
        return None
    from tqdm import tqdm

    return tqdm(total=until - t0, delay=2.0, unit="s", file=sys.stderr,
                disable=None if progress is None else False,
                bar_format="{l_bar}{bar}| t={n:.3f}/{total:.3f} s [{elapsed}<{remaining}]")


__all__ = ["SimulationResult", "simulate"]

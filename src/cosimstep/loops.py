"""The synchronous time loops: every sub-model takes the same communication step.

:class:`ControllerLoop` asks the controller for an attempt at each step, lands steps on the
sub-models' time events and the end time, and records every attempt and accepted point in the
store; :class:`FixedLoop` is the same run for a plain fixed step without per-step objects. Both
are actors of the run kernel (:mod:`cosimstep.kernel`): a synchronous co-simulation is one
actor, which runs up to the limit the kernel gives it.
"""

from __future__ import annotations

import bisect
import math
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from cosimstep.checkpoint import Checkpoints, restore
from cosimstep.controllers import Controller
from cosimstep.controllers.base import Attempt
from cosimstep.errors import RESTORE_CHECKS, StepSizeError, SubModelError, still_failing
from cosimstep.kernel import Actor, Budget
from cosimstep.masters import Master
from cosimstep.store import Checkpoint, Store

HISTORY_ROWS = 4  # stored points handed to controllers/masters for extrapolation
FAILED_TRIAL_SHRINK = 0.25  # step factor after a trial step a sub-model failed on
EVENT_TOL = 1e-12
"""A state event is located to within ``EVENT_TOL · max(1, |t|)`` seconds of the crossing of the
trajectory the master computes (the step that ends on it is then taken again, by the
controller)."""


def lands(t: float, h: float, landing: float) -> bool:
    """Whether a step of ``h`` from ``t`` ends within a hair of ``landing`` (the next event or
    the end time) and is to end on it exactly."""
    return h >= (landing - t) * (1 - 1e-9) or (landing - t) - h < 1e-6 * h


def landing_step(t: float, h: float, landing: float, cap: float) -> float:
    """The step from ``t``: ``h``, or exactly to ``landing`` when ``h`` ends within a hair of
    it (:func:`lands`) — in two halves when that hair would pass ``cap``, the largest step a
    sub-model accepts (``Capabilities.max_step``, a contract: once passed by a few ulps)."""
    if not lands(t, h, landing):
        return h
    gap = landing - t
    return gap if gap <= cap else 0.5 * gap


class LoopContext:
    """The :class:`~cosimstep.controllers.StepContext` the loop hands to controllers: the
    stored points extrapolation may use, and steps, saves and restores through the master (a
    companion run, :mod:`cosimstep.companion`, keeps one of its own beside the run's)."""

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
        self.discrete = master.discrete
        self.iterated = master.iteration is not None
        system = master.system
        self.readers = [(np.asarray(src, dtype=int), sl)
                        for src, sl in zip(system.src, system.output_slices)]
        self._segment = 0  # index of the first point after the last time event
        self.first_token: Any = None  # the first state saved during the current attempt
        self.edge = math.nan  # the next time event: a step ending there is told so

    def push(self, t: float, y: np.ndarray) -> None:
        self.all_times.append(t)
        self.rows.append(y)
        self._window()

    def reset(self, times: list[float], rows: list[np.ndarray], segment: int) -> None:
        """Hold these points (a resumed run's), the segment starting at row ``segment``."""
        self.all_times, self.rows, self._segment = list(times), list(rows), segment
        self._window()

    def _window(self) -> None:
        """The points extrapolation may use: the last ones of the segment."""
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
        return self.master.step(t, h, times, history, order=order, end=end,
                                edge=self.at_edge(t + h, h))

    def at_edge(self, end: float, h: float) -> bool:
        """Whether a step of ``h`` ending at ``end`` ends on the next time event: within the
        loop's landing tolerance, or a few ulps (a second half step, ``(t + h/2) + h/2``, can
        miss it by one; such a step taken as no edge was rejected over and over)."""
        return abs(end - self.edge) <= max(1e-9 * h, 4.0 * math.ulp(self.edge))

    def defect(self) -> tuple[np.ndarray, np.ndarray]:
        y = self.master.last
        return y - self.master.assumed, self.master.predicted & ~self.master.discrete

    def derivatives(self) -> np.ndarray | None:
        return self.master.derivatives()

    def save(self) -> Any:
        token = self.master.save()
        if self.first_token is None:
            self.first_token = token
        return token

    def restore(self, token: Any) -> None:
        self.master.restore(token)


class _Loop(Actor):
    """What both synchronous loops are to the kernel: one actor at the common time ``t``."""

    t: float
    until: float
    budget: Budget | None = None  # whole-run limits, checked as the loop goes

    @property
    def time(self) -> float:
        return self.t

    @property
    def finished(self) -> bool:
        return self.t >= self.until


class ControllerLoop(_Loop):
    """The time loop for any controller: attempts, rejections, the step context."""

    def __init__(self, runner: Master, controller: Controller, t0: float, until: float,
                 events: list[float], sink: Store | None, bar: Any) -> None:
        self.runner, self.controller = runner, controller
        self.t0, self.until, self.events = t0, until, events
        self.final_event = False  # a time event at the end time too (its step is an edge)
        self.sink, self.bar = sink, bar
        self.ctx = LoopContext(runner)
        self.t = t0
        self.steps: list[float] = []
        self.rejected = 0
        self.failed_trials = 0  # rejected because a sub-model failed on the trial step
        # the last such failure and the end of the step it failed on (see _failed_trial)
        self._failure: tuple[SubModelError, float] | None = None
        self._clock: _Clock | None = None  # set by the first turn
        # state events (see _crossing_inside): watch(row) is the largest indicator of the
        # state-event sub-models (an event when it reaches 0 from below), fire(t) fires them
        self.watch: Callable[[np.ndarray], float] | None = None
        self.fire: Callable[[float, bool, np.ndarray], None] | None = None
        self.located = 0  # state events located inside a step
        self._located = math.nan  # the time a located crossing lands on
        self._h = 0.0  # the step the controller proposed last
        self._hmax = math.inf
        self.offset = 0  # the store's index of the first point held (resumed: not 0)
        self.checkpoints: Checkpoints | None = None  # when to write checkpoints, if at all
        self.resume_from: Checkpoint | None = None  # start from this instead of t0
        self.companion: Any = None  # a companion.Companion estimating the global error

    def act(self, limit: float) -> None:
        """Steps until ``limit`` (a step that would pass it lands on it)."""
        if self._clock is None:
            self.start()
        while self.t < limit:
            event = _next_landing(self.events, self.t, self.until)
            self._attempt(min(event, limit), event)

    def start(self) -> None:
        """Initialize the sub-models and record the first point (or resume)."""
        if self.resume_from is not None:
            restore(self, self.resume_from, self.t0)
            return
        t = self.t0
        self._clock = _Clock(t)
        y0 = self.runner.initialize(t)
        self.ctx.push(t, y0)
        if self.sink is not None:
            self.sink.add_point(0, t, y0)
        self._h = self.controller.initial_step(t, self.until)
        self._hmax = self.runner.max_step  # the sub-models' own limit
        if self.companion is not None:
            self.companion.begin(t, y0)

    def _attempt(self, landing: float, event: float) -> None:
        """One attempt at the next step; a step that would pass ``landing`` lands on it
        (``event``: the next time event or the end)."""
        ctx, sink, t = self.ctx, self.sink, self.t
        if self.budget:
            self.budget.check(int(self.runner.calls.sum()) + self._companion_calls())
        h = self._proposed(t, landing)
        ctx.first_token = None
        ctx.edge = event if event < self.until or self.final_event else math.nan
        if self.companion is not None:
            self.companion.ctx.edge = ctx.edge
        attempt = self._try(t, h)
        if sink is not None:
            sink.add_attempt(None, t, h, attempt.accepted, attempt.error)
        self._h = attempt.h_next
        if not attempt.accepted:
            self.rejected += 1
            if self.rejected <= RESTORE_CHECKS:  # the first few: restored to t?
                row, slices = ctx.rows[-1], self.runner.system.output_slices
                self.runner.check_restored(t, [row[out] for out in slices])
            return
        if self.watch is not None and self._crossing_inside(t, h, attempt.y):
            return  # back at t; the next attempt ends on the crossing
        before = ctx.rows[-1]
        located = t + h == self._located
        clock = self._clock
        clock.add(h)
        t = self.t = landing if abs(clock.value - landing) <= 1e-9 * h else clock.value
        y = attempt.y
        if t == event and (t < self.until or self.final_event):
            # the step's own end was judged (an edge step, Master.step); the run goes on
            # from, shows, and watches for state events, the event's right-hand values
            y = self.runner.right_limits(t, y)
        crossed = self.watch is not None and self.watch(y) >= 0.0  # against the point at t
        self._keep(t, h, y, t == landing, t == event)
        if self.watch is not None and (located or crossed):
            self._located = math.nan
            # not located: no saved state to go back to, a step already at the time
            # tolerance, or an indicator already at 0 when the step began
            late = not located and h > EVENT_TOL * max(1.0, abs(t))
            self.fire(self.t, late, before)  # type: ignore[misc]

    def _try(self, t: float, h: float) -> Attempt:
        """The controller's attempt at ``[t, t + h]``; a sub-model's failure on it is a
        rejection (:meth:`_failed_trial`), and a step that fell below ``hmin`` short of where a
        sub-model last failed ends the run on that failure (:func:`still_failing`)."""
        try:
            return self.controller.attempt(self.ctx, t, h)
        except SubModelError as exc:
            return self._failed_trial(exc, t, h)
        except StepSizeError as stop:
            policy = getattr(self.controller, "policy", None)
            share = policy.tol * h / (self.until - self.t0) if policy is not None else math.inf
            error = still_failing(self._failure, t, share, stop)
            if error is not None and self._failure is not None:
                raise error from self._failure[0]
            raise

    def _keep(self, t: float, h: float, y: np.ndarray, landed: bool, on_event: bool) -> None:
        """Record the accepted step of ``h`` ending at ``t`` with outputs ``y``; ``landed``: on
        the landing (an event or the end), ``on_event``: on the next time event or the end
        time (a restart before the end)."""
        at_event = on_event and t < self.until
        if at_event:
            self._restart(self.controller.event(t))
        self.ctx.push(t, y)
        if self.companion is not None:
            self.companion.accepted(t, y, landed)
            self._feed_back(self.controller)
        if at_event:
            self.ctx.restart()
            if self.companion is not None:
                self.companion.restart()
        self.steps.append(h)
        if self.sink is not None:
            self._store(t, y)
        if self.bar is not None:
            self.bar.update(h)

    def _feed_back(self, controller: Any) -> None:
        """With ``feedback``: the growth the companion measured beyond the summed local
        estimates, for the step control (see :attr:`StepPolicy.feedback`)."""
        policy = getattr(controller, "policy", None)
        summed = getattr(controller, "summed_estimate", 0.0)
        if policy is None or not policy.feedback or not summed > 0.0:
            return
        policy.propagation = max(1.0, self.companion.estimate / summed)

    def _companion_calls(self) -> int:
        return int(self.companion.calls.sum()) if self.companion is not None else 0

    def _proposed(self, t: float, landing: float) -> float:
        """The next attempt's step: the controller's, landing exactly on ``landing`` (the next
        event or the end) when it would end within a hair of it — but a located crossing is
        kept as located, even a hair before ``landing`` (else the step would end past the
        crossing again, and be located again, forever)."""
        if t + self._h == self._located and self._located <= landing:
            return self._h
        return landing_step(t, min(self._h, self._hmax), landing, self._hmax)

    def _store(self, t: float, y: np.ndarray) -> None:
        """Hand the new point to the store, and a checkpoint when one is due."""
        assert self.sink is not None
        n = len(self.steps)
        self.sink.add_point(self.offset + n, t, y)
        if self.checkpoints is not None and self.watch is None and self.checkpoints.due(n):
            self.checkpoints.take(self, n)

    def _crossing_inside(self, t: float, h: float, y: np.ndarray) -> bool:
        """Whether an accepted step crossed a state event and was undone to be redone up to the
        crossing, located to :data:`EVENT_TOL` by :meth:`_locate`.

        Without a saved state (a controller that never rolls back, e.g. a fixed step) the
        event fires at the end of the step instead: late by up to one step.
        """
        watch, token = self.watch, self.ctx.first_token
        assert watch is not None
        if t + h == self._located or watch(y) < 0.0 or watch(self.ctx.rows[-1]) >= 0.0:
            return False  # the located landing itself, no crossing, or one already under way
        if token is None or h <= EVENT_TOL * max(1.0, abs(t)):
            return False
        b = self._locate(t, h, token, watch(self.ctx.rows[-1]), watch(y))
        self.ctx.restore(token)
        self._h, self._located = b, t + b
        self.located += 1
        return True

    def _locate(self, t: float, h: float, token: Any, g0: float, g1: float) -> float:
        """The step from ``t`` at whose end the largest indicator reaches 0, within
        :data:`EVENT_TOL` (:func:`crossing`; each trial is one master step from the saved state
        at ``t``)."""
        watch = self.watch
        assert watch is not None

        def g(c: float) -> float:
            self.ctx.restore(token)
            return watch(self.ctx.step(t, c))

        return crossing(g, 0.0, h, g0, g1, EVENT_TOL * max(1.0, abs(t)))

    def snapshot(self) -> dict[str, Any]:
        """The loop's own state for a checkpoint (:mod:`cosimstep.checkpoint`): its clock, the
        controller, the last points of the segment (more than the step reads)."""
        ctx, clock = self.ctx, self._clock
        assert clock is not None
        n = len(ctx.rows) - 1
        first = max(ctx._segment, n - HISTORY_ROWS)
        return {"first": self.offset + first, "segment": ctx._segment - first,
                "clock": (clock._sum, clock._carry), "times": ctx.all_times[first:],
                "rows": [r.copy() for r in ctx.rows[first:]], "steps": self.steps[first:],
                "rejected": self.rejected, "failed_trials": self.failed_trials,
                "h": self._h, "controller": self.controller}

    def resume_snapshot(self, state: dict[str, Any]) -> None:
        """Go on from :meth:`snapshot`'s state (the sub-models and master already are)."""
        self.offset = state["first"]
        self.ctx.reset(state["times"], state["rows"], max(state["segment"], 0))
        self.t = state["times"][-1]
        self._clock = _Clock(self.t0)
        self._clock._sum, self._clock._carry = state["clock"]
        self.steps = list(state["steps"])
        self.rejected, self.failed_trials = state["rejected"], state["failed_trials"]
        self._h = state["h"]
        # the same object stays the scheme's (its error estimate is read at the end)
        vars(self.controller).update(vars(state["controller"]))
        self._hmax = self.runner.max_step

    def last(self) -> np.ndarray:
        """The outputs at the current time."""
        return self.ctx.rows[-1]

    def jump(self, columns: slice | np.ndarray, values: np.ndarray) -> None:
        """Some outputs jumped at the current time (an event): the point now holds the new
        values, and extrapolation starts again from it (a jump is not a trend)."""
        self.ctx.rows[-1] = self.ctx.rows[-1].copy()
        self.ctx.rows[-1][columns] = values
        self._restart(self.controller.event(self.t))
        self.ctx.restart()
        if self.companion is not None:
            self.companion.resync(self.t, self.ctx.rows[-1])

    def _restart(self, h: float | None) -> None:
        """Go on from an event with the step the controller chose (``None``: as proposed)."""
        if h is not None:
            self._h = min(self._h, h)

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
        self._failure = (exc, t + h)
        return Attempt(np.empty(0), False, h_next, math.inf)

    def finish(self) -> None:
        """Nothing to hand on: every point went to the store as it was accepted."""

    def results(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        ctx = self.ctx
        values = np.array(ctx.rows) if ctx.rows else np.empty((0, self.runner.system.n_outputs))
        return np.array(ctx.all_times), values, np.array(self.steps)


class FixedLoop(_Loop):
    """The fixed-step time loop without per-step objects: the same run as
    :class:`ControllerLoop` with :class:`~cosimstep.controllers.Fixed` (same calls, values,
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
        self.final_event = False  # a time event at the end time too (its step is an edge)
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
        self.lean: Any = None  # the master's lean step (_HeldKernel, _ExtrapolatingKernel)
        self._block: tuple[int, float, list, float] | None = None  # the lean run under way
        self._state: tuple[float, float, int, int] | None = None  # set by the first turn
        self._stored = 0  # points handed to the store so far
        self._shown = 0  # steps shown on the progress bar so far
        self._published = (0, time.perf_counter())  # (n, time) of the last publication
        self.offset = 0  # the store's index of row 0 (a resumed run starts at a checkpoint)
        self.checkpoints: Checkpoints | None = None  # when to write checkpoints, if at all
        self.resume_from: Checkpoint | None = None  # start from this instead of t0

    def _grow(self) -> None:
        rows = 2 * self.times.shape[0]
        for name in ("times", "table", "hs"):
            old = getattr(self, name)
            new = np.empty((rows, *old.shape[1:]))
            new[:old.shape[0]] = old
            setattr(self, name, new)

    def act(self, limit: float) -> None:
        """Steps until ``limit``."""
        self._run_to(limit)

    def start(self) -> None:
        """Initialize the sub-models and record the first point (or resume)."""
        if self.resume_from is not None:
            restore(self, self.resume_from, self.t0)
            return
        t = self.t0
        y0 = self.runner.initialize(t)
        self.times[0], self.table[0], self.n = t, y0, 0
        self.lean = self.runner.held_kernel() or self.runner.extrapolating_kernel()
        self._state = (t, 0.0, 0, 1)  # (clock, carry, segment, due): see _run_to
        self._published = (0, time.perf_counter())

    def _run_to(self, limit: float) -> None:
        if self._state is None:
            self.start()
        runner, until, events, lean = self.runner, self.until, self.events, self.lean
        # An extrapolating kernel needs `order` equal steps before the step in its segment: the
        # general step does the first `order` steps of each segment (where it lowers the order
        # and may use grey-box slopes). Within a segment every step is h_plain except the one
        # landing on the event or end time, so "h == h_plain" after them means equal spacing.
        lean_after = getattr(lean, "order", 0)
        clock, carry, segment, due = self._state  # clock: _Clock, inlined
        t, n = self.t, self.n
        table = self.table
        flat, base = table.reshape(-1), table.ctypes.data
        h_plain = min(self.h_step, runner.max_step)
        event, landing = until, min(until, limit)
        while t < limit:
            if events:  # without events the landing is always the end time
                event = _next_landing(events, t, until)
                landing = min(event, limit)
            if lean is not None and (not lean_after or n - segment >= lean_after):
                run = self._lean_run(lean, t, n, h_plain, landing, clock, carry, due)
                if run is not None:  # equal steps up to the landing step or the next batch
                    t, n, clock, carry = run
                    due = self._after_point(n, clock, carry, segment, due)
                    continue
            h = landing_step(t, h_plain, landing, runner.max_step)
            if n + 1 == table.shape[0]:
                self._grow()
                table = self.table
                flat, base = table.reshape(-1), table.ctypes.data
            if lean is not None and not self._onto_event(t, h, landing, event) and (
                    not lean_after or (n - segment >= lean_after and h == h_plain)):
                lean.step(t, h, n, flat, base)
            else:
                self._general_step(t, h, n, segment, event if landing == event else math.nan)
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
            if t == event and t < until:
                segment = n
                runner.restart()
            due = self._after_point(n, clock, carry, segment, due)
        self._state = (clock, carry, segment, due)

    def _onto_event(self, t: float, h: float, landing: float, event: float) -> bool:
        """Whether a step of ``h`` from ``t`` lands on a time event (not the end time): such
        a step is the master's own (an edge, :meth:`Master.step`), never the lean kernel's."""
        return landing == event and h == event - t and (event < self.until or self.final_event)

    def _general_step(self, t: float, h: float, n: int, segment: int, event: float) -> None:
        """The master's general step from row ``n`` into row ``n + 1``; ``event``: the time
        event this step may land on (NaN: none). A step landing on one is an edge
        (:meth:`Master.step`), and the row gets the event's right-hand values."""
        table, first = self.table, max(segment, n + 1 - HISTORY_ROWS)
        edge = h == event - t and (event < self.until or self.final_event)
        table[n + 1] = self.runner.step(t, h, self.times[first:n + 1].tolist(),
                                        table[first:n + 1].copy(), edge=edge)
        if edge:
            table[n + 1] = self.runner.right_limits(event, table[n + 1])

    def _after_point(self, n: int, clock: float, carry: float, segment: int, due: int) -> int:
        """At the batch's last point: publish, check the budget; the next batch's end."""
        if n != due:
            return due
        self._state = (clock, carry, segment, due)  # what a checkpoint captures
        due = n + self._publish()
        if self.budget:
            self.budget.check(self._calls())
        return due

    def _lean_run(self, lean: Any, t: float, n: int, h: float, landing: float, clock: float,
                  carry: float, due: int) -> tuple[float, int, float, float] | None:
        """The equal steps of ``h`` from ``t`` before the one that lands (on an event, the end
        or ``limit``), at most up to the next batch's end, in one call of the lean kernel.

        The times are those the step-by-step loop computes (the same compensated sum and
        landing tests), so the run is the same; what goes is the loop's bookkeeping per step.
        Returns ``(t, n, clock, carry)`` after them, or ``None`` if there are none. If a step
        fails, the points before it are kept, as the step-by-step loop keeps them.
        """
        cap = min(due - n, self.table.shape[0] - 1 - n)
        starts: list[float] = []
        append = starts.append
        # the loop's own expressions, their constant factors taken out (the same values)
        eps, close, size = 1e-6 * h, 1e-9 * h, abs(h)
        for _ in range(cap):
            gap = landing - t
            if h >= gap * (1 - 1e-9) or gap - h < eps:
                break  # this step lands: the step-by-step loop takes it
            s = clock + h
            c = carry + (((clock - s) + h) if abs(clock) >= size else ((h - s) + clock))
            value = s + c
            if abs(value - landing) <= close:
                break  # ends on the landing after all: likewise
            append(t)
            clock, carry, t = s, c, value
        if not starts:
            return None
        table = self.table
        self._block = (n, h, starts, t)
        try:
            lean.steps(starts, h, n, table.reshape(-1), table.ctypes.data)
        finally:
            self._catch_up()
        return self.t, self.n, clock, carry

    def _catch_up(self) -> None:
        """Record the steps the lean kernel completed of the run it was given (all of them,
        or those before a failure; also when a hung call was abandoned mid-run): each step
        ends where the next starts, the last at ``end``."""
        if self._block is None or self.lean is None:
            return
        n, h, starts, end = self._block
        done = self.lean.done
        if done:
            self.times[n + 1:n + done] = starts[1:done]
            self.times[n + done] = starts[done] if done < len(starts) else end
            self.hs[n:n + done] = h
            self.n, self.t = n + done, float(self.times[n + done])
        self._block = None

    def snapshot(self) -> dict[str, Any]:
        """The loop's own state for a checkpoint (:mod:`cosimstep.checkpoint`): its clock and
        the last points of the segment (more than the step reads)."""
        assert self._state is not None
        clock, carry, segment, _ = self._state
        n = self.n
        first = max(segment, n - HISTORY_ROWS)
        return {"first": self.offset + first, "segment": self.offset + segment,
                "clock": clock, "carry": carry, "times": self.times[first:n + 1].copy(),
                "rows": self.table[first:n + 1].copy(), "hs": self.hs[first:n].copy(),
                "rejected": self.rejected}

    def resume_snapshot(self, state: dict[str, Any]) -> None:
        """Go on from :meth:`snapshot`'s state (the sub-models and master already are)."""
        rows = state["rows"]
        k = rows.shape[0]
        self.offset = state["first"]
        self.times[:k], self.table[:k], self.hs[:k - 1] = state["times"], rows, state["hs"]
        self.n, self.t = k - 1, float(state["times"][-1])
        self.rejected = state["rejected"]
        self._state = (state["clock"], state["carry"],
                       max(state["segment"] - state["first"], 0), k)
        self.lean = self.runner.held_kernel() or self.runner.extrapolating_kernel()
        self._stored, self._shown = k, k - 1
        self._published = (k - 1, time.perf_counter())

    def last(self) -> np.ndarray:
        """The outputs at the current time."""
        return self.table[self.n]

    def _calls(self) -> int:
        lean = getattr(self.lean, "calls", None) or []
        return int(self.runner.calls.sum()) + int(sum(lean))

    def jump(self, columns: slice | np.ndarray, values: np.ndarray) -> None:
        """Some outputs jumped at the current time (an event): the point now holds the new
        values, and extrapolation starts again from it."""
        assert self._state is not None
        self.table[self.n, columns] = values
        clock, carry, _, due = self._state
        self._state = (clock, carry, self.n, due)
        self.runner.restart()

    def _publish(self) -> int:
        """Hand the points not yet stored to the store, and the steps to the progress bar;
        return how many steps to run until the next publication."""
        n = self.n
        if self.sink is not None and n >= self._stored:
            first = self._stored
            self.sink.add_points(self.offset + first, self.times[first:n + 1],
                                 self.table[first:n + 1])
            if first == 0:
                first = 1
            self.sink.add_accepted_attempts(self.times[first - 1:n], self.hs[first - 1:n])
            self._stored = n + 1
            if self.checkpoints is not None and self.checkpoints.due(n):
                self.checkpoints.take(self, n)
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
        self._catch_up()
        if self.lean is not None:
            self.lean.sync()
            self.lean = None
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


def crossing(g: Callable[[float], float], a: float, b: float, ga: float, gb: float,
             tol: float) -> float:
    """Where ``g`` reaches 0 from below inside ``[a, b]`` (``ga < 0 <= gb``), to within
    ``tol``: the first side of the final bracket where ``g >= 0``. The Illinois variant of
    regula falsi, every third trial a bisection (``g`` may be only piecewise smooth)."""
    side = 0
    for i in range(200):
        if b - a <= tol:
            break
        c = 0.5 * (a + b) if i % 3 == 2 else b - gb * (b - a) / (gb - ga)
        c = min(max(c, a + 0.25 * tol), b - 0.25 * tol)
        gc = g(c)
        if gc >= 0.0:
            b, gb = c, gc
            ga, side = (0.5 * ga if side == 1 else ga), 1
        else:
            a, ga = c, gc
            gb, side = (0.5 * gb if side == -1 else gb), -1
    return b


def _next_landing(events: list[float], t: float, t_end: float) -> float:
    i = bisect.bisect_right(events, t + 1e-12 * max(1.0, abs(t)))
    return min(events[i], t_end) if i < len(events) else t_end

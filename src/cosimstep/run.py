"""One run: the store, the progress bar, failure capture and the result, around the kernel.

:class:`Run` is the only place that opens the results store, shows progress, turns a failure or
an interrupt into a status and a message, and assembles the :class:`SimulationResult`; the
coupling scheme is an object chosen once (:func:`scheme_for`) that hands the kernel its actors
and says what it produced:

- :class:`Synchronous`: every sub-model takes the same step (Jacobi, Gauss–Seidel or a fixed
  order), one actor (:mod:`cosimstep.loops`);
- :class:`MultiRate`: one actor per sub-model with its own step (:mod:`cosimstep.multirate`).
"""

from __future__ import annotations

import contextlib
import dataclasses
import signal
import sys
import threading
import time
import traceback
import warnings
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from cosimstep.controllers import Controller, Fixed
from cosimstep.errors import EndOfSimulation, StepSizeError, SubModelError
from cosimstep.events import MAX_EVENTS, DiscreteEventModel, Event
from cosimstep.kernel import Actor, Budget, BudgetExceeded, Kernel
from cosimstep.loops import ControllerLoop, FixedLoop
from cosimstep.masters import Master, MasterOptions, _Watchdog
from cosimstep.reference import ErrorReport, Reference, error_report
from cosimstep.result import ModelStats, SimulationResult
from cosimstep.store import GridStore, Store


@dataclass
class Outcome:
    """What a scheme produced, however far it got."""

    t_end: float
    times: np.ndarray  # the common grid of the result
    values: np.ndarray
    steps: np.ndarray  # every accepted step, all sub-models
    models: dict[str, ModelStats]
    calls: dict[str, int]
    time_in_models: dict[str, float]
    accepted: int
    rejected: int
    error_estimate: float | None
    events: list[Event] = field(default_factory=list)
    estimate_calls: int = 0  # calls spent on the error estimate alone (a companion run)


class Scheme(ABC):
    """A coupling scheme: its actors, how it ends, and what it produced."""

    def __init__(self, compiled: Any, t0: float, until: float,
                 call_timeout: float | None = None) -> None:
        self.compiled, self.t0, self.until = compiled, t0, until
        self.call_timeout = call_timeout or None  # 0: no limit
        # sub-models whose call was abandoned: their thread may still be inside them, so they
        # are not terminated (freeing an FMU instance under a running call would crash it)
        self.hung: set[str] = set()

    def resumable(self) -> str | None:
        """Why a run of this scheme cannot take checkpoints and be resumed (``None``: it can)."""
        return f"{type(self).__name__.lower()} runs cannot be resumed yet"

    def resume(self, checkpoints: Any, resume_from: Any) -> None:  # noqa: B027
        """Write checkpoints as set in ``checkpoints`` (a :class:`~cosimstep.checkpoint.
        Checkpoints`, or ``None``); start from ``resume_from`` (a stored checkpoint, or
        ``None``). Only called when :meth:`resumable` is ``None``."""

    @property
    def offset(self) -> int:
        """The store's index of the result's first point (0 unless resumed)."""
        return 0

    @abstractmethod
    def masters(self) -> list[Master]:
        """The masters that make the sub-model calls (a run's watchdog stamps them)."""

    @property
    @abstractmethod
    def t(self) -> float:
        """How far the run got (every sub-model is at least there)."""

    @abstractmethod
    def actors(self, kernel: Kernel, sink: Store | None, bar: Any) -> list[Actor]: ...

    def settle(self) -> list[Actor]:
        """Actors to run again once the kernel's heap is empty (none by default)."""
        return []

    @abstractmethod
    def limit(self, budget: Budget | None) -> None:
        """Have the actors check the run's budget as they go."""

    @abstractmethod
    def close(self) -> None:
        """Hand the last rows to the store and free the sub-models; called in any case."""

    @abstractmethod
    def outcome(self) -> Outcome: ...

    @abstractmethod
    def error(self, reference: Reference, out: Outcome,
              names: list[str]) -> tuple[ErrorReport, np.ndarray]:
        """The error against ``reference`` and its values on the result's grid."""

    def store(self, sink: Store, out: Outcome) -> None:  # noqa: B027 - optional hook
        """Anything the store does not have yet once the run has ended."""


class Synchronous(Scheme):
    """Every sub-model takes the same communication step (one actor)."""

    def __init__(self, compiled: Any, t0: float, until: float, controller: Controller,
                 master: MasterOptions, events: list[float], richardson: bool = False) -> None:
        super().__init__(compiled, t0, until, master.call_timeout)
        self.controller, self.master, self.events = controller, master, events
        self.richardson = richardson  # estimate the global error by a companion run
        self.runner = Master(compiled, master)
        self.loop: FixedLoop | ControllerLoop | None = None
        self._checkpoints: Any = None  # see resume()
        self._resume_from: Any = None
        self.fired: list[Event] = []
        self.max_events = MAX_EVENTS
        discrete = [k for k, m in enumerate(compiled.models) if isinstance(m, DiscreteEventModel)]
        self._event_models = discrete  # (an ABC's isinstance, asked once per model)
        self.state_events = [k for k in discrete if type(compiled.models[k]).indicator
                             is not DiscreteEventModel.indicator]
        # continuous sub-models with discrete outputs: a change of one is an event too (the
        # master's table of discrete outputs spares a large system a look at every port)
        self.changing: dict[int, list[int]] = {}
        columns = np.flatnonzero(self.runner.discrete).tolist()
        event_models = set(discrete)
        for j in columns:
            k = compiled.owners[j]
            if k not in event_models:
                self.changing.setdefault(k, []).append(j)
        self._discrete_cols = np.array(sorted(j for c in self.changing.values() for j in c),
                                       dtype=int)

    @property
    def t(self) -> float:
        return self.loop.t if self.loop is not None else self.t0

    def masters(self) -> list[Master]:
        return [self.runner]

    def resumable(self) -> str | None:
        if self.state_events or self.changing or self._event_models:
            return "runs with discrete events or discrete outputs cannot be resumed yet"
        return None

    def resume(self, checkpoints: Any, resume_from: Any) -> None:
        self._checkpoints, self._resume_from = checkpoints, resume_from

    @property
    def offset(self) -> int:
        return self.loop.offset if self.loop is not None else 0

    def actors(self, kernel: Kernel, sink: Store | None, bar: Any) -> list[Actor]:
        # The fixed step needs no controller, context or attempt per step: a lean loop gives
        # the same run (a subclass of Fixed may change attempt(), so only Fixed qualifies).
        watched = bool(self.state_events or self.changing)
        self.runner.correct_start = isinstance(self.controller, Fixed)
        if type(self.controller) is Fixed and not watched:
            self.loop = FixedLoop(self.runner, self.controller.step, self.t0, self.until,
                                  self.events, sink, bar)
            self.loop.checkpoints, self.loop.resume_from = self._checkpoints, self._resume_from
        else:
            self.loop = ControllerLoop(self.runner, self.controller, self.t0, self.until,
                                       self.events, sink, bar)
            self.loop.checkpoints, self.loop.resume_from = self._checkpoints, self._resume_from
        self.loop.final_event = any(float(e) == self.until for m in self.compiled.models
                                    for e in m.time_events())
        if watched and isinstance(self.loop, ControllerLoop):
            self.loop.watch, self.loop.fire = self._watch, self._fire_crossed
        if self.richardson and isinstance(self.loop, ControllerLoop):
            from cosimstep.companion import Companion

            policy = self.controller.policy  # type: ignore[attr-defined]
            self.loop.companion = Companion(self.runner, lambda y: policy.scale(y) / policy.tol)
        discrete = [_EventActor(self, k) for k in self._event_models]
        if discrete:
            self.loop.start()  # the event models tell their first time once initialized
        return [self.loop, *discrete]

    def _inputs(self, k: int, row: np.ndarray) -> np.ndarray:
        compiled = self.compiled
        return compiled.a[k] * row[compiled.src[k]] + compiled.b[k]

    def _watch(self, row: np.ndarray) -> float:
        """The largest state-event indicator at a point (an event where it reaches 0); a
        discrete output that differs from the last accepted point's counts as +1, else -1."""
        models = self.compiled.models
        g = max((models[k].indicator(self._inputs(k, row)) for k in self.state_events),
                default=-1.0)
        cols = self._discrete_cols
        if cols.size and g < 0.0:
            assert self.loop is not None
            g = 1.0 if bool(np.any(row[cols] != self.loop.last()[cols])) else -1.0
        return g

    def _fire_changed(self, t: float, before: np.ndarray, late: bool) -> bool:
        """Record the discrete outputs that changed over the last step as events of their
        sub-models, and restart extrapolation there; whether any did."""
        assert self.loop is not None
        row = self.loop.last()
        changed = False
        for k, cols in self.changing.items():
            if np.array_equal(row[cols], before[cols]):
                continue
            changed = True
            names = [self.compiled.output_names[j].split(".", 1)[-1] for j in cols]
            self.loop.jump(np.asarray(cols), row[cols])
            self.fired.append(Event(t, self.compiled.names[k], "change",
                                    {n: float(v) for n, v in zip(names, row[cols])}, late))
        return changed

    def _fire_crossed(self, t: float, late: bool = False,
                      before: np.ndarray | None = None) -> None:
        """Fire the state-event sub-models whose indicator reached 0 at ``t`` (the one located
        there fires even if rounding left it a hair below), then those that the new outputs
        push past 0 at the same time — at most :attr:`max_events` in all, then the run fails
        naming the sub-models still firing (an endless event loop). ``before`` is the point
        the step started from: discrete outputs that differ from it are events first."""
        assert self.loop is not None
        changed = self._fire_changed(t, before, late) if before is not None else False
        values = self._indicators()
        top = max(values.values(), default=0.0)
        due = [k for k, g in values.items() if g >= 0.0 or (g == top and not changed)]
        fired, involved = 0, set()
        while due:
            fired += len(due)
            involved.update(due)
            if fired > self.max_events:
                names = ", ".join(self.compiled.names[k] for k in sorted(involved))
                raise RuntimeError(f"more than {self.max_events} events at t = {t:.9g}: "
                                   f"{names} keep firing each other (an endless event loop; "
                                   "add hysteresis or break the cycle)")
            for k in due:
                self.fire(k, t)
                if late:
                    self.fired[-1] = dataclasses.replace(self.fired[-1], late=True)
            # a jump may carry another indicator past 0 now: strictly, so that a monitor left
            # exactly on its level (indicator 0 after firing) does not fire back at once
            due = [k for k, g in self._indicators().items() if g > 0.0]

    def _indicators(self) -> dict[int, float]:
        assert self.loop is not None
        row = self.loop.last()
        return {k: self.compiled.models[k].indicator(self._inputs(k, row))
                for k in self.state_events}

    def limit(self, budget: Budget | None) -> None:
        if self.loop is not None:
            self.loop.budget = budget

    def fire(self, k: int, t: float) -> bool:
        """Discrete-event sub-model ``k`` has its event now (the loop stands at ``t``): it
        reads its inputs there, its outputs jump, the loop goes on from the new values."""
        assert self.loop is not None
        compiled = self.compiled
        model = compiled.models[k]
        y = self.loop.last()
        kind = model.apply(t, self._inputs(k, y))
        new = np.asarray(model.get_outputs(), dtype=float)
        self.loop.jump(compiled.output_slices[k], new)
        self.fired.append(Event(t, compiled.names[k], kind,
                                {p.name: float(v) for p, v in zip(model.outputs, new)}))
        return True

    def close(self) -> None:
        try:
            if self.loop is not None:
                self.loop.finish()  # hands the last rows to the store (may fail: disk full)
        finally:
            self.runner.terminate(self.hung)  # frees FMU instances (their folders: fmu_base)

    def outcome(self) -> Outcome:
        assert self.loop is not None
        compiled, runner = self.compiled, self.runner
        times, values, steps = self.loop.results()
        rejected = self.loop.rejected
        accepted = len(steps) + self.offset  # a resumed run's steps before its checkpoint too
        # every sub-model took the run's steps: one copy for all of them, as their times and
        # values are views of the run's (a system of thousands of models made a copy each)
        shared = steps.copy()
        shared.flags.writeable = False  # (one model's cannot be changed alone)
        models = {n: ModelStats(c, accepted, rejected, 0, shared, times, values[:, columns])
                  for n, c, columns in zip(compiled.names, runner.calls.tolist(),
                                           compiled.output_slices)}
        estimate = getattr(self.controller, "error_estimate", None)
        companion = getattr(self.loop, "companion", None)
        extra = 0
        if companion is not None:
            extra = int(companion.calls.sum())
            if companion.lost is None:
                estimate = companion.estimate
            caveat = companion.caveat()
            if caveat is not None:
                warnings.warn(f"estimate='richardson': {caveat}", stacklevel=2)
        return Outcome(
            float(self.loop.t), times, values, steps, models,
            dict(zip(compiled.names, runner.calls.tolist())),
            dict(zip(compiled.names, runner.time_in_models.tolist())),
            accepted, rejected, estimate, list(self.fired), extra)

    def error(self, reference: Reference, out: Outcome,
              names: list[str]) -> tuple[ErrorReport, np.ndarray]:
        cols = [self.compiled.output_names.index(n) for n in names]
        reference.solve(self.t0, out.t_end)  # only as far as the run got
        ref_values = reference.values(out.times, names)
        return error_report(out.times, out.values[:, cols], ref_values, names), ref_values


def _say_beyond_tolerance(result: SimulationResult, controller: Any) -> None:
    """Status ``ok`` says the run reached its end, not that it kept its tolerance; where the
    run's own estimate (no reference needed) says it did not, the message says so, so that a
    user without a monolithic model is not left with "completed" alone. The estimate is within
    0.2-5x of the measured error on most of the suite, so this is a sign, not a verdict."""
    tol = getattr(controller, "tol", None)
    if tol is None:
        tol = getattr(getattr(controller, "policy", None), "tol", None)
    if result.tightened is not None and result.tightened["run"] == "first":
        tol = result.tightened["tol"]  # a repeat at a tighter tol: judged by the one asked for
    estimate = result.error_estimate
    if result.status == "ok" and isinstance(tol, float) and estimate is not None \
            and estimate > tol:
        result.message += (f"; its own error estimate is {estimate / tol:.3g} x tol (tighten "
                           "tol, or check against a reference)")


class MultiRate(Scheme):
    """One adaptive step per sub-model (:mod:`cosimstep.multirate`), one actor each.

    The controller lends its error policy (tolerance, limits, global budget) to every
    sub-model's own step control. Results: every sub-model's own points, and on the union of all
    points each trajectory evaluated by its local cubic; the error against the reference is
    taken at each sub-model's own points (no interpolation error enters it).
    """

    def __init__(self, compiled: Any, t0: float, until: float, controller: Controller,
                 master: MasterOptions, events: list[float]) -> None:
        from cosimstep.multirate import Multirate

        super().__init__(compiled, t0, until, master.call_timeout)
        self.controller = controller  # lends its policy; its tol is the run's
        policy = getattr(controller, "policy", None)
        if policy is None:
            raise ValueError("the multirate master steps every sub-model with a controller's "
                             "error policy (pc, corrector, defect, doubling, embedded); "
                             f"'{controller.name}' has none")
        h0 = getattr(controller, "h0", None) or 1e-4 * (until - t0)
        # the error memory is probed as the controller would probe it (pc: every 20 accepted
        # steps once known, probe_every=0 off; the other controllers do not probe)
        probe = getattr(controller, "probe", None)
        self.race = Multirate(compiled, policy, min(max(h0, policy.hmin), policy.hmax),
                              order=master.extrapolation, interpolation=master.interpolation,
                              resync=master.resync,
                              probe_every=probe.every if probe is not None else 0)
        self.events = events
        self._behind = t0
        self.fired: list[Event] = []

    def masters(self) -> list[Master]:
        return [self.race._caller]

    @property
    def t(self) -> float:
        tracks = self.race.tracks
        return min(tr.t for tr in tracks) if all(tr.times for tr in tracks) else self.t0

    def actors(self, kernel: Kernel, sink: Store | None, bar: Any) -> list[Actor]:
        if sink is not None:
            self.race.on_attempt = lambda name, t, h, ok: sink.add_attempt(name, t, h, ok, None)

        def on_step(track: Any) -> None:
            t_min = min(tr.t for tr in self.race.tracks)
            bar.update(t_min - self._behind)
            self._behind = t_min

        self.race.initialize(self.t0, self.until, self.events)
        discrete = [_EventActor(self, k) for k, m in enumerate(self.compiled.models)
                    if isinstance(m, DiscreteEventModel)]
        return [*self.race.actors(kernel, on_step if bar is not None else None), *discrete]

    def fire(self, k: int, t: float) -> bool:
        """See :meth:`cosimstep.multirate.Multirate.fire`; whether it fired."""
        event = self.race.fire(k, t)
        if event is not None:
            self.fired.append(event)
        return event is not None

    def settle(self) -> list[Actor]:
        return self.race.settle()

    def limit(self, budget: Budget | None) -> None:
        self.race.budget = budget

    def close(self) -> None:
        self.race._caller.terminate(self.hung)

    def outcome(self) -> Outcome:
        race, tracks, compiled = self.race, self.race.tracks, self.compiled
        started = all(tr.times for tr in tracks)
        t_end = self.t
        grid = np.array([self.t0])
        values = np.empty((0, compiled.n_outputs))
        if started:  # the union of all points up to where every trajectory reaches
            grid = np.unique(np.concatenate([np.asarray(tr.times) for tr in tracks]))
            grid = grid[grid <= t_end * (1 + 1e-14) + 1e-15]
            values = np.hstack([race.values_at(tr.index, grid) for tr in tracks])
        models = {tr.name: ModelStats(tr.calls, tr.accepted, tr.rejected, tr.corrections,
                                      np.array([h for h in tr.steps if h > 0]),
                                      np.asarray(tr.times),
                                      np.array(tr.rows).reshape(
                                          len(tr.times), len(compiled.models[tr.index].outputs)),
                                      tr.replaced, tr.gain_checks, tr.probes)
                  for tr in tracks}
        steps = np.concatenate([np.array([h for h in tr.steps if h > 0]) for tr in tracks]) \
            if tracks else np.zeros(0)
        estimate = race.error_estimate()
        took = getattr(self.controller, "took_estimates", None)
        if took is not None:  # what follows the run (cosimstep.tighten) reads them there
            took(estimate, race.summed_estimate())
        return Outcome(float(t_end), grid, values, steps, models,
                       {tr.name: tr.calls for tr in tracks},
                       {tr.name: tr.time_in_model for tr in tracks},
                       sum(tr.accepted for tr in tracks), sum(tr.rejected for tr in tracks),
                       estimate,
                       sorted([*self.fired, *race.state_fired], key=lambda e: e.t))

    def error(self, reference: Reference, out: Outcome,
              names: list[str]) -> tuple[ErrorReport, np.ndarray]:
        reference.solve(self.t0, float(max(tr.t for tr in self.race.tracks)))
        ref_values = reference.values(out.times, names)
        report = self._own_point_error(reference, names)
        cols = [self.compiled.output_names.index(n) for n in names]
        if cols and len(out.times):
            grid = np.abs(out.values[:, cols] - ref_values) / (1.0 + np.abs(ref_values))
            report = dataclasses.replace(report, grid_max_scaled=float(grid.max()))
        return report, ref_values

    def _own_point_error(self, reference: Reference, names: list[str]) -> ErrorReport:
        """The error against the reference at each sub-model's own points (no interpolation)."""
        compiled, tracks = self.compiled, self.race.tracks
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

    def store(self, sink: Store, out: Outcome) -> None:
        """The common grid (known only at the end) and every sub-model's own points."""
        for i, (t, y) in enumerate(zip(out.times, out.values)):
            sink.add_point(i, float(t), y)
        for tr in self.race.tracks:
            sl = self.compiled.output_slices[tr.index]
            sink.add_own_points(list(range(sl.start, sl.stop)), np.asarray(tr.times),
                                np.array(tr.rows).reshape(len(tr.times), -1))


class _EventActor(Actor):
    """A discrete-event sub-model as an actor of the kernel: it stands at its next event, and
    no other actor steps past that time (``bounds``); at equal times it acts first."""

    rank, bounds = -1, True

    def __init__(self, scheme: Synchronous | MultiRate, k: int) -> None:
        self.scheme, self.k = scheme, k
        self.model: DiscreteEventModel = scheme.compiled.models[k]
        self.name = scheme.compiled.names[k]
        self._after = scheme.t0  # the time of its last event (or the start)

    @property
    def time(self) -> float:
        return self.model.next_event(self._after)

    @property
    def finished(self) -> bool:
        return not self.time < self.scheme.until

    def act(self, limit: float) -> None:
        t = self.time
        if not self.scheme.fire(self.k, t):
            return  # not yet: some sub-model was rolled back behind t and catches up first
        if not self.model.next_event(t) > t:
            raise RuntimeError(f"discrete-event sub-model '{self.name}' scheduled its next "
                               f"event at {self.model.next_event(t):.9g}, not after t = {t:.9g}")
        self._after = t


def scheme_for(compiled: Any, t0: float, until: float, controller: Controller,
               master: MasterOptions, events: list[float],
               richardson: bool = False) -> Scheme:
    """The coupling scheme of a run, chosen once (``richardson``: a synchronous run's global
    error estimated by a companion run, :mod:`cosimstep.companion`)."""
    if master.name == "multirate":
        return MultiRate(compiled, t0, until, controller, master, events)
    return Synchronous(compiled, t0, until, controller, master, events, richardson)


class Run:
    """One run of a scheme: store, progress, failure capture, result."""

    def __init__(self, scheme: Scheme, *, store: str | Path | None, name: str,
                 settings: dict[str, Any], progress: bool | None,
                 budget: Budget | None = None,
                 output: tuple[float, bool] | None = None,
                 checkpoints: Any = None, resume: int | None = None) -> None:
        self.scheme, self.store, self.name = scheme, store, name
        self.settings, self.progress = settings, progress
        self.budget = budget
        self.output = output  # (interval, keep every step): values stored on a grid
        self.checkpoints = checkpoints  # a checkpoint.Checkpoints, or None
        self.resume = resume  # the id of the stored run to continue from its checkpoint

    def execute(self, reference: Reference | None,
                amend: Callable[[SimulationResult], None] | None = None, *,
                raise_on_failure: bool = False) -> SimulationResult:
        """Run to the end or to a failure and return the result; ``amend(result)`` runs before
        the store's summary is written (a re-run error estimate). The failure is raised after
        the store is closed if ``raise_on_failure``."""
        scheme, compiled = self.scheme, self.scheme.compiled
        sink: Any = Store(self.store) if self.store is not None else None
        resumed, checkpoint = "", None
        if sink is not None and self.output is not None:
            sink = GridStore(sink, self.output[0], scheme.t0, self.output[1])
        if sink is not None and self.resume is not None:
            try:
                checkpoint = sink.reopen(self.resume, self.settings, compiled.output_names)
            except Exception:
                sink.close()
                raise
            scheme.resume(self.checkpoints, checkpoint)
            resumed = f" (resumed from its checkpoint at t = {checkpoint.t:.9g})"
        elif sink is not None:
            sink.begin(self.name, self.settings, compiled.output_names, compiled.output_units)
            if self.checkpoints is not None and self.output is None \
                    and scheme.resumable() is None:
                scheme.resume(self.checkpoints, None)
        wall0 = time.perf_counter()
        bar = _progress(self.progress, scheme.t0, scheme.until)
        if bar is not None and checkpoint is not None:
            bar.update(checkpoint.t - scheme.t0)
        try:
            with _terminate_as_interrupt():
                status, message, failure = self._drive(sink, bar)
        finally:
            try:
                scheme.close()
            finally:
                if bar is not None:
                    bar.close()
        wall = time.perf_counter() - wall0
        result = self._result(status, message + resumed, wall, reference, sink)
        # an interrupt is the caller's to raise (simulate: RunInterrupted, with the result)
        failed = failure if status == "failed" else None
        if failed is not None:
            result.traceback = "".join(traceback.format_exception(failed))
        if amend is not None:
            amend(result)
        _say_beyond_tolerance(result, getattr(scheme, "controller", None))
        if sink is not None:
            sink.finish(result.status, result.message, result.t_end, result.wall_s,
                        result.summary(), result.calls, result.time_in_models,
                        symbols=result.symbol_table())
            sink.close()
        if failed is not None and raise_on_failure:
            raise failed
        return result

    def _drive(self, sink: Store | None,
               bar: Any) -> tuple[str, str, BaseException | None]:
        """The kernel over the scheme's actors; ``(status, message, failure)``."""
        scheme = self.scheme

        def job() -> None:
            kernel = Kernel(scheme.until)
            for actor in scheme.actors(kernel, sink, bar):
                kernel.add(actor)
            scheme.limit(self.budget)
            kernel.run(scheme.settle)

        try:
            if scheme.call_timeout is None:
                job()
            else:  # in a worker thread that this one watches (a hung call cannot hang the run)
                watch = _Watchdog(scheme.call_timeout)
                for master in scheme.masters():
                    master._watch = watch
                try:
                    watch.run(job, scheme.compiled.names)
                finally:
                    for master in scheme.masters():
                        master._watch = None
        except BudgetExceeded as exc:
            return "timed_out", f"at t = {scheme.t:.9g}: {exc}", None
        except EndOfSimulation as exc:
            return "ok", f"ended at t = {scheme.t:.9g}: {exc}", None
        except SubModelError as exc:
            if exc.hung:
                scheme.hung.add(exc.model)
            return "failed", str(exc), exc
        except StepSizeError as exc:
            return "failed", f"at t = {scheme.t:.9g}: {exc}", exc
        except Exception as exc:
            return "failed", f"at t = {scheme.t:.9g}: {type(exc).__name__}: {exc}", exc
        except Terminated as exc:
            return "interrupted", f"terminated (SIGTERM) at t = {scheme.t:.9g}", exc
        except KeyboardInterrupt as exc:
            return "interrupted", f"interrupted by the user at t = {scheme.t:.9g}", exc
        return "ok", "completed", None

    def _result(self, status: str, message: str, wall: float, reference: Reference | None,
                sink: Store | None) -> SimulationResult:
        scheme, compiled = self.scheme, self.scheme.compiled
        out = scheme.outcome()
        if sink is not None and scheme.offset:  # resumed: the points before it, from the store
            times, values = sink.points_before(scheme.offset)
            out.times = np.concatenate([times, out.times])
            out.values = np.vstack([values, out.values])
            out.steps = np.concatenate([np.diff(out.times[:scheme.offset + 1]), out.steps])
        err, ref_values = None, None
        names = [n for n in compiled.output_names if reference is not None
                 and n in reference.mapping]
        if reference is not None and len(out.times) > 1 and out.t_end > scheme.t0:
            try:
                err, ref_values = scheme.error(reference, out, names)
            except RuntimeError as exc:  # the reference's own solver failed: the run stands
                message = f"{message}; no error against the reference: {exc}"
        if sink is not None:
            scheme.store(sink, out)
            sink.add_events(out.events)
            if ref_values is not None:
                sink.add_reference(ref_values, [compiled.output_names.index(n) for n in names])
        return SimulationResult(
            status=status, message=message, t_end=out.t_end, names=compiled.output_names,
            units=compiled.output_units, times=out.times, values=out.values, calls=out.calls,
            steps_accepted=out.accepted, steps_rejected=out.rejected, step_sizes=out.steps,
            wall_s=wall, time_in_models=out.time_in_models,
            store=str(self.store) if self.store is not None else None,
            run_id=None if sink is None else sink.run_id, error=err,
            reference=ref_values, models=out.models, error_estimate=out.error_estimate,
            estimate_calls=out.estimate_calls, events=out.events,
            coupling=self._coupling_stats(), loops=self._loop_stats())

    def _coupling_stats(self) -> dict[str, Any] | None:
        """Strong coupling's passes and residuals (:mod:`cosimstep.iteration`), if iterated."""
        iterated = [m.iteration for m in self.scheme.masters() if m.iteration is not None]
        return iterated[0].stats.to_dict() if iterated else None

    def _loop_stats(self) -> dict[str, Any] | None:
        """What solving the algebraic loops cost, if the system has any."""
        solving = [m for m in self.scheme.masters() if m.system.loops]
        return solving[0].loop_stats.to_dict() if solving else None


class Terminated(KeyboardInterrupt):
    """SIGTERM during a run: ended like Ctrl-C (status ``interrupted``, results kept)."""


@contextlib.contextmanager
def _terminate_as_interrupt() -> Iterator[None]:
    """While a run goes on in the main thread, SIGTERM (what a batch system or ``kill`` sends)
    ends it the way Ctrl-C does; the previous handler comes back afterwards."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def stop(signum: int, frame: Any) -> None:
        raise Terminated

    previous = signal.signal(signal.SIGTERM, stop)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _progress(progress: bool | None, t0: float, until: float) -> Any:
    if progress is False:
        return None
    from tqdm import tqdm

    return tqdm(total=until - t0, delay=2.0, unit="s", file=sys.stderr,
                disable=None if progress is None else False,
                bar_format="{l_bar}{bar}| t={n:.3f}/{total:.3f} s [{elapsed}<{remaining}]")


__all__ = ["MultiRate", "Outcome", "Run", "Scheme", "Synchronous", "scheme_for"]

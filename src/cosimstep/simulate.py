"""The entry point: :func:`simulate` checks a system, picks its coupling scheme and runs it.

The work is elsewhere: :mod:`cosimstep.run` (one run: store, progress, failures, result),
:mod:`cosimstep.kernel` (the time-ordered heap of actors), :mod:`cosimstep.loops` (the
synchronous time loops) and :mod:`cosimstep.multirate`. Sub-model failures, step-size failures
and Ctrl-C become a result with a status and the values computed so far — never a lost run.
"""

from __future__ import annotations

import copy
import math
import sqlite3
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

from cosimstep.controllers import Controller, StepPolicy
from cosimstep.errors import RunInterrupted
from cosimstep.estimate import FACTOR
from cosimstep.kernel import Budget
from cosimstep.masters import MasterOptions, trapezoidal_refusal
from cosimstep.pair import first_error
from cosimstep.reference import Reference
from cosimstep.result import ModelStats, SimulationResult
from cosimstep.run import Run, scheme_for
from cosimstep.system import System
from cosimstep.tighten import (
    along_motion,
    calibrated,
    for_repeat,
    keeps_repeat,
    may_repeat,
    note,
    scaled,
    tightening,
)


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
    max_wall: float | None = None,
    max_calls: int | None = None,
    output_interval: float | None = None,
    output_steps: bool = False,
    checkpoint_every: float | None = None,
    checkpoint_steps: int | None = None,
    resume: int | None = None,
    tighten: bool = True,
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
        An interrupted run (Ctrl-C, SIGTERM) always raises, once everything it computed is
        stored: :class:`~cosimstep.errors.RunInterrupted`, a ``KeyboardInterrupt`` whose
        ``result`` is the run's result (status ``interrupted``; the first run's where a repeat
        was stopped; the looser twin's where ``estimate="rerun"`` was stopped in that), so
        that a script stops too.
    estimate:
        How an adaptive run estimates the global error it delivered
        (``SimulationResult.error_estimate``), without a reference: ``"sum"`` (free) adds up
        the controller's local estimates, as if no error decayed (``pc``: fading with its
        measured error memory, and the part along the outputs' motion carried as a time
        shift, :mod:`cosimstep.controllers.drift`); ``"rerun"`` runs the system
        again at 10× the tolerance first and takes a ninth of the difference
        (:mod:`cosimstep.estimate`; about 50 % more calls, counted in
        ``estimate_calls``), which also sees errors that decay, cancel or grow;
        ``"richardson"`` (controller ``pc``, synchronous masters) runs the co-simulation beside
        itself over the same step sequence at doubled steps and takes the difference over
        ``2^p − 1`` (:mod:`cosimstep.companion`; about 45 % more calls, counted in
        ``estimate_calls``): the most faithful of the three at tight tolerances.
    max_wall, max_calls:
        Whole-run budgets: wall-clock seconds and sub-model calls. A run that spends one ends
        with status ``"timed_out"`` and everything it computed so far (stored too).
    output_interval, output_steps:
        Store the values every ``output_interval`` seconds (linear between the run's points)
        instead of at every point, and with ``output_steps`` at every accepted point as well
        (:class:`~cosimstep.store.GridStore`). The result in memory keeps every point.
    checkpoint_every, checkpoint_steps:
        Write a checkpoint to the store every so many seconds of wall time and/or steps
        (fixed-step runs storing every point; :mod:`cosimstep.checkpoint`).
    resume:
        The id of a run in ``store`` to continue from its newest checkpoint, with the same
        system and settings; it keeps its id, and ends as one run that had never stopped. The
        result is the whole run (the points before the checkpoint read back from the store).
    tighten:
        Repeat the run once at a tighter tolerance when its own error estimate exceeds twice
        ``tol`` (controller ``pc``; under the multi-rate master only where its time shift is
        most of the estimate or the estimate is past 10 × ``tol``; :mod:`cosimstep.tighten`): the
        tolerance reduced by the factor the estimate missed by, at most 1000-fold, and where
        the summed estimate's time shift is its larger part (a limit cycle's phase error)
        without the error memory (:func:`~cosimstep.tighten.for_repeat`). The repeat is
        returned unless it failed or its own estimate is missing or no lower than the first
        run's; its message says why, ``SimulationResult.tightened`` describes the other run
        (which, its tolerance, estimate, calls and store id; for the repeat whether it kept
        the error memory) and ``calls_spent`` counts both. A kept repeat with the summed
        estimate measures the first run against itself (:mod:`cosimstep.pair`) and scales its
        own estimate by that run's measured error over its estimate
        (:func:`~cosimstep.tighten.calibrated`). Both runs are stored, the one
        that is not the result marked so. A budget (``max_calls``, ``max_wall``) covers both,
        and no repeat starts where what is left could not pay for a run like the first.
        ``False``: one run, whatever its estimate.
    """
    _check_types(system, controller, master, reference)
    budget = Budget(max_wall, max_calls)
    problems = estimate_problems(estimate, controller, master, resume)
    if problems:
        raise ValueError("`estimate`: " + "; ".join(f"{what} ({fix})" for what, fix in problems))
    if output_interval is not None and not (math.isfinite(output_interval)
                                            and output_interval > 0):
        raise ValueError(f"`output_interval` must be positive, got {output_interval}")
    output = (output_interval, output_steps) if output_interval is not None else None
    if resume is not None and (store is None or output is not None or estimate == "rerun"):
        raise ValueError("`resume` continues a run in `store` that stored every point: give "
                         "`store`, and no `output_interval` or re-run estimate")
    # the controller as given, before a run moves it: what a repeat starts from
    pristine = copy.deepcopy(controller) if tighten and may_repeat(controller) \
        else None

    def once(ctrl: Controller, spent: Budget, resumed: int | None,
             run_config: dict[str, Any] | None,
             amend: Callable[[SimulationResult], None] | None,
             repeat: bool = False) -> SimulationResult:
        """One run (after its looser twin for ``"rerun"``); a ``repeat`` (:func:`_repeat`)
        neither raises its failure nor writes checkpoints, which no command line could resume
        (its settings carry the tighter tol)."""
        looser = None
        if estimate == "rerun":  # the looser twin's calls come out of the run's budget
            looser = _simulate(system, until, scaled(ctrl, FACTOR), master, t0, None, None,
                               name, None, False, False, None, spent)
            if looser.status == "interrupted":
                raise RunInterrupted(looser)
            spent = spent.after(looser.calls_total)
        checkpoints = None
        if not repeat and (checkpoint_every is not None or checkpoint_steps is not None):
            from cosimstep.checkpoint import Checkpoints

            checkpoints = Checkpoints(checkpoint_every, checkpoint_steps)
        return _simulate(system, until, ctrl, master, t0, reference, store, name, run_config,
                         progress, raise_on_failure and not repeat, looser, spent, output,
                         checkpoints=checkpoints, resume=resumed,
                         richardson=estimate == "richardson", amend=amend)

    first = once(controller, budget, resume, config, None)
    if first.status == "interrupted":
        raise RunInterrupted(first)
    factor = tightening(first.status, first.error_estimate, controller,
                        multirate=master is not None and master.name == "multirate") \
        if pristine is not None else None
    if factor is None:
        return first
    # the controller that ran (a resumed run's too: a checkpoint is loaded into it) holds
    # the parts of its estimate that decide how the repeat treats the error memory
    measure = _first_error(system, pristine) if estimate == "sum" else None
    return _repeat(first, factor, along_motion(controller), pristine, budget, config, once,
                   raise_on_failure, measure)


def _first_error(system: System, controller: Controller
                 ) -> Callable[[SimulationResult, SimulationResult], float | None]:
    """How the pair measures its first run (:func:`cosimstep.pair.first_error`)."""
    policy: StepPolicy = controller.policy  # type: ignore[attr-defined]
    return lambda first, repeat: first_error(first, repeat, system, policy)


def _repeat(first: SimulationResult, factor: float, forget: bool, pristine: Controller,
            budget: Budget, config: dict[str, Any] | None, once: Callable[..., SimulationResult],
            raise_on_failure: bool,
            measure: Callable[[SimulationResult, SimulationResult], float | None] | None = None
            ) -> SimulationResult:
    """The run again at ``factor`` × its tolerances, without the error memory where
    ``forget`` (:mod:`cosimstep.tighten`), or the first
    run's result where the repeat did not improve on it: a failure, or an estimate of its own
    missing or not below the first run's (the only judge there is without a reference;
    measured: a Brusselator repeated from 2.4 x tol estimated 6.9 x and delivered 42 x). No
    repeat where the budget left could not pay for a run as long as the first (its calls, its
    estimate's, its wall time). The store says the same: the run that is not the result is
    marked so (:func:`~cosimstep.store.amend_run`)."""
    tol = pristine.policy.tol  # type: ignore[attr-defined]
    assert first.error_estimate is not None
    cost = first.calls_total + first.estimate_calls
    facts = _other("first", tol, first)
    why = note(tol, first.error_estimate, first.calls_total, factor, forget)
    remaining = budget.after(cost)
    if not remaining.affords(cost, first.wall_s):
        _amend(first, f"; not {why}: the budget left is smaller than this run", None)
        return first

    def amend(result: SimulationResult) -> None:
        result.message += f"; {why}"
        result.tightened = facts
        if measure is not None:
            _calibrate(result, first, measure, tol)

    # a failing repeat is reported, not raised: the first run is a whole result to fall back on
    try:
        second = once(for_repeat(pristine, factor, forget), remaining, None,
                      {**(config or {}), "tightened": facts}, amend, repeat=True)
    except RunInterrupted:  # stopped in the repeat's looser twin: the first run stands
        raise RunInterrupted(first) from None
    at = f"at tol {tol * factor:.3g}" + (f" (run {second.run_id})" if second.run_id else "") \
        + (" without the error memory" if forget else "")
    estimate = (second.tightened or {}).get("estimate_alone", second.error_estimate)
    if keeps_repeat(second.status, first.error_estimate, estimate):
        _amend(first, f"; repeated {at}, which is the result", False)
        return second
    if second.status != "ok":
        what = f"ended {second.status} ({second.message.removesuffix(f'; {why}')})"
    elif estimate is None or not math.isfinite(estimate):
        what = "gave no usable estimate of its own error"
    else:
        what = f"estimated its own error no lower, at {estimate / tol:.3g} x tol"
    first.tightened = {**_other("repeat", tol * factor, second), "status": second.status,
                       "memory": not forget}
    _amend(second, f"; not kept: run {first.run_id}, the first, is the result", False)
    _amend(first, f"; a repeat {at} {what}: this is the first run's result", None,
           {"tightened": first.tightened, "calls_spent": first.calls_spent})
    if second.status == "interrupted":
        raise RunInterrupted(first)  # the user stopped the repeat: the first run stands
    return first


def _calibrate(repeat: SimulationResult, first: SimulationResult,
               measure: Callable[[SimulationResult, SimulationResult], float | None],
               tol: float) -> None:
    """The repeat's estimate scaled by the first run's error as measured against the repeat
    over the first run's own estimate (:func:`~cosimstep.tighten.calibrated`), where it is
    the result; its own estimate and the first run's measured error are kept in
    ``tightened`` (``estimate_alone``, ``error``). Nothing changes where the pair cannot be
    compared.

    Whether the repeat is the result is decided on its own estimate, unscaled (:func:`_repeat`
    reads ``estimate_alone``): the scaled one may exceed the first run's estimate, which was
    never measured. This check runs first, with the same rule, so that a repeat that is not
    kept keeps the estimate it made."""
    alone, before = repeat.error_estimate, first.error_estimate
    if before is None or not keeps_repeat(repeat.status, before, alone):
        return
    error = measure(first, repeat)
    scaled = calibrated(alone, before, error)
    if scaled is None:
        return
    assert alone is not None and error is not None  # (calibrated gave a number)
    repeat.error_estimate = scaled
    repeat.tightened = {**(repeat.tightened or {}), "error": error, "estimate_alone": alone}
    repeat.message += (f"; measured against this run, the first one's error is "
                       f"{error / tol:.3g} x tol, {error / before:.3g} x its estimate: this "
                       f"run's estimate is scaled alike, to {repeat.error_estimate / tol:.3g} "
                       f"x tol ({alone / tol:.3g} x tol alone)")


def _other(run: str, tol: float, result: SimulationResult) -> dict[str, Any]:
    """``SimulationResult.tightened`` of the pair's other run: ``result``, run at ``tol``."""
    return {"run": run, "tol": tol, "error_estimate": result.error_estimate,
            "calls": result.calls_total, "estimate_calls": result.estimate_calls,
            "run_id": result.run_id}


def _amend(result: SimulationResult, text: str, kept: bool | None,
           updates: dict[str, Any] | None = None) -> None:
    """Add ``text`` to ``result``'s message, in memory and in its store (there marking it as
    not the result with ``kept = False``, and merging ``updates`` into its summary). A store
    that cannot be written (locked, full, the run deleted) costs the note there, never the
    result: the message says so and a warning is issued."""
    result.message += text
    if result.store is None or result.run_id is None:
        return
    from cosimstep.store import amend_run

    try:
        amend_run(result.store, result.run_id, text, kept, updates)
    except (sqlite3.Error, LookupError, OSError) as exc:
        result.message += f" (the store was not updated: {exc})"
        warnings.warn(f"{result.store}: run {result.run_id} not updated: {exc}", stacklevel=3)


ESTIMATES = ("sum", "rerun", "richardson")
"""How an adaptive run estimates its global error (:func:`simulate`'s ``estimate``)."""


def estimate_problems(estimate: str, controller: Controller, master: MasterOptions | None,
                      resume: int | None = None) -> list[tuple[str, str]]:
    """What keeps ``estimate`` from serving this run, each as (what, how to fix): checked by
    :func:`simulate`, and up front by ``run`` and sweeps, which report them all at once."""
    if estimate not in ESTIMATES:
        return [(f"must be one of {', '.join(ESTIMATES)}, got {estimate!r}",
                 f"choose one of {', '.join(ESTIMATES)}")]
    out = []
    if estimate == "rerun" and getattr(controller, "policy", None) is None:
        out.append((f"'rerun' re-runs at 10x the tolerance; controller '{controller.name}' "
                    "has none", "give --tol TOL, or drop --estimate"))
    if estimate != "richardson":
        if getattr(getattr(controller, "policy", None), "feedback", False):
            out.append(("the step control's feedback reads the companion's estimate, and "
                        f"estimate {estimate!r} runs none", "add --estimate richardson, or "
                        "drop the controller option feedback"))
        return out
    # the companion run repeats what pc keeps over one common step sequence
    if controller.name != "pc":
        adaptive = getattr(controller, "policy", None) is not None
        out.append((f"'richardson' repeats controller pc's scheme at doubled steps; controller "
                    f"'{controller.name}' is not pc",
                    "give --tol TOL without --controller (pc)"
                    + (", or --estimate rerun" if adaptive else "")))
    if master is not None and master.name == "multirate":
        out.append(("'richardson' needs one step sequence for every sub-model; the multirate "
                    "master has one per sub-model",
                    "use --master gauss-seidel or jacobi, or --estimate rerun"))
    if resume is not None:
        out.append(("'richardson' keeps a companion state that a checkpoint does not hold",
                    "a run with it cannot be resumed: run it again without --resume"))
    return out


def _check_types(system: Any, controller: Any, master: Any, reference: Any) -> None:
    """``TypeError`` naming every argument of :func:`simulate` of the wrong kind, with what
    to give instead (a string where an object belongs raised an ``AttributeError`` from deep
    inside: ``master="gauss-seidel"``)."""
    wrong = [f"`{name}` must be {kind}, got {type(value).__name__} {value!r:.60} ({fix})"
             for name, value, cls, kind, fix in (
                 ("system", system, System, "a System", "System().add(...).connect(...), or "
                  "load_system(path).system"),
                 ("controller", controller, Controller, "a Controller",
                  "e.g. Fixed(0.01) or make_controller('pc', None, 1e-4)"),
                 ("master", master, (MasterOptions, type(None)), "MasterOptions or None",
                  "e.g. MasterOptions('gauss-seidel', 2)"),
                 ("reference", reference, (Reference, type(None)), "a Reference or None",
                  "load_system(path).reference"))
             if not isinstance(value, cls)]
    if wrong:
        raise TypeError("; ".join(wrong))


def _simulate(system: System, until: float, controller: Controller,
              master: MasterOptions | None, t0: float, reference: Reference | None,
              store: str | Path | None, name: str, config: dict[str, Any] | None,
              progress: bool | None, raise_on_failure: bool,
              looser: SimulationResult | None, budget: Budget | None = None,
              output: tuple[float, bool] | None = None, *, checkpoints: Any = None,
              resume: int | None = None, richardson: bool = False,
              amend: Callable[[SimulationResult], None] | None = None) -> SimulationResult:
    """:func:`simulate` once; ``looser`` is the run at 10× the tolerance for ``"rerun"``;
    ``amend(result)`` runs once the estimate is in, before the store's summary is written."""
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
    if controller.needs_rollback and master.coupling_input == "trapezoidal":
        raise ValueError(trapezoidal_refusal(controller.name))
    events = sorted({float(e) for m in compiled.models for e in m.time_events() if t0 < e < until})
    scheme = scheme_for(compiled, t0, until, controller, master, events, richardson)
    settings = {"t0": t0, "until": until, "master": vars(master),
                "controller": controller.describe(), **(config or {})}
    if output is not None:
        settings["output_interval"], settings["output_steps"] = output
    if resume is not None and scheme.resumable() is not None:
        raise ValueError(f"cannot resume run {resume}: {scheme.resumable()}")
    run = Run(scheme, store=store, name=name, settings=settings, progress=progress,
              budget=budget, output=output, checkpoints=checkpoints, resume=resume)

    def finish(result: SimulationResult) -> None:
        _rerun_estimate(result, looser, controller, events)
        if amend is not None:
            amend(result)

    return run.execute(reference, finish, raise_on_failure=raise_on_failure)


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


__all__ = ["ModelStats", "SimulationResult", "simulate"]

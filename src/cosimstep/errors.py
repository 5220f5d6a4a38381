"""Error types.

Build-time problems (a wrong system description) are kept apart from run-time trouble (a
sub-model that fails while stepping): the first is raised with *every* problem listed so a user
fixes the file once; the second ends a run with a status and keeps the results computed so far.
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass
from typing import Any

import numpy as np


def is_number(value: Any) -> bool:
    """A setting's real number, NumPy's included, and not a boolean (``True`` is an int to
    Python, and ``--opt predictive=1`` is no switch)."""
    return isinstance(value, numbers.Real) and not isinstance(value, bool | np.bool_)


@dataclass(frozen=True)
class Problem:
    """One configuration problem: where it is, what is wrong and how to fix it."""

    where: str
    what: str
    fix: str = ""

    def __str__(self) -> str:
        text = f"{self.where}: {self.what}"
        return f"{text} (fix: {self.fix})" if self.fix else text


class ConfigurationError(ValueError):
    """A system description is wrong; ``problems`` lists every problem found, not just the first."""

    def __init__(self, problems: list[Problem], source: str | None = None) -> None:
        self.problems = list(problems)
        self.source = source
        # a system file's [master] and [controller] as read (MasterOptions and dict, each
        # None where the file's table has problems of its own), where the file could be read
        # that far (cosimstep.spec.finish)
        self.defaults: tuple[Any, dict[str, Any] | None] | None = None
        head = f"{len(self.problems)} problem(s) in {source or 'the system'}:"
        super().__init__("\n".join([head, *(f"  - {p}" for p in self.problems)]))


class SubModelError(RuntimeError):
    """A sub-model failed during a run (raised, returned NaN, or exceeded its time budget)."""

    def __init__(self, model: str, t: float, reason: str, h: float | None = None) -> None:
        self.model = model
        self.t = t
        self.h = h
        self.reason = reason
        where = f"t = {t:.9g}" + (f" (step to {t + h:.9g})" if h is not None else "")
        super().__init__(f"sub-model '{model}' failed at {where}: {reason}")

    @property
    def hung(self) -> bool:
        """The call timed out: its thread may still be running the model, so no retry."""
        return isinstance(self.__cause__, TimeoutError) or "TimeoutError" in self.reason


class EndOfSimulation(Exception):
    """A sub-model asked to end the simulation (an FMU's ``terminateSimulation``): the run
    ends ``ok`` at the last point every sub-model completed, saying who ended it and why."""

    def __init__(self, model: str, reason: str) -> None:
        self.model, self.reason = model, reason
        super().__init__(f"sub-model '{model}' ended the simulation: {reason}")


class StepSizeError(RuntimeError):
    """A step controller cannot continue (for example the step fell below its minimum)."""


class RestoreError(RuntimeError):
    """A sub-model's ``restore_state`` did not bring back the state it saved: every step
    re-run after a rejection would start from wherever the sub-model had got to."""


RESTORE_CHECKS = 3
"""Rejections per run (per sub-model under multirate) after which the restored sub-models'
outputs are compared with those stored at the step's start (:func:`restore_problems`)."""


def restore_problems(names: list[str], stored: list[np.ndarray], now: list[np.ndarray],
                     state: list[np.ndarray]) -> str | None:
    """Why ``restore_state`` failed, or ``None``: per sub-model, the outputs stored at the
    step's start, those read after the restore, and which of them come from its state (not
    direct feedthrough, not discrete), compared to within rounding: without this a restore
    that does nothing makes every re-run start wherever the sub-model had got to, and the
    run ends on a step size far below anything the error asks for. A value that is not finite
    now is not judged: a sub-model whose trial step just failed may report NaN until it steps
    again, which is the failure's business, not the restore's."""
    wrong = []
    for name, a, b, mask in zip(names, stored, now, state):
        mask = mask & np.isfinite(b)
        a, b = a[mask], b[mask]
        if a.size and not np.all(np.abs(a - b) <= 1e-13 * (1.0 + np.abs(a))):
            i = int(np.argmax(np.abs(a - b)))
            wrong.append(f"'{name}' (an output was {a[i]:.6g} at the step's start, "
                         f"{b[i]:.6g} after restore_state)")
    if not wrong:
        return None
    return (f"restore_state did not bring back the saved state of {', '.join(wrong)}; a "
            "controller that rejects and re-runs steps needs it: fix save_state/restore_state, "
            "or declare can_save_state=False and run with a fixed step")


ROUND_OFF = 1e-13
"""A step's share of ``tol`` (relative) below which its error estimate is round-off: a
difference of two runs' outputs resolves no more (about 500 ulps)."""


def still_failing(failure: tuple[SubModelError, float] | None, t: float, share: float,
                  stop: Exception) -> SubModelError | None:
    """The error to end a run with when its step fell below ``hmin`` at ``t`` (``stop``)
    while creeping up on the end of the step a sub-model last failed on (``failure``: that
    error and that end), else ``None``.

    After a failed trial the steps creep up on the time the sub-model fails at; there, at
    steps of ~1e-10 s, a step's share of ``tol`` falls below round-off, the last rejection is
    the error estimate's, and ``hmin`` was reached on a message about an error of 1e-16 while
    the sub-model's own exception was lost (a Python sub-model raising past t = 1000 s under
    ``pc``). Only there — short of the failed step's end, at a share (``tol·h/T``) below
    :data:`ROUND_OFF` — is the failure what stopped the run; a stop with a resolvable share
    is the estimate's own (a jump the master was not told of), however recent a failure."""
    if failure is None or not t < failure[1] or not share < ROUND_OFF:
        return None
    exc, end = failure
    return SubModelError(exc.model, exc.t, f"{exc.reason} (the run did not get past "
                         f"t = {end:.12g}, where it failed: retried with steps down to where "
                         f"their share of tol, {share:.1g}, is round-off; then {stop})", exc.h)


class RunInterrupted(KeyboardInterrupt):
    """A run ended by Ctrl-C or SIGTERM, after everything it computed was stored: its
    :class:`~cosimstep.result.SimulationResult` (status ``interrupted``) is :attr:`result`.

    Raised rather than returned so that the interrupt stops the caller as well: a script
    looping over runs went on with its next run after each Ctrl-C. A ``KeyboardInterrupt``,
    so code that does not expect it ends as on any Ctrl-C.
    """

    def __init__(self, result: Any) -> None:
        super().__init__(result.message)
        self.result = result

    def __reduce__(self) -> tuple[Any, ...]:
        # rebuilt from its result (the default would pass the message as the result): a run
        # in a worker process of a pool comes back whole
        return (type(self), (self.result,))

"""The global error of an adaptive run, estimated by a companion run at doubled steps.

A sum of local error estimates says what the error would be if every error made were carried to
the end unchanged; the coupled system decides otherwise (errors decay, cancel in oscillations,
or grow with a phase drift), and on the benchmark suite that spreads the delivered error over
0.14–10× the sum. *Global Richardson extrapolation* measures the propagation instead of assuming
it: beside the run, the same co-simulation takes the same step sequence with every two of the
run's steps as one. Both make the same kind of error, ``C(t)·h^p`` and ``C(t)·(2h)^p`` (the
step sequence is the same up to the factor), so at the companion's points they differ by
``(2^p − 1)`` times the run's own global error, however it was propagated.

What the companion repeats is what the run keeps, so its error has the run's order:

* ``pc``'s corrector — inputs interpolated one degree above the extrapolation order ``q`` —
  global order ``q + 2``: pairs of accepted steps, each pair one predictor–corrector step;
* where some receiver holds its inputs over a step, ``pc`` keeps two half steps of plain
  passes (step doubling): each accepted step once, as one plain pass, at the global order
  ``q + 1`` that ``pc``'s own doubling estimate assumes. A receiver with a state that holds
  its inputs is second-order at best, which makes the estimate up to 7/3 too small at ``q = 2``;
  a held receiver without state (a spring that only computes a force) loses nothing by holding
  (measured: the algebraic-loop example with IQN-ILS, global order 3).

It runs from its own saved state and its own history, one step behind the run (when the run has
completed a pair); its calls are counted apart (``estimate_calls``), about 40–50 % of the run's.
At a time event the pair is closed and its extrapolation restarts, as the run's does; where the
sub-models' state jumps (a discrete event, a state event) the companion starts again from the
run's state, carrying the estimate reached so far (the error made before the jump is not
propagated further). Measured on the suite with ``pc`` (docs/benchmarks.md): within 0.2–5× of
the measured error on every problem at tol ≤ 1e-4, where the summed estimate spans 0.14–10×.
"""

from __future__ import annotations

import copy
from typing import Any

import numpy as np

from cosimstep.controllers.coupling import _effective_order, _predictor_order
from cosimstep.errors import SubModelError
from cosimstep.loops import LoopContext
from cosimstep.masters import Master


class Companion:
    """The run at doubled steps beside it, and the global error estimate it gives."""

    def __init__(self, master: Master, scale: Any) -> None:
        """``scale(y)``: the tolerance's norm per value divided by ``tol`` (``1 + |y|`` for
        ``atol = rtol = tol``), the norm of the estimate."""
        self.master, self.scale = master, scale
        held = bool(np.any(master.held & master.consumed))
        q = master.options.extrapolation
        # see the module docstring: what pc keeps, and its global order
        self.pairing = 1 if held else 2
        self.order = q + 1 if held else q + 2
        self.factor = 2.0 ** self.order - 1.0
        self.ctx = LoopContext(master)
        # strong coupling: its own accelerator (IQN-ILS keeps a Jacobian across steps), so
        # the run's iterations do not see the companion's steps
        self._iteration = copy.deepcopy(master.iteration)
        self.estimate = 0.0  # the largest scaled global error estimate so far
        self.calls = np.zeros(len(master.system.models), dtype=np.int64)
        self.lost: str | None = None  # why the companion stopped, if it did
        self.pairs = 0  # steps the companion took
        self.fallbacks = 0  # of which taken as the run took them (a doubled step failed)
        self._carried = 0.0  # the estimate at the last restart from the run's state
        self._token: Any = None
        self._start = 0.0
        self._ends: list[float] = []  # the run's step ends since the companion's last point

    def begin(self, t: float, y: np.ndarray) -> None:
        """Start beside the run at ``t`` (its state now, its outputs ``y``)."""
        self._token = self.master.save()
        self.ctx = LoopContext(self.master)
        self.ctx.push(t, y)
        self._start, self._ends = t, []

    def accepted(self, t: float, y: np.ndarray, close: bool) -> None:
        """The run accepted a step ending at ``t`` with outputs ``y``; ``close``: it landed on
        an event or the end, so the pair ends here even if it is a single step."""
        if self.lost is not None:
            return
        self._ends.append(t)
        if len(self._ends) >= self.pairing or close:
            self._step(t, y)

    def restart(self) -> None:
        """A time event at the companion's last point: extrapolation starts again there."""
        if self.lost is None:
            self.ctx.restart()

    def resync(self, t: float, y: np.ndarray) -> None:
        """The sub-models' state jumped at ``t``: go on from the run's state, keeping the
        estimate reached (the companion's own state knows nothing of the jump)."""
        if self.lost is None:
            self._carried = self.estimate
            self.begin(t, y)

    def _step(self, t: float, y_run: np.ndarray) -> None:
        master = self.master
        h = t - self._start
        run_state = master.save()
        calls, spent = master.calls.copy(), master.time_in_models.copy()
        kept = master.last, master.assumed, master.iteration
        master.iteration = self._iteration
        try:
            y = self._advance(h)
        except SubModelError as exc:
            if exc.hung:
                raise
            self.lost = f"the companion run failed at t = {self._start:.9g}: {exc.reason}"
            return
        finally:
            master.last, master.assumed, master.iteration = kept
            master.restore(run_state)
            self.calls += master.calls - calls
            master.calls[:] = calls
            master.time_in_models[:] = spent
        self._start, self._ends = t, []
        gap = float(np.max(np.abs(y_run - y) / self.scale(y_run))) if y.size else 0.0
        self.estimate = max(self.estimate, self._carried + gap / self.factor)

    def _advance(self, h: float) -> np.ndarray:
        """From the companion's state over ``h`` (the pair), its points pushed; if a sub-model
        fails on the doubled step (a step longer than the run ever took may leave its domain),
        the pair is taken as the run took it: it then adds no difference of its own, which is
        better than losing the estimate."""
        master, start = self.master, self._start
        master.restore(self._token)
        try:
            ends = [start + h]
            y = self._scheme(start, h)
        except SubModelError as exc:
            if exc.hung or len(self._ends) < 2:
                raise
            self.fallbacks += 1
            master.restore(self._token)
            ends, t = self._ends, start
            for end in ends[:-1]:
                self.ctx.push(end, self._scheme(t, end - t))
                t = end
            y = self._scheme(t, ends[-1] - t)
        if self.ctx.at_edge(ends[-1], h):  # as the run: go on from the right-hand values
            y = master.right_limits(ends[-1], y)
        self.ctx.push(ends[-1], y)
        self._token = master.save()
        self.pairs += 1
        return y

    def caveat(self) -> str | None:
        """What makes the estimate unreliable, if anything (the run says so)."""
        if self.lost is not None:
            return (f"{self.lost}; error_estimate is the controller's own (the summed "
                    "local estimates) instead")
        if self.fallbacks > 0.1 * max(self.pairs, 1):
            return (f"the companion took {self.fallbacks} of its {self.pairs} steps as the run "
                    "took them (a sub-model failed on the doubled step): error_estimate misses "
                    "their error and is too small")
        return None

    def _scheme(self, t: float, h: float) -> np.ndarray:
        """One step of what the run keeps, at the companion's (doubled) step."""
        ctx = self.ctx
        if self.pairing == 1:
            return ctx.step(t, h)
        q = _effective_order(ctx)
        token = self.master.save()
        y_p = ctx.step(t, h, order=_predictor_order(q))
        self.master.restore(token)
        return ctx.step(t, h, order=q + 1, end=y_p)

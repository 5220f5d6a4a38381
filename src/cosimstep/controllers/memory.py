"""How long an error made now persists: the *error memory* of the coupled system, measured.

A controller that holds the sum of its local errors to the tolerance assumes every error is
carried to the end of the run. Where the coupled system forgets (damping, a stable fast
partition, a slow part relaxing to its forcing), an error made at ``t`` has faded a while
later, so the global error is about the local error rate times the *memory*
``M = ∫₀^T φ(s) ds`` — ``φ(s)`` what an output still holds of a perturbation ``s`` after it
was made, relative to the perturbation's first size — not times the run's length ``T``: the
controller then delivers about ``M/T`` of what was asked (measured 1–5 % on damped and KPR-type
problems). Knowing ``M``, each step may spend its share of the tolerance over ``M`` instead of
``T``.

``M`` of a black-box system is measured, not guessed, by a *probe*: now and then, right after
an accepted step, the coupled system is run on for :attr:`ErrorMemory.steps` steps of the
current length twice — from the kept (corrector) state and from the predictor's end state,
which differs from it by about one local error, the right kind of perturbation — both with the
same scheme (extrapolated inputs from their own histories), then the run goes on from the kept
state. ``φ_j`` is their scaled difference in output ``j``, relative to the largest first
difference; ``M`` is the largest over the outputs of ``∫ φ_j`` over the probe plus a tail: each
output holds its own part of every local error for as long as its ``φ_j`` says (an output that
integrates another's keeps what it took while that one's part fades).

The tail is where a wrong answer would break the tolerance, so decay is extrapolated only when
the probe shows the *shape* of decay, and then only at the slowest rate seen. A perturbation
that fades is a mixture of decaying modes, and a positive sum of decaying exponentials is
log-convex: ``log φ`` in the middle of the probe lies on or below the chord between its ends.
(One output's part may mix modes of both signs, which need not be log-convex: it is then held,
the safe side.)
A perturbation rotating through an oscillation (between a position and a velocity of different
scales) dips like a cosine, which is log-concave, above the chord. Only rounding is allowed for
(:data:`CONVEXITY_SLACK`); a concave probe holds ``φ`` at its last value (no decay assumed) —
a memory too short would overspend the tolerance, one too long only spends calls. For the same
reason the memory used is the longest of the last :attr:`~ErrorMemory.window` measurements,
and the run length until that many exist (since the last event: :meth:`ErrorMemory.forget`).
A probe costs ``2 × steps`` master steps. Until the window is full the probes follow each other
every ``steps`` accepted steps (every step meanwhile pays for the run's whole length); then
they are at least :attr:`~ErrorMemory.every` accepted steps and 1/:attr:`~ErrorMemory.per_run`
of the run apart, and stop when two in a row found half the run or more (nothing to gain).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from cosimstep.errors import SubModelError

NO_DECAY = 0.5
"""A memory of this share of the run or more counts as no decay to speak of: the probe saw the
perturbation stay about its size (an undamped system), not fade."""

Step = Callable[[float, float, tuple[tuple[float, np.ndarray], ...]], np.ndarray]
"""``step(t, h, points)``: one master step from the current state, extrapolating from the
run's history plus ``points`` (time, outputs) after it."""


class ErrorMemory:
    """Probes of the coupled system's error memory (see the module docstring)."""

    def __init__(self, every: int = 10, steps: int = 6, window: int = 3,
                 per_run: int = 40) -> None:
        if every < 0 or steps < 3 or window < 1 or per_run < 1:
            raise ValueError("need every >= 0 (0: off), steps >= 3, window >= 1, per_run >= 1")
        self.every, self.steps, self.window = int(every), int(steps), int(window)
        self.per_run = int(per_run)
        # (time, memory [s], horizon [s]) of the probes that still hold (see :meth:`due`)
        self.measured: list[tuple[float, float, float]] = []
        self.made = 0  # probes that measured something since the run started
        self._since = 0
        self._last = -math.inf
        self._gap = 0.0
        self._span = math.inf
        self._end = math.inf

    def describe(self) -> dict[str, int]:
        """Its settings, for the results store (what it measured is state, not settings)."""
        return {"every": self.every, "steps": self.steps, "window": self.window,
                "per_run": self.per_run}

    def reset(self, t0: float, t_end: float) -> None:
        """A run starts: no measurement yet, the first probe after `steps` accepted steps."""
        self.measured.clear()
        self.made = 0
        self._since, self._last = 0, -math.inf
        self._gap = (t_end - t0) / self.per_run
        self._span, self._end = t_end - t0, t_end

    @property
    def memory(self) -> float:
        """The memory the controller may use [s]: the longest of the last measurements."""
        if self.every == 0 or len(self.measured) < self.window:
            return math.inf
        return max(m for _, m, _ in self.measured[-self.window:])

    def due(self, t: float, h: float = 0.0) -> bool:
        """Whether a step of ``h`` accepted at ``t`` is to be probed (save the predictor's
        state).

        Until :attr:`window` measurements exist (at the start and after an event) every step
        shares the tolerance over the run's whole length, the dearest assumption, so the
        probes come as soon as they can — each :attr:`steps` accepted steps after the last,
        whatever the time between — and the spacing (:attr:`every`, 1/:attr:`per_run` of the
        run) applies only once the memory is known, to keep it up to date at little cost.

        A measurement that saw no decay to speak of (half the run or more) over a horizon
        shorter than the step now taken is dropped first: that nothing faded within a span
        shorter than one of today's steps says nothing about the errors these steps make.
        Out of a boundary layer the steps grow a hundredfold; the first probes, made at its
        small steps, saw the layer's slow part standing still and would otherwise have
        stopped the probing for the whole run (:meth:`_settled`). A measurement that saw
        decay is kept: it is evidence that errors fade, and the window's longest is used.
        """
        if h > 0.0 and any(m >= NO_DECAY * self._span and horizon < h
                           for _, m, horizon in self.measured):
            self.measured = [e for e in self.measured
                             if e[1] < NO_DECAY * self._span or e[2] >= h]
        if self.every == 0 or self.made >= self.per_run or self._settled():
            return False
        if len(self.measured) < self.window:
            return self._since >= self.steps
        return self._since >= self.every and t - self._last >= self._gap

    def _settled(self) -> bool:
        """The last two measurements found a memory of half the run or more: the calls a
        probe costs would not buy a looser step worth them (an undamped system). Two, not a
        window: stopping early only keeps the whole-run budget, which is safe."""
        last = self.measured[-2:]
        return len(last) == 2 and all(m >= NO_DECAY * self._span for _, m, _ in last)

    def forget(self) -> None:
        """An event: the dynamics after it are not those the probes measured (a plant at rest
        before a pump failure forgets fast; the transient after it does not), so the memory is
        the run's length again until probes after the event measure it."""
        self.measured.clear()
        self._since = 0

    def accepted(self) -> None:
        self._since += 1

    def attempted(self, t: float) -> None:
        """A probe was started at ``t``: the next one is counted from here, whether this one
        measures anything or not."""
        self._since, self._last = 0, t

    def probe(self, t: float, h: float, kept: tuple[Any, np.ndarray],
              other: tuple[Any, np.ndarray], scale: np.ndarray, step: Step,
              restore: Callable[[Any], None]) -> None:
        """Run on from the ``kept`` (state, outputs at ``t``) and the ``other`` one, ``steps``
        steps of ``h``, and record the memory; the sub-models end at the kept state.

        A probe that would pass the end of the run (an FMU may refuse to step past its stop
        time) is not made; one in which a sub-model fails is a measurement lost, not a failed
        run (a hung sub-model still ends it).
        """
        self._since, self._last = 0, t
        lengths = np.full(self.steps, h)
        times = t + np.concatenate([[0.0], np.cumsum(lengths)])
        if times[-1] > self._end:
            return
        paths = []
        try:
            for token, y0 in (kept, other):
                restore(token)
                points = [(t, y0)]
                for j, length in enumerate(lengths):
                    y = step(float(times[j]), length, tuple(points))
                    points.append((float(times[j + 1]), y))
                paths.append(np.array([y for _, y in points]))
        except SubModelError as exc:
            if exc.hung:
                raise
            restore(kept[0])
            return
        restore(kept[0])
        parts = np.abs(paths[1] - paths[0]) / scale  # rows: the probe's times; columns: outputs
        first = float(parts[0].max())
        if not (first > 0 and np.isfinite(parts).all()):
            return
        self.measured.append((t, _longest(times - t, parts / first, self._span), times[-1] - t))
        self.made += 1


def _longest(s: np.ndarray, parts: np.ndarray, span: float) -> float:
    """The memory of the output that keeps its part of a perturbation longest: the largest
    :func:`_memory` over the columns of ``parts`` (each output's difference over the probe,
    relative to the largest first difference of all), outputs the probe never moved left out.

    Why each output on its own: output ``j``'s global error is the sum of the local errors,
    each weighted by the part ``φ_j`` of it that ``j`` still holds later, so the budget must
    hold for the output with the largest ``∫φ_j``. The difference's norm alone (its largest
    output at each time) has the tail of whatever part was largest at first: a fast part that
    fades hides an output that integrates it and keeps what it took (a PI controller's
    integral, a product's amount, a residual that only integrates): on a PI-controlled DC
    motor the norm's tail said 0.08 s where the integral keeps its part for the rest of the
    run (docs/concepts.md, "Integrating outputs: each output's memory").

    ``parts`` must hold a positive, finite entry in its first row (:meth:`ErrorMemory.probe`
    checks it): there is then at least one output to take the largest over.
    """
    return max(_memory(s, parts[:, j], span) for j in range(parts.shape[1])
               if parts[:, j].any())


def _memory(s: np.ndarray, phi: np.ndarray, span: float) -> float:
    """``∫₀^span φ`` for a perturbation's relative size ``φ`` sampled at the offsets ``s``.

    Trapezoids over the samples, then the tail: decaying at the slowest rate seen when the
    samples after the first (the first interval may still hold a fast transient) are
    log-convex (see the module docstring), held at the last value otherwise.
    """
    sampled = float(np.sum(0.5 * (phi[1:] + phi[:-1]) * np.diff(s)))
    rest = span - float(s[-1])
    if rest <= 0:
        return sampled
    rate = _decay_rate(s[1:], phi[1:])
    if rate > 0:
        return sampled + float(phi[-1]) * -math.expm1(-rate * rest) / rate
    return sampled + float(phi[-1]) * rest


CONVEXITY_SLACK = 0.01
"""How far above the chord (a fraction of the drop) the middle of ``log φ`` may lie and still
count as decay: rounding only. A decay's mixture lies on or below the chord; a cosine lies above
it by ``Δ/(4 sin 2a)`` of the drop over a window of ``Δ`` radians from phase ``a``, so even a
slow oscillation seen for a few steps (``Δ`` of a few hundredths) is told apart. With 0.1, the
undamped stiff two-mass oscillator passed windows from the flank of its slow mode as decay and
delivered 7.9 × tol at tol 1e-6 (2.4 × with 0.01)."""


def _decay_rate(s: np.ndarray, phi: np.ndarray) -> float:
    """The rate the tail of ``φ`` decays at when ``φ`` over ``s`` looks like decay, else 0.

    Decay means a log-convex drop (see :data:`CONVEXITY_SLACK`); its local rate then falls
    towards the slowest mode's, so the smallest rate seen over the intervals is the one carried
    on — the last interval's, unless the samples scatter (then the slowest of them: a rate read
    too fast overspends the tolerance, one read too slow only spends calls).
    """
    if len(phi) < 3 or not (phi > 0).all():
        return 0.0
    log = np.log(phi)
    drop = float(log[0] - log[-1])
    if drop <= 0 or log[-1] >= log[-2]:
        return 0.0
    mid = len(s) // 2
    chord = log[0] + (log[-1] - log[0]) * (s[mid] - s[0]) / (s[-1] - s[0])
    if log[mid] - chord > CONVEXITY_SLACK * drop:
        return 0.0
    return max(float(np.min(-np.diff(log) / np.diff(s))), 0.0)

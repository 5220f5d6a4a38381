"""Multi-rate asynchronous co-simulation (thesis 4.2.6, appendix C).

Every sub-model keeps its own time, its own step and its own stored trajectory. The scheduler is
a priority queue on time: the sub-model farthest behind runs next (appendix C's "race"). The
values it needs over ``[T, T + h]`` come from its partners' stored trajectories: interpolated
where a partner has already been, extrapolated beyond a partner's current time.

**Extrapolate, verify, correct.** A step that used extrapolated values is *pending*. A sub-model
is only picked again when every other one has passed its time, so by then its partners' true
trajectories cover the whole pending step: the master compares the inputs it assumed with the
inputs that actually happened and, when they differ, rolls the sub-model back to the start of
that one step (a single saved state per sub-model suffices, for the reason just given) and
re-runs it with the true inputs — one extra call, which also measures the sub-model's
sensitivity to its inputs. Every such step is corrected: keeping the ones whose estimated error
looked small (sensitivity × input difference) was measured to be where nearly all of the error
came from (docs/concepts.md). Waiting for partners instead would let the slow sub-model step no
further than the fast one.

**Step control per sub-model.** A sub-model's step decides how well *others* can interpolate its
trajectory: the error a consumer makes is its sensitivity to inputs times the interpolation
error of this trajectory. The interpolation error is estimated for free from the stored points
(a cubic through the newest four against a quartic through five), the sensitivity is measured by
the corrections, and the step follows from the same global-error policy as the synchronous
controllers (:class:`~cosimstep.controllers.StepPolicy`). Grey-box sub-models are also checked
for steps too long to resolve their own trajectory (aliasing), which no sample-based estimate
can see. How long an error persists in the coupled system (its *error memory*) is measured as
the synchronous ``pc`` measures it, by probes made after bringing the sub-models to one time
(:mod:`cosimstep.race_memory`); the tolerance is then shared over that memory. A sub-model that
holds its inputs over a step (no input derivatives) is judged by what it holds — the mean of
the held value's deviation and the lag a held ramp leaves (:meth:`Multirate.hold_deviation`,
:meth:`Multirate.hold_lag`) — and its sensitivities are measured by probes from its first step.
"""

from __future__ import annotations

import bisect
import dataclasses
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from cosimstep.controllers.base import StepPolicy
from cosimstep.errors import (
    RESTORE_CHECKS,
    StepSizeError,
    SubModelError,
    still_failing,
)
from cosimstep.events import MAX_EVENTS, DiscreteEventModel, Event
from cosimstep.extrapolation import (
    evaluate,
    evaluate_small,
    negligible,
    taylor_coefficients,
    weight_matrix,
)
from cosimstep.kernel import Actor, Budget, Kernel
from cosimstep.loops import EVENT_TOL, crossing, landing_step
from cosimstep.masters import Master, MasterOptions, jumped
from cosimstep.race_drift import RaceShift
from cosimstep.race_memory import PROBE_EVERY, RaceMemory
from cosimstep.system import CompiledSystem

NODES = np.array([0.0, 1 / 3, 2 / 3, 1.0])  # where inputs are sampled over a step (a cubic)
BETWEEN = np.array([1 / 6, 1 / 2, 5 / 6])  # where that cubic is checked against the partners
STENCIL = 4  # stored points a partner's trajectory is interpolated from (a local cubic)
INITIAL_GAIN = 10.0  # 1/s, until a consumer's sensitivity has been measured once
GAIN_SPAN = 4.0
"""A measured gain is taken to hold for steps within this factor of the one it was measured
on, and measured again outside (:meth:`Multirate._refresh_gain`). The estimate scales the
response to an input error linearly with the step (``gain · h · e``), which is right for a
receiver that integrates its input; one that settles within the step (a stiff partition) answers
with its static sensitivity, so its gain falls like ``1/h``: a gain from the steps of a boundary
layer, kept, overstated the slow sub-model's error 100-500× once the steps were 100× longer,
and one measured on long steps would understate it on short ones."""
CALIBRATION = 0.3
"""Scale of the one-sided interpolation estimate, measured (docs/concepts.md). The
cubic-against-quartic difference at the newest interval overstates what a consumer reads there
(consumers mostly read through centred stencils, and local errors of oscillating systems partly
cancel). At tol 1e-4, 0.3 put the mixed pendulums, problem 6 and problem 9 at 0.03–4.4 × tol;
0.1 left the λ = 10 / 30 pendulums at 25× / 39×, 1.0 cost 30 % more calls for 2–3× less error."""
MAX_RESYNC = 3
"""Rollback rounds per chain of corrections (guard against endless re-synchronization): a
sub-model rolled back by a correction of round ``r`` re-runs its steps as round ``r + 1``
until it is past the time it was rolled back from (:attr:`Track.resync`)."""
MAX_PIECES = 64  # a pending step is re-run as at most this many steps
FAILED_TRIAL_SHRINK = 0.25  # step factor after a trial step the sub-model failed on
ALIAS = 0.3  # relative slope mismatch beyond which a grey-box output's samples no longer
# resolve it, and the mismatch is read as an interpolation error (Multirate.slope_error)


@dataclass(frozen=True)
class _Verdict:
    """A trial step judged: the next step, why it was rejected (``None``: accepted), and the
    errors it adds to the run's estimate (:meth:`Multirate.error_estimate`)."""

    h_next: float
    why: str | None
    spent_out: float
    spent_in: float
    ratio: float = 0.0  # the consumer-facing error ratio (interpolation of the trajectory)
    power: float = 4.0  # the power of h that ratio scales with on a smooth trajectory
    lag: float = 0.0  # the lasting error of a receiver that holds its inputs (hold_lag)


@dataclass
class Track:
    """One sub-model's clock, trajectory, step control and statistics."""

    index: int
    name: str
    policy: StepPolicy
    h: float
    times: list[float] = field(default_factory=list)
    rows: list[np.ndarray] = field(default_factory=list)
    slopes: list[np.ndarray] = field(default_factory=list)  # grey box only
    segment: int = 0  # first point after the last time event (extrapolation restarts there)
    pending: tuple | None = None  # (token, t0, h, assumed inputs at NODES)
    gain: float | None = None  # measured: scaled output change / (h · scaled input change)
    gain_h: float = math.nan  # the step the gain was measured on
    # a receiver that holds its inputs: scaled output change per scaled half-step swing of an
    # input (down in the first half, up in the second) / h^2 (Multirate._refresh_gain)
    moment: float = math.nan  # nan: not measured yet; inf: its probe failed (taken as fast)
    lag: float = 0.0  # the largest lasting error of holding its inputs so far (hold_lag)
    gain_checks: int = 0  # calls that measured the gain (and a swing response) again
    probes: int = 0  # calls made by the error memory's probes (race_memory)
    calls: int = 0
    accepted: int = 0
    rejected: int = 0
    corrections: int = 0
    verified: int = 0
    failed_trials: int = 0  # rejections because the sub-model failed on the trial step
    # the last such failure and the end of the step it failed on (errors.still_failing)
    failure: tuple[SubModelError, float] | None = None
    rollbacks: int = 0  # times it was rolled back to re-run with a partner's corrected values
    missed_rollbacks: int = 0  # rollbacks wanted with no saved state to go back to
    replaced: int = 0  # accepted steps later dropped (rollback) or re-run in more pieces, net
    states: dict[int, Any] = field(default_factory=dict)  # saved state at times[i], by i
    resync: tuple[int, float] = (0, -math.inf)  # (round, until): see MAX_RESYNC
    discrete: bool = False  # a discrete-event sub-model: outputs held, changed only by fire()
    spent_out: float = 0.0  # Σ estimated errors its interpolated trajectory caused in consumers
    spent_in: float = 0.0  # Σ estimated errors from inputs its steps did not resolve
    steps: list[float] = field(default_factory=list)
    time_in_model: float = 0.0

    @property
    def t(self) -> float:
        return self.times[-1]


class Multirate:
    """Runs a compiled system with one adaptive step per sub-model.

    Parameters
    ----------
    system:
        The compiled system; sub-models must be able to save and restore their state and have no
        direct feedthrough (an output that depends on the input at the same instant has no
        trajectory of its own to interpolate).
    policy:
        The error policy (tolerance, limits) every sub-model's controller copies.
    h0:
        First step of every sub-model.
    order:
        Degree of the extrapolation beyond a partner's current time.
    interpolation:
        ``None`` for the built-in local cubic (fast), or a method of
        :mod:`cosimstep.interpolation` by name for the partners' trajectories.
    probe_every:
        Accepted rounds between probes of the error memory once it is known
        (:mod:`cosimstep.race_memory`); 0: not measured, the tolerance is shared over the run.
    """

    def __init__(self, system: CompiledSystem, policy: StepPolicy, h0: float,
                 order: int = 2, interpolation: str | None = None,
                 resync: str = "partial", probe_every: int = PROBE_EVERY) -> None:
        problems = refusals(dict(zip(system.names, system.models)), interpolation)
        if problems:
            raise ValueError("the multirate master re-runs steps and interpolates trajectories; "
                             + "; ".join(problems) + " — use the gauss-seidel or jacobi master")
        self.system = system
        self.order = order
        self.h0 = h0
        # the calls are made (and named, counted, watched) as the synchronous master makes them
        self._caller = Master(system, MasterOptions("multirate", order, call_timeout=None))
        self.method = None
        if interpolation is not None:
            from cosimstep.interpolation import make_interpolator

            self.method = make_interpolator(interpolation)
        self.owner = np.array(system.owners, dtype=int)
        # per global output: its owner and its column among the owner's outputs (Python ints)
        self._column = [(k, j - system.output_slices[k].start)
                        for j, k in enumerate(system.owners)]
        self.consumers = [sorted({k for k in range(len(system.models))
                                  if j in self._sources(k)}) for j in range(len(system.models))]
        self.tracks = [Track(k, n, _copy_policy(policy), h0,
                             discrete=isinstance(m, DiscreteEventModel))
                       for k, (n, m) in enumerate(zip(system.names, system.models))]
        self.events: list[float] = []  # time events, every sub-model lands on them
        # per sub-model: the times its trajectory is cut at (time events and the state events
        # that reach it) and lands on
        self.cuts: list[list[float]] = [[] for _ in system.models]
        self.resync = resync
        self.reach = [self._downstream(k) for k in range(len(system.models))]
        # the sub-models that hold each input at one value over a step (no input derivatives):
        # what they are fed is judged by the held value's effect, not the cubic's
        # (hold_deviation); a discrete-event model's outputs do not follow its inputs
        self.holds = {k for k, m in enumerate(system.models)
                      if m.capabilities.max_input_derivative_order == 0
                      and bool(np.any(system.a[k] != 0.0)) and not self.tracks[k].discrete}
        self._discrete_parts()
        self.state_fired: list[Event] = []  # state events found inside steps, in order found
        self.until = math.inf
        self._requeue: list[int] = []  # sub-models rolled back since the kernel last saw them
        self.on_attempt: Any = None  # on_attempt(name, t, h, accepted): for the results store
        self._kernel = Kernel(math.inf)  # replaced by actors()
        self.budget: Budget | None = None  # whole-run limits
        self._on_step: Any = None
        self._steppers: list[_Stepper] = []
        # the error memory, measured per group of sub-models joined by connections (0: not
        # probed): two branches that exchange nothing forget at their own rates
        self.memories = [RaceMemory(self, group, probe_every) for group in self._groups()]
        self._memory_of = {k: m for m in self.memories for k in m.members}
        self._peak = 0.0  # the largest estimate so far (it fades where a memory is measured)
        self.shift = RaceShift(len(system.models))  # the estimate with the time shift

    def _discrete_parts(self) -> None:
        """The outputs whose changes are events, and the sub-models that watch for them."""
        models = self.system.models
        # continuous sub-models' discrete outputs (local columns): a change is a state event
        self.changing = {k: np.array([i for i, p in enumerate(m.outputs) if p.discrete])
                         for k, m in enumerate(models)
                         if not isinstance(m, DiscreteEventModel)
                         and any(p.discrete for p in m.outputs)}
        # threshold-type sub-models (a state event on their inputs) and the sub-models they read
        self.monitors = {k: sorted(self._sources(k)) for k, m in enumerate(models)
                         if isinstance(m, DiscreteEventModel)
                         and type(m).indicator is not DiscreteEventModel.indicator}
        self.checked = dict.fromkeys(self.monitors, -math.inf)  # searched up to this time

    def _sources(self, k: int) -> set[int]:
        """The sub-models ``k`` reads (an unconnected input reads a constant: gain 0)."""
        return {int(self.owner[j]) for j, a in zip(self.system.src[k], self.system.a[k])
                if a != 0.0}

    def _groups(self) -> list[list[int]]:
        """The sub-models in groups joined by connections (either direction)."""
        groups: list[list[int]] = []
        seen: set[int] = set()
        for k in range(len(self.system.models)):
            if k in seen:
                continue
            group, todo = [], [k]
            while todo:
                j = todo.pop()
                if j not in seen:
                    seen.add(j)
                    group.append(j)
                    todo.extend(self._sources(j) | set(self.consumers[j]))
            groups.append(sorted(group))
        return groups

    def _downstream(self, k: int) -> set[int]:
        """The sub-models ``k``'s outputs reach through the connections (itself excluded
        unless on a loop)."""
        seen: set[int] = set()
        todo = list(self.consumers[k])
        while todo:
            c = todo.pop()
            if c not in seen:
                seen.add(c)
                todo.extend(self.consumers[c])
        return seen

    # -- partners' trajectories ----------------------------------------------------------------
    def _segment_bounds(self, t: float, k: int) -> tuple[float, float]:
        cuts = self.cuts[k]
        i = bisect.bisect_right(cuts, t)
        lo = cuts[i - 1] if i > 0 else -math.inf
        hi = cuts[i] if i < len(cuts) else math.inf
        return lo, hi

    def _trajectory(self, j: int, at: np.ndarray,
                    stencil: int = STENCIL) -> tuple[np.ndarray, bool]:
        """Values of global output ``j`` at times ``at`` from its owner's stored points, and
        whether any of them was extrapolated (:meth:`_owned`, for one output)."""
        owner, col = self._column[j]
        values, beyond = self._owned(owner, [col], at, stencil)
        return values[:, 0], beyond

    def _signals(self, cols: Sequence[int], at: np.ndarray) -> tuple[np.ndarray, bool]:
        """Global outputs ``cols`` at times ``at`` (rows), and whether any was extrapolated:
        the outputs of one owner read together (:meth:`_owned`), each exactly as
        :meth:`_trajectory` reads it alone."""
        out = np.empty((len(at), len(cols)))
        groups: dict[int, tuple[list[int], list[int]]] = {}
        for i, j in enumerate(cols):
            owner, col = self._column[j]
            where, which = groups.setdefault(owner, ([], []))
            where.append(i)
            which.append(col)
        if len(groups) == 1:  # one owner: its columns are these, in this order
            (owner, (_, which)), = groups.items()
            return self._owned(owner, which, at)
        extrapolated = False
        for owner, (where, which) in groups.items():
            values, beyond = self._owned(owner, which, at)
            out[:, where] = values
            extrapolated |= beyond
        return out, extrapolated

    def _owned(self, owner: int, cols: list[int], at: np.ndarray,
               stencil: int = STENCIL) -> tuple[np.ndarray, bool]:
        """Outputs ``cols`` of sub-model ``owner`` at times ``at`` (one column each) from its
        stored points, and whether any of them was extrapolated.

        Within the owner's trajectory: a local cubic through the nearest stored points of the
        same segment (between time events), or the chosen interpolation method over them. Beyond
        the owner's last point: the degree-``order`` extrapolation through its last points.
        The stencil, the weights and the offsets depend on the owner's times only, so they are
        worked out once for all ``cols``; every column's own arithmetic is that of one output
        read alone, in the same order.
        """
        tr = self.tracks[owner]
        t0 = float(at[0])
        lo, hi = self._segment_bounds(t0 + 1e-12 * max(1.0, abs(t0)), owner)
        plain = not tr.discrete and tr.index not in self.changing  # nothing held: every
        if plain:                                                  # column read alike
            window = self._window(tr, at, lo, hi, stencil)
            if window is not None:
                return self._fill(tr, cols, at, *window), window[2]
        out = np.empty((len(at), len(cols)))
        changing = self.changing.get(tr.index, ())
        held = [c for c, col in enumerate(cols) if tr.discrete or col in changing]
        for c in held:
            out[:, c] = self._held(tr, cols[c], at, hi)
        rest = [c for c in range(len(cols)) if c not in held]
        if not rest:
            return out, False
        if not plain:  # (a plain owner's window was found None above)
            window = self._window(tr, at, lo, hi, stencil)
        if window is None:
            # the window spans several of the owner's steps: one stencil per point, each
            # around its own time (a single stencil at the window's end would extrapolate
            # backwards over the owner's earlier steps)
            wanted = [cols[c] for c in rest]
            for i, s in enumerate(at):
                out[i, rest] = self._owned(owner, wanted, np.array([s]), stencil)[0][0]
            return out, False
        start, last, beyond = window
        out[:, rest] = self._fill(tr, [cols[c] for c in rest], at, start, last, beyond)
        return out, beyond

    def _fill(self, tr: Track, cols: list[int], at: np.ndarray, start: int, last: int,
              beyond: bool) -> np.ndarray:
        """Outputs ``cols`` at ``at`` (one column each) from the owner's points ``[start,
        last)``: the interpolation method's curve within the trajectory, else the polynomial
        through the points (its weights and offsets worked out once for all columns)."""
        out = np.empty((len(at), len(cols)))
        pts = tr.times[start:last]
        block = np.array(tr.rows[start:last])
        # each column is copied out contiguous, as one output read alone was built: the same
        # products, so the same floats
        if self.method is not None and not beyond and len(pts) > 1:
            hermite = self.method.name == "hermite"
            slopes = np.array(tr.slopes[start:last]) if tr.slopes and hermite else None
            for c, col in enumerate(cols):
                curve = self.method.fit(pts, block[:, col].copy(), None if slopes is None
                                        else slopes[:, col].copy())
                out[:, c] = np.asarray(curve(at), dtype=float)
            return out
        t0 = float(at[0])
        weights = weight_matrix(tuple([float(ti) - t0 for ti in pts]))
        offsets = (at - t0).tolist()
        for c, col in enumerate(cols):
            out[:, c] = _through(weights, block[:, col].copy(), offsets)
        return out

    def _window(self, tr: Track, at: np.ndarray, lo: float, hi: float,
                stencil: int) -> tuple[int, int, bool] | None:
        """The owner's stored points ``[start, last)`` that :meth:`_owned` reads for times
        ``at`` within the segment ``[lo, hi]``, and whether ``at`` reaches past its last point
        (then the newest points, to extrapolate from); ``None`` when, without an interpolation
        method, the window spans several of the owner's steps (one stencil per point then)."""
        times = tr.times
        first, end = _segment_range(times, lo, hi)
        if at[-1] > times[-1] + 1e-12 * max(1.0, abs(times[-1])):
            return max(first, len(times) - (self.order + 1)), len(times), True
        if self.method is None and len(at) > 1 and bisect.bisect_right(
                times, float(at[-1])) - bisect.bisect_left(times, float(at[0])) > 2:
            return None
        width = stencil if self.method is None else max(stencil, self.method.window)
        # (read at a jump's time from the segment after it: from its right limit on)
        last = min(end, max(first, bisect.bisect_left(times, float(at[-1]))) + stencil // 2)
        start = max(first, last - width)
        return start, min(end, start + width), False

    @staticmethod
    def _held(tr: Track, col: int, at: np.ndarray, hi: float) -> np.ndarray:
        """A discrete-event sub-model's piecewise-constant output: the value of its latest point
        at or before each time, the left limit at the end ``hi`` of the window's segment (its
        jump there belongs to the next segment). Nothing to extrapolate: no sub-model steps
        past its next event."""
        times = tr.times
        end = bisect.bisect_left(times, hi - 1e-9 * max(1.0, abs(hi))) + 1 \
            if math.isfinite(hi) else len(times)
        idx = [min(bisect.bisect_right(times, float(s) + 1e-12 * max(1.0, abs(float(s)))), end)
               - 1 for s in at]
        return np.array([tr.rows[max(i, 0)][col] for i in idx])

    def inputs_over(self, k: int, t: float, h: float) -> tuple[np.ndarray, bool]:
        """Model ``k``'s inputs at ``t + NODES·h`` (rows) and whether any were extrapolated."""
        return self._inputs(k, t + NODES * h)

    def _inputs(self, k: int, at: np.ndarray) -> tuple[np.ndarray, bool]:
        """Model ``k``'s inputs at the times ``at`` (rows) from its sources' trajectories,
        and whether any were extrapolated (an input with gain 0 is its offset)."""
        system = self.system
        a, b = system.a[k], system.b[k]
        sources = system.src[k].tolist()
        live = [i for i, gain in enumerate(a.tolist()) if gain != 0.0]
        if live and len(live) == len(sources):  # every input read: the same products and
            values, extrapolated = self._signals(sources, at)  # sums as below, at once
            return a * values + b, extrapolated
        out = np.empty((len(at), len(a)))
        for i in range(len(a)):
            if a[i] == 0.0:
                out[:, i] = b[i]
        if not live:
            return out, False
        values, extrapolated = self._signals([sources[i] for i in live], at)
        for c, i in enumerate(live):
            out[:, i] = a[i] * values[:, c] + b[i]
        return out, extrapolated

    def input_resolution(self, k: int, t: float, h: float, inputs: np.ndarray) -> float:
        """How far the cubic that model ``k`` follows over ``[t, t + h]`` (through its inputs
        at :data:`NODES`) strays from the partners' trajectories between the nodes.

        Returns the largest mean deviation at :data:`BETWEEN`, scaled like the inputs. A step
        longer than a partner's dynamics (a slow chassis stepping across its wheel's
        oscillation) is not seen by the partner-facing estimate; this is the check that the
        step resolved what it was fed.
        """
        if not len(self.system.src[k]):
            return 0.0
        coef = taylor_coefficients(list(t + NODES * h), inputs, t, 3)
        fed = evaluate_small(coef, (BETWEEN * h).tolist())
        true = self._inputs(k, t + BETWEEN * h)[0]
        scale = self.tracks[k].policy.scale(true)
        # what rounding leaves between two evaluations of the same values is no variation a
        # shorter step could resolve: at the ship plant's hit a valve position held constant
        # deviated by ~1e-16 between the cubic and the trajectory, which the network's large
        # gain and a share of tol that shrinks with the step turned into a constant 2.31x
        # the allowed error, rejected down to hmin
        rounding = ROUNDING * np.maximum(np.abs(fed), np.abs(true))
        deviation = np.maximum(np.abs(fed - true) - rounding, 0.0) / scale
        # the mean over the nodes as np.mean takes it (their sum over their count)
        return float((np.add.reduce(deviation, axis=0) / deviation.shape[0]).max())

    def hold_deviation(self, k: int, t: float, h: float, inputs: np.ndarray
                       ) -> tuple[float, float]:
        """What holding the mid-step value of its inputs over ``[t, t + h]`` leaves model
        ``k`` (one of :attr:`holds`) of the partners' trajectories, scaled like the inputs:
        the largest |mean| of the deviation over the step, and the largest swing of it from
        the first half to the second (half the difference at 5/6 and 1/6 of the step).

        Why two numbers: the receiver's state answers the deviation's mean (a constant
        error) and, through its own dynamics within the step, its swing (a ramp held flat).
        Holding the mid-step value is a midpoint rule, so the mean falls like ``h^2``; the
        swing falls like ``h``, but what it costs depends on how fast the receiver is — a
        slow lag averages it away, a fast oscillator follows it — which only the receiver
        can tell (:meth:`_refresh_gain` measures it). The mean at :data:`BETWEEN` (a
        three-panel midpoint rule) is 8/9 of the exact mean's leading term."""
        held = _midstep(t, h, inputs)
        true = self._inputs(k, t + BETWEEN * h)[0]
        scale = self.tracks[k].policy.scale(true).max(axis=0)
        rounding = ROUNDING * np.maximum(np.abs(held), np.abs(true)).max(axis=0)
        deviation = true - held
        mean = np.add.reduce(deviation, axis=0) / deviation.shape[0]
        swing = 0.5 * (deviation[-1] - deviation[0])
        return (float((np.maximum(np.abs(mean) - rounding, 0.0) / scale).max()),
                float((np.maximum(np.abs(swing) - rounding, 0.0) / scale).max()))

    @staticmethod
    def hold_lag(tr: Track, h: float, swing: float, gain: float) -> float:
        """The lasting error (scaled like the outputs) that holding its inputs over steps of
        ``h`` leaves a receiver: a ramp held flat at its mid-step value lags.

        A lag ``x' = -a x + b u`` fed a ramp held at mid-step values settles, at the ends of
        its steps, at a distance from the exact response that does not grow with time: ``b``
        × slope × ``h^2/12`` for a receiver slower than the step (``a h`` small), the static
        response × slope × ``h/2`` for one much faster. In the measured quantities — the
        gain, the swing of :meth:`hold_deviation` (slope × ``h/3``) and the receiver's
        measured answer to a swing relative to its gain × ``h`` (``rho``: ``a h/4`` when slow,
        1 when fast, :meth:`_swing_response`) — that is gain × ``h`` × swing × ``kappa``
        with ``kappa`` from 1/4 to 3/2, joined linearly in ``rho``. It is an error that
        persists rather than one that adds up, so it is met against tol itself, not a share
        of it (:meth:`_fed_ratio`). Until the swing response is measured the receiver is
        taken as fast (``rho`` = 1)."""
        measured = gain > 0.0 and not math.isnan(tr.moment)
        rho = min(1.0, tr.moment * h / gain) if measured else 1.0
        return gain * h * swing * (0.25 + 1.25 * rho)

    def _fed_ratio(self, tr: Track, t: float, h: float, inputs: np.ndarray, y: np.ndarray,
                   gain: float) -> tuple[float, int, float, float]:
        """What ``tr``'s step ``[t, t + h]`` failed to resolve of its inputs, against what it
        may: the ratio, the power of ``h`` it falls with, the error that adds up (scaled like
        the outputs: the sensitivity ``gain`` × ``h`` × :meth:`input_resolution`, or × the
        mean of :meth:`hold_deviation` for a receiver that holds its inputs) and the lasting
        one as a share of tol.
        For a receiver that holds its inputs the ratio is the larger of the two (the lag,
        :meth:`hold_lag`, power 2), whichever asks for the shorter step."""
        pol = tr.policy
        lasting, power = 0.0, self.resolution_power(tr.index)
        if tr.index not in self.holds:
            fed = gain * h * self.input_resolution(tr.index, t, h, inputs)
            ratio, _ = pol.ratio(fed * pol.scale(y), y, h)
        else:
            mean, swing = self.hold_deviation(tr.index, t, h, inputs)
            fed = gain * h * mean
            ratio, _ = pol.ratio(fed * pol.scale(y), y, h)
            lag = self.hold_lag(tr, h, swing, gain)
            lasting = float(np.max(lag * pol.scale(y) / pol.norm_scale(y))) if y.size else 0.0
            if lasting > 1.0 and lasting ** 0.5 > max(ratio, 1.0) ** (1.0 / power):
                ratio, power = lasting, 2
        return ratio, power, fed, lasting

    def resolution_power(self, k: int) -> int:
        """How the error :meth:`_fed_ratio` adds up falls with the receiver's step ``h``:
        ``h^5`` for a cubic it follows (deviation ``h^4`` integrated over ``h``), ``h^3`` for
        a held mid-step value (its mean ``h^2`` over ``h``)."""
        return 3 if k in self.holds else 5

    # -- calls -----------------------------------------------------------------------------------
    def _guard(self, k: int, t: float, fn: Any, *args: Any, h: float | None = None) -> Any:
        """A sub-model call through the synchronous master's guard (errors named, time-outs)."""
        return self._caller._guard(k, t, fn, *args, h=h)

    def run_step(self, k: int, t: float, h: float, inputs: np.ndarray) -> np.ndarray:
        """One call: model ``k`` over ``[t, t + h]`` following the cubic through ``inputs``."""
        model = self.system.models[k]
        tr = self.tracks[k]
        q = model.capabilities.max_input_derivative_order
        coef: np.ndarray | None = None  # the input derivatives sent (q > 0)
        if not len(inputs[0]):
            coef, u = np.zeros((4, 0)), np.zeros(0)
        elif q == 0:  # hold: the mid-step value
            u = _midstep(t, h, inputs)
        elif h <= negligible(t):  # a step of a few ulps: inputs held
            coef = np.zeros((4, len(inputs[0])))
            coef[0] = inputs[0]
            u = coef[0]
        else:
            coef = taylor_coefficients(list(t + NODES * h), inputs, t, 3)
            u = coef[0]
        start = time.perf_counter()
        tr.calls += 1
        self._guard(k, t, model.set_inputs, u, h=h)
        if coef is not None and q > 0:
            self._guard(k, t, model.set_input_derivatives, coef[1:q + 1], h=h)
        self._guard(k, t, model.do_step, t, h, h=h)
        y = self._caller._outputs(k, t, h)  # one float per declared output, or an error
        tr.time_in_model += time.perf_counter() - start
        if not np.all(np.isfinite(y)):
            bad = [f"{tr.name}.{model.outputs[i].name}" for i in np.flatnonzero(~np.isfinite(y))]
            raise SubModelError(tr.name, t, f"returned non-finite output(s) {', '.join(bad)}", h)
        return y

    def _slope(self, k: int, t: float) -> np.ndarray | None:
        model = self.system.models[k]
        if not model.capabilities.provides_derivatives:
            return None
        return np.asarray(self._guard(k, t, model.get_output_derivatives), dtype=float)

    # -- error estimates -------------------------------------------------------------------------
    def interpolation_error(self, tr: Track, t_new: float, y_new: np.ndarray) -> np.ndarray:
        """How wrong a consumer's cubic through this trajectory is, per output (no call).

        The cubic through the newest four points against the quartic through five, at the
        middle of the newest interval (with fewer points, one degree lower each), scaled by
        :data:`CALIBRATION`.
        """
        times = [*tr.times[tr.segment:][-4:], t_new]
        rows = np.vstack([*tr.rows[tr.segment:][-4:], y_new])
        if len(times) < 3:
            # Start-up: with one stored point a consumer can only hold it, so its error is the
            # change itself. That error is made once, over this first interval, so advance()
            # holds it to the tolerance per step, not per unit time: measured as a rate it
            # shrank only like h and stalled the fast pendulum bar (λ = 30, tol 1e-5) at 1e-10 s.
            return np.abs(y_new - rows[0])
        mid = 0.5 * (times[-2] + times[-1])
        hi = taylor_coefficients(times, rows, mid, len(times) - 1)[0]
        lo = taylor_coefficients(times[1:], rows[1:], mid, len(times) - 2)[0]
        return CALIBRATION * np.abs(hi - lo)

    def slope_error(self, tr: Track, t_new: float, y_new: np.ndarray,
                    slope: np.ndarray | None) -> np.ndarray | None:
        """Grey box: the interpolation error the model's own slope at the new point reveals,
        per output, where some output's slope contradicts its trajectory; ``None`` where none
        does, or where it cannot be read.

        Samples too far apart to see an oscillation look smooth to every sample-based
        estimate; the end slope of the cubic through the newest points then disagrees with the
        model's slope by more than :data:`ALIAS` of the slopes involved (for a signal at ``ω``
        sampled ``h`` apart that end slope is off by about ``(ωh)³/4``, so this is ``ωh ≳ 1``:
        samples that no longer resolve it). Only there is the mismatch ``Δ`` read as an error,
        ``5h|Δ|/32`` (scaled like :meth:`interpolation_error`): for a resolved signal the
        cubic's error in the middle of its newest interval (``5/128·f⁽⁴⁾h⁴``) is ``5h/32``
        times its error in the end slope (``f⁽⁴⁾h³/4``), and where ``ωh ≳ 1`` the same
        expression is of the order of the oscillation's amplitude or more, so it does not
        understate an aliased error. The track's outputs are read together: once one of them
        contradicts its trajectory, every output's mismatch counts (measured against counting
        only the contradicting outputs': docs/concepts.md, "The aliasing check read against
        the tolerance"). Black boxes cannot be checked (use ``hmax``, e.g. from
        :func:`~cosimstep.controllers.fft_hmax`).
        """
        if slope is None or len(tr.times) - tr.segment < 3:
            return None
        times = [*tr.times[tr.segment:][-3:], t_new]
        rows = np.vstack([*tr.rows[tr.segment:][-3:], y_new])
        end = taylor_coefficients(times, rows, t_new, 3)[1]
        h = times[-1] - times[-2]
        typical = np.abs(slope) + np.abs(rows[-1] - rows[-2]) / h + tr.policy.scale(y_new) / h
        mismatch = np.abs(end - slope)
        if not np.any(mismatch > ALIAS * typical):
            return None
        return CALIBRATION * (5.0 / 32.0) * h * mismatch

    def consumer_gain(self, k: int) -> float:
        """The largest measured sensitivity of ``k``'s consumers (a guess until measured)."""
        gains = [self.tracks[c].gain for c in self.consumers[k]]
        if not gains:
            return 0.0
        known = [g for g in gains if g is not None]
        return max(known) if len(known) == len(gains) else max([INITIAL_GAIN, *known])

    # -- the verification of a pending step ------------------------------------------------------
    def verify(self, k: int) -> bool:
        """Compare the inputs a pending step assumed with those that happened; correct if needed.

        Returns whether partners were rolled back because the correction changed what they had
        read (:meth:`_resynchronize`); ``k`` must then wait for them to catch up again.
        """
        tr = self.tracks[k]
        if tr.pending is None:
            return False
        token, t0, h, assumed, rounds, first = tr.pending
        tr.pending = None
        actual, _ = self.inputs_over(k, t0, h)
        scale = tr.policy.scale(actual)
        if k in self.holds:  # what it was fed: the mid-step values
            change = _midstep(t0, h, actual) - _midstep(t0, h, assumed)
            delta = float(np.max(np.abs(change) / scale.max(axis=0)))
        else:
            delta = float(np.max(np.mean(np.abs(actual - assumed) / scale, axis=0)))
        tr.verified += 1
        if delta == 0.0:
            return False
        y_old = tr.rows[-1]
        model = self.system.models[k]
        self._guard(k, t0, model.restore_state, token)
        pieces = self._pieces(tr, t0, h, actual, y_old)
        cut_at = self._rerun(tr, first, pieces, actual if pieces == 1 else None)
        change = np.abs(tr.rows[-1] - y_old)
        if np.any(change > 1e3 * np.finfo(float).eps
                                  * np.maximum(np.abs(tr.rows[-1]), 1e-300)):
            gain = float(np.max(change / tr.policy.scale(tr.rows[-1]))) / (h * delta)
            if k not in self.holds:
                tr.gain = gain if tr.gain is None or _outside(h, tr.gain_h) \
                    else max(gain, 0.5 * tr.gain)
                tr.gain_h = h
            elif pieces == 1 and tr.gain is None:
                tr.gain, tr.gain_h = gain, h
        moved = float(np.max(change / tr.policy.scale(tr.rows[-1])))
        if rounds >= MAX_RESYNC:  # the consumers keep what they read: the estimate has it
            self._resynchronize(k, t0, moved, rounds + 1, roll=False)
            return False
        # a track whose step ended on a located discrete change keeps its whole step: a cut
        # would leave that change recorded at a time the track no longer reaches
        if cut_at is not None and k not in self.changing \
                and any(self._kept(k, c, t0, moved)[0] > 1.0 for c in self._past(k, t0)):
            self._truncate(tr, cut_at)
            return self._cut_short(k, token, t0, first, rounds)
        if not self._resynchronize(k, t0, moved, rounds + 1):
            return False
        # the correction read the partners' trajectories that were just discarded: check it
        # again against the ones they will compute now
        tr.pending = (token, t0, h, actual, rounds + 1, first)
        return True

    def _cut_short(self, k: int, token: Any, t0: float, first: int, rounds: int) -> bool:
        """A correction that must roll its consumers back is kept only up to where the
        partners began to move (:meth:`_rerun`'s ``cut_at``, :meth:`_truncate`); the rest of
        the pending step is gone.

        Why stop there: the partners ran through the whole pending step on its provisional
        trajectory, and where they moved in it their trajectories are as provisional as it
        was. Correcting the whole step on them and rolling them back, round after round, is a
        waveform relaxation over the step, which converges slowly where the step spans the
        partners' dynamics: the quarter car with the unannounced road step (multi-rate, tol
        1e-6) had its chassis step 0.43 → 1.65 s across the road step at rest; three rounds
        moved it by 7e4, 3e4 and 6e3 × tol, the rounds ran out, and the wheel kept what it had
        read of a chassis trajectory since replaced: 538 × tol, status ok. Stopped where the
        partners began to move, the stretch still to relax is one piece long. Only where the
        consumers go back anyway: cutting every correction that needed shorter pieces rolled
        them back where a correction within their tolerance leaves them be (the mixed
        pendulum, multi-rate at tol 1e-5: 0.77 → 2.3 × tol at the same calls).

        Every consumer past ``t0`` goes back to ``t0`` (they read points that are gone); a
        threshold-type model searches again instead. The pieces read the partners as they
        were, so they stand as a pending step over ``[t0, t_cut]``, verified again once the
        partners have re-run. Returns True: ``k`` waits for them.
        """
        tr = self.tracks[k]
        self._requeue.append(k)  # it is behind where it stood: the kernel must see it again
        span = tr.t - t0
        assumed, _ = self.inputs_over(k, t0, span)
        for c in self._past(k, t0):
            if _beyond(self.tracks[c].t, t0):  # not rolled back with another
                self._rollback(c, t0, k, rounds + 1)
        tr.pending = (token, t0, span, assumed, rounds + 1, first)
        return True

    def _truncate(self, tr: Track, i: int) -> None:
        """Drop the track's points after ``i`` (they count as re-runs: ``corrections``) and
        restore its sub-model to the state saved at ``i``."""
        k = tr.index
        self._guard(k, tr.times[i], self.system.models[k].restore_state, tr.states[i])
        dropped = len(tr.times) - 1 - i
        del tr.times[i + 1:], tr.rows[i + 1:], tr.steps[i:]
        if tr.slopes:
            del tr.slopes[i + 1:]
        tr.states = {j: s for j, s in tr.states.items() if j <= i}
        tr.accepted -= dropped
        tr.corrections += dropped
        tr.replaced += dropped
        tr.segment = self._segment_start(tr)
        self.shift.unread(k)  # the motion it had was the dropped steps'

    def _past(self, k: int, t0: float) -> list[int]:
        """The consumers of ``k`` that ran past ``t0`` and would be rolled back by a change of
        its trajectory after ``t0``; a threshold-type model among them is told to search its
        inputs again from ``t0`` instead (:meth:`watch`)."""
        past = []
        for c in self.consumers[k]:
            if c == k or not _beyond(self.tracks[c].t, t0):
                continue
            if c in self.monitors:
                # its outputs depend on its inputs only through a crossing: a crossing found
                # before its time rolls it back then (_fire_monitor)
                self.checked[c] = min(self.checked[c], t0)
                continue
            past.append(c)
        return past

    def _kept(self, k: int, c: int, t0: float, moved: float) -> tuple[float, float]:
        """The error consumer ``c`` keeps of a change ``moved`` (scaled) of ``k``'s trajectory
        after ``t0`` if it is not rolled back: its ratio to what ``c`` allows, and its size
        (scaled): ``c``'s sensitivity × the time it ran on the old trajectory × ``moved / 2``
        (the change grows from nothing at ``t0``)."""
        other = self.tracks[c]
        overlap = min(other.t, self.tracks[k].t) - t0
        gain = other.gain if other.gain is not None else INITIAL_GAIN
        y = other.rows[-1]
        kept = gain * overlap * 0.5 * moved
        ratio, _ = other.policy.ratio(kept * other.policy.scale(y), y, overlap)
        return ratio, kept

    def _refresh_gain(self, k: int, token: Any, t: float, h: float, inputs: np.ndarray,
                      y: np.ndarray) -> None:
        """Measure ``k``'s gain on its step just accepted (``[t, t + h]`` from the state
        ``token``, outputs ``y``) when the one it has was measured on a step outside
        :data:`GAIN_SPAN` of ``h``: the step again with each input in turn one tolerance unit
        higher (a call each), the responses added up as the worst signs of an error in every
        input would add them (inputs can act against each other: a pendulum bar's partner angle
        and rate), divided by ``h``, then back to where it was. A gain is otherwise only
        measured when a pending step is corrected, which a consumer that meets its partners'
        points never is. A receiver that holds its inputs is measured from its first step on,
        with its answer to a swing beside the gain (:meth:`_swing_response`, :meth:`hold_lag`).
        A sub-model that fails on a shifted step loses the measurement, not the run (one that
        hangs still ends it)."""
        tr = self.tracks[k]
        hold = k in self.holds
        # a receiver that holds its inputs is measured from its first step: its gain from a
        # correction is biased (Multirate.verify) and its swing response comes only from here
        measured = tr.gain is not None
        due = not measured or _outside(h, tr.gain_h) or (hold and math.isnan(tr.moment))
        if tr.discrete or not inputs.size or not due or not (measured or hold):
            return
        model = self.system.models[k]
        after = self._guard(k, t, model.save_state)
        scale, response = tr.policy.scale(inputs), np.zeros_like(y)
        try:
            for i in range(inputs.shape[1]):
                self._guard(k, t, model.restore_state, token)
                shifted = inputs.copy()
                shifted[:, i] += scale[:, i]
                tr.gain_checks += 1
                response += np.abs(self.run_step(k, t, h, shifted) - y)
        except SubModelError as exc:
            if exc.hung:
                raise
            self._guard(k, t, model.restore_state, after)
            return
        tr.gain = float(np.max(response / tr.policy.scale(y))) / h
        tr.gain_h = h
        if hold:
            self._measure_swing(k, token, t, h, inputs, y)
        self._guard(k, t, model.restore_state, after)

    def _measure_swing(self, k: int, token: Any, t: float, h: float, inputs: np.ndarray,
                       y: np.ndarray) -> None:
        """:attr:`Track.moment` of a receiver that holds its inputs, from
        :meth:`_swing_response`; a sub-model that fails on the probe (one that refuses half
        steps) is taken as fast, not probed again until its gain is (one that hangs still ends
        the run)."""
        tr = self.tracks[k]
        try:
            swing = self._swing_response(k, token, t, h, inputs)
        except SubModelError as exc:
            if exc.hung:
                raise
            tr.moment = math.inf
            return
        tr.moment = float(np.max(swing / tr.policy.scale(y))) / (h * h)

    def _swing_response(self, k: int, token: Any, t: float, h: float,
                        inputs: np.ndarray) -> np.ndarray:
        """What a receiver that holds its inputs answers to a swing of each input in turn
        over ``[t, t + h]`` (from the state ``token``): the step in two halves, the input one
        tolerance unit below its held value in the first half and one above in the second,
        against the same halves without the swing (two calls, then two per input; the
        responses added with the worst signs, as for the gain). A ramp of the input that the
        hold flattens is such a swing (:meth:`hold_deviation`)."""
        tr = self.tracks[k]
        held = _midstep(t, h, inputs)
        unit = tr.policy.scale(inputs).max(axis=0)
        half = 0.5 * h

        def halves(first: np.ndarray, second: np.ndarray) -> np.ndarray:
            self._guard(k, t, self.system.models[k].restore_state, token)
            tr.gain_checks += 1
            self.run_step(k, t, half, np.tile(first, (len(NODES), 1)))
            tr.gain_checks += 1
            return self.run_step(k, t + half, h - half, np.tile(second, (len(NODES), 1)))

        plain = halves(held, held)
        response = np.zeros_like(plain)
        for i in range(len(held)):
            down, up = held.copy(), held.copy()
            down[i] -= unit[i]
            up[i] += unit[i]
            response += np.abs(halves(down, up) - plain)
        return response

    def _resynchronize(self, k: int, t0: float, moved: float, rounds: int,
                       roll: bool = True) -> bool:
        """Roll back the consumers of ``k`` that read its provisional trajectory after ``t0``
        where the correction moved it too much for their tolerance (thesis 4.3.5: partial
        re-synchronization by rollback).

        A consumer that ran ahead through ``k``'s pending step interpolated its provisional
        points, and those steps passed their own verification against them. ``moved`` is the
        correction's change at the step's end (scaled); the consumer's error from it is about
        its sensitivity × the time it ran on the old trajectory × ``moved / 2`` (the change
        grows from nothing at ``t0``). Returns whether any consumer was rolled back.
        Without ``roll`` (the chain's rounds are spent, :data:`MAX_RESYNC`) every consumer
        keeps its error; so does one with no saved state to go back to. Either way the run's
        estimate is told of it (not of what their own consumers keep in turn).
        """
        rolled = False
        for c in self._past(k, t0):
            if not _beyond(self.tracks[c].t, t0):
                continue  # rolled back already with another consumer it reads
            ratio, kept = self._kept(k, c, t0, moved)
            if ratio > 1.0 and roll and self._rollback(c, t0, k, rounds):
                rolled = True
            else:  # within its tolerance (or kept): an error all the same, the estimate has it
                self.tracks[c].spent_in += kept * self.tracks[c].policy.tol
                # made over the stretch c ran on the old trajectory, no step of its own: kept
                # as it is (h = 0)
                self.shift.lands(c, kept * self.tracks[c].policy.tol, 0.0)
        return rolled

    def _segment_start(self, tr: Track) -> int:
        """Index of the track's first point at or after the last time event it has reached
        (points move when steps are re-run or dropped; extrapolation restarts there)."""
        t, cuts = tr.t, self.cuts[tr.index]
        i = bisect.bisect_right(cuts, t + 1e-12 * max(1.0, abs(t)))
        if i == 0:
            return 0
        event = cuts[i - 1]
        first = bisect.bisect_left(tr.times, event - 1e-9 * max(1.0, abs(event)))
        while first + 1 < len(tr.times) and tr.times[first + 1] == tr.times[first]:
            first += 1  # a discrete-event track's point after its jump (the right limit)
        return first

    def _rollback(self, k: int, t0: float, origin: int, rounds: int,
                  across: bool = False) -> bool:
        """Restore ``k`` to its last saved point at or before ``t0`` and drop what came after
        (those steps count as re-runs: ``corrections``). Consumers of ``k`` that ran past that
        point are rolled back with it, except ``origin``, whose corrected step caused this (it
        is verified again instead). Only an event goes back ``across`` a time event the track
        has passed (a correction before it changes nothing after it)."""
        tr = self.tracks[k]
        candidates = [i for i in tr.states if not _beyond(tr.times[i], t0)
                      and (across or i >= tr.segment)]
        if not candidates:
            # before a time event the track has passed (nothing to redo), or a state already
            # forgotten (not seen on the suite with the margin in _forget_states)
            tr.missed_rollbacks += 1
            return False
        i = max(candidates)
        # a chain's round carries over only while the track still re-runs that chain's
        # stretch: past it, this rollback starts a round of its own (MAX_RESYNC)
        carried = tr.resync[0] if tr.t < tr.resync[1] else 0
        tr.resync = (max(rounds, carried), max(tr.t, tr.resync[1]))
        self._truncate(tr, i)
        tr.rollbacks += 1
        tr.pending = None
        self.state_fired = [e for e in self.state_fired
                            if e.source != tr.name or e.t <= tr.t]  # undone with the steps
        if k in self.checked:  # a threshold-type model searches its inputs again from here
            self.checked[k] = min(self.checked[k], tr.t)
        self._requeue.append(k)
        # k's trajectory changes only after t0 (before it, its re-run reads what it read the
        # first time): its consumers go back to t0, not to the earlier point k restarts from,
        # or in a cycle of partners each hop would go back one more step, down to the last
        # time event
        for c in self.consumers[k]:
            if c in (k, origin) or not _beyond(self.tracks[c].t, t0):
                continue
            if c in self.monitors and not across:
                self.checked[c] = min(self.checked[c], t0)  # see _resynchronize
            else:
                self._rollback(c, t0, origin, rounds, across)
        return True

    def _pieces(self, tr: Track, t0: float, h: float, actual: np.ndarray,
                y: np.ndarray) -> int:
        """Into how many steps a pending step must be cut so that it resolves the inputs that
        actually happened (they were partly extrapolated when the step was accepted: a partner
        that had not yet moved after an event looked constant). 1: the step can stand."""
        gain = tr.gain if tr.gain is not None else INITIAL_GAIN
        ratio, power, _, _ = self._fed_ratio(tr, t0, h, actual, y, gain)
        if ratio <= 1.0:
            return 1
        return int(min(MAX_PIECES, math.ceil((ratio / tr.policy.safety) ** (1 / power))))

    def _rerun(self, tr: Track, first: int, pieces: int,
               inputs: np.ndarray | None) -> int | None:
        """Re-run the (restored) pending step from point ``first`` to the track's last point
        with the inputs that happened; the new points replace those after ``first`` (the step's
        end point, or the pieces of an earlier re-run).

        One step when ``pieces`` is 1; otherwise steps of about ``1/pieces`` of it, each
        shortened until it resolves its inputs (:meth:`_fed_ratio`: no call needed to
        check) — a first guess from the whole step's deviation cannot see how fast the partner
        moves inside it.

        Returns the index of the point that ends the first piece that had to be shortened to
        resolve its inputs — where the partners began to move within the step — if pieces
        follow it, else ``None`` (:meth:`_cut_short`).
        """
        k = tr.index
        t0, t_end = tr.times[first], tr.times[-1]
        h = t_end - t0
        shortened, cut_at = False, None  # a piece had to be shortened to resolve its inputs
        dropped = self._drop_after(tr, first)
        t, step_try, made = t0, h / pieces, 0
        gain = tr.gain if tr.gain is not None else INITIAL_GAIN
        model = self.system.models[k]
        # a remainder this short is taken with the piece before it: at t = 200 s, 1e-9 of a
        # 17 µs step is below one ulp (a piece of one ulp once ended the ship plant). A few
        # dozen ulps stay well below hmin: a rejected piece can still shrink past this and end
        # at hmin instead of being stretched back for ever
        shortest = max(1e-9 * h, negligible(t_end))
        while t < t_end:
            step = min(step_try, t_end - t)
            if t_end - t - step < shortest:
                step = t_end - t
            u = inputs if inputs is not None else self.inputs_over(k, t, step)[0]
            shorter = None if inputs is not None else self._unresolved(tr, t, step, u, gain)
            if shorter is not None:
                step_try, shortened = shorter, True
                continue
            at = len(tr.times) - 1
            if at not in tr.states:
                tr.states[at] = self._guard(k, t, model.save_state)
            try:
                y = self.run_step(k, t, step, u)
            except SubModelError as exc:
                # a re-run is a step like a trial one: what it failed on is a shorter piece
                # (the inputs of the whole step no longer fit it: read them per piece)
                step_try = self._failed_trial(tr, exc, tr.states[at], t, step)
                inputs = None
                continue
            slope = self._slope(k, t + step)
            end = t_end if step == t_end - t else t + step
            # a piece onto a time event k declared keeps both sides of what jumped there
            left = self._left_of_jump(k, t, step, y) if k in self.declared.get(end, ()) \
                else None
            if inputs is None:
                h_next, kept = self._judge_piece(tr, t, step, y if left is None else left, u,
                                                 slope, tr.states[at], left is not None)
                if not kept:
                    step_try = min(h_next, step)
                    continue
                step_try = min(h_next, h / pieces)
            made += 1
            t = end
            tr.steps.append(step)
            _append(tr, t, y, slope, left)
            if shortened and cut_at is None and t < t_end:
                cut_at = len(tr.times) - 1
        tr.accepted += made - dropped
        tr.replaced += dropped - made
        if pieces > 1:  # the step did not resolve its inputs: do not try it again at once
            tr.h = min(tr.h, h / pieces)
        tr.segment = self._segment_start(tr)
        return cut_at

    def _drop_after(self, tr: Track, first: int) -> int:
        """Drop the track's points after ``first``, to be re-run; returns how many steps
        went (they count as re-runs, ``corrections``; the new ones as accepted)."""
        dropped = len(tr.times) - 1 - first
        del tr.times[first + 1:], tr.rows[first + 1:], tr.steps[first:]
        if tr.slopes:
            del tr.slopes[first + 1:]
        tr.states = {i: s for i, s in tr.states.items() if i <= first}
        tr.corrections += dropped
        tr.segment = self._segment_start(tr)
        return dropped

    def _judge_piece(self, tr: Track, t: float, step: float, y: np.ndarray, u: np.ndarray,
                     slope: np.ndarray | None, token: Any, at_jump: bool) -> tuple[float, bool]:
        """A piece of a re-run judged as any step: its consumers must be able to read it too
        (a re-run that only resolved its inputs left the quarter car's chassis stepping 5-20 ms
        through the wheel hop after an unannounced road step). ``y``: its end, the left limit
        where it ends on a jump of an output at its sub-model's time event (``at_jump``: no
        alias check there, the slope belongs to the next segment). Returns the next step and
        whether the piece is kept; a rejected one is restored to ``token``."""
        verdict = self._judge(tr, t, step, y, u, slope, at_jump)
        if verdict.why is not None and step > tr.policy.hmin:
            tr.rejected += 1
            self._guard(tr.index, t, self.system.models[tr.index].restore_state, token)
            return verdict.h_next, False
        tr.spent_out += verdict.spent_out
        tr.spent_in += verdict.spent_in
        tr.lag = max(tr.lag, verdict.lag)
        # a piece's motion is not read (h = 0: kept as they are); read against the motion
        # before the re-run, the quarter car's pieces through the road step became shifts
        # estimated at 2,800 x tol (0.12 x delivered)
        self._lands(tr.index, 0.0, verdict.spent_out, verdict.spent_in)
        return verdict.h_next, True

    def _unresolved(self, tr: Track, t: float, step: float, u: np.ndarray,
                    gain: float) -> float | None:
        """The shorter piece to try if ``[t, t + step]`` does not resolve its inputs ``u``
        (:meth:`_fed_ratio`, no call needed), else ``None``."""
        if step <= tr.policy.hmin:
            return None
        ratio, power, _, _ = self._fed_ratio(tr, t, step, u, tr.rows[-1], gain)
        if ratio <= 1.0:
            return None
        return step * max(0.1, tr.policy.safety * ratio ** (-1 / power))

    # -- one step of the sub-model farthest behind -----------------------------------------------
    def advance(self, k: int, landing: float) -> bool:
        """Verify ``k``'s pending step, then take its next accepted step (retrying on rejection).

        Returns whether it landed on ``landing``.
        """
        tr = self.tracks[k]
        if self.verify(k):
            return False
        t = tr.t
        trial, chain = self._accepted_trial(k, t, landing)
        token, h, lands, y, slope, inputs, extrapolated, left, verdict = trial
        tr.accepted += 1
        memory = tr.policy.memory
        fade = math.exp(-h / memory) if math.isfinite(memory) else 1.0
        self._spend(tr, fade, verdict)
        sudden = _discontinuity(chain, h, verdict, tr.steps[-1] if tr.steps else None)
        # a step with a jump inside (a discrete output's change, an unannounced
        # discontinuity) shows no motion: its change is the jump
        self._shift(tr, h, fade, verdict, None if left is not None or sudden else y)
        tr.steps.append(h)
        if self.on_attempt is not None:
            self.on_attempt(tr.name, t, h, True)
        rounds = tr.resync[0] if t < tr.resync[1] else 0  # re-running a rolled-back stretch
        # a discrete-event track's outputs do not depend on its inputs between events
        tr.pending = (token, t, h, inputs, rounds, len(tr.times) - 1) \
            if extrapolated and not tr.discrete else None
        tr.states[len(tr.times) - 1] = token
        if left is None:
            self._refresh_gain(k, token, t, h, inputs, y)
        _append(tr, landing if lands else t + h, y, slope, left)
        tr.h = verdict.h_next
        if left is not None and self._changed(k, left, y):
            self._state_event(k, left)
        elif sudden and not lands and left is None:
            self._event(k, "discontinuity", {}, at=len(tr.times) - 2)
        if not tr.discrete:
            self._memory_of[k].accepted()
        return lands

    def _spend(self, tr: Track, fade: float, verdict: _Verdict) -> None:
        """Add an accepted step's errors to the run's estimate; where an error memory ``M``
        was measured, what was spent before fades by ``fade = exp(−h/M)`` (as ``pc``'s sum
        does)."""
        tr.spent_out = fade * tr.spent_out + verdict.spent_out
        tr.spent_in = fade * tr.spent_in + verdict.spent_in
        tr.lag = max(tr.lag, verdict.lag)
        if fade < 1.0:
            self._peak = max(self._peak, self._estimate_now())

    def _shift(self, tr: Track, h: float, fade: float, verdict: _Verdict,
               y: np.ndarray | None) -> None:
        """Hand an accepted step to the estimate with the time shift (:mod:`~cosimstep.
        race_drift`): its errors where they land, then its motion to ``y`` (``None``: not
        readable, a jump inside; before ``y`` is appended)."""
        k, pol = tr.index, tr.policy
        self.shift.fades(k, fade)
        self._lands(k, h, verdict.spent_out, verdict.spent_in)
        velocity = None
        if tr.discrete:
            velocity = np.zeros(0)
        elif h > 0.0 and y is not None:
            velocity = (y - tr.rows[-1]) / (h * pol.norm_scale(y) / pol.tol)
        self.shift.moved(k, tr.t + h, h, velocity, pol.memory)

    def _lands(self, k: int, h: float, out: float, own: float) -> None:
        """Errors of a step of ``k`` of length ``h`` in the estimate with the time shift:
        ``out`` in each of its consumers (its trajectory's interpolation), ``own`` in itself
        (inputs it did not resolve), as :meth:`_estimate_now` counts them."""
        for c in self.consumers[k]:
            self.shift.lands(c, out, h)
        self.shift.lands(k, own, h)

    def _accepted_trial(self, k: int, t: float, landing: float) -> tuple[tuple, list]:
        """Trial steps of ``k`` from ``t`` until one is accepted: ``(token, h, lands, y,
        slope, inputs, extrapolated, left, verdict)`` of that one, and the rejections before
        it as ``(h, verdict)`` (for :func:`_discontinuity`)."""
        tr, model = self.tracks[k], self.system.models[k]
        pol = tr.policy
        reach = self._reach(k, t)
        chain: list[tuple[float, _Verdict]] = []
        while True:
            cap = model.capabilities.max_step
            h = landing_step(t, self._meet(k, t, min(tr.h, cap, pol.hmax, reach)), landing, cap)
            lands = h == landing - t
            token = self._guard(k, t, model.save_state)
            try:
                y, slope, inputs, extrapolated, left, step = self._trial(k, token, t, h)
            except SubModelError as exc:
                tr.h = self._failed_trial(tr, exc, token, t, h)
                continue
            lands, h = lands and step == h, step
            if left is None and lands and k in self.declared.get(landing, ()):
                left = self._left_of_jump(k, t, h, y)
            # the slope at an event belongs to the next segment: no alias check there
            verdict = self._judge(tr, t, h, y if left is None else left, inputs, slope,
                                  (lands and landing < self.until) or left is not None)
            if verdict.why is None:
                return (token, h, lands, y, slope, inputs, extrapolated, left, verdict), chain
            chain.append((h, verdict))
            tr.rejected += 1
            if self.on_attempt is not None:
                self.on_attempt(tr.name, t, h, False)
            self._guard(k, t, model.restore_state, token)
            if tr.rejected <= RESTORE_CHECKS:  # the first few: restored to t?
                self._caller.check_restored(t, [tr.rows[-1]], [k])
            try:
                pol.check(t, h, verdict.h_next, verdict.why)
            except StepSizeError as stop:
                share = pol.tol * h / max(self.until - self.tracks[k].times[0], h)
                error = still_failing(tr.failure, t, share, stop)
                if error is not None and tr.failure is not None:
                    raise error from tr.failure[0]
                raise
            tr.h = verdict.h_next

    def _meet(self, k: int, t: float, h: float) -> float:
        """The step ``h``, or shorter to end where a partner already is, when that costs at
        most half of it: a step that reads only what its partners have computed is not
        pending and needs no correction — one call for at least half the length instead of
        two for the whole, so never more calls per unit time — and has no extrapolation
        error. With several partners, meeting one still removes its extrapolation (on the
        triple pendulum, also meeting only when every partner is then covered spent 1.2-1.3x
        more calls). A slow sub-model whose partners are far behind its step still
        extrapolates them (multi-rate)."""
        meet = h
        for s in self._sources(k) - {k}:
            other = self.tracks[s]
            if not other.discrete and 0.5 * h <= other.t - t < meet:
                meet = other.t - t
        return meet

    def _reach(self, k: int, t: float) -> float:
        """How far past ``t`` model ``k`` may step on its partners' extrapolated trajectories.

        Extrapolation needs a trend: ``order + 1`` points of the partner since its last cut
        (time event, state event). With fewer — right after an event, where the partner has
        only the point at the event — it is a hold or a line through one step, which says
        nothing about what the partner does next; a step on it sees unchanged inputs, makes no
        error its estimates could see, and is accepted however long (the quarter car's chassis
        took 1 → 3 s after the road step, and the wheel then read that flat trajectory). Such
        a step reaches no further than the partner's own next step; beyond a trend, the
        verification of pending steps takes over.
        """
        reach = math.inf
        for s in self._sources(k) - {k}:
            other = self.tracks[s]
            if other.discrete:
                continue
            lo, hi = self._segment_bounds(t + 1e-12 * max(1.0, abs(t)), s)
            first, _ = _segment_range(other.times, lo, hi)
            if len(other.times) - first < self.order + 1:
                reach = min(reach, other.t + other.h - t)
        return reach if reach > 0 else math.inf

    def _trial(self, k: int, token: Any, t: float, h: float) -> tuple[
            np.ndarray, np.ndarray | None, np.ndarray, bool, np.ndarray | None, float]:
        """One trial step of ``k`` from ``t`` (saved as ``token``): its outputs, slope, inputs
        and whether they were partly extrapolated; if a discrete output changed inside it, the
        step is cut at the change (:meth:`_locate_change`) and the left limit there is
        returned too (else ``None``), with the step actually taken."""
        inputs, extrapolated = self.inputs_over(k, t, h)
        y = self.run_step(k, t, h, inputs)
        left = None
        cols = self.changing.get(k)
        if cols is not None and not np.array_equal(y[cols], self.tracks[k].rows[-1][cols]):
            h, left, y, inputs = self._locate_change(k, token, t, h)
            extrapolated = self.inputs_over(k, t, h)[1]
        return y, self._slope(k, t + h), inputs, extrapolated, left, h

    def watch(self, k: int) -> None:
        """After ``k`` stepped: search the threshold-type sub-models that read ``k`` for a
        crossing in the stretch all their sources now cover, and fire them there.

        Their inputs are read from the sources' trajectories as any input is (no call): the
        indicator is sampled at the sources' own points and a crossing between two samples is
        located on the trajectories to :data:`~cosimstep.loops.EVENT_TOL`, as an ODE solver
        locates an event on its dense output.
        """
        for m, sources in self.monitors.items():
            if k not in sources:
                continue
            lo, hi = self.checked[m], min(self.tracks[s].t for s in sources)
            if hi <= lo:
                continue
            samples = sorted({t for s in sources for t in self.tracks[s].times if lo < t < hi})
            g_prev, prev = self._indicator(m, lo), lo
            # already past its level where the search starts (at the start, or pushed there by
            # another event at that time): it fires there
            found = lo if g_prev > 0.0 else None
            for s in [*samples, hi] if found is None else []:
                g = self._indicator(m, s)
                if g_prev < 0.0 <= g:
                    found = crossing(lambda c, m=m: self._indicator(m, c), prev, s, g_prev, g,
                                     EVENT_TOL * max(1.0, abs(s)))
                    break
                g_prev, prev = g, s
            self.checked[m] = hi if found is None else found
            if found is not None:
                self._fire_monitor(m, found)
                self.checked[m] = found
                self.watch(m)  # its new outputs may carry another monitor over

    def _inputs_at(self, k: int, t: float) -> np.ndarray:
        """Model ``k``'s inputs at ``t`` from its sources' trajectories."""
        return self._inputs(k, np.array([t]))[0][0]

    def _indicator(self, m: int, t: float) -> float:
        model: DiscreteEventModel = self.system.models[m]  # type: ignore[assignment]
        g = model.indicator(self._inputs_at(m, t))
        return -math.inf if g is None else float(g)

    def _fire_monitor(self, m: int, t: float) -> None:
        """Fire threshold-type sub-model ``m`` at ``t``: its track goes back to ``t`` if it was
        past it (its outputs held there), gets both sides of the jump, and the event
        re-synchronizes what it reaches (:meth:`_event`)."""
        tr, model = self.tracks[m], self.system.models[m]
        if _beyond(tr.t, t) and not self._rollback(m, t, m, 0, across=True):
            raise RuntimeError(f"'{tr.name}' crossed its level at t = {t:.9g} but its saved "
                               "state there is gone; report this as a bug")
        old = tr.rows[-1].copy()
        kind = model.apply(t, self._inputs_at(m, t))  # type: ignore[attr-defined]
        new = np.asarray(model.get_outputs(), dtype=float)
        tr.steps.append(t - tr.t if tr.t < t else 0.0)
        _append(tr, t, new, None, old if tr.t < t else None)
        self._requeue.append(m)
        self._event(m, kind, {p.name: float(v) for p, v in zip(model.outputs, new)})

    def _locate_change(self, k: int, token: Any, t: float,
                       h: float) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
        """The step from ``t`` (``token``) at whose end a discrete output of ``k`` has just
        changed, to :data:`~cosimstep.loops.EVENT_TOL`, by bisection of the step (each trial
        one call of ``k`` alone, its inputs read from the partners' trajectories as for any
        step). Returns the step, the outputs just before the change (the last trial without
        it), those after, and the inputs of the step."""
        tr, model = self.tracks[k], self.system.models[k]
        cols = self.changing[k]
        before = tr.rows[-1][cols]
        a, b, left = 0.0, h, tr.rows[-1]
        tol = EVENT_TOL * max(1.0, abs(t))
        while b - a > tol:
            c = 0.5 * (a + b)
            self._guard(k, t, model.restore_state, token)
            y = self.run_step(k, t, c, self.inputs_over(k, t, c)[0])
            if np.array_equal(y[cols], before):
                a, left = c, y
            else:
                b = c
        self._guard(k, t, model.restore_state, token)
        inputs = self.inputs_over(k, t, b)[0]
        return b, left, self.run_step(k, t, b, inputs), inputs

    def _changed(self, k: int, left: np.ndarray, y: np.ndarray) -> bool:
        """Whether a discrete output of ``k`` changed between ``left`` and ``y`` (a state
        event), not only a continuous one at a time event ``k`` declared (_left_of_jump)."""
        cols = self.changing.get(k)
        return cols is not None and not np.array_equal(left[cols], y[cols])

    def _left_of_jump(self, k: int, t: float, h: float, y: np.ndarray) -> np.ndarray | None:
        """The left limit of ``k``'s outputs at the time event it declared at ``t + h``, where
        some of them are read already on the event's far side (a step source): those that
        missed the track's own extrapolation by more than the whole change it foresaw over the
        step, replaced by that extrapolation; ``None`` where none did. Stored as both sides of
        the event (:func:`_append`), the consumers read the step up to the event on its own
        side; read through the new value, the jump was an interpolation error no step
        shortened, and the run ended at ``hmin`` on the event (as Master._jumped argues for
        the synchronous masters). Not judged with one point in the segment: an extrapolation
        of order 0 foresees no change."""
        tr = self.tracks[k]
        if tr.discrete or len(tr.times) - tr.segment < 2:
            return None
        # the degree-`order` extrapolation through the segment's newest points, as its
        # consumers read past its end (_window), at the event from this side
        start = max(tr.segment, len(tr.times) - (self.order + 1))
        at = np.array([t + h])
        own = self._fill(tr, list(range(len(y))), at, start, len(tr.times), True)[0]
        jump = jumped(y, own, tr.rows[-1])
        cols = self.changing.get(k)
        if cols is not None:
            jump[cols] = False  # discrete outputs: held, located as state events
        if not jump.any():
            return None
        left = y.copy()
        left[jump] = own[jump]
        return left

    def _state_event(self, k: int, left: np.ndarray) -> None:
        """A discrete output of ``k`` changed at its newest point ``t``: record the event and
        re-synchronize (:meth:`_resync`)."""
        tr, model = self.tracks[k], self.system.models[k]
        cols = self.changing[k]
        self._event(k, "change", {model.outputs[c].name: float(tr.rows[-1][c]) for c in cols})

    def _event(self, k: int, kind: str, payload: dict[str, float], at: int | None = None) -> None:
        """``k`` has an event at its newest point ``t`` (both sides of the jump stored), or at
        its point ``at`` (an unannounced discontinuity inside the step after it): record it,
        cut the trajectories it reaches there (extrapolation restarts, steps land on it), and
        re-synchronize — roll back to ``t`` the sub-models past it that the event reaches
        (:attr:`resync` ``"partial"``) or all of them (``"complete"``), thesis 4.3.5."""
        tr = self.tracks[k]
        if at is None:
            at = len(tr.times) - 1
            tr.states[at] = self._guard(k, tr.t, self.system.models[k].save_state)
        t = tr.times[at]
        tr.segment = at
        self._memory_of[k].forget()
        self.shift.jump()
        self.state_fired.append(Event(t, tr.name, kind, payload))
        if sum(e.t == t for e in self.state_fired) > MAX_EVENTS:
            names = ", ".join(sorted({e.source for e in self.state_fired if e.t == t}))
            raise RuntimeError(f"more than {MAX_EVENTS} events at t = {t:.9g}: {names} keep "
                               "firing each other (an endless event loop; add hysteresis or "
                               "break the cycle)")
        affected = set(range(len(self.tracks))) if self.resync == "complete" \
            else {k, *self.reach[k]}
        for c in sorted(affected):
            if t not in self.cuts[c]:
                bisect.insort(self.cuts[c], t)
        for c in sorted(affected - {k}):
            other = self.tracks[c]
            if other.discrete and c not in self.monitors:
                continue  # a scheduled discrete-event model: nothing it does depends on others
            if _beyond(other.t, t):
                self._rollback(c, t, k, 0, across=True)
            elif other.t == t:
                other.segment = len(other.times) - 1
        for c in affected:  # at the event now: step control starts again (see _Stepper.act)
            if self.tracks[c].t == t or c == k:
                self.tracks[c].h = min(self.tracks[c].h, self.h0)

    def _judge(self, tr: Track, t: float, h: float, y: np.ndarray, inputs: np.ndarray,
               slope: np.ndarray | None, at_event: bool) -> _Verdict:
        """Accept or reject a trial step ``[t, t + h]`` of ``tr`` and propose the next step.

        Two checks: consumers can interpolate the new trajectory (its interpolation error ×
        their sensitivity; grey box: the larger of the samples' estimate and what the model's
        own slope reveals, :meth:`slope_error`), and the step resolved its own inputs
        (:meth:`_fed_ratio`: :meth:`input_resolution` × its sensitivity; for a receiver that
        holds its inputs, :meth:`hold_deviation` and :meth:`hold_lag`). A step whose slope
        reveals aliasing and whose outputs no consumer reads with a sensitivity (gain 0: no
        consumers) is rejected outright; any rejection of a step whose slope revealed aliasing
        at least halves it.
        """
        pol = tr.policy
        gain = self.consumer_gain(tr.index)
        e = self.interpolation_error(tr, t + h, y)
        revealed = None if at_event else self.slope_error(tr, t + h, y, slope)
        if revealed is not None:
            e = np.maximum(e, revealed)
        startup = len(tr.times) - tr.segment < 2
        if startup:  # a one-off error, not a rate
            r = gain * h * e / pol.scale(y)
            i = int(np.argmax(r)) if r.size else 0
            ratio, power = (float(r[i]) if r.size else 0.0), 2
        else:
            ratio, i = pol.ratio(gain * h * e, y, h)
            power = 4 + pol.extra_power
        own_gain = tr.gain if tr.gain is not None else INITIAL_GAIN
        unresolved, fed_power, fed, lasting = self._fed_ratio(tr, t, h, inputs, y, own_gain)
        why = self._rejection(tr, i, e, gain, ratio, unresolved, revealed)
        # the step control's memory (PI, mean step) sees only the steps that are kept
        h_next = pol.next_step(h, ratio, power, why is None)
        if unresolved > 1.0:  # a lasting lag (power 2) is met against tol, not a share of it
            extra = pol.extra_power if fed_power != 2 else 0
            h_next = min(h_next, pol.next_step(h, unresolved, fed_power + extra, False))
        if revealed is not None and why is not None:
            h_next = min(h_next, 0.5 * h)
        norm = pol.norm_scale(y)  # the norm the error is met in (StepPolicy.norm_scale)
        spent_out = 0.0 if gain == 0.0 or startup else \
            float(np.max(gain * h * e / (norm / pol.tol)))
        return _Verdict(h_next, why, spent_out, fed * pol.tol, ratio, power, lasting * pol.tol)

    def _rejection(self, tr: Track, i: int, e: np.ndarray, gain: float, ratio: float,
                   unresolved: float, revealed: np.ndarray | None) -> str | None:
        """Why :meth:`_judge` rejects the step (``None``: it does not), for the message a
        rejected attempt leaves (``i``: the output that decided ``ratio``; ``revealed``: what
        the slope revealed, :meth:`slope_error`)."""
        if revealed is not None and gain == 0.0:
            return "its own slope contradicts the trajectory (aliasing)"
        if unresolved > 1.0:
            return f"its inputs vary within the step ({unresolved:.3g}× the allowed error)"
        if ratio > 1.0 and gain != 0.0:
            name = self.system.output_names[self.system.output_slices[tr.index].start + i]
            by_slope = revealed is not None and 0.0 < revealed[i] >= e[i]
            return f"{name}: interpolation error {e[i]:.3g} × sensitivity {gain:.3g}/s" + \
                ("; its own slope contradicts the trajectory" if by_slope else "")
        return None

    def _failed_trial(self, tr: Track, exc: SubModelError, token: Any, t: float,
                      h: float) -> float:
        """A trial step the sub-model failed on (raised, non-finite outputs) is a rejection:
        restore it and return the shorter step to retry with. The inputs of a trial step are
        partly extrapolated and may lie where the true inputs never go (a singularity of the
        right-hand side); only a failure down to ``hmin`` or a hung call ends the run."""
        if exc.hung:
            raise exc
        h_next = FAILED_TRIAL_SHRINK * h
        if h_next < tr.policy.hmin:
            raise SubModelError(exc.model, exc.t, f"{exc.reason} (still after retrying with "
                                f"steps down to {h:.3g} s; hmin = {tr.policy.hmin:.3g} s)",
                                exc.h) from exc
        tr.rejected += 1
        tr.failed_trials += 1
        tr.failure = (exc, t + h)
        if self.on_attempt is not None:
            self.on_attempt(tr.name, t, h, False)
        self._guard(tr.index, t, self.system.models[tr.index].restore_state, token)
        return h_next

    # -- the race ------------------------------------------------------------------------------
    def initialize(self, t0: float, until: float, events: list[float]) -> None:
        """Initialize every sub-model; the first point of every trajectory is at ``t0``."""
        self.events = events
        self.cuts = [list(events) for _ in self.tracks]
        # who declared which time event: its outputs may stand on the event's far side there
        self.declared: dict[float, set[int]] = {}
        for k, m in enumerate(self.system.models):
            for e in m.time_events():
                self.declared.setdefault(float(e), set()).add(k)
        self.checked = dict.fromkeys(self.monitors, t0)
        self.until = until
        system = self.system
        for k, m in enumerate(system.models):
            self._guard(k, t0, m.initialize, t0)
        y0 = np.concatenate([self._caller._outputs(k, t0, None)
                             for k in range(len(system.models))])
        for k, (m, tr) in enumerate(zip(system.models, self.tracks)):
            self._guard(k, t0, m.set_inputs, system.a[k] * y0[system.src[k]] + system.b[k])
            tr.times, tr.rows = [t0], [y0[system.output_slices[k]]]
            slope = self._slope(k, t0)
            tr.slopes = [slope] if slope is not None else []
            tr.policy.start(t0, until)
        for memory in self.memories:
            memory.reset(t0, until)
        self._peak = 0.0
        self.shift = RaceShift(len(self.tracks))

    def actors(self, kernel: Kernel, on_step: Any = None) -> list[Actor]:
        """One actor per sub-model for the run kernel (the race of appendix C: whoever is
        farthest behind steps next); ``on_step(track)`` after every accepted step."""
        self._kernel, self._on_step = kernel, on_step
        self._steppers = [_Stepper(self, k) for k in range(len(self.tracks))]
        return list(self._steppers)

    def settle(self) -> list[Actor]:
        """When every sub-model is at the end: verify the last steps (the partners are all at
        ``until`` now) and name the sub-models that rolled back to run again."""
        for k in range(len(self.tracks)):
            self.verify(k)
        return self._woken()

    def fire(self, k: int, t: float) -> Event | None:
        """Discrete-event sub-model ``k`` has its event at ``t``, where every sub-model stands
        (no one steps past it). Pending steps are verified first; if that rolled anyone back,
        nothing fires yet (``None``) and the rolled-back sub-models catch up again. Otherwise
        the model fires with its inputs at ``t``, its track gets a second point at ``t`` (the
        right limit) and ``t`` becomes a segment boundary for everyone: extrapolation restarts."""
        woken = self.settle()
        if woken:
            for actor in woken:
                self._kernel.wake(actor)
            return None
        tr, model = self.tracks[k], self.system.models[k]
        row = np.concatenate([other.rows[-1] for other in self.tracks])
        inputs = self.system.a[k] * row[self.system.src[k]] + self.system.b[k]
        kind = model.apply(t, inputs)
        new = np.asarray(model.get_outputs(), dtype=float)
        tr.times.append(t)
        tr.rows.append(new)
        tr.states[len(tr.times) - 1] = self._guard(k, t, model.save_state)
        if t not in self.events:
            bisect.insort(self.events, t)
        for cuts in self.cuts:
            if t not in cuts:
                bisect.insort(cuts, t)
        for other in self.tracks:
            other.segment = len(other.times) - 1
        self._memory_of[k].forget()
        return Event(t, tr.name, kind, {p.name: float(v) for p, v in zip(model.outputs, new)})

    def _woken(self) -> list[Actor]:
        """The actors of the sub-models rolled back since the last call."""
        woken = [self._steppers[k] for k in sorted(set(self._requeue))]
        self._requeue.clear()
        return woken

    def run(self, until: float, on_step: Any = None) -> None:
        """The whole race on a kernel of its own (:meth:`initialize` first)."""
        kernel = Kernel(until)
        for actor in self.actors(kernel, on_step):
            kernel.add(actor)
        kernel.run(self.settle)

    def _forget_states(self) -> None:
        """Drop saved states no rollback can reach. A rollback goes back to the start of a
        pending step (its first point, which after a re-run in pieces lies before the track's
        previous point) or to a track's previous point; each track keeps one state before
        the earliest of those, for consumers rolled back with a partner."""
        horizon = min(tr.times[tr.pending[5]] if tr.pending is not None
                      else tr.times[-2] if len(tr.times) > 1 else tr.times[-1]
                      for tr in self.tracks)
        # a rollback cascades (a consumer goes back to where its partner went back to, each
        # level at most one step of that partner): keep two of the longest recent steps more
        horizon -= 2.0 * max((tr.steps[-1] for tr in self.tracks if tr.steps), default=0.0)
        for tr in self.tracks:
            keep = [i for i in tr.states if tr.times[i] >= horizon]
            floor = max((i for i in tr.states if tr.times[i] < horizon), default=None)
            tr.states = {i: tr.states[i] for i in [*keep, *([floor] if floor is not None
                                                              else [])]}

    def error_estimate(self) -> float:
        """The run's global error estimate, in the norm ``tol`` bounds (``|e| / (1 + |y|)`` for
        the default ``atol = rtol = tol``), without a reference: the larger of the plain sum
        (:meth:`summed_estimate`) and the same errors carried as a time shift of the system
        (:mod:`~cosimstep.race_drift`), met at the speeds later."""
        return max(self.summed_estimate(), self.shift.value)

    def summed_estimate(self) -> float:
        """The plain sum of the local estimates, at its largest.

        A sub-model's outputs are wrong by what its inputs were wrong: the interpolation errors
        of its partners' trajectories times its sensitivity (each partner's step control
        estimates exactly that, per step) plus what its own steps failed to resolve of its
        inputs. Summed over the run per receiver, as if no error ever decayed, except where
        an error memory was measured (:mod:`~cosimstep.race_memory`): there the sums fade
        (:meth:`_spend`), and the estimate is the largest receiver's sum at its largest. A
        receiver that holds its inputs adds the largest lasting lag it met (:meth:`hold_lag`),
        which does not add up and does not fade.
        """
        return max(self._peak, self._estimate_now())

    def _estimate_now(self) -> float:
        # a lasting error of a receiver that holds its inputs (hold_lag) adds to what it sums
        totals = [tr.spent_in + sum(self.tracks[s].spent_out for s in range(len(self.tracks))
                                    if tr.index in self.consumers[s]) + tr.lag
                  for tr in self.tracks]
        return max(totals, default=0.0)

    def values_at(self, k: int, times: np.ndarray) -> np.ndarray:
        """Model ``k``'s outputs at arbitrary ``times`` within its trajectory."""
        sl = self.system.output_slices[k]
        cols = list(range(sl.stop - sl.start))
        out = np.empty((len(times), len(cols)))
        for i, t in enumerate(times):
            out[i] = self._owned(k, cols, np.array([t]))[0][0]
        return out


ROUNDING = 64 * np.finfo(float).eps


def _midstep(t: float, h: float, inputs: np.ndarray) -> np.ndarray:
    """The value a receiver that holds its inputs gets over ``[t, t + h]`` (inputs at
    :data:`NODES`): the cubic through them at mid-step, as :meth:`Multirate.run_step` gives it."""
    if h <= negligible(t):  # a step of a few ulps: its inputs held at the start
        return np.array(inputs[0], dtype=float)
    return evaluate(taylor_coefficients(list(t + NODES * h), inputs, t, 3), 0.5 * h)
"""Relative size below which a deviation between the cubic a sub-model follows and its
partners' trajectory is rounding: both are evaluated from the same stored values through a
handful of multiplications (a cubic's Lagrange weights sum to 1 with magnitudes of a few), so
their difference in exact arithmetic is below a few dozen ulps of the values."""

SUDDEN = 16.0
"""A step that had to shrink this many times below the sub-model's previous accepted step, with
its error falling far slower than a smooth trajectory's would, crossed a discontinuity."""


def _discontinuity(chain: list[tuple[float, _Verdict]], h: float, accepted: _Verdict,
                   previous: float | None) -> bool:
    """Whether the rejections before an accepted step of ``h`` show an unannounced
    discontinuity inside the last rejected step (Gear and Østerby's test, for black boxes).

    On a smooth trajectory the consumer-facing error ratio falls like ``h^power`` (4 or 5)
    as the step shrinks; across a jump in the trajectory or one of its first derivatives it
    falls like ``h^0 … h^2``. So: the step had to shrink by :data:`SUDDEN` or more below the
    previous accepted step (the dynamics did not change gradually), and between the first
    rejection and the accepted step the ratio fell with an observed power below
    ``power − 1.5``. The accepted step then ends at or past the jump, or just before it.
    """
    tried = [(hh, v) for hh, v in chain if v.ratio > 1.0]  # rejected for the trajectory
    if previous is None or len(tried) < 2 or h * SUDDEN > previous:
        return False
    (h0, first), (h1, last) = tried[0], tried[-1]
    powers = []
    if h0 > h1 and first.ratio > last.ratio:
        powers.append(math.log(first.ratio / last.ratio) / math.log(h0 / h1))
    if h0 > h and 0.0 < accepted.ratio < first.ratio:
        powers.append(math.log(first.ratio / accepted.ratio) / math.log(h0 / h))
    return bool(powers) and min(powers) < first.power - 1.5


def _beyond(s: float, t: float) -> bool:
    """Whether time ``s`` lies past ``t`` by more than rounding (a track that stands at ``t``
    after a sum of steps may read a few ulps either side of it)."""
    return s > t * (1 + 1e-12) + 1e-15


def _through(weights: np.ndarray, values: np.ndarray, offsets: list[float]) -> list[float]:
    """The polynomial through one signal's ``values`` (``weights``: :func:`weight_matrix` of
    their times less the expansion point ``t0``) at ``t0 + offsets``:
    :func:`~cosimstep.extrapolation.taylor_coefficients` and
    :func:`~cosimstep.extrapolation.evaluate_small`, written out for one signal (the same
    operations in the same order, bit for bit, without their generality)."""
    c = weights.dot(values[:, None])[:, 0].tolist()
    out = []
    for dt in offsets:
        term, value = 1.0, c[0]
        for k in range(1, len(c)):
            term = term * (dt / k)
            value = value + term * c[k]
        out.append(value)
    return out


def _segment_range(times: list[float], lo: float, hi: float) -> tuple[int, int]:
    """The points of ``times`` in the segment ``[lo, hi]`` as a slice ``[first, end)``: from
    the right limit of a jump at ``lo`` to the left limit of one at ``hi`` (a jump is stored as
    two points at the same time)."""
    first = bisect.bisect_left(times, lo - 1e-9 * max(1.0, abs(lo)))
    while first + 1 < len(times) and times[first + 1] == times[first]:
        first += 1
    end = bisect.bisect_right(times, hi + 1e-9 * max(1.0, abs(hi)))
    if end - 1 > first and times[end - 1] == times[end - 2]:  # (not the jump at lo)
        end -= 1
    return first, end


def _append(tr: Track, t: float, y: np.ndarray, slope: np.ndarray | None,
            left: np.ndarray | None) -> None:
    """An accepted step's end point; with ``left`` (a jump there), both sides at ``t``, the
    left limit first, joined by a step of length 0."""
    for i, row in enumerate([y] if left is None else [left, y]):
        if i:
            tr.steps.append(0.0)
        tr.times.append(t)
        tr.rows.append(row)
        tr.policy.observe(t, row)
        if slope is not None:
            tr.slopes.append(slope)


class _Stepper(Actor):
    """One sub-model of the race as an actor of the run kernel: a turn is one accepted step,
    landing on the next time event or the end."""

    def __init__(self, race: Multirate, k: int) -> None:
        self.race, self.k = race, k
        self.name, self.rank = race.tracks[k].name, k

    @property
    def time(self) -> float:
        return self.race.tracks[self.k].t

    @property
    def finished(self) -> bool:
        return self.race.tracks[self.k].t >= self.race.until

    def act(self, limit: float) -> None:
        race, tr = self.race, self.race.tracks[self.k]
        if race.budget:
            race.budget.check(sum(other.calls for other in race.tracks))
        t = tr.t
        cuts = race.cuts[self.k]
        i = bisect.bisect_right(cuts, t + 1e-12 * max(1.0, abs(t)))
        landing = min(cuts[i], limit) if i < len(cuts) else limit
        if race.advance(self.k, landing) and landing < race.until:
            tr.segment = len(tr.times) - 1  # a time event: extrapolate from here on only
            # the dynamics change here: step control starts again as at the run's start,
            # and the error memory is measured again once the whole group is here
            tr.h = min(tr.h, race.h0)
            race._memory_of[self.k].landed(landing)
            race.shift.jump()  # an event on the clock does not move with the trajectory
        race.watch(self.k)
        if race._on_step is not None:
            race._on_step(tr)
        for actor in race._woken():
            race._kernel.wake(actor)
        if len(tr.times) % 64 == 0:
            race._forget_states()


def refusals(models: dict[str, Any], interpolation: str | None = None, *,
             state: bool = True) -> list[str]:
    """Why the multi-rate master cannot run these sub-models (empty: it can).

    It re-runs steps (every sub-model must save and restore its state) and hands each
    sub-model's trajectory to the others (an output that depends on the input at the same
    instant has no trajectory of its own). ``state=False`` leaves out the first reason."""
    problems = [f"'{n}' cannot save/restore its state" for n, m in models.items()
                if state and not m.capabilities.can_save_state]
    problems += [f"'{n}' has direct feedthrough" for n, m in models.items()
                 if m.capabilities.has_direct_feedthrough]
    if interpolation == "hermite":
        problems += [f"'{n}' gives no output derivatives (needed by 'hermite')"
                     for n, m in models.items() if not m.capabilities.provides_derivatives]
    return problems


def _outside(h: float, measured_on: float) -> bool:
    """Whether a gain measured on a step of ``measured_on`` is not to be used for ``h``
    (:data:`GAIN_SPAN`; never measured: ``nan``, which is inside)."""
    return not math.isnan(measured_on) \
        and not measured_on / GAIN_SPAN <= h <= measured_on * GAIN_SPAN


def _copy_policy(policy: StepPolicy) -> StepPolicy:
    """Each sub-model's own copy of the controller's policy, with the global-error budget the
    multi-rate estimate's :data:`CALIBRATION` was measured with (``distribute``, cancellation
    3, the step control settling at ratio 0.5). Without ``distribute`` the multi-rate error
    drifted from 0.6-2× tol at tol 1e-2 to 4.6-27× at 1e-6 (steps are shared less evenly than
    the synchronous master's, whose one step serves every sub-model); target 0.1 made the
    duplicated state and the KPR problem 10-100× more accurate than asked (docs/concepts.md).
    The predictive control is not offered (its forecast followed every swing of the mixed
    pendulums: 27.8 × tol at 1e-3, 10.9 × at 1e-5); ``trend`` and ``unbiased`` are kept as
    asked, and act, as for every controller, where the group's error memory probes measured
    the system settling (:meth:`StepPolicy._settling`; always on, the mixed pendulums reached
    11-21 × tol). Nor does it catch up with a settling system (:attr:`StepPolicy.catch_up`):
    tried, its own estimate overshot the error 60-80 × on the holdout's forced loop, whose
    repeats then ended at 0.006-0.008 × tol."""
    fields = {f.name: getattr(policy, f.name) for f in dataclasses.fields(policy)}
    fields.update(distribute=True, cancellation=3.0, target=0.5, predictive=False,
                  catch_up=False)
    return StepPolicy(**fields)


__all__ = ["Multirate", "Track", "refusals"]

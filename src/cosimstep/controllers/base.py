"""The controller interface, and the step-size policy our error-controlled controllers share.

A controller receives a :class:`StepContext` (which runs coupled steps, saves and restores the
sub-models, and exposes the stored history) and makes one *attempt* at ``[t, t + h]``: it runs
whatever calls it needs, decides whether the result is accepted, and proposes the next step. The
orchestrator owns the loop, time events, storage and failure handling, so a new controller is a
small class registered by name.
"""

from __future__ import annotations

import bisect
import dataclasses
import math
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any, ClassVar, Protocol

import numpy as np

from cosimstep.controllers.magnitude import RecurringLow
from cosimstep.controllers.memory import NO_DECAY
from cosimstep.errors import StepSizeError, is_number


@dataclass
class Attempt:
    """Outcome of one attempt at a communication step.

    ``error`` is the controller's error ratio (estimate / allowed; accepted when <= 1) or ``None``
    for controllers without error control.
    """

    y: np.ndarray
    accepted: bool
    h_next: float
    error: float | None = None


class StepContext(Protocol):
    """What a controller may use during an attempt."""

    times: list[float]
    history: np.ndarray
    order: int  # the master's input extrapolation order
    names: list[str]  # exchanged outputs, the columns of ``history``
    predicted: np.ndarray  # outputs some receiver uses extrapolated (not yet computed)
    consumed: np.ndarray  # outputs some sub-model reads as an input
    held: np.ndarray  # outputs some receiver holds constant over a step (no input derivatives)
    discrete: np.ndarray  # piecewise-constant outputs, held by every receiver (Port.discrete)
    readers: list[tuple[np.ndarray, slice]]  # per sub-model: the outputs it reads, its own
    iterated: bool  # strong coupling: every step is iterated until its end values agree

    def step(self, t: float, h: float, *, order: int | None = None,
             end: np.ndarray | None = None,
             extra: tuple[tuple[float, np.ndarray], ...] = ()) -> np.ndarray:
        """Run every sub-model over ``[t, t + h]`` (see :meth:`cosimstep.masters.Master.step`).

        ``extra`` are provisional points after ``t`` (e.g. a half step) to extrapolate from.
        """
        ...

    def save(self) -> Any: ...
    def restore(self, token: Any) -> None: ...

    def defect(self) -> tuple[np.ndarray, np.ndarray]:
        """After a step: (new value − value the receivers assumed at ``t + h``, mask of the
        outputs that were extrapolated). The cost-free coupling-error signal of fig. 87."""
        ...

    def derivatives(self) -> np.ndarray | None:
        """Grey-box time derivatives of the outputs now, or ``None`` if a model cannot tell."""
        ...


class Controller(ABC):
    """Base class; subclasses set ``name`` and implement :meth:`attempt`."""

    name: ClassVar[str]
    needs_rollback: ClassVar[bool] = False
    # what a run leaves in its public attributes (not settings): left out of :meth:`describe`,
    # so a controller used for a second run records that run's settings, not the last run's
    run_state: ClassVar[frozenset[str]] = frozenset({"error_estimate"})

    @abstractmethod
    def initial_step(self, t0: float, t_end: float) -> float: ...

    @abstractmethod
    def attempt(self, ctx: StepContext, t: float, h: float) -> Attempt: ...

    def event(self, t: float) -> float | None:
        """Called when the run lands on an event (a discontinuity of some sub-model); returns
        the step to go on with, or ``None`` to keep the one proposed."""
        return None

    def describe(self) -> dict[str, Any]:
        """Settings, for the results store."""
        return {"name": self.name, **{k: _plain(v) for k, v in vars(self).items()
                                      if not k.startswith("_") and k not in self.run_state}}


def _plain(value: Any) -> Any:
    if isinstance(value, StepPolicy):  # its fields; what a run measures (memory, floor) is state
        return {f.name: getattr(value, f.name) for f in dataclasses.fields(value)}
    if isinstance(value, Controller) or hasattr(value, "describe"):
        return value.describe()  # a controller's part (its error memory probe): its settings
    return value


NOISE_SHARE = 1e-3
"""An estimate below this share of ``tol`` that no smaller step reduces is noise
(:meth:`StepPolicy.noise`)."""


SMOOTHING = 2.0 / 3.0
"""Discount ``θ`` of the predictive control's double exponential smoothing of ``log c``
(level gain ``1 − θ²``, trend gain ``(1 − θ)²``). With ``θ = 2/3`` the forecast's error on
estimates that scatter at random has about the variance the PI control leaves in ``log r``
(1.6 times the scatter's, both simulated), so it is as steady as the PI control, and unlike it
it follows a steady drift of ``c`` without offset. ``θ = 0`` would be Gustafsson's
predictive control (6.0 times the scatter's variance: on the suite's pendulums it made the
steps zigzag, docs/concepts.md)."""


TREND_WINDOW = 1.0 - (1.0 - SMOOTHING) ** 2
"""Discount of the running statistics the step control judges its estimates by: the scatter
of ``log c`` about its forecast, and the arithmetic and geometric means of the accepted ratios.
The forecast's trend moves by ``(1 − θ)²`` of each miss, so it averages over about
``1/(1 − θ)² = 9`` steps; the scatter it is tested against and the means that correct the aim
are taken over the same window (8/9)."""

TREND_SD = 0.100
"""Standard deviation of the smoothed trend (per step, in ``log c``) over that of the misses,
when ``log c`` only scatters at random (no trend at all), for :data:`SMOOTHING` = 2/3
(simulated over 200,000 steps: 0.1003; tests/controllers/test_step_control_statistics.py)."""

BISECTIONS = 40
"""Halvings of the interval in ``log g`` when the trend's step is solved for: ``log 25 / 2^40``,
far below any step change that matters."""

SIGNIFICANT = 2.0
"""A trend is followed when it is at least this many of its standard deviations (a two-sigma
test: white scatter passes it about one step in twenty)."""


def _smooth(level: float, trend: float, x: float) -> tuple[tuple[float, float], float]:
    """One step of Brown's double exponential smoothing (:data:`SMOOTHING`): the new level and
    trend after the value ``x``, and the miss of the old forecast."""
    miss = x - (level + trend)
    level += trend + (1.0 - SMOOTHING**2) * miss
    trend += (1.0 - SMOOTHING) ** 2 * miss
    return (level, trend), miss


def _smooth_in_time(timed: tuple[float, float, float], x: float, last: float | None,
                    h: float) -> tuple[float, float, float]:
    """:func:`_smooth` for values unevenly spaced in time: ``timed`` is the level of ``log c``
    at the middle of the last step, its slope per unit time, and that step's length; ``x`` is
    measured on the next step, of length ``h``, whose middle is ``(h_last + h)/2`` later (taken
    from the lengths, not as a difference of absolute times, which loses the spacing of short
    steps late in a long run). The gains are Brown's (:data:`SMOOTHING`), the slope's miss
    taken per unit of the spacing. The value smoothed is no lower than the last coefficient
    carried along the slope: a coefficient can vanish by coincidence, and a step sized on that
    moment is too long for the next (carried along the slope, not held, so that a steady fall
    is followed without lag)."""
    level, slope, h_last = timed
    gap = 0.5 * (h_last + h)
    expected = level + slope * gap
    if last is not None:
        x = max(x, last + slope * gap)
    miss = x - expected
    return (expected + (1.0 - SMOOTHING**2) * miss,
            slope + (1.0 - SMOOTHING) ** 2 * miss / gap, h)


def _wrong_types(policy: Any) -> list[str]:
    """The step policy's settings whose type is not the declared one (a switch given as
    ``--opt predictive=maybe`` ran as if true; ``hmax=abc`` failed deep inside with a
    comparison error). Numbers: any real number (NumPy's too), not a boolean; ``None``
    where allowed."""
    wrong = []
    for f in dataclasses.fields(policy):
        value, kind = getattr(policy, f.name), str(f.type)
        if value is None and "None" in kind:
            continue
        if kind == "bool":
            if not isinstance(value, bool | np.bool_):
                wrong.append(f"`{f.name}` must be true or false, got {value!r}")
        elif kind.startswith("float") and not (is_number(value) and value == value):
            wrong.append(f"`{f.name}` must be a number, got {value!r}")
    return wrong



@dataclass
class StepPolicy:
    """Error norm and step-size update shared by the error-controlled controllers.

    Attributes
    ----------
    tol:
        The tolerance; ``atol``/``rtol`` default to it (mixed: ``atol + rtol·|y|``).
    hmin, hmax:
        Step limits [s]. A step that would fall below ``hmin`` ends the run (status ``failed``).
    safety, grow, shrink:
        The new step is ``safety·h·ratio^(-1/k)``, limited to ``[shrink·h, grow·h]``.
    predictive:
        Step control that forecasts the error coefficient ``c = r/h^k`` instead of ``pi``: its
        logarithm is smoothed with a level and a trend (Brown's double exponential smoothing,
        :data:`SMOOTHING`), and the next step is the one whose forecast ratio is the target;
        at an event the step starts again from the run's first step (the controllers'
        ``event``). The error per step of a system that settles (a transient decaying, a pump
        run down) falls by a steady factor per step *besides* what the step does; the PI
        control alone (``catch_up`` off) treats that drift as a disturbance and settles below
        the target (at 0.51 of it for a fall of 18 % per step; measured on the pump-failure
        example: ratios of 0.03–0.05 against 0.1 for the whole settle, so ``pc`` spent 6–11 %
        of its tolerance). A forecast with a trend follows a steady drift without offset. It starts
        again, as after a rejection, when the error memory is measured anew (a new share of
        the budget; see :attr:`trend`). Off by default (docs/concepts.md, "Step control that
        follows a settling system").
    trend:
        Follow a drift of the error coefficient where the estimates show one: the coefficients
        are forecast on every accepted step, and the forecast's step is taken when the trend
        of the measured ones is significant (more than :data:`SIGNIFICANT` standard
        deviations, judged by the scatter of their misses over :data:`TREND_WINDOW`);
        otherwise the PI control decides. A settling system (a transient decaying, a pump run
        down) shows a steady trend that the PI control lags behind; estimates that only
        scatter show none, and there the PI control's damping is kept. The step is sized on
        a forecast *in time* (:meth:`_timed_step`): a settling system's modes decay like
        ``e^(−λt)``, so the fall per step grows with the step, and a forecast per step stayed
        behind it. What is forecast is no lower than the last coefficient carried along the
        forecast's slope: one measured on a single step can vanish by coincidence (the
        leading term of a coupling error, a derivative of an oscillating signal, passes
        through zero), and a step sized for that moment is too long for the next — followed,
        such troughs took steps at 7× their share on a stiff oscillator. Meant with
        :attr:`unbiased`. Both act only where the error memory probes measured a memory below
        half the run (:meth:`_settling`), the black-box evidence that the system settles, so
        only under a controller that probes (``pc``, the multi-rate master; others refuse the
        options): on a swing the slope per second carried over a long step promises a fall
        that the motion takes back (followed everywhere, the mixed and the triple pendulum
        reached 15–17 × tol under ``pc``, 11–21 × under the multi-rate master). A memory
        measured anew starts the forecast again: the ratio is the error over its share of the
        budget, and a new share is no fall of the error. Off by default (measured on the
        suite and the pump-failure example in docs/concepts.md, "A trend only where the
        estimates show one" and "A trend forecast in time, and a step longer than the
        memory").
    unbiased:
        Aim the step control so that the *arithmetic* mean of the accepted ratios is the
        target. The controls settle the logarithm of the ratio, i.e. its geometric mean, at
        the target, while the global budget adds the ratios themselves; where the estimates
        scatter from step to step the arithmetic mean is the larger (Jensen; by ``exp(σ²/2)``
        for a log-normal scatter ``σ``): on the pendulums the runs spent 2–5 times the budget
        they aimed at. The quotient of the two running means (over :data:`TREND_WINDOW`)
        divides the target. Off by default: alone, it also reads the PI control's lag on a
        settling system as scatter and makes those runs more accurate still (21 suite cells
        outside the band; docs/concepts.md). It acts, as :attr:`trend`, only where the error
        memory probes saw the system settle, and its means start again with a new memory.
    pi:
        Proportional–integral control (Gustafsson, the default): damps the step oscillation an
        I-controller shows on smooth problems.
    catch_up:
        With ``pi``, where the error memory probes measured the system settling
        (:meth:`_settling`, so only under ``pc``, the controller that probes) and an accepted
        step's ratio is below the aim, the step grows at least to the elementary controller's
        step towards the aim, ``(aim/r)^(1/k)``, when that is longer than the PI control's. A
        settling system's error coefficient ``log c`` falls by some ``a`` per step besides what
        the step does; the PI control, whose integral part alone answers a steady offset, then
        settles at ``r = aim·e^(−a/0.3)`` and leaves most of the budget unspent, the elementary
        step at ``aim·e^(−a)``, one step behind the fall. Above the aim the PI control is kept:
        a rejection is near there, and its damping is what holds the ratio. Where the probes
        saw no settling it is kept too: a fall of ``c`` there is a swing the motion takes
        back, and a step that jumps on every low ratio but is damped on every high one
        roughens the step sequence and spends more than the aim, past what the summed
        estimates see. Off with ``trend``, ``predictive`` or ``unbiased`` (the opt-in answers
        to the same lag and its scatter, measured on their own), and with ``feedback`` or
        ``overrun`` (for errors that grow beyond their sum, where the probes are the ones to
        doubt: they misread a relaxation oscillator's memory as short). The multi-rate master
        does not use it (:func:`cosimstep.multirate._copy_policy`). Measured in
        docs/concepts.md, "Catching up with a settling system".
    target:
        The error ratio the PI control settles at. The local estimates scatter from step to
        step, and a rejected step costs its calls again, so the control aims well below the
        rejection threshold: with the aim fixed at 0.5 tol, target 0.5 rejected 28 % of the
        steps of problem 6 (3712 calls at tol 1e-4), 0.1 rejected 12 % (2676 calls, same
        error), and on the toggled pendulum 90 against 8 rejections.
    global_error:
        The tolerance bounds the *global* error over the run: each step may spend a share of it
        proportional to its length (error per unit step, scaled by the run length). Without it,
        ``tol`` bounds each step's local error, and the global error grows with the step count.
        The share is taken over the run's length, or over its *error memory* where a
        controller measured one (``memory`` [s], :mod:`~cosimstep.controllers.memory`): an
        error that fades within ``memory`` adds up over that long, not over the run. A step
        longer than the memory spends the whole budget, not more: its own error stands in
        full at its end, however fast it fades afterwards (uncapped, a step of 165 s under a
        memory of 25 s could make 6.5 times the tolerance, and did).
    feedback:
        Tighten the share by the propagation the run's companion measures (opt-in; needs
        ``estimate="richardson"``, so ``pc`` on a synchronous master): after every accepted
        step the ratios are multiplied by the companion's global estimate over the summed
        local estimates (:attr:`propagation`), where that is above 1. The summed estimates
        miss errors that grow — a limit cycle's phase error comes back, multiplied by the
        slope, at every jump; a pendulum's amplitude error becomes a growing phase drift —
        and the companion, the run repeated beside itself at doubled steps, sees them as they
        happen. Only tightening: where the factor is below 1 (errors that fade) the companion
        also ran below the error on the pendulums (0.26–1 × it), and loosening on it took them
        to 15 × tol. It cannot help before the growth has shown: the first spike of the
        Brusselator is paid in full (measured in docs/concepts.md, "Limit cycles").
    overrun:
        Controller ``pc``, with ``global_error`` and without ``feedback`` (opt-in): once the
        run's own estimate (``error_estimate``, its errors along the motion carried as a time
        shift, :mod:`~cosimstep.controllers.drift`) exceeds ``tol``, the ratios are multiplied
        by that estimate over the plain sum of the local estimates: what the time shift has
        made of the sum the control keeps within its share. Below ``tol`` nothing changes, so
        settling systems keep their runs. It brings the limit cycles' phase errors down (Van
        der Pol at 1e-4: 29.4 -> 4.6 x tol, in one run each) but trusts the estimate: where
        that overshoots a run already within the band (the stiff two-mass example with
        IQN-ILS, its spring's force met at 36,000 N/s), it spent 1.3-2.3 x the calls for the
        same error, which is why it is not the default (docs/concepts.md, "The run's own
        estimate past the tolerance").
    cancellation:
        With ``global_error``: the sum of the local error estimates may reach
        ``cancellation × tol`` before a step is rejected. The control aims at ``target`` of
        that, so the sum it aims at is ``target × cancellation × tol`` = 0.5 tol by default: the
        delivered error is set by the product, the rejections by ``target`` alone (see there).
        An earlier default of 3 with the step control settling at 4 % of it had been fitted
        to the pendulums.
    distribute:
        With ``global_error``: share the budget so the calls are spent where they reduce the
        global error most. For a fixed number of steps, the sum of local errors ``c·h^(k+1)``
        is smallest when every step makes the same error, so a step may spend
        ``cancellation × tol / N`` with ``N`` the steps taken plus those left at the current
        length: per unit time where the steps are short (a boundary layer is paid for by its own
        length, not by every later step), per step once the run has a history. Where an error
        memory is measured, ``N`` counts the steps within the memory instead (:meth:`_steps`).
        An earlier form (the share scaled by the running time-average of ``1/h²``) let 100
        steps of 1e-6 s in a boundary layer shrink every later step's share 1000× (delivered
        7e-4 × tol).
        Off by default for the synchronous controllers: it assumes every local error is carried
        to the end, as the plain sum does, and measured no better there (docs/concepts.md).
    """

    tol: float = 1e-4
    atol: float | None = None
    rtol: float | None = None
    hmin: float = 1e-10
    hmax: float = math.inf
    safety: float = 0.9
    grow: float = 5.0
    shrink: float = 0.2
    predictive: bool = False
    trend: bool = False
    unbiased: bool = False
    pi: bool = True
    catch_up: bool = True
    target: float = 0.1
    global_error: bool = True
    distribute: bool = False
    feedback: bool = False
    overrun: bool = False
    cancellation: float = 5.0

    def __post_init__(self) -> None:
        wrong = _wrong_types(self)
        if wrong:
            raise ValueError("; ".join(wrong))
        if not (self.tol > 0 and math.isfinite(self.tol)):
            raise ValueError(f"`tol` must be a positive finite number, got {self.tol}")
        if not 0 < self.hmin < self.hmax:
            raise ValueError(f"need 0 < `hmin` < `hmax`, got {self.hmin}, {self.hmax}")
        if not (0 < self.shrink < 1 < self.grow and 0 < self.safety <= 1
                and 0 < self.target < 1):
            raise ValueError("need 0 < shrink < 1 < grow, 0 < safety <= 1, 0 < target < 1")
        self._span = 1.0
        self.memory = math.inf  # the measured error memory [s], set by the controller
        self._previous = self.target
        # level, trend of log c per step, and k (predictive); with trend only its k and the
        # mark that the forecast has started: the trend's own forecast is in time (_timed)
        self._forecast: tuple[float, float, float] | None = None
        self._timed = (0.0, 0.0, 0.0)  # level of log c, its slope per second, step (trend)
        self._basis = math.inf  # the memory the forecasts' ratios were shared over
        self._scatter: float | None = None  # mean square miss of the forecast (TREND_WINDOW)
        self._misses = 0  # misses since the forecast started
        self._last_c: float | None = None  # log c of the last accepted step
        self._raw = (0.0, 0.0)  # level, trend of the measured log c (the significance test)
        self._means: tuple[float, float] | None = None  # of the accepted ratios: r, log r
        self._count = 0  # accepted steps
        self._elapsed = 0.0
        self._ends: list[float] = []  # elapsed time at each accepted step's end (distribute)
        self._rejected: tuple[float, float, float] | None = None  # t, h, estimate / tol
        self.floor = 0.0  # the estimates' noise floor, a share of the tolerance (:meth:`noise`)
        self.noise_steps = 0  # times a floor was recognised
        # measured growth of the errors beyond their sum, multiplying every ratio: set by the
        # run's loop from the companion (feedback) or by `pc` from its own estimate (overrun)
        self.propagation = 1.0
        self._lows = RecurringLow()  # the outputs' recurring low points (:meth:`norm_scale`)

    def start(self, t0: float, t_end: float) -> None:
        self._span = t_end - t0
        self.memory = math.inf
        self._previous = self.target  # neutral: the first accepted step is not pushed
        self._forecast, self._scatter, self._misses, self._means = None, None, 0, None
        self._basis = math.inf
        self._last_c = None
        self._count, self._elapsed, self._ends = 0, 0.0, []
        self._rejected, self.floor, self.noise_steps = None, 0.0, 0
        self.propagation = 1.0
        self._lows.reset()

    @property
    def extra_power(self) -> int:
        """How many more powers of ``h`` the ratio carries with ``distribute``."""
        return 1 if (self.global_error and self.distribute) else 0

    def scale(self, y: np.ndarray) -> np.ndarray:
        atol = self.tol if self.atol is None else self.atol
        rtol = self.tol if self.rtol is None else self.rtol
        return atol + rtol * np.abs(y)

    def norm_scale(self, y: np.ndarray) -> np.ndarray:
        """The scale an error made at outputs ``y`` is measured by while it persists:
        :meth:`scale` at ``|y|`` lowered to the low points the outputs keep returning to
        (:mod:`~cosimstep.controllers.magnitude`; recorded by :meth:`observe`)."""
        return self.scale(self._lows.level(y))

    def observe(self, t: float, y: np.ndarray) -> None:
        """Record an accepted step's outputs ``y`` at its end ``t`` (:meth:`norm_scale`)."""
        self._lows.observe(t, y, min(self._span, self.memory))

    def ratio(self, error: np.ndarray, y: np.ndarray, h: float,
              lagging: np.ndarray | None = None) -> tuple[float, int]:
        """Largest error / allowed over the variables, and the index where it occurs.

        The allowed error is scaled by :meth:`norm_scale`, not by ``y`` now: the error is met
        wherever the outputs go while it persists. Outputs marked ``lagging`` (their error a
        lag of the step, :mod:`~cosimstep.controllers.lag`) are met against the whole budget,
        not a share of it: their error does not add up."""
        r = self.ratios(error, y, h, lagging)
        i = int(np.argmax(r)) if r.size else 0
        return (float(r[i]) * self.propagation if r.size else 0.0), i

    def ratios(self, error: np.ndarray, y: np.ndarray, h: float,
               lagging: np.ndarray | None = None) -> np.ndarray:
        """Each variable's error / allowed (:meth:`ratio`, without :attr:`propagation`)."""
        allowed = self.norm_scale(y)
        whole = allowed * self.cancellation if lagging is not None else None
        if self.global_error:
            # an error is carried for the rest of the run, or for the measured error memory
            window = min(self._span, self.memory)
            if self.distribute:  # cancellation / N, bounded by the whole budget as N >= 1;
                # written in the order it was measured in, so stored runs repeat to the bit
                allowed = allowed * (self.cancellation * h / window) * window \
                    / (h * self._steps(h))
            else:
                allowed = allowed * (self.cancellation * min(h, window) / window)
            if whole is not None:
                allowed = np.where(lagging, whole, allowed)
        if self.floor > 0.0:  # the sub-models' noise is no step's error
            return np.maximum(np.abs(error) - self.floor * self.scale(y), 0.0) / allowed
        return np.abs(error) / allowed

    def _steps(self, h: float) -> float:
        """How many steps share the budget (``distribute``): those whose errors add up with
        this one's. Without a measured memory that is every step of the run — the steps taken
        plus those left at this length. Errors that fade within ``memory`` add up only with
        the steps within ``memory`` of them: the steps taken in the last ``memory`` plus those
        left to complete the first such window. Counting every step of the run there instead
        shrank each share by the run's mean step over the current one: on a plant settling
        after a failure, where the steps grow a hundredfold, to a few per cent of what the
        memory allows. (The window is in accepted time, which a multi-rate track's re-runs
        push past the run's length; so without a memory the count stays the run's.)"""
        if self.memory >= self._span:
            return self._count + max(self._span - self._elapsed, h) / h
        recent = len(self._ends) - bisect.bisect_right(self._ends, self._elapsed - self.memory)
        return recent + max(self.memory - self._elapsed, h) / h

    def next_step(self, h: float, ratio: float, k: float, accepted: bool) -> float:
        """New step from the error ratio; ``k`` is the power of ``h`` the ratio scales with."""
        r = max(ratio, 1e-10)
        if accepted and self.unbiased:
            self._track(r)
        s = self._aim()
        forecast = self._forecast_step(h, r, k, s) \
            if accepted and (self.predictive or self.trend) else None
        if forecast is not None and (self.predictive or self._drifting()):
            factor = forecast / h
        elif accepted and self.pi:
            # Written the usual way, safety · r^(-0.7/k) · r_prev^(0.4/k), the control settles
            # where safety · r^(-0.3/k) = 1, i.e. at r = safety^(k/0.3): 0.04 for safety 0.85
            # and k = 6, so every step spent 4 % of what it was allowed. Normalising both
            # errors by the target makes the fixed point r = target.
            factor = (s / r) ** (0.7 / k) * (self._previous / s) ** (0.4 / k)
            if self._catching_up(r, s):
                factor = max(factor, (s / r) ** (1.0 / k))  # see `catch_up`
        else:
            factor = self.safety * r ** (-1.0 / k)
        if accepted:
            self._previous = r
            self._count += 1
            self._elapsed += h
            if self.distribute:
                self._ends.append(self._elapsed)
        else:
            self._forecast = None  # the error model changed abruptly: forecast it anew
            factor = min(factor, 1.0)
        return min(h * min(max(factor, self.shrink), self.grow), self.hmax)

    def _catching_up(self, r: float, aim: float) -> bool:
        """Whether an accepted step's ratio ``r`` lets the step catch up with a settling
        system (:attr:`catch_up`)."""
        return self.catch_up and r < aim and self._settling() \
            and not (self.overrun or self.feedback or self.trend or self.predictive
                     or self.unbiased)

    def _forecast_step(self, h: float, r: float, k: float, aim: float) -> float:
        """The step whose forecast error ratio is ``aim`` (:attr:`predictive`, :attr:`trend`).

        Two forecasts of ``log c``: one of the coefficients as measured, per step, whose trend
        and misses decide whether a drift is shown (:meth:`_drifting`, calibrated on those) and
        which sizes the :attr:`predictive` step; and, with :attr:`trend`, one in time
        (:meth:`_timed_step`), which sizes the trend's step.
        """
        x = math.log(r) - k * math.log(h)  # log c, the error coefficient of this step
        last, self._last_c = self._last_c, x
        if self._forecast is None or self._forecast[2] != k or self._basis != self.memory:
            # a new error model (first step, order change, rejection), or a new share of the
            # budget (a memory measured): no trend yet. The ratio is the error over its share,
            # and a share that grows fivefold at once is no fall of the error to follow.
            if self._basis != self.memory:  # the ratios' means were shared otherwise too
                self._basis, self._means = self.memory, None
            self._raw, self._forecast = (x, 0.0), (x, 0.0, k)
            self._timed = (x, 0.0, h)
            self._scatter, self._misses = None, 0
        else:
            self._raw, miss = _smooth(*self._raw, x)
            self._scatter = miss * miss if self._scatter is None else \
                TREND_WINDOW * self._scatter + (1.0 - TREND_WINDOW) * miss * miss
            self._misses += 1
            if self.predictive:
                self._forecast = (*_smooth(*self._forecast[:2], x)[0], k)
            else:
                self._timed = _smooth_in_time(self._timed, x, last, h)
        if self.predictive:
            level, trend, _ = self._forecast
            return math.exp((math.log(aim) - level - trend) / k)
        return self._timed_step(h, k, aim)

    def _timed_step(self, h: float, k: float, aim: float) -> float:
        """The next step ``g`` whose forecast ratio is ``aim`` (:attr:`trend`): ``log c`` at
        its middle, ``(h + g)/2`` after this step's, from the level and slope per unit time of
        :func:`_smooth_in_time`, plus ``k log g``.

        Why in time: a settling system's error coefficient falls with its modes, like
        ``e^(−λt)``, so its fall per *step* grows with the step. Forecast per step, the trend
        lagged a fall that grew as the steps did: the multi-rate pump example settled with its
        ratios at 1–3 % of the aim (0.063 × tol at tol 1e-3). The forecast ratio
        ``k log g + slope·g/2`` rises with ``g`` only up to ``g = 2k/|slope|`` on a fall; past
        that the forecast says any longer step is cheaper, which no error model supports, so
        the step stops there. Solved by bisection in ``log g`` within the step's limits
        ``[shrink·h, grow·h]``."""
        level, slope, _ = self._timed
        if not (math.isfinite(level) and math.isfinite(slope)):
            return h  # nothing to forecast from (cannot arise from finite ratios)
        goal = math.log(aim) - level - 0.5 * slope * h

        def excess(u: float) -> float:  # forecast log ratio minus the aim's, at g = e^u
            return k * u + 0.5 * slope * math.exp(u) - goal

        lo, hi = math.log(h * self.shrink), math.log(h * self.grow)
        if slope < 0.0:
            hi = min(hi, math.log(2.0 * k / -slope))
        if hi <= lo or excess(lo) >= 0.0:
            return math.exp(lo)
        if excess(hi) <= 0.0:
            return math.exp(hi)
        for _ in range(BISECTIONS):
            middle = 0.5 * (lo + hi)
            if excess(middle) > 0.0:
                hi = middle
            else:
                lo = middle
        return math.exp(lo)

    def _settling(self) -> bool:
        """Whether the error memory probes measured the system settling: a memory below
        :data:`~cosimstep.controllers.memory.NO_DECAY` of the run (:attr:`trend`,
        :attr:`unbiased`)."""
        return self.memory < NO_DECAY * self._span

    def _drifting(self) -> bool:
        """Whether the measured coefficients' trend is significant against the scatter of
        their misses (:attr:`trend`), where the system settles; three misses at least, so
        that there is a scatter to judge by."""
        if self._forecast is None or self._scatter is None or self._misses < 3 \
                or not self._settling():
            return False
        return abs(self._raw[1]) > SIGNIFICANT * TREND_SD * math.sqrt(self._scatter)

    def _track(self, r: float) -> None:
        """Running arithmetic and geometric means of the accepted ratios (:attr:`unbiased`)."""
        if self._means is None:
            self._means = (r, math.log(r))
        else:
            mean, log_mean = self._means
            w = TREND_WINDOW
            self._means = (w * mean + (1.0 - w) * r, w * log_mean + (1.0 - w) * math.log(r))

    def _aim(self) -> float:
        """The ratio the step control aims at: the target, divided by the measured quotient of
        the arithmetic and the geometric mean of the ratios (:attr:`unbiased`; at least 1)."""
        if not self.unbiased or self._means is None or not self._settling():
            return self.target
        mean, log_mean = self._means
        return self.target / max(mean / math.exp(log_mean), 1.0)

    def restart(self) -> None:
        """An event: the error coefficient's trend and the PI memory belong to the dynamics
        before it, so the control starts again as at the run's first step."""
        self._forecast = None
        self._previous = self.target

    def noise(self, t: float, h: float, error: np.ndarray, y: np.ndarray) -> bool:
        """After a rejection: whether the estimate is a floor that no smaller step reduces;
        if so, that level becomes :attr:`floor` and the step is judged again.

        With a global target a step's share of ``tol`` shrinks with ``h``, so an estimate with
        a part that does not — a sub-model's internal solver tolerance, round-off in a stiff
        network — rejects ever shorter steps until ``hmin`` (measured: the ship plant at the
        hit, Gauss–Seidel ``pc`` at tol 1e-4, estimates of 1.5e-13 rejected down to 1e-10 s).
        Recognised by two facts together: the step was cut at least in half since the last
        rejection at this ``t`` and its estimate did not fall even in proportion (a coupling
        error falls like ``h^(q+2)``); and it is below :data:`NOISE_SHARE` of the tolerance,
        so an unannounced jump (an estimate of the jump's size) is still located. The part of
        later estimates below the floor is not counted (:meth:`ratio`): it is the sub-models'
        own noise, which no communication step changes, so steps can grow again.
        """
        size = float(np.max(np.abs(error) / self.scale(y))) if error.size else 0.0
        last, self._rejected = self._rejected, (t, h, size)
        if last is None or last[0] != t or h > 0.5 * last[1]:
            return False
        if not last[2] * h / last[1] <= size <= NOISE_SHARE:
            return False
        self.floor = max(self.floor, size)
        self.noise_steps += 1
        return True

    def accepted_step(self) -> None:
        self._rejected = None

    def check(self, t: float, h: float, h_next: float, what: str) -> None:
        """Raise :class:`StepSizeError` when a rejected step wants to go below ``hmin``."""
        if h_next < self.hmin:
            raise StepSizeError(
                f"step size {h_next:.3g} s fell below hmin = {self.hmin:.3g} s after a rejected "
                f"step of {h:.3g} s from t = {t:.9g} ({what}); loosen `tol`, lower `hmin`, or "
                "check the sub-models for a discontinuity the master does not know about")

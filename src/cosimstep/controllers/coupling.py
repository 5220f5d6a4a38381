"""Estimators of the *coupling* error — the error a co-simulation master actually makes.

A sub-model integrates its own equations as accurately as it was built to; what the master adds
is that each receiver follows an *assumed* input trajectory (extrapolated from the history)
instead of the one its source really produces. These controllers measure that:

``defect`` (thesis 5.3, fig. 87: slope-free extrapolation predictor–corrector)
    After the step, compare each source's new value with the value the receivers assumed at
    ``t + h``: the defect ``d``. Over the step the input error grows like ``(s/h)^(p+1)``, so the
    receiver's state moves by about ``κ·h·|d|/(p+2)``. The gain ``κ`` (how strongly inputs drive
    the receivers — unknown for a black box) is *measured* now and then by re-running the step
    with the corrected inputs (interpolated through the new values) and comparing; between
    calibrations the estimate costs no calls, and a step inside the band is kept as computed.
``corrector``
    That comparison on every step: predictor (extrapolated inputs), corrector (interpolated),
    error = their difference; the corrector is kept. Two calls per sub-model per step.
``doubling`` (Richardson; as PyFMI's and MasterSim's masters do)
    One step of ``h`` against two of ``h/2``; the two half steps are kept. Three calls.
``embedded``
    The step with extrapolation order ``p`` against order ``p − 1``; error of the lower order, the
    order-``p`` result kept. Two calls.

All four share :class:`~cosimstep.controllers.base.StepPolicy`: mixed tolerance, PI control,
growth limits, ``hmin`` failure, ``hmax``, and by default a *global* error target (each step may
spend a share of ``tol`` proportional to its length).
"""

from __future__ import annotations

import functools
import math
from typing import Any

import numpy as np

from cosimstep.controllers.base import Attempt, Controller, StepContext, StepPolicy
from cosimstep.controllers.drift import DriftEstimate
from cosimstep.controllers.lag import LaggingOutputs
from cosimstep.controllers.memory import ErrorMemory
from cosimstep.errors import is_number
from cosimstep.extrapolation import evaluate_at, weight_matrix


def _effective_order(ctx: StepContext) -> int:
    """Extrapolation order the master can reach with the stored history."""
    return min(ctx.order, len(ctx.times) - 1)


def _predictor_order(q: int) -> int | None:
    """The extrapolation order of the predictor of ``pc`` and ``corrector`` when the history
    supports order ``q`` (the corrector interpolates at ``q + 1``).

    At a segment's second step the history (two points) is shorter than the master's order
    (2), and the master's default would interpolate the outputs a Gauss–Seidel receiver reads
    fresh through one more point than it extrapolates the others with: the same curve as the
    corrector's, so the two runs differed only in the extrapolated inputs and the estimate was
    blind to the fresh ones (measured on ``kpr_forced``, tol 1e-5: the second step, 5x the
    first, was estimated at 0.02 of its share and left a defect of 2x tol that nothing damps).
    The same held for every input of an iterated step (strong coupling), whose predictor
    converged to the corrector's curve. At order ``q`` the two curves differ by a degree there
    too. From the third step on ``q`` is the master's order, and with extrapolation 0 or 1 it
    always is: nothing changes there. The first step (``q = 0``) keeps the master's default:
    grey-box slopes where the sub-models give them (fresh and iterated inputs stay unjudged on
    that one step); inputs held instead make the estimate the error of a zeroth-order hold,
    one power of ``h`` larger than the corrector's, which shrank the first step below ``hmin``
    at tol 1e-8.
    """
    return q if q > 0 else None


def _correct(ctx: StepContext, t: float, h: float, y: np.ndarray, q: int) -> np.ndarray:
    """Re-run ``[t, t + h]`` with inputs *interpolated* through the predictor's new values.

    The corrector's polynomial goes through every point the predictor extrapolated from plus the
    new one, so its degree is ``q + 1``: a receiver that follows input derivatives gets a coupling
    error one order smaller than the predictor's (docs/concepts.md has the measured orders).
    """
    return ctx.step(t, h, order=q + 1, end=y)


class _PolicyController(Controller):
    needs_rollback = True
    run_state = frozenset({"error_estimate", "unforeseen"})

    measures_memory = False  # whether it probes the error memory (``trend``, ``unbiased``)
    # whether its own estimate may act on the run — tighten the step control
    # (StepPolicy.overrun) or repeat a run past its tolerance (cosimstep.tighten): only `pc`'s
    # is measured within 0.2-5x the error; `corrector` and `embedded` estimate the result they
    # discard (50-100x the error of the kept one), so past tol they would only spend calls
    trusted_estimate = False

    def __init__(self, tol: float = 1e-4, h0: float | None = None, **policy: Any) -> None:
        self.policy = StepPolicy(tol=float(tol), **policy)
        if (self.policy.trend or self.policy.unbiased) and not self.measures_memory:
            # they act only where a measured memory shows the system settling: silently
            # nothing here (StepPolicy.trend)
            raise ValueError(f"controller '{self.name}' measures no error memory, and `trend` "
                             "and `unbiased` act only where one shows the system settling; "
                             "use controller 'pc'")
        if h0 is not None and not (is_number(h0) and 0 < h0 < math.inf):
            raise ValueError(f"`h0` (the initial step) must be a positive finite number, got "
                             f"{h0!r}")
        self.h0 = h0
        self.error_estimate: float | None = None  # the run's global error estimate (scaled)
        # step doubling: second halves run again because the partners did what their
        # history did not foretell (Doubling)
        self.unforeseen = 0
        self._drift = DriftEstimate()
        self._lagging = LaggingOutputs()  # outputs whose error is a lag of the step
        # the error memory probe (controllers/memory.py): off unless a controller measures it
        self.probe = ErrorMemory(every=0)

    def initial_step(self, t0: float, t_end: float) -> float:
        self.policy.start(t0, t_end)
        self._drift.reset()
        self._lagging.reset()
        self.probe.reset(t0, t_end)
        self.error_estimate = 0.0
        self.unforeseen = 0
        self._budget = self.policy.tol  # the run's, which `adaptive-tol` varies per step
        h0 = self.h0 if self.h0 is not None else 1e-4 * (t_end - t0)
        self._restart = min(max(h0, self.policy.hmin), self.policy.hmax)
        return self._restart

    def event(self, t: float) -> float | None:
        """Start again from the run's first step, with the error memory unmeasured: what the
        control and the probes learnt holds for the dynamics before the event, not after it.
        Right after an event the estimate is at its weakest (extrapolation restarts at order
        0) and cannot see a transient inside a long step. The PI control once kept its step
        across events: on the pump-failure example with other failure times (seeds 1 … 19,
        tol 1e-4 … 1e-6) 12 of 48 runs ended at 13–2,600 × tol with status ok, the first steps
        after the failure sized by the plant at rest (and by its error memory, measured at
        rest). Starting again, none exceeded 0.41 × tol; the price was a slow climb back, the
        settling after an event more accurate than asked (0.013–0.07 × tol at 1e-4 and 1e-5;
        docs/concepts.md, "An event starts the step control again"), which the step now
        makes up where the probes see the settling (:attr:`StepPolicy.catch_up`; on seeds 1,
        4 and 5 0.30 / 1.42 / 0.76 × tol)."""
        self.probe.forget()
        self._lagging.event()
        self._drift.jump()
        self.policy.memory = self.probe.memory
        self.policy.restart()
        return self._restart

    def _account(self, error: np.ndarray, values: np.ndarray, t: float, h: float,
                 jumping: np.ndarray | None) -> None:
        """Add an accepted step's local error estimate to the run's global error estimate.

        The running sum of the local estimates, per output, in the norm ``tol`` bounds
        (``|e| / (atol/tol + rtol/tol·|y|)``, i.e. ``|e| / (1 + |y|)`` with the default
        ``atol = rtol = tol``): what the error would be if every step's error were carried to
        the end unchanged — or, where the error memory ``τ`` was measured
        (:mod:`~cosimstep.controllers.memory`), fading by ``exp(−h/τ)`` per step; except that
        the part of each error along the motion is carried as a time shift, met later at the
        motion's speed then (:mod:`~cosimstep.controllers.drift`). Errors that decay faster or
        partly cancel make it an overestimate; docs/benchmarks.md has the measured ratios.
        ``t``: the step's start; ``jumping``: the discrete outputs. Once the estimate exceeds
        the run's ``tol``, ``pc`` may tighten the step control by it (:attr:`StepPolicy.overrun`).
        """
        self._drift.add(error, values, t, h, self.policy.scale(values), self.policy.tol,
                        math.exp(-h / self.policy.memory), jumping, self._lagging.mask)
        self.error_estimate = self._drift.value
        policy = self.policy
        if self.trusted_estimate and policy.overrun and policy.global_error \
                and not policy.feedback and self._drift.value > self._budget:
            # the run's own estimate says the tolerance is spent (StepPolicy.overrun)
            policy.propagation = max(1.0, self._drift.value / self._drift.summed)

    def took_estimates(self, value: float, summed: float) -> None:
        """A run of the multi-rate master, which steps with this controller's policy but
        estimates on its own (:meth:`cosimstep.multirate.Multirate.error_estimate`), reports
        its estimate and plain sum here, so that the repeat (:mod:`cosimstep.tighten`) reads
        them as it reads a synchronous run's."""
        self.error_estimate = value
        self._drift.value, self._drift.summed = value, summed

    @property
    def summed_estimate(self) -> float:
        """The plain sum of the local estimates (no time shift), scaled like ``tol``: what
        ``feedback`` compares the companion's estimate with."""
        return self._drift.summed

    def _decide(self, ctx: StepContext, token: Any, t: float, h: float, y: np.ndarray,
                error: np.ndarray, values: np.ndarray, k: float, names: list[str],
                lag_error: np.ndarray | None = None) -> Attempt:
        """Accept or reject (restoring the models to ``t``) and propose the next step.

        ``k``: the power of ``h`` the ratio of an error that adds up scales with; the ratio of
        an output taken as lagging (:mod:`~cosimstep.controllers.lag`), met against the whole
        budget, scales with ``h`` itself. ``lag_error``: the error of each output were it a lag
        (step doubling: the whole difference, Richardson's estimate for order 1), given where
        the estimate can see a lag of the step (a predictor and a corrector that start from
        the same inputs cannot), so lagging outputs are looked for."""
        policy, finder = self.policy, self._lagging
        lagging, estimated = finder.marked, error

        def judged(marked: np.ndarray | None) -> tuple[np.ndarray, float, int]:
            kept = estimated if marked is None or lag_error is None else \
                np.where(marked, lag_error, estimated)
            return (kept, *policy.ratio(kept, values, h, marked))

        error, ratio, i = judged(lagging)
        if lag_error is not None and policy.global_error:  # without a share a lag is met
            scaled = np.abs(error) / policy.scale(values)  # like any error; a noise floor
            if policy.floor > 0.0:                          # is no step's error (noise)
                scaled = np.maximum(scaled - policy.floor, 0.0)
            rerun = finder.judge(t, h, scaled, policy.ratios(error, values, h, lagging), ratio,
                                 policy.target, policy.hmin)
            if rerun is not None:  # the same state stepped shorter: is it a lag?
                ctx.restore(token)
                return Attempt(y, False, rerun, ratio)
            if finder.marked is not lagging:
                lagging = finder.marked
                error, ratio, i = judged(lagging)
        if ratio > 1.0 and policy.noise(t, h, error, values):
            ratio, i = policy.ratio(error, values, h, lagging)  # above the floor just found
        accepted = ratio <= 1.0
        if accepted:
            policy.accepted_step()
            policy.observe(t + h, values)
            self._account(error, values, t, h,
                          ctx.discrete if ctx.discrete.any() else None)
        if lagging is not None and lagging[i]:
            k = 1.0
        else:
            k = (k if policy.global_error else k + 1) + policy.extra_power
        h_next = policy.next_step(h, ratio, k, accepted)
        if not accepted:
            ctx.restore(token)
            what = f"{names[i]}: error {abs(error[i]):.3g} is {ratio:.3g}× the allowed" \
                if names else f"error ratio {ratio:.3g}"
            self.policy.check(t, h, h_next, what)
        return Attempt(y, accepted, h_next, ratio)


class Defect(_PolicyController):
    """Fig. 87's band check on the input defect, with a measured input-to-output gain."""

    name = "defect"

    def __init__(self, tol: float = 1e-4, calibrate_every: int = 40, h0: float | None = None,
                 **policy: Any) -> None:
        super().__init__(tol, h0, **policy)
        if calibrate_every < 0:
            raise ValueError("`calibrate_every` must be >= 0 (0: calibrate once)")
        self.calibrate_every = int(calibrate_every)
        self._gain: float | None = None
        self._since = 0

    def initial_step(self, t0: float, t_end: float) -> float:
        self._gain, self._since = None, 0
        return super().initial_step(t0, t_end)

    def event(self, t: float) -> float | None:
        self._since = max(self._since, self.calibrate_every)  # dynamics changed: re-measure
        return super().event(t)

    def attempt(self, ctx: StepContext, t: float, h: float) -> Attempt:
        q = _effective_order(ctx)
        token = ctx.save()
        y = ctx.step(t, h)
        d, mask = ctx.defect()
        cols = np.flatnonzero(mask)
        source_error = h * np.abs(d[cols]) / (q + 2)
        calibrate = self._gain is None or (self.calibrate_every > 0
                                           and self._since >= self.calibrate_every)
        if calibrate and cols.size:
            ctx.restore(token)
            y_corrected = _correct(ctx, t, h, y, q)
            local = np.abs(y_corrected - y)  # the predictor's local coupling error
            scale = self.policy.scale(y)
            seen = float(np.max(source_error / scale[cols]))
            if seen > 1e-13:
                gain = float(np.max(local / scale)) / seen
                self._gain = gain if self._gain is None else max(gain, math.sqrt(gain * self._gain))
            self._since = 0
            attempt = self._decide(ctx, token, t, h, y_corrected, local, y_corrected, q + 1,
                                   ctx.names)
        else:
            # the estimate lives on the predicted outputs; the others get none (0), so the
            # decision is the same and the run's global estimate sums one vector throughout
            error = np.zeros_like(y)
            error[cols] = (self._gain or 1.0) * source_error
            attempt = self._decide(ctx, token, t, h, y, error, y, q + 1, ctx.names)
        if attempt.accepted:
            self._since += 1
        return attempt


class Corrector(_PolicyController):
    """Predictor (extrapolated inputs) and corrector (interpolated) on every step."""

    name = "corrector"

    def attempt(self, ctx: StepContext, t: float, h: float) -> Attempt:
        q = _effective_order(ctx)
        token = ctx.save()
        y = ctx.step(t, h, order=_predictor_order(q))
        ctx.restore(token)
        y_corrected = _correct(ctx, t, h, y, q)
        return self._decide(ctx, token, t, h, y_corrected, y_corrected - y, y_corrected, q + 1,
                            ctx.names)


class PredictorCorrector(_PolicyController):
    """Predictor, corrector, and a call-free estimate of the *corrector's* own error.

    The corrector (kept) is far more accurate than the predictor, so ``|corrector − predictor|``
    grossly overestimates the error of what is kept (the ``corrector`` controller delivers
    0.3–1 % of ``tol``). Here the two runs are used as an experiment instead: the same step under
    two *known* input trajectories, the extrapolated ``u_p`` and the interpolated ``u_c``, moved
    the receivers by ``|y_c − y_p|``. The kept result's input error is estimated as
    ``u_best − u_c``, with ``u_best`` the interpolant one degree higher through the *corrected*
    new values. The receivers respond about linearly to input errors over one step, so the
    corrector's error is ``(y_c − y_p) · ‖u_best − u_c‖ / ‖u_p − u_c‖``, negated where the
    input error left points against the change tried (:meth:`_input_ratio`) — measured
    sensitivity, no extra calls, no slopes.

    This needs receivers that follow the input curves (input derivatives, like the ODE adapter
    and FMUs with ``canInterpolateInputs``). When some receiver holds its inputs over a step, the
    controller runs step doubling instead (:class:`Doubling`).
    """

    name = "pc"
    trusted_estimate = True

    def __init__(self, tol: float = 1e-4, h0: float | None = None, probe_every: int = 20,
                 **policy: Any) -> None:
        # 0.85 rather than 0.9: on the benchmark problems it halved the rejections and, as the
        # estimate is least reliable at the largest steps, gave a steadier error / tol
        # (docs/benchmarks.md).
        policy.setdefault("safety", 0.85)
        self.measures_memory = probe_every != 0
        super().__init__(tol, h0, **policy)
        self.probe = ErrorMemory(every=probe_every)
        self._plan: tuple[StepContext, _RatioPlan] | None = None

    def attempt(self, ctx: StepContext, t: float, h: float) -> Attempt:
        if self._plan_for(ctx).holding:
            # A receiver that holds its inputs (a plain FMU without input derivatives) does not
            # follow the curves this estimate compares: measured on the toggled pendulum, the
            # estimate then let the error reach 28-190x tol. Step doubling measures the step
            # whatever the receivers do (0.15-0.24x tol there), at about three calls per step.
            return Doubling.attempt(self, ctx, t, h)  # type: ignore[arg-type]
        q = _effective_order(ctx)
        token = ctx.save()
        y_p = ctx.step(t, h, order=_predictor_order(q))
        probe = self.probe
        token_p = ctx.save() if probe.due(t + h, h) else None  # a probe may start from here
        self.policy.memory = probe.memory  # less, if measurements at shorter steps expired
        ctx.restore(token)
        y_c = _correct(ctx, t, h, y_p, q)
        rho = self._input_ratio(ctx, t, h, q, y_p, y_c)
        attempt = self._decide(ctx, token, t, h, y_c, rho * (y_c - y_p), y_c, q + 2, ctx.names)
        if attempt.accepted:
            probe.accepted()
            if token_p is not None:
                probe.probe(t + h, attempt.h_next, (ctx.save(), y_c), (token_p, y_p),
                            self.policy.scale(y_c),
                            lambda s, step, points: ctx.step(s, step, extra=points),
                            ctx.restore)
                self.policy.memory = probe.memory
        return attempt

    def __getstate__(self) -> dict[str, Any]:
        # a checkpoint keeps the controller, not the context the plan was made for (the master
        # and its sub-models, saved apart); the plan is made again on the first attempt
        return {**self.__dict__, "_plan": None}

    def _plan_for(self, ctx: StepContext) -> _RatioPlan:
        """What :meth:`_input_ratio` reads from ``ctx`` that stays fixed over a run (the
        columns, which are read fresh, who reads what), worked out once per context."""
        if self._plan is None or self._plan[0] is not ctx:
            self._plan = (ctx, _RatioPlan(ctx))
        return self._plan[1]

    def _input_ratio(self, ctx: StepContext, t: float, h: float, q: int, y_p: np.ndarray,
                     y_c: np.ndarray) -> np.ndarray:
        """Per output: ‖u_best − u_c‖ / ‖u_p − u_c‖ over the inputs of the sub-model that owns it
        (scaled, mean over the step), with the sign of ``⟨u_c − u_best, u_c − u_p⟩``.

        The curves are those the master used: a predicted output is extrapolated (degree ``q``)
        by the predictor and interpolated through the predictor's new value (``q + 1``) by the
        corrector; an output a receiver reads fresh (Gauss–Seidel) is interpolated through the
        new value of the same pass — and so is every output of an iterated step (strong
        coupling), whose passes go on until the end values they interpolate through are the
        step's own. Judging an iterated corrector by the predictor's end values counted the
        difference of the two runs' end values as input error left in the corrector, which the
        iteration had removed (problem 7 with IQN-ILS: 0.099–0.15 × tol).

        Why per receiver: the experiment measured how far each sub-model's outputs moved under
        the input change *it* saw, so only its own inputs' ratio scales that response. One ratio
        for the whole system (largest left over largest moved, over every input) lets the
        inputs that moved most — typically a fast partner's — set the ratio for a receiver that
        reads only slow inputs: on the double pendulum with a short light lower bar, the lower
        bar's error was then estimated 460× too low and ``pc`` delivered 15–29× tol
        (docs/concepts.md, "One input ratio per receiver").

        Why a sign: the kept result's error is the response to ``u_c − u_best``, the experiment
        measured the response to ``u_c − u_p``, and the two input errors need not point the
        same way (an extrapolation overshoots where an interpolation undershoots). The ratio
        is negative where their inner product over the step is (scaled, summed over the
        receiver's inputs and the nodes; with several inputs the sign is that of the change
        as a whole, while the size is the largest input's). The step control reads only the
        size; the sign is what the run's estimate adds up as a time shift (and with
        ``overrun``, where that estimate feeds back, it moves the steps too). With every ratio
        positive a limit cycle's shifts cancelled where the solution's added up (the
        two-variable Oregonator at tol 1e-4: estimated at 0.048 × its error, 0.25 × signed;
        docs/concepts.md, "The sign of the corrector's input error").
        """
        plan = self._plan_for(ctx)
        if plan.cols.size == 0:
            return np.zeros(plan.outputs)
        if len(ctx.times) < q + 2:
            return np.ones(plan.outputs)  # no older point to judge the corrector by: count the
            # predictor's error
        cols, n = plan.cols, q + 2
        hist = ctx.history[-n:, cols]
        # the five curves over the step (rows: the last n stored points, then the predictor's
        # and the corrector's new values); each is the polynomial through its points, in the
        # Taylor form the master steps with: the same operations as taylor_coefficients and
        # evaluate, so the estimate is bit for bit the one each curve built on its own gave
        values = np.empty((n + 2, cols.size))
        values[:n] = hist
        values[n] = y_p[cols]
        values[n + 1] = y_c[cols]
        s = [float(ti) - t for ti in ctx.times[-n:]]
        s.append(float(t + h) - t)  # rows n and n + 1, the predictor's and the corrector's
        s.append(s[-1])  # new values, both stand at t + h
        coefficients = np.zeros((5, n + 1, cols.size))
        for i, rows in enumerate(_curve_rows(n)):
            coefficients[i, :rows.size] = weight_matrix(tuple([s[r] for r in rows])).dot(
                values[rows])
        u = evaluate_at(coefficients, h * _NODES)
        fresh = plan.fresh
        u_p = np.where(fresh, u[0], u[1])
        u_c = np.where(fresh, u[2], u[3])
        scale = self.policy.scale(hist[-1])
        # np.mean's sum over the four nodes and division by their count, without its wrapper
        moved = np.zeros(plan.outputs)
        left = np.zeros(plan.outputs)
        agreement = np.zeros(plan.outputs)
        moved[cols] = np.add.reduce(np.abs(u_p - u_c), axis=0) / len(_NODES) / scale
        left[cols] = np.add.reduce(np.abs(u[4] - u_c), axis=0) / len(_NODES) / scale
        agreement[cols] = np.add.reduce((u_c - u[4]) * (u_c - u_p), axis=0) / (scale * scale)
        ratio = np.ones(plan.outputs)
        for src, own in plan.readers:
            if src is None:
                ratio[own] = 0.0  # reads nothing: no coupling error of its own
                continue
            m = float(moved[src].max())
            if m > 0:
                ratio[own] = float(left[src].max()) / m
                if float(agreement[src].sum()) < 0.0:  # the error left opposes the change
                    ratio[own] = -ratio[own]
        return ratio


class _RatioPlan:
    """The fixed part of ``pc``'s input ratio for one step context (see
    :meth:`PredictorCorrector._plan_for`)."""

    def __init__(self, ctx: StepContext) -> None:
        self.outputs = len(ctx.names)
        # a discrete output is held by every receiver in both runs: it moves no one
        self.cols = np.flatnonzero(ctx.consumed & ~ctx.discrete)
        self.fresh = ~ctx.predicted[self.cols] | ctx.iterated
        self.holding = bool(np.any(ctx.held & ctx.consumed))
        self.readers = [(src if src.size else None, own) for src, own in ctx.readers]


@functools.lru_cache(maxsize=8)
def _curve_rows(n: int) -> tuple[np.ndarray, ...]:
    """Rows of the stacked values (the last ``n`` stored points, the predictor's and the
    corrector's new values) that each of ``pc``'s five curves goes through."""
    return tuple(np.array(rows, dtype=np.intp) for rows in (
        [*range(2, n), n],            # u_p, read fresh
        list(range(1, n)),            # u_p, extrapolated
        [*range(1, n), n + 1],        # u_c, read fresh
        [*range(1, n), n],            # u_c, through the predictor's
        [*range(n), n + 1]))          # u_best


_NODES = np.array([0.25, 0.5, 0.75, 1.0])  # where input curves are compared over a step


class Doubling(_PolicyController):
    """Step doubling: one step of ``h`` against two of ``h/2`` (Richardson), checked against
    the partners' trajectories the receivers did not see.

    Richardson's estimate holds where both runs are in their asymptotic regime. Under
    Gauss–Seidel the first sub-model to step extrapolates its partners in both runs; where a
    partner then does something its history did not foretell (an unannounced jump inside the
    second half of the step, a transient starting there) both runs extrapolate the same
    nothing, agree, and the step would be kept whatever it missed. The inputs' own misses show
    it at no cost: the second half's miss at ``t + h`` (the partner's new value against what
    the receivers assumed) should be as much smaller than the whole step's as its nearer
    points make an extrapolation's error (:func:`_unforeseen`). Where it is not, the second
    half is run again with its inputs interpolated through the values the partners reached
    (one more call per sub-model), and its response bounds the error: the correction changed
    the input by ``|d|/(q+2)`` on average (a miss ``d`` growing like ``(s/h)^(q+1)``) where
    the true input may have been off by ``|d|`` throughout (a jump at the half's start), so
    the bound is ``(q + 2) · |y_c − y|``. The corrected run is kept. docs/concepts.md, "Step
    doubling and what the first mover did not see", has the measurements.
    """

    name = "doubling"

    def attempt(self, ctx: StepContext, t: float, h: float) -> Attempt:
        q = _effective_order(ctx)
        token = ctx.save()
        y_full = ctx.step(t, h)
        missed_full, mask = ctx.defect()
        ctx.restore(token)
        y_half = ctx.step(t, 0.5 * h)
        half = ctx.save()
        extra = ((t + 0.5 * h, y_half),)
        y = ctx.step(t + 0.5 * h, 0.5 * h, extra=extra)
        error = (y_full - y) / (2.0 ** (q + 1) - 1.0)
        missed, _ = ctx.defect()
        # an iterated step (strong coupling) ends on its own end values: what is left of its
        # inputs' miss is the iteration's tolerance, nothing a history failed to foretell
        if not ctx.iterated and _unforeseen(missed, missed_full, mask,
                                            _shrink(ctx.times, t, h, q),
                                            self.policy.scale(y), y):
            ctx.restore(half)
            y_c = ctx.step(t + 0.5 * h, 0.5 * h, order=q + 1, end=y, extra=extra)
            self.unforeseen += 1
            bound = (q + 2) * (y_c - y)
            error = np.where(np.abs(bound) > np.abs(error), bound, error)
            y = y_c
        # a lag of h against one of h/2: the whole difference is the half's lag (a lag's
        # second half misses its partners as if they jumped, so the check above fires on it
        # too; a jump read as a lag is caught by the re-run of the next step, lag.py). Not on
        # an iterated step (strong coupling): what its iteration leaves, within its tolerance,
        # does not fall with the step as a coupling error does, and read as a lag it marked the
        # stiff two-mass example's velocities (IQN-ILS, tol 1e-6: 796 x tol, status ok)
        return self._decide(ctx, token, t, h, y, error, y, q + 1, ctx.names,
                            lag_error=None if ctx.iterated else y_full - y)


def _shrink(times: list[float], t: float, h: float, q: int) -> float:
    """How much smaller than the whole step's the second half's extrapolation miss at
    ``t + h`` should be for a smooth partner: an extrapolation of degree ``q`` misses by its
    next derivative times the product of the distances from ``t + h`` to its ``q + 1`` points,
    so the ratio of the two products (the half's points: the history's and ``t + h/2``).
    Equal steps at ``q = 2`` give 1/6; after a step grew fivefold, 0.36."""
    whole = [t + h - s for s in times[-(q + 1):]]
    nearer = [t + h - s for s in [*times, t + 0.5 * h][-(q + 1):]]
    return math.prod(nearer) / math.prod(whole)


def _unforeseen(missed: np.ndarray, missed_full: np.ndarray, mask: np.ndarray, shrink: float,
                scale: np.ndarray, y: np.ndarray) -> bool:
    """Whether the second half step's inputs missed the partners' new values by more than a
    smooth partner allows: the largest scaled miss (over the extrapolated outputs whose miss
    is above round-off) beyond ``√shrink`` × the whole step's — the geometric middle between
    the miss that shrank as an extrapolation's does (:func:`_shrink`) and one that did not
    shrink at all (a change no history foretold). Read over all outputs at once: one output's
    ratio alone is arbitrary where its miss passes through zero."""
    cols = np.flatnonzero(mask)
    if not cols.size:
        return False
    now = np.abs(missed[cols])
    real = now > 1e3 * np.finfo(float).eps * np.maximum(np.abs(y[cols]), 1e-300)
    if not real.any():
        return False
    unit = scale[cols]
    largest = float(np.max(now[real] / unit[real]))
    return largest > math.sqrt(shrink) * float(np.max(np.abs(missed_full[cols]) / unit))


class Embedded(_PolicyController):
    """The step with extrapolation order ``p`` against order ``p − 1``."""

    name = "embedded"

    def attempt(self, ctx: StepContext, t: float, h: float) -> Attempt:
        q = _effective_order(ctx)
        if ctx.order < 1:
            raise ValueError("controller 'embedded' compares extrapolation orders p and p - 1; "
                             "it needs extrapolation >= 1")
        token = ctx.save()
        y_low = ctx.step(t, h, order=max(q - 1, 0))
        ctx.restore(token)
        y = ctx.step(t, h)
        return self._decide(ctx, token, t, h, y, y - y_low, y, max(q, 1), ctx.names)

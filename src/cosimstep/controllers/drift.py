"""The run's own global error estimate from its accepted local estimates, with errors along
the motion carried as a time shift.

A sum of local errors assumes each is carried to the end unchanged (or, where the error memory
``M`` was measured, fading by ``exp(−h/M)`` per step). That misses the one propagation that
is known without a Jacobian: if ``y(t)`` solves an autonomous system, so does ``y(t + τ)``, so
a perturbation along the motion, ``τ·ẏ``, is (to first order) the same trajectory shifted in
time. It stays a time shift ``τ`` and meets the outputs later as ``τ·ẏ(s)``: as large as the
motion is fast then. On a relaxation oscillation (Van der Pol, the Brusselator) the errors
made along a slow branch come back multiplied by the speed of the next jump, which the sum,
read at the speeds where they were made, put 5–20 times too low.

So each accepted step's local error ``e`` is split, in the norm ``tol`` bounds, into its part
along the step's motion (the outputs' change over the step divided by its length, ``v``) and
the rest. The part along is the time shift ``τ = ⟨e, v⟩ / ⟨v, v⟩`` (scaled inner products);
the rest of an output is what is left of its own error, never more than that error.
Time shifts are scalars and add with their signs: a step that lags and one that leads cancel,
as they do in the solution. The rest is summed as before, without signs (its propagation is
unknown: oscillations rotate it between outputs of different scales). Both fade alike where a
memory was measured: a forced system (the KPR problems) has no time-shift symmetry, and there
its errors along the motion decay like any others. The estimate at a step is the rest's sum
plus ``|Σ τ|·|v|`` now, per output, in the norm; the run's estimate is its largest value.

The direction of the motion is read from the step only where the step moved the outputs by
more than its error (``|v|·h > |e|``; at rest or nearly so there is no motion to shift along)
and where the shift is first order (``|τ|·|a| < |v|``, the acceleration ``a`` from the last two
steps; at a turning point the speed vanishes and ``e / v`` is no shift); elsewhere the whole
error is the rest. Outputs that jump (discrete ones) are left out of ``v``: their
change over a step is not a speed. An event breaks the symmetry (a failure at a set time does
not move with the trajectory): there the shift becomes an ordinary error, its size at the
speeds then (:meth:`DriftEstimate.jump`). docs/concepts.md ("Errors along the motion: a time shift")
has the measurements.
"""

from __future__ import annotations

import math

import numpy as np


class DriftEstimate:
    """The running estimate (see the module): feed every accepted step to :meth:`add`."""

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        """Back to a run's start: nothing spent."""
        self.value = 0.0  # the largest estimate so far, scaled like ``tol``
        self.summed = 0.0  # the same for the plain sum of the local estimates (no shift)
        self._across: np.ndarray | None = None  # the rest, summed (absolute units)
        self._plain: np.ndarray | None = None  # every error, summed without a split
        self._shift = 0.0  # Σ τ, in seconds (signed)
        self._last: np.ndarray | None = None  # the outputs at the last accepted step's end
        self._velocity: np.ndarray | None = None  # the last accepted step's motion (v)
        self._h = 0.0  # the last accepted step's length
        self._end = math.nan  # and its end

    def jump(self) -> None:
        """An event: the outputs may jump here, so the next step's change is no motion; and
        the time shift so far becomes an error like the others, the size it has at the
        speeds now. An event on the clock (a failure at 148 s, a switched input) does not move
        with the trajectory, so what lags behind it is not carried as a lag past it: carried
        on as a shift, the pump example's shift from its slow drift before the failure was
        met at the transient after it, 150 times the error."""
        if self._velocity is not None and self._across is not None:
            self._across = self._across + abs(self._shift) * np.abs(self._velocity)
        self._shift, self._last, self._velocity = 0.0, None, None

    def add(self, error: np.ndarray, values: np.ndarray, t: float, h: float,
            scale: np.ndarray, tol: float, fade: float,
            jumping: np.ndarray | None = None, lagging: np.ndarray | None = None) -> None:
        """One accepted step from ``t`` to ``t + h``: its local ``error`` estimate and the
        outputs ``values`` at its end (absolute units), ``scale`` the norm's (``atol +
        rtol·|y|``), ``fade`` what the error memory lets the past keep (``exp(−h/M)``),
        ``jumping`` a mask of discrete outputs (``None``: there are none). The motion is read
        only from a step that starts where the last one ended: a step accepted and then
        undone (one that crossed a state event, redone up to the crossing) leaves the last
        end point behind, and the change from there is no motion. ``lagging``: outputs whose
        error is a lag of the step (:mod:`~cosimstep.controllers.lag`): not summed and no time
        shift, but a level the estimate holds while the step lasts."""
        level = None
        if lagging is not None:
            level = np.where(lagging, np.abs(error), 0.0)
            error = np.where(lagging, 0.0, error)
        magnitude = np.abs(error)
        if self._plain is None:
            self._plain = magnitude
        else:  # (a fade of 1, no memory measured, keeps everything: no product to form)
            self._plain = (self._plain if fade == 1.0 else fade * self._plain) + magnitude
        norm = scale / tol
        plain = self._plain if level is None else self._plain + level
        self.summed = max(self.summed, float((plain / norm).max()))
        velocity = None
        if not abs(t - self._end) <= 1e-9 * h:  # not where the last step ended
            self._last = self._velocity = None
        if self._last is not None and h > 0.0:
            velocity = (values - self._last) / h
            if jumping is not None:
                velocity[jumping] = 0.0
        tau = self._time_shift(error, velocity, h, scale)
        self._last = values.copy()
        self._velocity, self._h, self._end = velocity, h, t + h
        # the split moves error between the shift and the rest, it never creates any: an
        # output's rest is at most its own error (a fast output whose motion sets the shift's
        # direction would otherwise carry others' errors twice, +τ·v in the shift and −τ·v in
        # the rest: the stiff two-mass example's force, 3.2 times its error, 1.05 bounded)
        across = magnitude if tau == 0.0 else \
            np.minimum(np.abs(error - tau * velocity), magnitude)
        if self._across is None:
            self._across = across
        else:
            self._across = (self._across if fade == 1.0 else fade * self._across) + across
        self._shift = fade * self._shift + tau
        now = self._across if velocity is None else \
            self._across + abs(self._shift) * np.abs(velocity)
        if level is not None:
            now = now + level
        self.value = max(self.value, float((now / norm).max()))

    def _time_shift(self, error: np.ndarray, velocity: np.ndarray | None, h: float,
                    scale: np.ndarray) -> float:
        """The part of ``error`` along ``velocity`` as a time shift, or 0 where it cannot be
        read: no motion known, a motion smaller over the step than its error, or one that
        changes too fast for a first-order shift. ``y(t + τ) ≈ y(t) + τ·v`` holds while
        ``|τ·a| < |v|`` (``a``: the change of the motion between the last two steps); near a
        turning point of an oscillation the speed passes through zero while the acceleration
        does not, and ``e / v`` read there is no shift at all (the announced quarter car at
        tol 1e-2 settling: the estimate 17 times the error, read so; 7 times without it)."""
        if velocity is None or self._velocity is None:
            return 0.0
        e, v = error / scale, velocity / scale
        vv = float(v.dot(v))
        if not (vv > 0.0 and vv * h * h > float(e.dot(e))):
            return 0.0
        tau = float(e.dot(v)) / vv
        change = (velocity - self._velocity) / scale  # a = change / (the steps' mean length)
        mean = 0.5 * (h + self._h)
        return tau if tau * tau * float(change.dot(change)) < vv * mean * mean else 0.0

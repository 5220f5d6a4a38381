"""Outputs whose error is a lag of the step, not a contribution to a sum: recognised from a
descent of the step that the error control cannot end.

A global error target shares ``tol`` over the run in proportion to each step's length, which
assumes every step adds its local error to the global one: a coupling error made over a step
falls like ``h^(k+1)`` (``k ≥ 1``), so the share, falling like ``h``, is always reached by a
short enough step. One kind of output breaks that assumption. A sub-model that computes an
output in ``do_step`` from the inputs it was given at the step's start, without declaring
direct feedthrough (a sampled controller, a gain, many FMUs), answers at ``t + h`` with what
its inputs were at ``t``: its output lags its input by the step. Step doubling sees that lag
(one step of ``h`` against two of ``h/2`` differs by half of it), and it falls only like ``h``.
Against a share that falls like ``h`` its ratio stays where it is however short the step, and
the control shrinks the step by the same factor on every accepted step down to ``hmin``: the
run ends failed where a fixed step of 0.01 s delivers the tolerance (an oscillator fed back
through such a gain, tol 1e-3: the step fell from 7e-3 to 3e-15 s in 60 accepted steps, the
gain's output error at a constant 0.24 of its share throughout).

Such an error does not add up: the next step's output is computed afresh from the next input,
and the lag the step leaves is what the output is wrong by *now*, as long as the step lasts.
So it is met against the tolerance itself, not against a share of it (as the multi-rate master
meets a held input's lag, :meth:`cosimstep.multirate.Multirate.hold_lag`), and it enters the
run's estimate as a level, not as a term of the sum. What it does to the sub-models that read
the lagging output is their own error, which falls faster and is summed as before.

Recognised by the order of the error in the step, measured where the same state is stepped
with two different steps (the order then read exactly: nothing else changed between them):

- rejected attempts from one time, each shorter than the last, down by :data:`DESCENT`. But a
  jump a partner makes just after the step's start, which the master was not told of, leaves
  its receiver an error in proportion to the step too, once. So one such reading only lets the
  attempt be judged as a lag; the output is taken as lagging for the rest of the run when a
  second reading, from a later time, says so again (a lag recurs on every step, a jump does
  not). A PI controller's proportional part computed from the held error: the first step of
  a plant and such a controller, tol 1e-3, had crawled on at steps of 6e-9 s (600,000 calls
  in 20 s for 0.001 s of a 5 s run; the estimate read as a noise floor,
  :meth:`~cosimstep.controllers.base.StepPolicy.noise`).
- now and then (after :data:`EVERY` accepted steps, then after twice as many as before each
  time the re-run found no lag: a lag belongs to a sub-model and shows early) an accepted step
  whose ratio is near the aim is re-run from the same state at a quarter of its length
  (:data:`PROBE`). A lag whose
  ratio happens to sit just below the aim moves the step neither way: the ratio does not
  answer the step, so the control creeps (a stiff fast partition, slaved to its held input,
  lags it like a gain: the suite's boundary layer with held inputs at tol 1e-3 crept at steps
  of 7e-5 to 1.2e-4 s with its ratio at 0.09–0.099, 288,000 calls for 0.005 × tol). The re-run
  is accepted in the step's place.
- a *descent* of accepted steps — consecutive accepted steps, each shorter than the one before,
  each with its ratio above the aim — that shrank the step by :data:`DESCENT` while an
  output's error fell no faster than ``h^ORDER`` raises the suspicion, no more: a coefficient
  that rises while the step falls reads the same (the split double pendulum with held inputs,
  from rest: its ratios held at 1.03–1.2 × the aim through a tenfold descent, error against
  step of order 1 over it, while at one time its error falls like ``h²``). The step is then
  re-run from the same state at a quarter of its length (:data:`PROBE`), and only that
  comparison decides; the descent, spread over time, already shows a lag that recurs.

A coupling error of the lowest order the controllers estimate falls like ``h²`` or faster,
twice as fast in the logarithm as a lag's, so :data:`ORDER` is the geometric middle.
"""

from __future__ import annotations

import math

import numpy as np

DESCENT = 10.0
"""How many times shorter the step must have become over a descent before the order of its
errors is read (a decade: the two candidate orders, 1 and 2 or more, then differ by a factor
of 10 in the error)."""

EVERY = 50
"""Accepted steps before the first re-run that reads the order; the gap doubles after each that
finds no lag (every 50 steps throughout cost the held-input double pendulum 9.5 % more calls:
each re-run also restarts the step from a quarter of its length)."""

PROBE = 4.0
"""A suspected lag is checked by re-running the step from the same state this many times
shorter (the orders 1 and 2 then differ by a factor of 4 in the error)."""

ORDER = 1.5
"""An output whose error fell no faster than ``h^ORDER`` lags: the geometric middle between a
lag (order 1) and the lowest-order error that adds up (order 2)."""

BINDING = 0.5
"""Only the outputs whose ratio to the allowed error is at least this share of the largest are
read: those that drive the step (the others may fall at any rate without holding it down)."""


class LaggingOutputs:
    """The outputs recognised as lagging (:attr:`mask`), from the errors of the attempts the
    controller judges (see the module): :meth:`judge` on every attempt."""

    def __init__(self) -> None:
        self.mask: np.ndarray | None = None
        self._start: tuple[float, np.ndarray] | None = None  # an accepted descent's first step
        self._last = math.inf  # the last accepted step's length
        self._from: tuple[float, float, np.ndarray] | None = None  # t, h, errors: rejections
        self._shortest = math.inf  # the last rejected attempt's length
        self._read: tuple[float, np.ndarray] | None = None  # the last reading from rejections
        self._probe: tuple[float, float, np.ndarray, np.ndarray] | None = None  # t, h, errors,
        # the suspected outputs: a step re-run shorter to read the order
        self._since = 0  # accepted steps since the last re-run
        self._gap = EVERY  # accepted steps until the next

    def reset(self) -> None:
        """A run starts: nothing recognised."""
        self.__init__()  # type: ignore[misc]

    def judge(self, t: float, h: float, scaled: np.ndarray, ratios: np.ndarray,
              ratio: float, aim: float) -> np.ndarray | float | None:
        """An attempt from ``t`` of ``h``, its errors ``scaled`` (in units of the norm) and
        their ``ratios`` to what is allowed, its ``ratio`` (above 1: rejected) and the aim of
        the control. Returns the outputs to judge it again with as lagging (an array), the
        step to re-run it with to read the order (a float), or ``None``."""
        rejected, above_aim = ratio > 1.0, ratio > aim
        probe, self._probe = self._probe, None
        if probe is not None and probe[0] == t and h < probe[1]:
            found = _lagging(probe[2], scaled, ratios, probe[1] / h)
            self._start, self._last = None, math.inf
            if found is not None and (found & probe[3]).any():
                found = found & probe[3]
                self.mask = found if self.mask is None else self.mask | found
                return self.mask
            self._gap *= 2
            return None
        if rejected:
            return self._rejected(t, h, scaled, ratios)
        self._from, self._shortest = None, math.inf
        suspect = self._accepted(h, scaled, ratios, above_aim)
        self._since += 1
        if suspect is None and self._since >= self._gap and ratio >= BINDING * aim:
            suspect = ratios >= BINDING * float(ratios.max())  # what drives the step now
        if suspect is None:
            return None
        self._since = 0
        self._probe = (t, h, scaled.copy(), suspect)
        return h / PROBE

    def _accepted(self, h: float, scaled: np.ndarray, ratios: np.ndarray,
                  above_aim: bool) -> np.ndarray | None:
        """An attempt about to be accepted: the outputs a descent ending here suspects."""
        descending = above_aim and h < self._last
        self._last = h
        if not descending or self._start is None:
            self._start = (h, scaled.copy()) if above_aim else None
            return None
        h0, e0 = self._start
        if h0 / h < DESCENT:
            return None
        self._start = (h, scaled.copy())
        return _lagging(e0, scaled, ratios, h0 / h)

    def _rejected(self, t: float, h: float, scaled: np.ndarray,
                  ratios: np.ndarray) -> np.ndarray | None:
        """A rejected attempt: the outputs to judge it again with as lagging (those read so
        now, and those recognised), or ``None`` when this attempt reads none."""
        self._start, self._last = None, math.inf
        if self._from is None or self._from[0] != t or not h < self._shortest:
            self._from, self._shortest = (t, h, scaled.copy()), h
            return None
        self._shortest = h
        _, h0, e0 = self._from
        if h0 / h < DESCENT:
            return None
        self._from = (t, h, scaled.copy())
        lagging = _lagging(e0, scaled, ratios, h0 / h)
        if lagging is None:
            return None
        earlier, self._read = self._read, (t, lagging)
        if earlier is not None and earlier[0] != t and (earlier[1] & lagging).any():
            again = earlier[1] & lagging  # read so at two times: a lag, not a jump
            self.mask = again if self.mask is None else self.mask | again
        return lagging if self.mask is None else lagging | self.mask


def _lagging(before: np.ndarray, after: np.ndarray, ratios: np.ndarray,
             shrink: float) -> np.ndarray | None:
    """The outputs that drive the step (their ``ratios`` at least :data:`BINDING` of the
    largest) and whose scaled error fell from ``before`` to ``after`` no faster than
    ``h^ORDER`` while the step shrank ``shrink`` times; ``None`` if there are none."""
    binding = ratios >= BINDING * float(ratios.max())
    with np.errstate(divide="ignore", invalid="ignore"):
        order = np.log(before / after) / math.log(shrink)
    lagging = binding & (before > 0.0) & (after > 0.0) & (order <= ORDER)
    return lagging if lagging.any() else None

"""Outputs whose error is a lag of the step, not a contribution to a sum: recognised from the
order of the error in the step, read from one state stepped with two steps.

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
through such a gain, tol 1e-3: the step fell by 12 % on each of about 215 accepted steps, down
to 3e-15 s, the gain's output error at a constant 0.24 of its share throughout).

Such an error does not add up: the next step's output is computed afresh from the next input,
and the lag the step leaves is what the output is wrong by *now*, as long as the step lasts.
So it is met against the whole budget, as the sum of the others is (rejected past
``cancellation × tol``, aimed at ``target ×`` that, 0.5 × tol by default), not against a share
of it (as the multi-rate master meets a held input's lag,
:meth:`cosimstep.multirate.Multirate.hold_lag`), and it enters the run's estimate as a level,
not as a term of the sum. What it does to the sub-models that read the lagging output is their
own error, which falls faster and is summed as before.

Which outputs lag is read from the order of their error in the step where the same state is
stepped with two steps (nothing else changed between them), and decided only by a re-run of an
*accepted* step at a quarter of its length (:data:`PROBE`), where no jump can hide:

- rejected attempts from one time, each shorter than the last, down by :data:`DESCENT`, whose
  error fell no faster than ``h^ORDER``, let the attempt be judged as a lag
  (:attr:`LaggingOutputs.provisional`), and the next accepted step is re-run to decide. A jump a
  partner makes just after the step's start, which the master was not told of, reads the same from
  the rejections, once: marked on two such readings, an integrator fed a square wave with two
  unannounced jumps was met against the whole budget for the rest of the run (1.5 × tol where it
  had 0.46 ×); the re-run past the jump reads the integrator's order 2. A PI controller's
  proportional part computed from the held error: every attempt of the first step of a lag plant
  and such a controller, tol 1e-3, was rejected at the same ratio until the estimate read as a
  noise floor (:meth:`~cosimstep.controllers.base.StepPolicy.noise`), then the run crawled at 6e-9
  s (600,000 calls in 20 s for 0.001 s of 5 s);
- a *descent* of accepted steps — consecutive accepted steps, each shorter than the one before,
  each with its ratio above the aim — that shrank the step by :data:`DESCENT` while an
  output's error fell no faster than ``h^ORDER`` asks for the re-run: a coefficient that rises
  while the step falls reads the same (the split double pendulum with held inputs, from rest:
  its ratios at 1.03–1.2 × the aim through a tenfold descent, its error against the step of
  order 1 over it, while at one time its error falls like ``h²``);
- and now and then, after :data:`EVERY` accepted steps, then after twice as many as before each
  time the re-run found no lag (a lag belongs to a sub-model and shows early), an accepted step
  whose ratio is near the aim: a lag whose ratio sits just below the aim moves the step
  neither way (the ratio does not answer the step), so the control creeps (the suite's boundary
  layer with held inputs at tol 1e-2, whose stiff fast partition at steps long against its time
  constant is slaved to its held input and lags it like a gain: 57,252 calls for 0.066 × tol).

A re-run reads every output it was asked about: an output marked before whose error now falls
like one that adds up is given up. The re-run is then judged as any attempt (and the attempt it
repeats is counted as a rejected one). Where the step is too short for a re-run above
``hmin``, a reading from rejections lapses unconfirmed.

A coupling error of the lowest order the controllers estimate falls like ``h²`` or faster,
twice as fast in the logarithm as a lag's, so :data:`ORDER` is the geometric middle; an error
that does not fall with the step at all (:data:`FLAT`) is noise, the floor's business.
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

FLAT = 0.5
"""An error that falls slower than ``h^FLAT`` does not come from the step at all: sub-model
noise, a floor (:meth:`~cosimstep.controllers.base.StepPolicy.noise` takes it), not a lag."""

BINDING = 0.5
"""Only the outputs whose ratio to the allowed error is at least this share of the largest are
read: those that drive the step (the others may fall at any rate without holding it down)."""


class LaggingOutputs:
    """The outputs recognised as lagging (:attr:`mask`) and those only read so from rejections
    (:attr:`provisional`), from the errors of the attempts the controller judges (see the
    module): :meth:`judge` on every attempt, :meth:`event` at an event."""

    def __init__(self) -> None:
        self.mask: np.ndarray | None = None
        self.provisional: np.ndarray | None = None  # read from rejections, to be confirmed
        self._confirm = False  # re-run the next accepted step to confirm `provisional`
        self._gap = EVERY  # accepted steps until the next periodic re-run
        self.event()

    def event(self) -> None:
        """An event (and a run's start): what was measured across it is no order, and a
        reading not yet confirmed belonged to the dynamics before it."""
        self._start: tuple[float, np.ndarray] | None = None  # an accepted descent's first step
        self._last = math.inf  # the last accepted step's length
        self._from: tuple[float, float, np.ndarray] | None = None  # t, h, errors: rejections
        self._shortest = math.inf  # the last rejected attempt's length
        # a step re-run shorter to read the order: t, h, errors, the outputs to read, and
        # whether it was a periodic one (only those lengthen the gap to the next)
        self._probe: tuple[float, float, np.ndarray, np.ndarray, bool] | None = None
        self._since = 0  # accepted steps since the last re-run
        self.provisional, self._confirm = None, False

    def reset(self) -> None:
        """A run starts: nothing recognised."""
        self.__init__()  # type: ignore[misc]

    @property
    def marked(self) -> np.ndarray | None:
        """The outputs an attempt is judged with as lagging: recognised, or read so from
        rejections and not yet confirmed (``None``: none)."""
        if self.provisional is None:
            return self.mask
        return self.provisional if self.mask is None else self.mask | self.provisional

    def judge(self, t: float, h: float, scaled: np.ndarray, ratios: np.ndarray,
              ratio: float, aim: float, hmin: float) -> float | None:
        """An attempt from ``t`` of ``h``, its errors ``scaled`` (in units of the norm) and
        their ``ratios`` to what is allowed, its ``ratio`` (above 1: rejected) and the aim of
        the control. Returns the step to re-run it with from the same state to read the
        order, or ``None``; :attr:`marked` says how to judge it."""
        probe, self._probe = self._probe, None
        if probe is not None and probe[0] == t and h < probe[1]:
            self._read_probe(probe, scaled, h)
            return None
        if ratio > 1.0:
            self._rejected(t, h, scaled, ratios)
            return None
        self._from, self._shortest = None, math.inf
        suspect = self._accepted(h, scaled, ratios, ratio > aim)
        self._since += 1
        periodic = False
        if self._confirm and self.provisional is not None:
            suspect = self.provisional
        elif suspect is None and self._since >= self._gap and ratio >= BINDING * aim:
            suspect, periodic = ratios >= BINDING * float(ratios.max()), True  # what drives
        if suspect is not None and h / PROBE < hmin:  # no shorter step to read the order with:
            self.provisional, self._confirm = None, False  # a reading left unconfirmed lapses
            return None
        if suspect is None:
            return None
        self._since, self._confirm = 0, False
        self._probe = (t, h, scaled.copy(), suspect, periodic)
        return h / PROBE

    def _read_probe(self, probe: tuple[float, float, np.ndarray, np.ndarray, bool],
                    scaled: np.ndarray, h: float) -> None:
        """The re-run of a step at a quarter of its length: the outputs read lag or do not,
        whatever they were taken for (a reading from rejections confirmed or dropped, a
        recognised lag that no longer reads so given up)."""
        _, h0, e0, read, periodic = probe
        read = read & (e0 > 0.0) & (scaled > 0.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            order = np.log(e0 / scaled) / math.log(h0 / h)
        lag, adds_up = read & (order >= FLAT) & (order <= ORDER), read & (order > ORDER)
        mask = lag if self.mask is None else (self.mask | lag) & ~adds_up
        self.mask = mask if mask.any() else None
        if self.provisional is not None:
            left = self.provisional & ~probe[3]
            self.provisional = left if left.any() else None
        if periodic and not lag.any():
            self._gap *= 2
        self._start, self._last = None, math.inf

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

    def _rejected(self, t: float, h: float, scaled: np.ndarray, ratios: np.ndarray) -> None:
        """A rejected attempt: a decade of them from one time whose error fell like a lag's
        lets the attempt be judged as a lag (:attr:`provisional`) until the next accepted step,
        re-run, says whether it is one."""
        self._start, self._last = None, math.inf
        if self._from is None or self._from[0] != t or not h < self._shortest:
            self._from, self._shortest = (t, h, scaled.copy()), h
            return
        self._shortest = h
        _, h0, e0 = self._from
        if h0 / h < DESCENT:
            return
        self._from = (t, h, scaled.copy())
        lagging = _lagging(e0, scaled, ratios, h0 / h)
        if lagging is not None:
            self.provisional = lagging if self.provisional is None \
                else self.provisional | lagging
            self._confirm = True


def _lagging(before: np.ndarray, after: np.ndarray, ratios: np.ndarray,
             shrink: float) -> np.ndarray | None:
    """The outputs that drive the step (their ``ratios`` at least :data:`BINDING` of the
    largest) and whose scaled error fell from ``before`` to ``after`` no faster than
    ``h^ORDER`` while the step shrank ``shrink`` times; ``None`` if there are none."""
    binding = ratios >= BINDING * float(ratios.max())
    with np.errstate(divide="ignore", invalid="ignore"):
        order = np.log(before / after) / math.log(shrink)
    lagging = binding & (before > 0.0) & (after > 0.0) & (order >= FLAT) & (order <= ORDER)
    return lagging if lagging.any() else None

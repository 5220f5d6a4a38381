"""The multi-rate master's global error estimate with errors along the motion carried as a
time shift: what :mod:`cosimstep.controllers.drift` is for the synchronous masters.

The multi-rate master's local estimates are scalars: the error a producer's interpolated
trajectory causes in a consumer (its interpolation error × the consumer's measured
sensitivity), and what a step left unresolved of its own inputs
(:class:`~cosimstep.multirate.Multirate`). Summed per consumer they assume every error
persists at the size it was made. On relaxation oscillations that missed by 10-200 × (Van der
Pol, FitzHugh–Nagumo, the Brusselator, the Oregonator: estimate 0.002-0.11 × the error where
the error passed 10 × tol): an error made along a slow branch is a time shift of the whole
system, met again at the next jump's speed.

``pc`` splits each local error vector into its part along the motion and the rest, in the
space of all outputs. Here only the error's size ``ε`` is known, and which sub-model it lands
in (``c``): the consumer's response to an input error is measured as a scalar gain. So it is
taken in the direction within ``c``'s outputs that lies most along the motion — the one in
which it persists — and, without its sign, split as ``pc`` splits: with ``v`` the system's
motion (every track's last step, scaled; ``v_c`` its part in ``c``'s outputs) the part along
is the time shift ``τ = ε·|v_c| / |v|²`` and ``ε·(1 − |v_c|² / |v|²)`` stays in ``c``'s
outputs ("the rest"). The shift is the system's, not the consumer's: a shift of one
sub-model's outputs alone is no solution of the coupled system, and read against one quiet
output (Rössler's ``z`` between its spikes) the whole error became a shift 100-2,700 × the
measured error. Met later the shift is ``|Σ τ| · |v|_∞`` then; the estimate is the largest
rest plus that, at its largest over the run. As in ``pc``, the shift is read only where the
motion over the step exceeds the error (``|v|·h > ε``: at rest there is no motion to shift
along), and only while every track's motion is known (a discrete-event track has none).
Each track's motion in the split is the largest speed it reaches within its last step,
``|v| + |a|·h/2`` from the step's chord and the change of the chords: a chord across a
turning point is near zero while the outputs moved fast on either side, and read so, a slow
partner's error became a shift of the whole system met at the oscillation's full speed (the
KPR problems, forced at ω = 100: estimates 2.6–4.2 × tol on runs of 0.20–0.45 × tol,
repeated to 0.015–0.033 × tol; ``pc`` guards the same case by ``|τ·a| < |v|``). The same
speeds decide whether the motion over the step exceeds the error. An
event turns the shift into an ordinary error of its size at the speeds then (a
failure on the clock does not move with the trajectory). Where the error memory ``M`` was
measured both fade: the shift with the run's front (the farthest any track has reached), the
rest with the consumer's steps (the plain sum fades with the producer's).

The run's estimate is the larger of this and the plain sum (where the motion slows, ``|Σ
τ|·|v|`` falls below what was made, and the plain sum still bounds that). docs/concepts.md
("The multi-rate estimate with a time shift") has the measurements.
"""

from __future__ import annotations

import math

import numpy as np


class RaceShift:
    """The running estimate (see the module) of ``n`` sub-models."""

    def __init__(self, n: int) -> None:
        self.rest = [0.0] * n  # errors not read as a shift, per consumer, scaled like tol
        self.peak = [math.nan] * n  # each track's last scaled velocity's largest component
        self.speed = [math.nan] * n  # the largest |v_k|² within its last step (see moved)
        self._motion: list[tuple[np.ndarray, float, float] | None] = [None] * n  # (v, h, end)
        self.shift = 0.0  # Σ τ, seconds
        self.front = -math.inf  # the farthest time any track has reached
        self.value = 0.0  # the largest estimate so far, scaled like tol

    def lands(self, c: int, error: float, h: float) -> None:
        """``error`` (scaled like tol) lands in consumer ``c`` over a step of length ``h``."""
        if error == 0.0:
            return
        vv = sum(self.speed)  # nan while any track's motion is unknown
        own = self.speed[c]
        if vv > 0.0 and vv * h * h > error * error:
            self.shift += error * math.sqrt(own) / vv
            self.rest[c] += error * (1.0 - own / vv)
        else:
            self.rest[c] += error

    def fades(self, k: int, fade: float) -> None:
        """Track ``k`` takes a step over which its error memory lets its rest keep ``fade``
        (called before the step's own errors land, as the plain sum fades what came before)."""
        self.rest[k] *= fade

    def moved(self, k: int, end: float, h: float, velocity: np.ndarray | None,
              memory: float) -> None:
        """Track ``k`` accepted a step of ``h`` ending at ``end`` with its outputs moving at
        ``velocity`` (scaled; ``None``: unreadable — zero length, or a jump inside; empty: no
        continuous outputs); ``memory``: its error memory, for the shift's fade over the
        front's advance."""
        if end > self.front:
            if math.isfinite(self.front) and math.isfinite(memory):
                self.shift *= math.exp(-(end - self.front) / memory)
            self.front = end
        if velocity is None:
            self.unread(k)
        elif not velocity.size:  # no continuous outputs (a discrete-event track): no motion
            self.peak[k], self.speed[k] = math.nan, 0.0
        else:
            self.peak[k] = float(np.abs(velocity).max())
            self.speed[k] = self._fastest_within(k, end, h, velocity)
        fastest = max((x for x in self.peak if x == x), default=0.0)
        self.value = max(self.value, max(self.rest) + abs(self.shift) * fastest)

    def _fastest_within(self, k: int, end: float, h: float, velocity: np.ndarray) -> float:
        """``(|v| + |a|·h/2)²``: the largest speed track ``k`` reaches within its step by the
        step's chord ``v`` and the change ``a`` of the chords over its last two steps. A chord
        across a turning point is near zero while the outputs moved fast on either side of
        it; read as the motion there, an error landing in a slow partner became a time shift
        of the whole system met at the oscillation's full speed (``|v|²`` where ``a`` is not
        known: the first step, or after a jump or a dropped step)."""
        last, self._motion[k] = self._motion[k], (velocity, h, end)
        speed = math.sqrt(float(velocity.dot(velocity)))
        if last is not None and abs(end - h - last[2]) <= 1e-9 * h:
            change = velocity - last[0]
            speed += math.sqrt(float(change.dot(change))) / (0.5 * (h + last[1])) * 0.5 * h
        return speed * speed

    def unread(self, k: int) -> None:
        """Track ``k``'s motion is unknown (its last step was dropped, or jumped): until it
        moves again no error is read as a shift, since the system's motion is not known
        (read without the track, a fast wheel's jump left out of ``|v|``, the quarter car's
        errors became shifts against the chassis's slow motion alone, 0.0003 × tol
        delivered after the repeat they caused)."""
        self.peak[k] = self.speed[k] = math.nan
        self._motion[k] = None

    def jump(self) -> None:
        """An event: the shift becomes an error like the others, its size at the speeds now,
        and the motion is read afresh after it."""
        for c, peak in enumerate(self.peak):
            if peak == peak:
                self.rest[c] += abs(self.shift) * peak
        self.shift = 0.0
        n = len(self.speed)
        self.peak, self.speed = [math.nan] * n, [math.nan] * n
        self._motion = [None] * n


__all__ = ["RaceShift"]

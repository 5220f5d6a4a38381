"""Strong coupling: a communication step repeated until the exchanged values agree (issue 18).

Explicit (loose) coupling runs each sub-model once per step on inputs extrapolated from the past
(thesis 3.3.2); with a stiff coupling that is unstable unless the step is tiny. Strong coupling
treats the values at the step's end as unknowns ``x``: one pass of the step, from the saved
states, with every input interpolated through the history and ``x``, gives the values the
sub-models actually produce, ``G(x)``. The step is converged when the residual
``r = G(x) - x`` is within ``atol + rtol |G(x)|`` on every exchanged value; otherwise the states
go back and the pass runs again with a new ``x``. The first pass is the explicit step itself
(``x`` extrapolated), so a step whose prediction was already good costs nothing extra.

How the next ``x`` is chosen (the accelerators below):

``fixed-point``
    ``x = G(x)``: Jacobi or Gauss–Seidel waveform iteration over one step; converges when the
    coupling is weak enough for the step, and only then.
``aitken``
    Dynamic under-relaxation ``x += w r`` with Aitken's factor
    ``w_k = -w_(k-1) r_(k-1)·(r_k - r_(k-1)) / |r_k - r_(k-1)|^2`` (Irons and Tuck; the first
    factor of a step :data:`INITIAL_RELAXATION`, as preCICE's default).
``iqn-ils``
    Interface quasi-Newton with an inverse Jacobian from least squares (Degroote et al.
    2009; preCICE's default): from the differences of residuals ``V`` and of outputs ``W`` of
    earlier passes, ``x = G(x) + W a`` with ``a`` minimising ``|V a + r|``. Columns from the
    last :data:`REUSE` converged steps are kept (the coupling changes slowly from step to step),
    and columns that are nearly dependent on newer ones are dropped (a QR filter, threshold
    :data:`FILTER`), so an outdated or redundant column cannot make the least squares singular.

Every pass calls every sub-model once: the calls count them. A step that does not converge in
``max_iterations`` passes raises :class:`CouplingError`, a :class:`~cosimstep.errors.SubModelError`:
an adaptive controller treats it like any failed trial (back to the step's start, a quarter of
the step), a fixed step ends the run ``failed`` with the residual, results kept.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from cosimstep.errors import SubModelError

COUPLINGS = ("explicit", "fixed-point", "aitken", "iqn-ils")
INITIAL_RELAXATION = 0.5
"""The first under-relaxation factor of a step (Aitken), and IQN-ILS's first update when it has
no columns yet: half of a fixed-point update, safe when the plain iteration diverges mildly."""
REUSE = 8
"""Converged steps whose IQN-ILS columns are kept (preCICE's reuse of earlier time windows)."""
FILTER = 1e-8
"""IQN-ILS QR filter: a column whose diagonal element falls below this share of the largest
(relative to its norm) is dropped."""


class CouplingError(SubModelError):
    """The iteration of a communication step did not converge."""

    def __init__(self, t: float, h: float, iterations: int, residual: float,
                 worst: str) -> None:
        self.iterations, self.residual = iterations, residual
        self.model, self.t, self.h = "coupling", t, h
        self.reason = (f"the coupling iteration did not converge in {iterations} passes: "
                       f"residual {residual:.3g} at '{worst}'")
        RuntimeError.__init__(self, f"{self.reason} (step from t = {t:.9g} to {t + h:.9g})")


class LoopError(SubModelError):
    """An algebraic loop could not be solved at a communication point."""

    def __init__(self, t: float, outputs: list[str], residual: float, why: str,
                 worst: tuple[str, float, float] | None = None) -> None:
        """``residual``: the largest ``|g(z) − z| / (1 + |g(z)|)`` (what ``coupling_tol``
        bounds); ``worst``: that output's name, its value ``g(z)`` and ``|g(z) − z|`` in its
        own unit, so the message says how far off the loop is, not only its scaled residual."""
        self.model, self.t, self.h, self.residual = "loop", t, None, residual
        where = "" if worst is None else \
            f" at {worst[0]} = {worst[1]:.6g}, off by {worst[2]:.3g} (in its unit);"
        self.reason = (f"the algebraic loop through {', '.join(outputs)} was not solved:"
                       f"{where} residual {residual:.3g} relative to 1 + |value| ({why})")
        RuntimeError.__init__(self, f"{self.reason} at t = {t:.9g}")


@dataclass
class LoopStats:
    """What solving the algebraic loops cost: solves (one per loop and communication point),
    evaluations of the loop's models (set inputs, get outputs: no step, no call)."""

    solves: int = 0
    evaluations: int = 0
    residual_max: float = 0.0

    def to_dict(self) -> dict[str, float | int]:
        return {"solves": self.solves, "evaluations": self.evaluations,
                "residual_max": self.residual_max}


@dataclass
class IterationStats:
    """What the iterations of a run cost: passes (each calls every sub-model once)."""

    steps: int = 0
    passes: int = 0
    max_passes: int = 0
    residual_max: float = 0.0  # the largest converged residual, scaled by the tolerance's norm

    def to_dict(self) -> dict[str, float | int]:
        return {"steps": self.steps, "iterations": self.passes,
                "iterations_max": self.max_passes,
                "iterations_per_step": self.passes / self.steps if self.steps else 0.0,
                "residual_max": self.residual_max}


class Accelerator:
    """Chooses the next ``x`` from the last one and its result ``G(x)``."""

    def start(self) -> None:
        """A new communication step."""

    def next(self, x: np.ndarray, g: np.ndarray) -> np.ndarray:
        return g

    def converged(self) -> None:
        """The step converged (IQN-ILS keeps its columns)."""


class Aitken(Accelerator):
    def __init__(self) -> None:
        self._r: np.ndarray | None = None
        self._w = INITIAL_RELAXATION

    def start(self) -> None:
        self._r, self._w = None, INITIAL_RELAXATION

    def next(self, x: np.ndarray, g: np.ndarray) -> np.ndarray:
        r = g - x
        if self._r is not None:
            dr = r - self._r
            denom = float(dr @ dr)
            if denom > 0.0:
                self._w = -self._w * float(self._r @ dr) / denom
        self._r = r
        return x + self._w * r


class IqnIls(Accelerator):
    def __init__(self) -> None:
        self._old: deque[tuple[np.ndarray, np.ndarray]] = deque(maxlen=REUSE)
        self._v: list[np.ndarray] = []  # this step's residual differences
        self._w: list[np.ndarray] = []  # this step's output differences
        self._last: tuple[np.ndarray, np.ndarray] | None = None  # (r, g) of the last pass

    def start(self) -> None:
        self._v, self._w, self._last = [], [], None

    def converged(self) -> None:
        if self._v:
            self._old.appendleft((np.column_stack(self._v), np.column_stack(self._w)))

    def next(self, x: np.ndarray, g: np.ndarray) -> np.ndarray:
        r = g - x
        if self._last is not None:
            self._v.insert(0, r - self._last[0])  # newest first: the filter keeps it
            self._w.insert(0, g - self._last[1])
        self._last = (r, g)
        v, w = self._columns(len(r))
        if v is None:
            return x + INITIAL_RELAXATION * r
        # least squares |V a + r| through the filtered QR of V
        q, rr = np.linalg.qr(v)
        a = np.linalg.solve(rr, -(q.T @ r))
        return g + w @ a

    def _columns(self, n: int) -> tuple[np.ndarray | None, np.ndarray | None]:
        """This step's columns, then the reused ones; nearly dependent columns dropped."""
        vs = [*self._v, *(c for v, _ in self._old for c in v.T)]
        ws = [*self._w, *(c for _, w in self._old for c in w.T)]
        keep_v: list[np.ndarray] = []
        keep_w: list[np.ndarray] = []
        for cv, cw in zip(vs, ws, strict=True):
            if len(keep_v) >= n:
                break
            trial = np.column_stack([*keep_v, cv])
            diag = np.abs(np.diag(np.linalg.qr(trial)[1]))
            if diag[-1] > FILTER * max(float(np.linalg.norm(cv)), 1e-300) and np.all(diag > 0):
                keep_v.append(cv)
                keep_w.append(cw)
        if not keep_v:
            return None, None
        return np.column_stack(keep_v), np.column_stack(keep_w)


ACCELERATORS: dict[str, Callable[[], Accelerator]] = {
    "fixed-point": Accelerator, "aitken": Aitken, "iqn-ils": IqnIls}


class Iteration:
    """The iteration of one master's communication steps (see the module docstring).

    ``pass_`` runs one pass of the step and returns the new exchanged values; ``unknowns``
    marks the values iterated on (those some receiver takes extrapolated: the others are
    computed fresh within the pass).
    """

    def __init__(self, scheme: str, tol: float, max_iterations: int,
                 names: list[str]) -> None:
        self.accelerator = ACCELERATORS[scheme]()
        self.tol, self.max_iterations, self.names = tol, max_iterations, names
        self.stats = IterationStats()

    def run(self, pass_: Callable[[np.ndarray | None], np.ndarray],
            save: Callable[[], object], restore: Callable[[object], None],
            assumed: Callable[[], np.ndarray], unknowns: np.ndarray,
            t: float, h: float) -> np.ndarray:
        """One converged communication step from ``t`` to ``t + h``."""
        tokens = save()
        y = pass_(None)  # the explicit step: x is the extrapolated end value
        x = assumed()[unknowns]
        acc = self.accelerator
        acc.start()
        passes = 1
        while True:
            g = y[unknowns]
            residual = np.abs(g - x) / (self.tol * (1.0 + np.abs(g)))
            worst = float(np.max(residual)) if residual.size else 0.0  # NaN: not converged
            if worst <= 1.0:
                break
            if passes >= self.max_iterations:
                at = self.names[int(np.flatnonzero(unknowns)[int(np.nanargmax(residual))])]
                raise CouplingError(t, h, passes, worst * self.tol, at)
            x = acc.next(x, g)
            end = y.copy()
            end[unknowns] = x
            restore(tokens)
            y = pass_(end)
            passes += 1
        acc.converged()
        stats = self.stats
        stats.steps += 1
        stats.passes += passes
        stats.max_passes = max(stats.max_passes, passes)
        stats.residual_max = max(stats.residual_max, worst * self.tol)
        return y


__all__ = ["COUPLINGS", "CouplingError", "Iteration", "IterationStats", "LoopError",
           "LoopStats"]

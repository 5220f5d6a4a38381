"""What a run produced: :class:`SimulationResult`, with each sub-model's share
(:class:`ModelStats`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from cosimstep.events import Event
from cosimstep.reference import ErrorReport
from cosimstep.symbols import SYMBOLS, TEXT_UNITS, decoded_frame


@dataclass
class ModelStats:
    """One sub-model's share of a run (for multi-rate runs each has its own steps)."""

    calls: int
    accepted: int
    rejected: int
    corrections: int  # multi-rate: steps re-run after a failed verification of extrapolated input
    step_sizes: np.ndarray = field(repr=False)
    times: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    """The sub-model's own communication points (multi-rate: its own steps; synchronous: the
    common grid)."""
    values: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)), repr=False)
    """Its outputs there, as it computed them (one column per output, in declaration order)."""
    replaced: int = 0
    """Multi-rate: accepted steps later dropped by a rollback or re-run in several pieces, net
    (the attempts log holds ``accepted + replaced`` accepted attempts)."""
    gain_checks: int = 0
    """Multi-rate: calls that measured its sensitivity to its inputs again, one per input, when
    its steps had moved far from those it was measured on (``calls`` = accepted + rejected +
    corrections + gain checks + probes)."""
    probes: int = 0
    """Multi-rate: calls made by the probes of the error memory (:mod:`cosimstep.race_memory`)."""

    def to_dict(self) -> dict[str, Any]:
        s = self.step_sizes
        return {"calls": self.calls, "accepted": self.accepted, "rejected": self.rejected,
                "corrections": self.corrections, "gain_checks": self.gain_checks,
                "probes": self.probes,
                "h_min": float(s.min()) if s.size else None,
                "h_max": float(s.max()) if s.size else None}


@dataclass
class SimulationResult:
    """What a run produced. ``status`` is ``"ok"``, ``"failed"``, ``"interrupted"`` or
    ``"timed_out"`` (a budget of ``simulate(max_wall=, max_calls=)`` was spent)."""

    status: str
    message: str
    t_end: float
    names: list[str]
    units: list[str]
    times: np.ndarray
    values: np.ndarray
    calls: dict[str, int]
    steps_accepted: int
    steps_rejected: int
    step_sizes: np.ndarray
    wall_s: float
    time_in_models: dict[str, float]
    store: str | None = None
    run_id: int | None = None
    """The run's id in :attr:`store` (``cosimstep runs``, :func:`~cosimstep.store.read_run`)."""
    error: ErrorReport | None = None
    reference: np.ndarray | None = field(default=None, repr=False)
    models: dict[str, ModelStats] = field(default_factory=dict)
    error_estimate: float | None = None
    """The global error the run estimates it delivered, without a reference, in the norm
    ``tol`` bounds (``max |e| / (1 + |y|)`` for the default ``atol = rtol = tol``); ``None``
    for controllers without error control. Compare with ``error.max_scaled``."""
    estimate_calls: int = 0
    """Calls the estimate cost (the looser run of ``estimate="rerun"``), not in ``calls``."""
    events: list[Event] = field(default_factory=list)
    """The events of discrete-event sub-models, in time order (:mod:`cosimstep.events`)."""
    coupling: dict[str, Any] | None = None
    """Strong coupling (:mod:`cosimstep.iteration`): steps, passes (``iterations``, every pass
    calls every sub-model once), the most in one step and the largest converged residual;
    ``None`` for explicit coupling."""
    loops: dict[str, Any] | None = None
    """Algebraic loops (solved at every communication point): solves, evaluations of the
    loops' models and the largest residual; ``None`` without loops."""
    tightened: dict[str, Any] | None = None
    """A run repeated at a tighter tolerance because its own estimate exceeded twice its
    ``tol`` (``simulate(tighten=True)``, :mod:`cosimstep.tighten`): the *other* run of the
    pair, whose calls are not in :attr:`calls` — ``run`` is ``"first"`` (this result is the
    repeat) or ``"repeat"`` (the repeat was not kept: it failed, or gave no estimate of its
    own — unscaled — lower than the first run's; with its ``status``), with its ``tol``,
    ``error_estimate``, ``calls``, ``estimate_calls`` and ``run_id`` in the store. A kept
    repeat of a run with the summed estimate also holds ``error``, the first run's error as
    measured against the repeat (:mod:`cosimstep.pair`), and ``estimate_alone``, its own
    estimate before it was scaled by ``error`` over the first run's estimate
    (:func:`~cosimstep.tighten.calibrated`; :attr:`error_estimate` is the scaled one).
    ``None``: the run was not repeated."""
    traceback: str | None = field(default=None, repr=False)
    """A failed run's traceback, the sub-model's own exception included (``run -v`` prints
    it; the message names the model, the time and the reason)."""

    @property
    def success(self) -> bool:
        return self.status == "ok"

    @property
    def calls_total(self) -> int:
        return int(sum(self.calls.values()))

    @property
    def calls_spent(self) -> int:
        """Every sub-model call the result cost: :attr:`calls_total`, and the other run's too
        where the run was repeated at a tighter tol (:attr:`tightened`); what a work–precision
        comparison counts. The estimates' own calls are apart: this run's in
        :attr:`estimate_calls`, the other run's in ``tightened["estimate_calls"]``."""
        return self.calls_total + (int(self.tightened["calls"]) if self.tightened else 0)

    def __getitem__(self, name: str) -> np.ndarray:
        """Trajectory of an exchanged output, e.g. ``result["bar1.theta"]``."""
        try:
            return self.values[:, self.names.index(name)]
        except ValueError:
            raise KeyError(f"no output '{name}'; outputs: {', '.join(self.names)}") from None

    def summary(self) -> dict[str, Any]:
        """The JSON summary the CLI prints with ``--json``."""
        steps = self.step_sizes
        out: dict[str, Any] = {
            "status": self.status,
            "message": self.message,
            "t_end": self.t_end,
            "calls": dict(self.calls),
            "calls_total": self.calls_total,
            "calls_spent": self.calls_spent,
            "steps_accepted": self.steps_accepted,
            "steps_rejected": self.steps_rejected,
            "h_min": float(steps.min()) if steps.size else None,
            "h_max": float(steps.max()) if steps.size else None,
            "wall_s": self.wall_s,
            "master_overhead_s": max(self.wall_s - sum(self.time_in_models.values()), 0.0),
            "store": self.store,
            "run_id": self.run_id,
        }
        out["events"] = [e.to_dict() for e in self.events]
        out["events_late"] = sum(e.late for e in self.events)  # state events not located
        out["error_estimate"] = self.error_estimate
        out["error_estimate_calls"] = self.estimate_calls
        out["tightened"] = self.tightened
        if self.error is not None:
            out["error"] = self.error.to_dict()
        out["models"] = {n: m.to_dict() for n, m in self.models.items()}
        if self.coupling is not None:
            out["iterations"] = {k: self.coupling[k] for k in
                                 ("iterations", "iterations_max", "iterations_per_step")}
            out["residual_max"] = self.coupling["residual_max"]
        if self.loops is not None:
            out["loops"] = dict(self.loops)
        return out

    def text(self, name: str) -> list[str | bytes]:
        """The values of a String or Binary output (its column holds codes,
        :mod:`cosimstep.symbols`)."""
        codes = self[name]
        if self.units[self.names.index(name)] not in TEXT_UNITS:
            raise ValueError(f"'{name}' is not a String or Binary output")
        return [SYMBOLS.value(c) for c in codes]

    def symbol_table(self) -> dict[int, str | bytes]:
        """Code → value for every code in the run's String and Binary columns."""
        coded = [i for i, u in enumerate(self.units) if u in TEXT_UNITS]
        return SYMBOLS.table(self.values[:, coded].ravel().tolist()) if coded else {}

    def to_pandas(self):
        """The values as a DataFrame indexed by time; String and Binary columns decoded."""
        return decoded_frame(self.values, self.times, self.names, self.units)


__all__ = ["ModelStats", "SimulationResult"]

"""Checkpoints of a fixed-step run, and resuming from one (``cosimstep run --resume``).

A checkpoint is everything the fixed-step loop needs to go on as if it had never stopped: the
loop's clock (the compensated sum of the steps, so the resumed times are the same floats), the
last stored points that extrapolation reads, the master's per-segment values, the call counts,
and every sub-model's state as bytes (:meth:`~cosimstep.submodel.SubModel.serialize_state`:
pickled for Python sub-models, the FMU's own serialization for FMUs). It is written to the
store with the points up to it, in one commit, so a run killed at any instant resumes from a
consistent state; the resumed run then computes exactly what the uninterrupted one would have
(tests/store/test_resume.py compares the stores bit for bit).

Only the fixed-step synchronous loop takes checkpoints: its whole state is the few numbers
above. The adaptive loop would also need its controller's and error estimator's state, and the
multi-rate master every sub-model's trajectory; they refuse ``--resume`` with that reason.
"""

from __future__ import annotations

import pickle
import time
from typing import TYPE_CHECKING, Any

import numpy as np

from cosimstep.store import Checkpoint

if TYPE_CHECKING:
    from cosimstep.loops import FixedLoop

HISTORY = 4
"""Stored points kept before the checkpoint's: as many as the general step reads
(``loops.HISTORY_ROWS``), more than extrapolation of order 2 needs."""
VERSION = 1


class Checkpoints:
    """When a fixed-step loop writes a checkpoint: every ``every_s`` seconds of wall time
    and/or every ``every_steps`` steps (checked where the loop hands its points to the store,
    at most :attr:`~cosimstep.loops.FixedLoop.BATCH` steps apart). A sub-model that cannot
    serialize its state stops them; the store says which (``--resume`` repeats it)."""

    def __init__(self, every_s: float | None = None, every_steps: int | None = None) -> None:
        for name, value in (("checkpoint_every", every_s), ("checkpoint_steps", every_steps)):
            if value is not None and not value > 0:
                raise ValueError(f"`{name}` must be positive, got {value}")
        self.every_s, self.every_steps = every_s, every_steps
        self._last = (0, time.perf_counter())  # (point, wall time) of the last checkpoint
        self.broken: str | None = None

    def due(self, n: int) -> bool:
        if self.broken is not None:
            return False
        last_n, last_time = self._last
        return ((self.every_steps is not None and n - last_n >= self.every_steps)
                or (self.every_s is not None
                    and time.perf_counter() - last_time >= self.every_s))

    def take(self, loop: FixedLoop) -> None:
        """Write the loop's checkpoint at its newest point (after the points up to it)."""
        sink = loop.sink
        assert sink is not None and loop._state is not None
        self._last = (loop.n, time.perf_counter())
        global_n = loop.offset + loop.n
        try:
            state = pickle.dumps(capture(loop), protocol=pickle.HIGHEST_PROTOCOL)
        except Exception as exc:  # a sub-model that cannot serialize its state
            self.broken = str(exc)
            sink.add_checkpoint(loop.t, global_n, None, f"no checkpoint: {exc}")
            return
        sink.add_checkpoint(loop.t, global_n, state)


def capture(loop: FixedLoop) -> dict[str, Any]:
    """The loop's state at its newest point (see the module docstring)."""
    runner, n = loop.runner, loop.n
    assert loop._state is not None
    clock, carry, segment, _ = loop._state
    first = max(segment, n - HISTORY)
    lean_calls = np.array(getattr(loop.lean, "calls", None) or [0] * len(runner.calls))
    lean_time = np.array(getattr(loop.lean, "time", None) or [0.0] * len(runner.calls))
    models = []
    for name, model in zip(runner.system.names, runner.system.models):
        try:
            models.append(model.serialize_state(model.save_state()))
        except Exception as exc:
            raise RuntimeError(f"sub-model '{name}' cannot serialize its state "
                               f"({type(exc).__name__}: {exc})") from exc
    return {"version": VERSION, "t": loop.t, "first": loop.offset + first,
            "segment": loop.offset + segment, "clock": clock, "carry": carry,
            "times": loop.times[first:n + 1].copy(), "rows": loop.table[first:n + 1].copy(),
            "hs": loop.hs[first:n].copy(),
            "rejected": loop.rejected, "calls": runner.calls + lean_calls,
            "time_in_models": runner.time_in_models + lean_time,
            "master": {"dy0": runner._dy0, "assumed": runner.assumed.copy(),
                       "last": runner.last.copy()},
            "models": models}


def restore(loop: FixedLoop, checkpoint: Checkpoint, t0: float) -> None:
    """Start ``loop`` from ``checkpoint`` instead of ``t0``: the sub-models are initialized
    at ``t0`` as in the first run, then set to their checkpointed states."""
    state = pickle.loads(checkpoint.state)
    if state.get("version") != VERSION:
        raise ValueError(f"checkpoint of run {checkpoint.run_id} was written by another "
                         "version of cosimstep")
    runner = loop.runner
    runner.initialize(t0)
    for k, (model, data) in enumerate(zip(runner.system.models, state["models"])):
        runner._guard(k, state["t"], lambda m=model, d=data: m.restore_state(
            m.deserialize_state(d)))
    rows = state["rows"]
    k = rows.shape[0]
    loop.offset = state["first"]
    loop.times[:k], loop.table[:k] = state["times"], rows
    loop.hs[:k - 1] = state["hs"]
    loop.n, loop.t = k - 1, state["t"]
    loop.rejected = state["rejected"]
    loop._state = (state["clock"], state["carry"], max(state["segment"] - state["first"], 0),
                   k)
    runner.calls[:] = state["calls"]
    runner.time_in_models[:] = state["time_in_models"]
    runner._dy0 = state["master"]["dy0"]
    runner.assumed = state["master"]["assumed"]
    runner.last = state["master"]["last"]
    loop.lean = runner.held_kernel() or runner.extrapolating_kernel()
    loop._stored, loop._shown = k, k - 1
    loop._published = (k - 1, time.perf_counter())


__all__ = ["Checkpoints", "capture", "restore"]

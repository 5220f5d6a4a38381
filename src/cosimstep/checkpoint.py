"""Checkpoints of a synchronous run, and resuming from one (``cosimstep run --resume``).

A checkpoint is everything the time loop needs to go on as if it had never stopped: the
loop's clock (the compensated sum of the steps, so the resumed times are the same floats), the
last stored points that extrapolation reads, the master's per-segment values, the call counts,
the step controller (pickled: its proposed step, error budget, error memory, random state),
and every sub-model's state as bytes (:meth:`~cosimstep.submodel.SubModel.serialize_state`:
pickled for Python sub-models, the FMU's own serialization for FMUs). It is written to the
store with the points up to it, in one commit, so a run killed at any instant resumes from a
consistent state; the resumed run then computes exactly what the uninterrupted one would have
(tests/store/test_resume.py compares the stores bit for bit).

Both synchronous loops (fixed step, and any controller) take checkpoints; each says what its
state is (``snapshot``/``resume_snapshot``). The multi-rate master would need every sub-model's
trajectory and pending verifications, and runs with discrete events their event models'
clocks; they refuse ``--resume`` with that reason.
"""

from __future__ import annotations

import pickle
import time
from typing import TYPE_CHECKING, Any

import numpy as np

from cosimstep.store import Checkpoint

if TYPE_CHECKING:
    from cosimstep.loops import ControllerLoop, FixedLoop

    Loop = FixedLoop | ControllerLoop

VERSION = 5  # 2: the controllers' run estimate (controllers/drift.py) in the pickle;
# 3: StepPolicy.overrun (an older policy would resume with the gate open by default);
# 4: StepPolicy.catch_up (an older policy would resume catching up, unlike its first part);
# 5: ErrorMemory.measured holds each output's memory (an older one, read from the norm of the
# difference, would steer the resumed run until three new probes replaced it)


class Checkpoints:
    """When a synchronous loop writes a checkpoint: every ``every_s`` seconds of wall time
    and/or every ``every_steps`` steps (checked where the loop hands its points to the store:
    every accepted step of the controller loop, at most
    :attr:`~cosimstep.loops.FixedLoop.BATCH` steps apart in the fixed-step loop). A sub-model
    that cannot serialize its state stops them; the store says which (``--resume`` repeats
    it)."""

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

    def take(self, loop: Loop, n: int) -> None:
        """Write the loop's checkpoint at its newest point, ``n`` points after its first
        (after the points up to it)."""
        sink = loop.sink
        assert sink is not None
        self._last = (n, time.perf_counter())
        global_n = loop.offset + n
        try:
            state = pickle.dumps(capture(loop), protocol=pickle.HIGHEST_PROTOCOL)
        except Exception as exc:  # a sub-model that cannot serialize its state
            self.broken = str(exc)
            sink.add_checkpoint(loop.t, global_n, None, f"no checkpoint: {exc}")
            return
        sink.add_checkpoint(loop.t, global_n, state)


def capture(loop: Loop) -> dict[str, Any]:
    """The run's state at the loop's newest point (see the module docstring)."""
    runner = loop.runner
    lean = getattr(loop, "lean", None)
    lean_calls = np.array(getattr(lean, "calls", None) or [0] * len(runner.calls))
    lean_time = np.array(getattr(lean, "time", None) or [0.0] * len(runner.calls))
    models = []
    for name, model in zip(runner.system.names, runner.system.models):
        try:
            models.append(model.serialize_state(model.save_state()))
        except Exception as exc:
            raise RuntimeError(f"sub-model '{name}' cannot serialize its state "
                               f"({type(exc).__name__}: {exc})") from exc
    return {"version": VERSION, "t": loop.t, "loop": loop.snapshot(),
            "calls": runner.calls + lean_calls,
            "time_in_models": runner.time_in_models + lean_time,
            "master": {"dy0": runner._dy0, "assumed": runner.assumed.copy(),
                       "last": runner.last.copy()},
            "models": models}


def restore(loop: Loop, checkpoint: Checkpoint, t0: float) -> None:
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
    runner.calls[:] = state["calls"]
    runner.time_in_models[:] = state["time_in_models"]
    runner._dy0 = state["master"]["dy0"]
    runner.assumed = state["master"]["assumed"]
    runner.last = state["master"]["last"]
    loop.resume_snapshot(state["loop"])


__all__ = ["Checkpoints", "capture", "restore"]

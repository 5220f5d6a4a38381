"""Coupling algorithms: how one communication step ``[t, t + h]`` is executed (thesis 3.3.2).

* **Jacobi**: every sub-model steps on its partners' values extrapolated from the history up to
  ``t`` — the sub-models are independent within a step (they could run in parallel).
* **Gauss–Seidel**: sub-models step one after another; a later one uses the fresh values of those
  already stepped (interpolated over the step instead of extrapolated).

A master executes calls and counts them; it does not decide the step size (controllers do) nor
keep the history (the orchestrator does). It can save and restore every sub-model's state, which
is what rejecting and re-running a step needs.
"""

from __future__ import annotations

import contextlib
import math
import queue
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from cosimstep.errors import SubModelError
from cosimstep.extrapolation import evaluate, taylor_coefficients
from cosimstep.system import CompiledSystem

MASTERS = ("jacobi", "gauss-seidel", "multirate")


@dataclass(frozen=True)
class MasterOptions:
    """How steps are executed.

    Attributes
    ----------
    name:
        ``"jacobi"`` or ``"gauss-seidel"`` (default: measured more accurate at equal calls), or
        ``"multirate"``: one adaptive step per sub-model (:mod:`cosimstep.multirate`).
    extrapolation:
        Order of the input polynomial over a step: 0 hold, 1 linear, 2 quadratic (default: the
        accurate one; see docs/concepts.md for the measured orders).
    order:
        Gauss–Seidel execution order by model name (default: the order models were added).
    call_timeout:
        Seconds one ``do_step`` may take before the run ends as failed (``None``: no limit). A
        timed-out call is abandoned in its worker thread.
    interpolation:
        Multi-rate only: how partners' stored trajectories are read (a method of
        :mod:`cosimstep.interpolation`; ``None``: the built-in local cubic, fastest).
    """

    name: str = "gauss-seidel"
    extrapolation: int = 2
    order: tuple[str, ...] | None = None
    call_timeout: float | None = None
    interpolation: str | None = None

    def problems(self) -> list[str]:
        out = []
        if self.name not in MASTERS:
            out.append(f"unknown master '{self.name}'; choose one of {', '.join(MASTERS)}")
        if self.extrapolation not in (0, 1, 2):
            out.append(f"extrapolation order {self.extrapolation} is not 0, 1 or 2")
        if self.call_timeout is not None and not self.call_timeout > 0:
            out.append("call_timeout must be positive")
        if self.interpolation is not None:
            from cosimstep.interpolation import INTERPOLATORS

            if self.interpolation not in INTERPOLATORS:
                out.append(f"unknown interpolation '{self.interpolation}'; choose one of "
                           f"{', '.join(INTERPOLATORS)}")
            elif self.name != "multirate":
                out.append("interpolation applies to the multirate master only")
        return out


class _TimedCaller:
    """Runs calls in one daemon worker thread so a hanging sub-model cannot hang the master."""

    def __init__(self, timeout: float) -> None:
        self.timeout = timeout
        self._jobs: queue.Queue = queue.Queue()
        self._worker = threading.Thread(target=self._loop, daemon=True)
        self._worker.start()

    def _loop(self) -> None:
        while True:
            fn, args, box, done = self._jobs.get()
            try:
                box.append((True, fn(*args)))
            except BaseException as exc:
                box.append((False, exc))
            done.set()

    def __call__(self, fn: Any, *args: Any) -> Any:
        box: list = []
        done = threading.Event()
        self._jobs.put((fn, args, box, done))
        if not done.wait(self.timeout):
            raise TimeoutError(f"no answer within {self.timeout:g} s (call abandoned)")
        ok, value = box[0]
        if not ok:
            raise value
        return value


class Master:
    """Executes communication steps over a compiled system."""

    def __init__(self, system: CompiledSystem, options: MasterOptions = MasterOptions()) -> None:
        problems = options.problems()
        if problems:
            raise ValueError("; ".join(problems))
        self.system = system
        self.options = options
        n = len(system.models)
        self.calls = np.zeros(n, dtype=np.int64)
        self.time_in_models = np.zeros(n)
        if options.order is None:
            self.sequence = list(range(n))
        else:
            unknown = [m for m in options.order if m not in system.names]
            if unknown or len(set(options.order)) != len(options.order):
                raise ValueError(f"`order` {list(options.order)} must name each model at most "
                                 f"once, from: {', '.join(system.names)}")
            self.sequence = [system.names.index(m) for m in options.order]
            self.sequence += [k for k in range(n) if k not in self.sequence]
        self._deriv_order = [m.capabilities.max_input_derivative_order for m in system.models]
        self._call = _TimedCaller(options.call_timeout) if options.call_timeout else None
        self._dy0: np.ndarray | None = None
        self.predicted = self._predicted_columns()
        self.consumed = np.zeros(system.n_outputs, dtype=bool)  # outputs some model reads
        self.held = np.zeros(system.n_outputs, dtype=bool)  # read by a hold-only receiver
        for k, src in enumerate(system.src):
            self.consumed[np.asarray(src, dtype=int)] = True
            if self._deriv_order[k] == 0:
                self.held[np.asarray(src, dtype=int)] = True
        self.assumed = np.zeros(system.n_outputs)
        self.last = np.zeros(system.n_outputs)

    def _predicted_columns(self) -> np.ndarray:
        """Outputs that some receiver uses *extrapolated* over a step (not yet computed).

        Under Jacobi that is every consumed output; under Gauss–Seidel only outputs of models that
        step after (or are) a receiver — the others are interpolated through their fresh values.
        """
        system = self.system
        rank = {k: i for i, k in enumerate(self.sequence)}
        owner = np.empty(system.n_outputs, dtype=int)
        for k, sl in enumerate(system.output_slices):
            owner[sl] = k
        mask = np.zeros(system.n_outputs, dtype=bool)
        for k in range(len(system.models)):
            for j in np.asarray(system.src[k], dtype=int):
                if self.options.name == "jacobi" or rank[owner[j]] >= rank[k]:
                    mask[j] = True
        return mask

    # -- life cycle --------------------------------------------------------------------------
    def initialize(self, t0: float) -> np.ndarray:
        """Initialize every sub-model and return the exchanged values at ``t0``."""
        for k, model in enumerate(self.system.models):
            self._guard(k, t0, model.initialize, t0)
        y = np.empty(self.system.n_outputs)
        for k in range(len(self.system.models)):
            y[self.system.output_slices[k]] = self._outputs(k, t0, None)
        self._settle_feedthrough(t0, y)
        self._check_finite(range(len(self.system.models)), t0, y)
        self._dy0 = None
        if all(m.capabilities.provides_derivatives for m in self.system.models):
            system = self.system
            for k, m in enumerate(system.models):  # slopes at t0 need the inputs at t0
                self._guard(k, t0, m.set_inputs, system.a[k] * y[system.src[k]] + system.b[k])
            self._dy0 = np.concatenate([self._guard(k, t0, m.get_output_derivatives)
                                        for k, m in enumerate(system.models)])
        return y

    def _outputs(self, k: int, t: float, h: float | None) -> np.ndarray:
        """Outputs of model ``k``, checked to be one float per declared output."""
        values = self._guard(k, t, self.system.models[k].get_outputs, h=h)
        try:
            arr = np.asarray(values, dtype=float)
        except (TypeError, ValueError):
            arr = None
        n = len(self.system.models[k].outputs)
        if arr is None or arr.shape != (n,):
            raise SubModelError(self.system.names[k], t, f"get_outputs returned {values!r}; "
                                f"expected {n} float(s), one per declared output", h)
        return arr

    def terminate(self) -> None:
        for model in self.system.models:
            with contextlib.suppress(Exception):
                model.terminate()

    def save(self) -> list[Any]:
        return [m.save_state() for m in self.system.models]

    def restore(self, tokens: Sequence[Any]) -> None:
        for m, token in zip(self.system.models, tokens):
            m.restore_state(token)

    # -- one communication step --------------------------------------------------------------
    def step(self, t: float, h: float, times: Sequence[float], history: np.ndarray, *,
             order: int | None = None, end: np.ndarray | None = None) -> np.ndarray:
        """Advance every sub-model from ``t`` to ``t + h``; return the new exchanged values.

        ``times``/``history`` are the stored points (the last row belongs to ``t``). ``order``
        overrides the extrapolation order for this step. ``end`` (values at ``t + h`` from an
        earlier attempt of the same step) turns extrapolation into interpolation: the corrector
        of a predictor–corrector step. After the step, :attr:`assumed` holds the value at
        ``t + h`` of the input polynomial each output was assumed to follow (see
        :attr:`predicted` for which outputs were actually extrapolated).
        """
        p = self.options.extrapolation if order is None else order
        if end is None:
            coef = taylor_coefficients(times, history, t, p)
        else:
            pts = [*times[-p:], t + h] if p > 0 else [t + h]
            vals = np.vstack([history[-p:], end]) if p > 0 else end[None, :]
            coef = taylor_coefficients(pts, vals, t, p)
        y_new = history[-1].copy()
        gauss_seidel = self.options.name == "gauss-seidel"
        if end is None and len(times) == 1 and p > 0 and self._dy0 is not None:
            coef[1] = self._dy0  # start-up: grey-box slopes instead of a first-order hold
        self.assumed = evaluate(coef, h)
        for k in self.sequence:
            self._step_model(k, t, h, coef)
            out = self.system.output_slices[k]
            model = self.system.models[k]
            if gauss_seidel and model.capabilities.has_direct_feedthrough:
                # its outputs must reflect inputs at t + h before later models interpolate them
                src, a, b = self.system.src[k], self.system.a[k], self.system.b[k]
                self._guard(k, t, model.set_inputs, a * evaluate(coef[:, src], h) + b, h=h)
            y_new[out] = self._outputs(k, t, h)
            if gauss_seidel:
                # Later models see this model's fresh values: interpolate through t + h.
                pts = [*times[-p:], t + h] if p > 0 else [t + h]
                vals = np.vstack([history[-p:, out], y_new[out]]) if p > 0 else y_new[None, out]
                coef[:, out] = taylor_coefficients(pts, vals, t, p)
        self._settle_feedthrough(t + h, y_new)
        self._check_finite(range(len(self.system.models)), t, y_new, h)
        self.last = y_new
        return y_new

    def restart(self) -> None:
        """After a time event: grey-box slopes (if any) for the first step of the new segment."""
        self._dy0 = self.derivatives()

    def derivatives(self) -> np.ndarray | None:
        """Grey-box output derivatives of every model now, or ``None`` if one cannot tell."""
        if not all(m.capabilities.provides_derivatives for m in self.system.models):
            return None
        return np.concatenate([np.asarray(self._guard(k, math.nan, m.get_output_derivatives),
                                          dtype=float)
                               for k, m in enumerate(self.system.models)])

    def _step_model(self, k: int, t: float, h: float, coef: np.ndarray) -> None:
        system = self.system
        model = system.models[k]
        src, a, b = system.src[k], system.a[k], system.b[k]
        q = min(self._deriv_order[k], coef.shape[0] - 1)
        if q > 0 or coef.shape[0] == 1:
            u = a * coef[0, src] + b
        else:
            # The sub-model holds inputs constant: give it the extrapolated mid-step value,
            # which is second-order accurate over the step where the start value is first-order.
            u = a * evaluate(coef[:, src], 0.5 * h) + b
        start = time.perf_counter()
        self.calls[k] += 1
        self._guard(k, t, model.set_inputs, u, h=h)
        if q > 0:
            self._guard(k, t, model.set_input_derivatives, a * coef[1:q + 1, src], h=h)
        self._guard(k, t, model.do_step, t, h, h=h)
        self.time_in_models[k] += time.perf_counter() - start

    def _settle_feedthrough(self, t: float, y: np.ndarray) -> None:
        """Refresh direct-feedthrough outputs from inputs at ``t`` (no step, no call)."""
        system = self.system
        for k in system.feedthrough_order:
            u = system.a[k] * y[system.src[k]] + system.b[k]
            self._guard(k, t, system.models[k].set_inputs, u)
            y[system.output_slices[k]] = self._outputs(k, t, None)

    def _check_finite(self, models: Any, t: float, y: np.ndarray,
                      h: float | None = None) -> None:
        if np.all(np.isfinite(y)):
            return
        for k in models:
            block = y[self.system.output_slices[k]]
            if not np.all(np.isfinite(block)):
                bad = [self.system.output_names[self.system.output_slices[k].start + i]
                       for i in np.flatnonzero(~np.isfinite(block))]
                raise SubModelError(self.system.names[k], t,
                                    f"returned non-finite output(s) {', '.join(bad)}", h)

    def _guard(self, k: int, t: float, fn: Any, *args: Any, h: float | None = None) -> Any:
        try:
            if self._call is not None:
                return self._call(fn, *args)
            return fn(*args)
        except SubModelError:
            raise
        except Exception as exc:
            raise SubModelError(self.system.names[k], t,
                                f"{type(exc).__name__}: {exc}", h) from exc

    @property
    def max_step(self) -> float:
        return min((m.capabilities.max_step for m in self.system.models), default=math.inf)

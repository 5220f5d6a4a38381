"""A sub-model whose outputs carry noise that no communication step reduces (an internal
solver's tolerance): the predictor–corrector estimate then has a floor, and a global error
target, whose share per step shrinks with the step, must not crawl down to hmin on it."""

from __future__ import annotations

import numpy as np

import cosimstep as cs
from cosimstep.adapters.ode import make_solver
from cosimstep.controllers.base import NOISE_SHARE
from cosimstep.models import REGISTRY


class Noisy(cs.SubModel):
    """Another sub-model's outputs plus ±eps, alternating call by call (not part of its state:
    a re-run of the same step differs by 2 eps, as a solver's error does on other inputs)."""

    def __init__(self, inner: cs.SubModel, eps: float) -> None:
        self.inner, self.eps, self.calls = inner, eps, 0
        self.inputs, self.outputs = inner.inputs, inner.outputs
        self.capabilities = inner.capabilities
        super().__init__()

    def initialize(self, t0: float) -> None:
        self.inner.initialize(t0)

    def set_inputs(self, values: np.ndarray) -> None:
        self.inner.set_inputs(values)

    def set_input_derivatives(self, derivatives: np.ndarray) -> None:
        self.inner.set_input_derivatives(derivatives)

    def do_step(self, t: float, h: float) -> None:
        self.inner.do_step(t, h)
        self.calls += 1

    def get_outputs(self) -> np.ndarray:
        return self.inner.get_outputs() + self.eps * (-1.0) ** self.calls

    def get_output_derivatives(self) -> np.ndarray:
        return self.inner.get_output_derivatives()

    def save_state(self):
        return self.inner.save_state()

    def restore_state(self, token) -> None:
        self.inner.restore_state(token)


def _system(eps: float) -> cs.System:
    params = cs.ParameterSchedule(dict(REGISTRY["linear_coupled"].parameters))
    start = {"u": 0.9000099990001, "v": -9.99900009999, "w": 1000.0}
    solver = make_solver({"method": "rk4", "max_dt": 1e-4})
    fast = REGISTRY["linear_coupled.fast"].build(params, start, solver)
    slow = REGISTRY["linear_coupled.slow"].build(params, start, solver)
    return (cs.System().add("fast", Noisy(fast, eps)).add("slow", slow)
            .connect("fast.u", "slow.u").connect("slow.w", "fast.w"))


def _run(eps: float, **options) -> tuple[cs.SimulationResult, cs.Controller]:
    controller = cs.make_controller("pc", None, 1e-4, h0=1e-9, **options)
    result = cs.simulate(_system(eps), 0.05, controller, cs.MasterOptions("gauss-seidel", 2),
                         progress=False)
    return result, controller


def test_a_noise_floor_is_recognised_and_steps_grow_past_it() -> None:
    # eps = 1e-9 against tol 1e-4: 1e-5 of the tolerance, but a first step of 1e-9 s may spend
    # 2.5e-13 of the 0.05 s run's budget
    # measured: recognised 3 times, floor 1.2e-4 of tol (one input ratio per receiver: the
    # slow model's ratio is taken over its noisy input alone, so the noise counts at about
    # its own size, not scaled down by the fast model's clean inputs); 27 steps
    result, controller = _run(1e-9)
    assert result.status == "ok", result.message
    assert controller.policy.noise_steps >= 1
    assert 2e-9 / (1e-4 * (1 + 0.9)) <= controller.policy.floor <= NOISE_SHARE
    assert result.steps_accepted < 200  # the steps grew back from 1e-9 s
    assert np.max(result.step_sizes) > 1e-4


def test_noise_above_the_floor_share_is_still_an_error() -> None:
    # eps = 1e-6 is 1e-2 of the tolerance: not taken for noise, the run ends at hmin as before
    result, controller = _run(1e-6)
    assert result.status == "failed" and "hmin" in result.message, result.message
    assert controller.policy.noise_steps == 0

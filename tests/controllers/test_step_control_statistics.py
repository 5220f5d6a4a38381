"""The step control's statistics (options ``trend`` and ``unbiased``, off by default): a trend
followed only where the estimates show one, and an aim corrected so that the ratios the budget
adds average the target.

docs/concepts.md ("A trend only where the estimates show one") has the reasoning and the suite.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import cosimstep as cs
from cosimstep.controllers.base import SMOOTHING, TREND_SD, StepPolicy

BOTH = {"trend": True, "unbiased": True}


def test_trend_sd_is_that_of_the_smoothing_on_white_scatter() -> None:
    """TREND_SD: the trend's standard deviation over the misses' when log c only scatters."""
    rng = np.random.default_rng(0)
    level, trend, trends, misses = 0.0, 0.0, [], []
    for x in rng.standard_normal(50_000):
        miss = x - (level + trend)
        level += trend + (1.0 - SMOOTHING**2) * miss
        trend += (1.0 - SMOOTHING) ** 2 * miss
        trends.append(trend)
        misses.append(miss)
    ratio = float(np.std(trends[100:]) / np.std(misses[100:]))
    assert ratio == pytest.approx(TREND_SD, rel=0.03)


def _closed_loop(policy: StepPolicy, sigma: float, rate: float = 0.0, steps: int = 400,
                 seed: int = 1) -> tuple[np.ndarray, int]:
    """Ratios of the step control on r = c(t) h^4 e^(σ z_n) (z standard normal, c falling like
    e^(−rate·t) at the step's middle, as a settling system's modes do), and the number of
    steps on which it followed a trend."""
    rng = np.random.default_rng(seed)
    h, t, ratios, followed = 0.01, 0.0, [], 0
    for _ in range(steps):
        r = 1e7 * math.exp(-rate * (t + 0.5 * h)) * h**4 * math.exp(sigma * rng.standard_normal())
        ratios.append(r)
        accepted = r <= 1.0
        h, t = policy.next_step(h, r, 4, accepted), t + (h if accepted else 0.0)
        followed += policy._drifting()
    return np.array(ratios), followed


def _settling(**options: bool) -> StepPolicy:
    """A step policy whose error memory probes measured the system settling (a memory of 40
    s in a run of 100 s, below half of it): where ``trend`` and ``unbiased`` act."""
    policy = StepPolicy(**options)
    policy.start(0.0, 100.0)
    policy.memory = 40.0
    return policy


def _accepted_mean(ratios: np.ndarray) -> float:
    late = ratios[100:]
    return float(np.mean(late[late <= 1.0]))


# measured (400 steps, seed 1): mean accepted ratio 0.150 at σ = 1.5 and 0.160 at σ = 1 with
# the PI control alone; 0.084–0.098 with both options, at σ = 0.5 … 1.5
@pytest.mark.parametrize("sigma", [0.5, 1.0, 1.5])
def test_the_ratios_the_budget_adds_average_the_target(sigma: float) -> None:
    target = StepPolicy().target
    ratios, _ = _closed_loop(_settling(**BOTH), sigma)
    assert 0.8 * target <= _accepted_mean(ratios) <= 1.1 * target
    if sigma >= 1.0:  # the PI control alone settles the geometric mean: the arithmetic is above
        plain, _ = _closed_loop(StepPolicy(), sigma)
        assert _accepted_mean(plain) > 1.4 * target


def test_a_trend_is_followed_where_there_is_one_and_not_in_scatter() -> None:
    target = StepPolicy().target
    # a settling error (c falls like e^(-5t)), no scatter: followed, the ratio at the target
    # (the forecast is in time, so a fall that grows with the step is no lag); the PI control
    # alone lags ever further behind (0.64 of the target at the end, and falling)
    settling, followed = _closed_loop(_settling(**BOTH), 0.0, rate=5.0, steps=60)
    assert np.allclose(settling[-20:], target, rtol=1e-3)
    assert followed >= 50
    pi, _ = _closed_loop(StepPolicy(), 0.0, rate=5.0, steps=60)
    assert max(pi[-5:]) < 0.7 * target and pi[-1] < pi[-20]
    # scatter without a drift: about the two-sigma test's share of false alarms (5 %;
    # measured 12-30 of 400 steps at σ = 0.5 … 1.5)
    for seed in (1, 2, 3):
        _, followed = _closed_loop(_settling(**BOTH), 1.0, seed=seed)
        assert followed <= 0.1 * 400


def _pump(tol: float, seed: int) -> cs.SimulationResult:
    """The pump-failure example with the failure law's seed (and the reference's) changed."""
    spec = cs.load_system("examples/pump_failure.toml", overrides={
        "parameters": {"health.seed": seed, "fail_seed": float(seed)}})
    return cs.simulate(spec.system, spec.until, cs.make_controller("pc", None, tol),
                       spec.master, reference=spec.reference)


# Before an event restarted the step control and cleared the error memory, these failure times
# (seed 1: 338.7 s, 4: 677.1 s, 5: 511.4 s) left 39.5 / 97 / 29.9 × tol: the first steps after
# the failure were sized by the control and the memory of the plant at rest. Measured after:
# 0.014 / 0.40 / 0.064 × tol (docs/concepts.md, "An event starts the step control again"), and
# 0.042 / 0.42 / 0.31 since the memory is measured again at once after the failure, and
# 0.30 / 1.42 / 0.76 (in 7-9 % fewer calls) since the step catches up with the settling
# (StepPolicy.catch_up; 0.038 / 0.42 / 0.22 without it).
@pytest.mark.parametrize(("seed", "tol"), [(1, 1e-4), (4, 1e-6), (5, 1e-5)])
def test_the_steps_after_a_failure_are_not_sized_by_the_plant_before_it(seed: int,
                                                                         tol: float) -> None:
    run = _pump(tol, seed)
    assert run.success and len(run.events) == 1
    assert run.error.max_scaled <= 2.0 * tol, run.error.max_scaled / tol


# the fall (rate, per unit time) is chosen where the PI control lags visibly within 60 steps;
# the multi-rate policy aims at a higher target, so its steps are longer for the same fall
@pytest.mark.parametrize(("multirate", "rate"), [(False, 5.0), (True, 3.0)])
def test_a_trend_is_followed_only_where_the_system_settles(multirate: bool, rate: float) -> None:
    """``trend`` and ``unbiased`` act only while the error memory probes measured a memory
    below half the run: without that evidence of settling it is the PI control, step for
    step, for the synchronous controllers and each multi-rate track alike."""
    from cosimstep.multirate import _copy_policy

    def policy(**options: bool) -> StepPolicy:
        return _copy_policy(StepPolicy(**options)) if multirate else StepPolicy(**options)

    pi, _ = _closed_loop(policy(), 0.0, rate=rate, steps=60)
    asked = policy(**BOTH)
    asked.start(0.0, 100.0)
    unmeasured, followed = _closed_loop(asked, 0.0, rate=rate, steps=60)
    assert followed == 0 and np.array_equal(unmeasured, pi)
    for memory, settles in ((60.0, False), (40.0, True)):  # half the run: 50
        asked = policy(**BOTH)
        asked.start(0.0, 100.0)
        asked.memory = memory
        ratios, followed = _closed_loop(asked, 0.0, rate=rate, steps=60)
        if settles:  # the drift is followed: the ratios rise to the target, while the PI
            # control lags ever further (multi-rate: 0.81 -> 0.72 of it over the last 25 steps)
            assert followed >= 50
            assert np.allclose(ratios[-10:], asked.target, rtol=0.01)
            assert max(pi[-5:]) < 0.75 * asked.target
        else:
            assert followed == 0 and np.array_equal(ratios, pi)


def test_a_new_share_of_the_budget_is_no_fall_to_follow() -> None:
    """A memory measured anew changes every later ratio's share of the budget at once (the
    ratio is the error over its share), which the forecast would read as a fall of the error:
    it starts again, and the PI control decides until it has three misses."""
    policy = _settling(**BOTH)
    _closed_loop(policy, 0.0, rate=5.0, steps=30)
    assert policy._drifting()
    policy.memory = 8.0  # a probe found the memory five times shorter
    policy.next_step(0.01, 0.02, 4, True)
    assert not policy._drifting()


# the suite's boundary layer under the multi-rate master at tol 1e-6 with both options: 17 × tol
# when a memory of 0.18 s measured after one of 0.91 s (a fivefold share) was followed as a
# steep fall of the error, 0.35 × with the forecast started again
def test_the_boundary_layer_keeps_the_tolerance_with_both_options() -> None:
    from cosimstep import suite

    problem = suite.get("boundary_layer")
    system, reference = problem.build()
    run = cs.simulate(system, problem.until, cs.make_controller("pc", None, 1e-6, **BOTH),
                      cs.MasterOptions("multirate", 2), reference=reference)
    assert run.success
    assert 0.1 <= run.error.max_scaled / 1e-6 <= 10.0, run.error.max_scaled / 1e-6


@pytest.mark.parametrize(("name", "options"), [("doubling", {"trend": True}),
                                               ("defect", {"unbiased": True}),
                                               ("pc", {"trend": True, "probe_every": 0})])
def test_the_options_are_refused_where_no_memory_is_measured(name: str, options: dict) -> None:
    """Without an error memory the options would silently do nothing."""
    with pytest.raises(ValueError, match="measures no error memory"):
        cs.make_controller(name, None, 1e-4, **options)

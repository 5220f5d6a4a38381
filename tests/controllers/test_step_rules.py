"""The step rules alone: appendix B's RKF23, fig. 23's stiff test, slopes, FFT and helpers."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cosimstep.controllers import RKF23, fft_hmax, fixed_step_from, make_controller
from cosimstep.controllers.slopes import cubic_fit, pchip, spline
from cosimstep.controllers.testbed import fixed, rkf23, stiff
from cosimstep.controllers.testbed import test_curve as appendix_b_curve


def max_error(run, exact) -> float:
    return max(abs(x - exact(t)) for t, x in zip(run.t, run.x, strict=True))


def test_appendix_b_curve_meets_tolerance_and_converges() -> None:
    exact, slope = appendix_b_curve(2.0)
    loose = rkf23(slope, 0.0, 100.0, exact(0.0), 1e-3)
    tight = rkf23(slope, 0.0, 100.0, exact(0.0), 1e-5)
    assert loose.completed and tight.completed
    assert loose.calls == 3 * (len(loose.t) - 1 + loose.rejected)
    assert max_error(loose, exact) < 1e-3 and max_error(tight, exact) < 1e-5
    # third-order local error, tol^(1/4) step rule: 100x tighter costs about 100^(1/4) ~ 3.2x
    assert 3.0 < tight.calls / loose.calls < 5.0


def test_stiff_equation_of_fig_23() -> None:
    exact, slope = stiff()
    euler = fixed(slope, 0.0, 0.6, 0.99, 0.025, "euler")
    rk2 = fixed(slope, 0.0, 0.6, 0.99, 0.025, "rk2")
    adaptive = rkf23(slope, 0.0, 0.6, 0.99, 1e-3)
    assert max_error(euler, exact) > 1.0 and max_error(rk2, exact) > 1.0  # both unstable
    assert max_error(adaptive, exact) < 1e-3


def test_rkf23_predictor_and_corrector_as_written() -> None:
    # x = t^3 from t = 0: slopes 0, 3h²/4, 3h² -> predictor 0.75 h³, corrector h³
    h = 0.1
    k = np.array([[0.0], [0.75 * h * h * 3 / 3], [3 * h * h]])
    assert RKF23(tol=1e-3)._difference(k, h)[0] == pytest.approx(0.25 * h**3, rel=1e-12)


def test_slope_estimators_on_a_cubic() -> None:
    times = [-0.1, 0.0, 0.05, 0.1]
    values = np.array([[t**3 - t] for t in times])
    at = [0.0, 0.05, 0.1]
    exact = np.array([[3 * t * t - 1] for t in at])
    assert np.allclose(cubic_fit(times, values, at), exact, atol=1e-12)
    assert np.allclose(spline(times, values, at), exact, atol=1e-12)  # 4 points: the cubic
    assert np.allclose(pchip(times, values, at), exact, atol=0.05)  # shape-preserving, not exact


def test_fft_hmax_finds_the_dominant_frequency() -> None:
    t = np.linspace(0.0, 10.0, 2001)
    y = np.column_stack([np.sin(2 * math.pi * 0.7 * t), 0.5 * np.sin(2 * math.pi * 2.0 * t)])
    spectrum = fft_hmax(t, y, points_per_period=20)
    assert spectrum.dominant_hz == pytest.approx(0.7, abs=0.1)
    assert spectrum.highest_hz == pytest.approx(2.0, abs=0.1)
    assert spectrum.hmax == pytest.approx(1 / (20 * spectrum.highest_hz))


def test_fixed_step_from_a_sample_run() -> None:
    steps = np.r_[np.full(20, 1e-5), 0.01, 0.004, 0.02, 0.006, 1e-9]
    assert fixed_step_from(steps) == 0.004  # start-up and the landing step ignored


def test_make_controller_defaults_and_errors() -> None:
    assert make_controller(None, None, 1e-4).name == "pc"
    assert make_controller(None, 0.01).name == "fixed"
    with pytest.raises(ValueError, match="does not use a tolerance"):
        make_controller("fixed", 0.01, 1e-4)
    with pytest.raises(ValueError, match="unknown controller 'rk99'"):
        make_controller("rk99", None, 1e-4)
    with pytest.raises(ValueError, match="`mode` must be one of"):
        make_controller("rkf23", None, 1e-4, mode="everything")


@pytest.mark.parametrize("step", [-0.01, 0.0, float("nan"), float("inf")])
def test_an_initial_step_must_be_positive_wherever_it_is_given(step):
    """`[controller] step` refused a negative initial step while `--step` and the API ran it,
    clamped to hmin: every route now refuses it, naming it."""
    with pytest.raises(ValueError, match=r"`step` \(the initial step\) must be a positive"):
        make_controller("pc", step, 1e-4)

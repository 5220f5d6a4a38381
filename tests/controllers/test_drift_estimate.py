"""The run's own estimate with errors along the motion carried as a time shift
(``cosimstep.controllers.drift``; docs/concepts.md, "Errors along the motion: a time shift")."""

from __future__ import annotations

import math

import numpy as np
import pytest

import cosimstep as cs
from cosimstep import suite
from cosimstep.controllers.drift import DriftEstimate

TOL = 1e-3


def _feed(estimate: DriftEstimate, times: np.ndarray, path, errors, jumping=None) -> None:
    """Accepted steps between ``times``, the outputs on ``path(t)``, local ``errors[i]``."""
    for i in range(1, len(times)):
        y = np.asarray(path(times[i]), dtype=float)
        estimate.add(np.asarray(errors[i - 1], dtype=float), y, times[i - 1],
                     times[i] - times[i - 1], TOL * (1.0 + np.abs(y)), TOL, 1.0, jumping)


def test_a_shift_made_on_a_slow_stretch_is_met_at_the_fast_one() -> None:
    """One output, slow (speed 0.01) for 1 s, then fast (speed 2): each slow step's error
    5e-4 is a time shift of 5e-4 / 0.01 = 0.05 s; eight add to 0.4 s (the first step has no
    motion to read yet, the second no change of motion: both count whole), met at speed 2 as
    0.8 — where the plain sum stays at 10 x 5e-4."""
    times = np.linspace(0.0, 1.5, 16)

    def path(t: float) -> float:
        return 0.01 * t if t <= 1.0 else 0.01 + 2.0 * (t - 1.0)

    errors = [[5e-4] if t <= 1.0 + 1e-12 else [0.0] for t in times[1:]]
    estimate = DriftEstimate()
    _feed(estimate, times, lambda t: [path(t)], errors)
    # largest at the first fast step's end, before 1 + |y| grows
    expected = (2 * 5e-4 + 8 * 0.05 * 2.0) / (1.0 + path(times[11]))
    assert estimate.value == pytest.approx(expected, rel=1e-6)
    assert estimate.summed == pytest.approx(10 * 5e-4 / (1.0 + path(times[10])), rel=1e-9)


def test_shifts_of_opposite_signs_cancel_and_the_plain_sum_does_not() -> None:
    times = np.linspace(0.0, 1.0, 11)
    errors = [[(-1.0) ** i * 1e-4] for i in range(10)]
    estimate = DriftEstimate()
    _feed(estimate, times, lambda t: [t], errors)
    # the first two steps whole, the third's shift of 1e-4 s at speed 1 beside them; then
    # the shifts cancel pairwise
    assert estimate.value == pytest.approx(3e-4 / 1.3, rel=1e-9)
    assert estimate.summed == pytest.approx(10 * 1e-4 / 2.0, rel=1e-9)


def test_no_shift_is_read_at_a_turning_point() -> None:
    """y = sin(2 pi t), steps of 0.05 s, an error of 0.04 on the step up to the crest
    (t = 0.25): its mean speed 0.98 moves y by 0.049 over the step, more than the error, but
    the motion turns within |v| / |a| = 0.026 s, and e / v = 0.041 s is no first-order shift
    (read as one, it would be met at the next flank's speed 2 pi as 6.4 times the error)."""
    times = np.linspace(0.0, 1.0, 21)
    errors = [[0.04] if i == 4 else [0.0] for i in range(20)]
    estimate = DriftEstimate()
    _feed(estimate, times, lambda t: [math.sin(2 * math.pi * t)], errors)
    assert estimate.value == pytest.approx(estimate.summed, rel=1e-9)
    assert estimate.summed == pytest.approx(0.04, rel=1e-6)  # met where y crosses zero


def test_errors_across_the_motion_are_summed_as_before() -> None:
    """The motion along output 0, the errors in output 1 only: no shift, the plain sum."""
    times = np.linspace(0.0, 1.0, 11)
    estimate = DriftEstimate()
    _feed(estimate, times, lambda t: [t, 0.0], [[0.0, 1e-4]] * 10)
    assert estimate.value == estimate.summed == pytest.approx(10 * 1e-4, rel=1e-12)


def test_at_rest_there_is_no_motion_to_shift_along() -> None:
    """Outputs that move by less than the error over a step give no direction: the error
    counts whole (a shift read from noise, met at a later transient, would be anything)."""
    times = np.linspace(0.0, 1.0, 11)
    estimate = DriftEstimate()
    _feed(estimate, times, lambda t: [1.0 + 1e-9 * t], [[1e-6]] * 10)
    assert estimate.value == estimate.summed


def test_a_discrete_output_is_no_speed() -> None:
    """A discrete output that jumps by 100 on the last step is no motion a shift is met at:
    left out, the estimate is what the continuous output's shifts give."""
    times = np.linspace(0.0, 1.0, 11)
    errors = [[1e-4, 0.0]] * 10

    def path(t: float) -> list[float]:
        return [t, 100.0 if t > 0.95 else 0.0]

    masked, unmasked = DriftEstimate(), DriftEstimate()
    _feed(masked, times, path, errors, np.array([False, True]))
    _feed(unmasked, times, path, errors)
    # masked: the first two steps whole, then shifts of 1e-4 s at speed 1, largest at y = 1
    assert masked.value == pytest.approx(10 * 1e-4 / 2.0, rel=1e-6)
    assert unmasked.value > 10 * masked.value  # 8e-4 s met at the jump's 1000 per second


def _steps(estimate: DriftEstimate, t: float, points: list[tuple[float, float, float]]
           ) -> float:
    """Steps of ``(h, y at the end, error)`` from ``t`` on one output, norm scale ``TOL``."""
    for h, y, e in points:
        estimate.add(np.array([e]), np.array([y]), t, h, np.array([TOL]), TOL, 1.0)
        t += h
    return t


def test_an_event_turns_the_shift_into_an_error_at_the_speed_then() -> None:
    """Three steps at speed 1 (the third's error a shift of 1e-4 s), an event, then motion at
    speed 100: the shift counts as the 1e-4 it was at the event (carried on as a shift, or
    read across the jump, it would be met at speed 100)."""
    estimate = DriftEstimate()
    t = _steps(estimate, 0.0, [(0.1, 0.1, 1e-4), (0.1, 0.2, 1e-4), (0.1, 0.3, 1e-4)])
    estimate.jump()
    _steps(estimate, t, [(0.1, 10.0, 0.0), (0.1, 20.0, 0.0), (0.1, 30.0, 0.0)])
    assert estimate.value == pytest.approx(3e-4, rel=1e-9)


def test_a_step_undone_leaves_no_motion_behind() -> None:
    """A step accepted to y = 0.4 and undone (it crossed a state event), then redone over
    0.001 s to y = 0.3999 and followed by a fast one (speed 100): the change from the undone
    end, -0.1 per second, is no motion (read as one, the redone step's error 5e-5 would be a
    shift of 5e-4 s, met at speed 100 as 0.05)."""
    estimate = DriftEstimate()
    t = _steps(estimate, 0.0, [(0.1, 0.1, 0.0), (0.1, 0.2, 0.0), (0.1, 0.3, 0.0)])
    _steps(estimate, t, [(0.1, 0.4, 0.0)])
    _steps(estimate, t, [(0.001, 0.3999, 5e-5), (0.1, 10.3999, 0.0)])
    assert estimate.value == pytest.approx(5e-5, rel=1e-9)



def test_the_split_creates_no_error_in_an_output_that_had_none() -> None:
    """A slow output (speed 1) carries the error, a fast one (speed 100) none. The motion's
    direction is the fast output's, so the shift claims tau*v there; the rest of the fast
    output is bounded by its own error (none), not -tau*v, which the sum without signs would
    keep beside the shift (the stiff two-mass example's force: 3.2 x its error, 1.05 so)."""
    times = np.linspace(0.0, 1.0, 11)
    estimate = DriftEstimate()
    _feed(estimate, times, lambda t: [t, 100.0 * t], [[1e-4, 0.0]] * 10)
    assert estimate._shift > 0.0  # shifts were read (eight steps)
    assert estimate._across[1] == 0.0  # the fast output's rest: it made no error
    assert estimate._across[0] <= 10 * 1e-4  # the slow output's: at most what it made

def test_fading_applies_to_the_shift_as_to_the_rest() -> None:
    """Four steps along y = t, each with an error of 1e-4, halved per step: the first two
    whole, the next two shifts (1e-4 s at speed 1); 1.875e-4 at the end (a shift that did
    not fade: 2.375e-4)."""
    estimate = DriftEstimate()
    for i in range(1, 5):
        y = np.array([0.5 * i])
        estimate.add(np.array([1e-4]), y, 0.5 * (i - 1), 0.5, np.array([TOL]), TOL, 0.5)
    assert estimate.value == pytest.approx(1.875e-4 / 1.0, rel=1e-9)
    assert estimate.summed == pytest.approx(1.875e-4, rel=1e-9)


# measured (pc, gauss-seidel order 2, the suite's 20 s, tol 1e-2, one run): err/tol 7.57,
# estimate/err 0.58 (0.433 before the local estimate took the corrector's sign; the plain sum of
# the local estimates: 0.056); Van der Pol at 1e-3: 5.34, 0.29 (0.130)
def test_the_brusselator_knows_its_phase_error() -> None:
    problem = suite.get("brusselator")
    system, reference = problem.build()
    controller = cs.make_controller("pc", None, 1e-2)
    result = cs.simulate(system, problem.until, controller, cs.MasterOptions("gauss-seidel", 2),
                         reference=reference, tighten=False)
    err = result.error.max_scaled
    assert controller.summed_estimate / err < 0.2  # what the plain sum said
    assert 0.2 <= result.error_estimate / err <= 5.0


def _controller_fed(errors: list[float], name: str = "pc", **options):
    """A controller at tol 1e-3 over 10 s fed accepted steps of 0.1 s by hand: one output
    moving at speed 0.1 for 1 s, then at 10 (the shift met at the fast stretch)."""
    controller = cs.make_controller(name, None, TOL, **options)
    controller.initial_step(0.0, 10.0)
    for i, e in enumerate(errors):
        t = 0.1 * i
        y = 0.1 * (t + 0.1) if t < 1.0 - 1e-12 else 0.1 + 10.0 * (t + 0.1 - 1.0)
        controller._account(np.array([e]), np.array([y]), t, 0.1, None)
    return controller


def test_the_control_tightens_once_its_own_estimate_exceeds_the_tolerance() -> None:
    """While the estimate stays within ``tol`` nothing changes; past it, each ratio is
    multiplied by the estimate over the plain sum (what the time shift made of the sum)."""
    within = _controller_fed([1e-5] * 10, overrun=True)
    assert within.error_estimate < TOL and within.policy.propagation == 1.0
    over = _controller_fed([1e-4] * 10 + [0.0] * 2, overrun=True)
    assert over.error_estimate > TOL
    assert over.policy.propagation == pytest.approx(
        over.error_estimate / over.summed_estimate, rel=1e-12)
    assert over.policy.propagation > 2.0
    assert _controller_fed([1e-4] * 10 + [0.0] * 2).policy.propagation == 1.0  # opt-in


@pytest.mark.parametrize("name, options", [
    ("corrector", {}),  # its estimate is the discarded predictor's error: 50-100x the kept's
    ("embedded", {}),
    ("pc", {"global_error": False}),  # tol bounds each step there, not the run
    ("pc", {"feedback": True}),  # the companion's measure takes precedence
])
def test_only_pc_with_a_global_target_and_no_companion_tightens_on_its_estimate(
        name, options) -> None:
    fed = _controller_fed([1e-4] * 10 + [0.0] * 2, name, overrun=True, **options)
    assert fed.error_estimate > TOL and fed.policy.propagation == 1.0


def test_adaptive_tol_starts_each_run_at_the_run_s_tolerance() -> None:
    """`adaptive-tol` moves its inner controller's tol every step; the gate reads the run's
    tol, and a reused controller starts from it, not from the last run's last value."""
    controller = cs.make_controller("adaptive-tol", None, TOL, overrun=True)
    controller._inner.policy.tol = 0.3 * TOL
    controller.initial_step(0.0, 10.0)
    assert controller._inner.policy.tol == TOL and controller._inner._budget == TOL


# measured (pc, gauss-seidel order 2, the suite's 12 s): without the tightening 29.4 x tol in
# 604 calls, estimate 6.25 x tol (15.2 x in 708 calls without catching up: the probes misread
# the limit cycle's memory as short, StepPolicy.catch_up); with it, which turns catching up
# off, 4.58 x tol in 980 calls (6.96 x in 848 before the local estimate took the corrector's
# sign; one run each: the repeat of a run past its tolerance, which
# would act on the first, is off)
def test_van_der_pol_stays_within_ten_times_the_tolerance_by_its_own_estimate() -> None:
    problem = suite.get("van_der_pol")
    tol, runs = 1e-4, {}
    for overrun in (False, True):
        system, reference = problem.build()
        runs[overrun] = cs.simulate(system, problem.until,
                                    cs.make_controller("pc", None, tol, overrun=overrun),
                                    cs.MasterOptions("gauss-seidel", 2), reference=reference,
                                    tighten=False)
    assert runs[False].error.max_scaled / tol > 10.0  # what it is for
    assert runs[False].error_estimate > tol  # and what the run knew, and said:
    assert runs[False].status == "ok" and runs[False].message == (
        f"completed; its own error estimate is {runs[False].error_estimate / tol:.3g} x tol "
        "(tighten tol, or check against a reference)")
    assert 0.1 <= runs[True].error.max_scaled / tol <= 10.0
    assert runs[True].calls_total > runs[False].calls_total


def test_a_run_within_its_own_estimate_says_completed_alone() -> None:
    problem = suite.get("linear_fast_slow")  # estimate 0.38 x tol at 1e-3 (suite table)
    system, _ = problem.build()
    result = cs.simulate(system, problem.until, cs.make_controller("pc", None, 1e-3),
                         cs.MasterOptions("gauss-seidel", 2))
    assert 0.0 < result.error_estimate < 1e-3 and result.message == "completed"


def test_the_oregonator_s_phase_error_is_seen_with_the_corrector_s_signs() -> None:
    """The holdout's two-variable Oregonator at tol 1e-3: the first run delivers 707 x tol,
    the error made on the long steps of its quiet phase and met at the spikes as a phase error.
    With every input ratio positive its estimate was 0.024 x the error (17 x tol) and the
    repeat at that tighter tolerance delivered 11.7 x; with each receiver's sign
    (docs/concepts.md, "The sign of the corrector's input error") 0.089 x (63 x tol), and the
    repeat 3.45 x tol in 2,716 calls in all."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
    import holdout

    tol = 1e-3
    system, reference = holdout.oregonator()
    result = cs.simulate(system, 20.0, cs.make_controller("pc", None, tol),
                         cs.MasterOptions("gauss-seidel", 2), reference=reference)
    assert result.success, result.message
    first = result.tightened
    assert first is not None and first["run"] == "first"  # the repeat is the result
    assert first["error_estimate"] / tol > 50.0
    assert 0.1 <= result.error.max_scaled / tol <= 10.0

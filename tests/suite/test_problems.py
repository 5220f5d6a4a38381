"""The benchmark suite: every problem converges to its reference; exact solutions; events."""

from __future__ import annotations

import numpy as np
import pytest

import cosimstep as cs
from cosimstep import suite
from cosimstep.suite.rates import kpr_exact

# problem: (horizon, n steps, measured max_scaled at n, measured at 2n, smallest ratio accepted)
# Gauss-Seidel with quadratic extrapolation, Fixed(horizon / n) and Fixed(horizon / 2n).
CONVERGENCE = {
    "pendulum_mixed": (2.0, 200, 5.19e-5, 5.79e-6, 6.0),            # ratio 8.96
    "linear_fast_slow": (0.5, 200, 4.96e-6, 6.02e-7, 6.0),          # ratio 8.24
    "two_mass_stiff": (2.0, 400, 6.49e-4, 7.57e-5, 6.0),            # ratio 8.58
    "two_mass_damped": (2.0, 400, 4.41e-5, 6.10e-6, 6.0),           # ratio 7.22
    # h = 2e-5 and 1e-5 s: steps below ε = 1e-4 s resolve the boundary layer (steps above
    # ε give an O(h) error from the first step, see the problem's docstring)
    "boundary_layer": (0.01, 500, 6.51e-7, 8.72e-8, 6.0),           # ratio 7.47
    "kpr_separated": (0.5, 100, 4.65e-6, 5.92e-7, 6.0),             # ratio 7.86
    "kpr_chirp": (0.5, 100, 4.66e-6, 5.92e-7, 6.0),                 # ratio 7.87
    "kpr_forced": (0.5, 100, 6.01e-4, 7.47e-5, 6.0),                # ratio 8.04
    "quarter_car_announced": (1.5, 400, 8.78e-4, 1.09e-4, 6.0),     # ratio 8.02
    # the unannounced road step: a step straddling the jump costs one order (ratio 4.09)
    "quarter_car_unannounced": (1.5, 400, 2.72e-3, 6.64e-4, 3.0),
    "duplicated_state": (2.0, 200, 1.11e-3, 1.34e-4, 6.0),          # ratio 8.31
    "pendulum_strongly_mixed": (1.0, 200, 1.40e-5, 1.82e-6, 6.0),   # ratio 7.70
    "triple_pendulum": (1.0, 100, 6.15e-5, 7.02e-6, 6.0),           # ratio 8.77
    "linear_lambda1000": (0.1, 200, 1.84e-6, 2.35e-7, 6.0),        # ratio 7.83
    "van_der_pol": (2.0, 100, 3.12e-6, 4.16e-7, 6.0),              # ratio 7.50
    "brusselator": (2.0, 100, 8.02e-6, 1.08e-6, 6.0),              # ratio 7.42
}


def test_registry_order_and_lookup() -> None:
    assert list(suite.PROBLEMS)[:2] == ["pendulum_mixed", "linear_fast_slow"]
    assert len(suite.PROBLEMS) == 16
    assert set(CONVERGENCE) == set(suite.PROBLEMS)
    assert suite.get("kpr_chirp") is suite.PROBLEMS["kpr_chirp"]
    with pytest.raises(KeyError, match="known: pendulum_mixed, linear_fast_slow"):
        suite.get("nope")


@pytest.mark.parametrize("name", list(suite.PROBLEMS))
def test_problem_is_well_formed(name: str) -> None:
    problem = suite.get(name)
    assert problem.name == name and problem.source and problem.classes
    assert 0 < problem.quick_until < problem.until
    system, reference = problem.build()
    assert system.problems() == []
    outputs = [f"{m}.{p.name}" for m, model in system.models.items() for p in model.outputs]
    assert sorted(reference.mapping) == sorted(outputs)  # every exchanged state is mapped
    states = {p.name for p in reference.model.state_ports}
    assert set(reference.mapping.values()) == states
    again, _ = problem.build()
    assert all(again.models[m] is not system.models[m] for m in system.models)  # fresh


@pytest.mark.parametrize("name", list(suite.PROBLEMS))
def test_fixed_step_converges_to_reference(name: str) -> None:
    until, n, first, second, ratio = CONVERGENCE[name]
    errors = []
    for steps in (n, 2 * n):
        system, reference = suite.get(name).build()
        result = cs.simulate(system, until, cs.Fixed(until / steps),
                             cs.MasterOptions("gauss-seidel", 2), reference=reference)
        assert result.status == "ok", result.message
        errors.append(result.error.max_scaled)
    assert errors[0] < 1.5 * first and errors[1] < 1.5 * second, errors
    assert errors[0] / errors[1] > ratio, errors


@pytest.mark.parametrize("chirp", [False, True])
def test_kpr_reference_matches_exact_solution(chirp: bool) -> None:
    problem = suite.get("kpr_chirp" if chirp else "kpr_separated")
    _, reference = problem.build()
    reference.solve(0.0, problem.until)
    times = np.linspace(0.0, problem.until, 2001)
    got = reference.values(times, ["fast.u", "slow.v"])
    # measured max deviation: 6.2e-11 (constant ω) and 5.9e-11 (chirp)
    assert np.max(np.abs(got - kpr_exact(times, chirp, problem.until))) < 1e-9


def test_kpr_forced_reference_matches_exact_solution() -> None:
    problem = suite.get("kpr_forced")
    _, reference = problem.build()
    reference.solve(0.0, problem.until)
    times = np.linspace(0.0, problem.until, 2001)
    got = reference.values(times, ["fast.u", "slow.v", "source.p", "source.q", "fast.w"])
    exact = np.column_stack([kpr_exact(times), np.cos(100.0 * times), np.sin(100.0 * times),
                             np.zeros_like(times)])
    # measured max deviation 1.3e-10 (the forcing's phase), w within 1.6e-12 of 0
    assert np.max(np.abs(got - exact)) < 1e-9


def test_quarter_car_announced_and_unannounced() -> None:
    announced, ref_a = suite.get("quarter_car_announced").build()
    hidden, ref_h = suite.get("quarter_car_unannounced").build()
    assert tuple(announced.models["wheel"].time_events()) == (1.0,)
    assert tuple(hidden.models["wheel"].time_events()) == ()
    assert hidden.models["wheel"].breakpoints(0.5, 1.5) == [1.0]  # still integrates piecewise
    times = np.linspace(0.0, 3.0, 301)
    names = ["chassis.x", "chassis.v", "wheel.x", "wheel.v"]
    for ref in (ref_a, ref_h):
        ref.solve(0.0, 3.0)
    np.testing.assert_array_equal(ref_a.values(times, names), ref_h.values(times, names))
    assert ref_a.values(np.array([3.0]), ["chassis.x"])[0, 0] == pytest.approx(0.05, abs=5e-3)

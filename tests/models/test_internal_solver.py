"""The ODE adapter's adaptive internal solver keeps what it learnt across communication steps.

A stiff Van der Pol oscillator (μ = 1000) as one sub-model, driven by a slow lag it drives
back, 1,000 s in communication steps of 1 s. Measured: Radau with finite differences spent
90,286 right-hand-side evaluations when every step started SciPy afresh (its step size
re-estimated and regrown, the Jacobian rebuilt), 41,609 when each step starts from the last
step size and Jacobian, 36,364 with the analytic Jacobian; the states agree to 3e-8.
"""

from __future__ import annotations

import numpy as np
import pytest

from cosimstep import Fixed, MasterOptions, OdeSubModel, Port, SolveIvp, System, simulate
from cosimstep.adapters.ode import make_solver

MU = 1000.0


def vdp(t: float, x: np.ndarray, u: np.ndarray, p: object) -> np.ndarray:
    return np.array([x[1], MU * (1.0 - x[0] ** 2) * x[1] - x[0] + u[0]])


def vdp_jacobian(t: float, x: np.ndarray, u: np.ndarray, p: object) -> np.ndarray:
    return np.array([[0.0, 1.0], [-2.0 * MU * x[0] * x[1] - 1.0, MU * (1.0 - x[0] ** 2)]])


class Counted:
    def __init__(self) -> None:
        self.calls = 0

    def __call__(self, t: float, x: np.ndarray, u: np.ndarray, p: object) -> np.ndarray:
        self.calls += 1
        return vdp(t, x, u, p)


def run(solver: SolveIvp, jac: bool = False, until: float = 300.0) -> tuple[object, int]:
    rhs = Counted()
    system = System()
    system.add("vdp", OdeSubModel(rhs, [Port("x", "1", 2.0), Port("v", "1", 0.0)],
                                  inputs=[Port("w", "1", 0.0)], solver=solver,
                                  jac=vdp_jacobian if jac else None))
    system.add("slow", OdeSubModel(lambda t, x, u, p: np.array([-0.1 * x[0] + 0.01 * u[0]]),
                                   [Port("w", "1", 1.0)], inputs=[Port("x", "1", 2.0)],
                                   solver=SolveIvp("RK45", rtol=1e-8, atol=1e-10)))
    system.connect("vdp.x", "slow.x").connect("slow.w", "vdp.w")
    result = simulate(system, until, Fixed(1.0), MasterOptions("gauss-seidel", 2))
    assert result.success, result.message
    return result, rhs.calls


@pytest.mark.parametrize("method", ["Radau", "BDF"])
def test_a_stiff_partition_keeps_its_step_and_jacobian(method: str) -> None:
    fresh, fresh_calls = run(SolveIvp(method, rtol=1e-6, atol=1e-8, carry=False))
    kept, kept_calls = run(SolveIvp(method, rtol=1e-6, atol=1e-8))
    exact, exact_calls = run(SolveIvp(method, rtol=1e-6, atol=1e-8), jac=True)
    assert kept_calls < 0.7 * fresh_calls and exact_calls < kept_calls
    for result in (kept, exact):
        assert np.max(np.abs(result.values - fresh.values)) < 1e-3  # rtol 1e-6 of |v| ~ 1e3


def test_a_second_run_of_the_same_system_repeats_the_first() -> None:
    """What the internal solver learnt belongs to its run: a second ``simulate`` of the same
    system objects starts from nothing learnt, as the first did (it started from the first
    run's last step size and Jacobian, and its numbers differed)."""
    rhs = Counted()
    system = System()
    system.add("vdp", OdeSubModel(rhs, [Port("x", "1", 2.0), Port("v", "1", 0.0)],
                                  inputs=[Port("w", "1", 0.0)],
                                  solver=SolveIvp("Radau", rtol=1e-6, atol=1e-8)))
    system.add("slow", OdeSubModel(lambda t, x, u, p: np.array([-0.1 * x[0] + 0.01 * u[0]]),
                                   [Port("w", "1", 1.0)], inputs=[Port("x", "1", 2.0)]))
    system.connect("vdp.x", "slow.x").connect("slow.w", "vdp.w")
    first = simulate(system, 20.0, Fixed(1.0), MasterOptions("gauss-seidel", 2))
    calls = rhs.calls
    second = simulate(system, 20.0, Fixed(1.0), MasterOptions("gauss-seidel", 2))
    assert first.success and second.success
    assert rhs.calls == 2 * calls
    assert np.array_equal(first.values, second.values)


def test_each_sub_model_has_its_own_memory_and_the_options_reach_scipy() -> None:
    shared = SolveIvp("RK45", rtol=1e-6, atol=1e-8, first_step=1e-3, max_step=0.05)
    a = OdeSubModel(vdp, [Port("x", "1", 2.0), Port("v", "1", 0.0)],
                    inputs=[Port("w", "1", 0.0)], solver=shared)
    b = OdeSubModel(vdp, [Port("x", "1", 2.0), Port("v", "1", 0.0)],
                    inputs=[Port("w", "1", 0.0)], solver=shared)
    assert a.solver is not b.solver and a.solver == shared
    steps: list[float] = []
    a.solver.advance(lambda t, x: (steps.append(t), np.array([1.0]))[1], 0.0, 1.0,
                     np.zeros(1))
    # the first step is 1e-3 (its stages inside it), and no step exceeds max_step
    times = np.unique(steps)
    assert 0.0 < times[1] <= 1e-3 and np.max(np.diff(times)) <= 0.05 + 1e-12
    assert a.solver._step == pytest.approx(0.05) and b.solver._step is None
    assert make_solver({"method": "radau"}).method == "Radau"
    with pytest.raises(ValueError, match="unknown solver method 'euler'"):
        make_solver({"method": "euler"})


def test_a_configured_solver_names_every_bad_option() -> None:
    """A negative step count or local step once ran and returned an order-one error."""
    with pytest.raises(ValueError) as bad:
        make_solver({"method": "rk4", "substeps": 0, "max_dt": -0.05})
    assert str(bad.value) == ("rk4: 'substeps' must be a whole number >= 1, got 0; 'max_dt' "
                              "must be a positive number, got -0.05")
    with pytest.raises(ValueError) as bad:
        make_solver({"method": "radau", "rtol": float("inf"), "carry": "yes", "jac": 1})
    assert str(bad.value) == ("Radau: 'rtol' must be a positive number, got inf; 'carry' must "
                              "be true or false; no option 'jac' (its options: rtol, atol, "
                              "first_step, max_step, carry)")
    assert make_solver({"method": "rk4", "max_dt": 1e-3}).max_dt == 1e-3
    assert make_solver({"method": "BDF", "max_step": float("inf")}).method == "BDF"


def test_numpy_numbers_and_defaults_pass_the_checks() -> None:
    """The checks refuse wrong values, not NumPy's numbers or an explicit default."""
    from cosimstep.controllers import Fixed, make_controller

    assert make_solver({"method": "rk4", "substeps": np.int64(4), "max_dt": None}).substeps == 4
    assert make_solver({"method": "rk4", "substeps": 2.0}).substeps == 2
    assert make_solver({"method": "RK45", "rtol": np.float32(1e-6), "first_step": None}).rtol
    assert Fixed(np.float32(0.01)).step == pytest.approx(0.01)
    pc = make_controller("pc", None, 1e-4, hmax=np.int64(1), predictive=np.bool_(True))
    assert pc.policy.hmax == 1

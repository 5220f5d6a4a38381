"""What the results store records as a controller's settings."""

from __future__ import annotations

import json

import pytest

import cosimstep as cs
from cosimstep import suite
from cosimstep.controllers import make_controller
from cosimstep.store import read_run


@pytest.mark.parametrize("name", ["pc", "corrector", "switching", "adaptive-tol"])
def test_a_controller_used_again_records_its_settings_not_the_last_run(name, tmp_path) -> None:
    # a run leaves what it measured in the controller (pc's error memory, every policy
    # controller's error estimate, switching's count); a second run's record once showed them
    # as that run's settings
    controller = make_controller(name, None, 1e-3)
    before = controller.describe()
    problem = suite.get("two_mass_damped")
    system, _ = problem.build()
    first = cs.simulate(system, problem.until, controller, cs.MasterOptions("gauss-seidel", 2))
    assert first.success
    if name == "pc":
        assert controller.policy.memory < problem.until  # the run measured a memory
    assert controller.describe() == before
    system, _ = problem.build()
    store = tmp_path / "again.db"
    cs.simulate(system, problem.until, controller, cs.MasterOptions("gauss-seidel", 2),
                store=store)
    recorded = read_run(store).config["controller"]
    assert recorded == json.loads(json.dumps(before, default=str))
    assert "error_estimate" not in recorded and "switches" not in recorded
    if "policy" in recorded:
        policy = recorded["policy"]
        assert "memory" not in policy and policy["tol"] == 1e-3 and policy["overrun"] is False


@pytest.mark.parametrize("name", ["switching", "adaptive-tol"])
def test_a_wrapping_controller_records_the_options_of_the_one_it_wraps(name) -> None:
    # `--opt overrun=true` goes to the wrapped pc: two runs that differ only there once
    # recorded the same settings, and a resume could not tell them apart
    plain = make_controller(name, None, 1e-3).describe()
    gated = make_controller(name, None, 1e-3, overrun=True).describe()
    assert plain != gated
    assert gated["inner_settings"]["policy"]["overrun"] is True
    assert plain["inner_settings"]["policy"]["tol"] == 1e-3

"""A sub-model that handles its own events (the bouncing ball, problem 8): its discrete output
changes inside a step, and the master lands a point on the change."""

from __future__ import annotations

import numpy as np
import pytest

import cosimstep as cs
from cosimstep.models import bouncing


@pytest.fixture(scope="module")
def spec(examples):
    return cs.load_system(examples / "bouncing_ball_events.toml")


def _exact(spec) -> list[float]:
    return [t for t, _ in bouncing.contacts(bouncing.default_parameters(), 1.0, 0.0, 0.0,
                                            spec.until)]


def test_the_ball_is_exact_whatever_its_steps():
    p = bouncing.default_parameters()
    one, many = bouncing.BouncingBall(p), bouncing.BouncingBall(p)
    one.initialize(0.0)
    many.initialize(0.0)
    one.do_step(0.0, 2.0)  # four contacts inside one step
    for i in range(300):
        many.do_step(i / 150, 1 / 150)
    assert np.allclose(one.get_outputs(), many.get_outputs(), rtol=0, atol=1e-11)
    impulse = sum(p["m"] * (1 + p["e"]) * s for _, s in bouncing.contacts(p, 1, 0, 0, 2))
    assert one.get_outputs()[2] == pytest.approx(impulse, rel=1e-14)


def test_contacts_are_located_to_the_analytic_times(spec):
    result = cs.simulate(spec.system, spec.until, cs.make_controller("pc", None, 1e-6),
                         cs.MasterOptions("gauss-seidel", 2), reference=spec.reference)
    assert result.success, result.message
    exact = _exact(spec)
    assert len(exact) == 4
    assert [(e.source, e.kind, e.late) for e in result.events] == [("ball", "change", False)] * 4
    times = np.array([e.t for e in result.events])
    # measured: 6.4e-13 relative (the location tolerance is 1e-12 s); the issue asks 1e-8
    assert np.max(np.abs(times - exact) / exact) < 1e-8
    assert set(times) <= set(result.times)  # a communication point on every contact
    # measured 1.5e-7 (the damper's own RK4); 392 calls, 352 of them locating the contacts
    assert result.error.max_scaled < 1e-6
    assert sum(result.calls.values()) < 500


def test_a_fixed_step_gets_each_contact_at_the_next_point_and_says_so(spec):
    result = cs.simulate(spec.system, spec.until, cs.Fixed(0.01),
                         cs.MasterOptions("gauss-seidel", 2), reference=spec.reference)
    assert result.success, result.message
    times = np.array([e.t for e in result.events])
    delay = times - _exact(spec)
    assert all(e.late for e in result.events)
    assert np.all((delay >= 0) & (delay < 0.01 + 1e-12))
    assert result.error.max_scaled > 1e-3  # measured 0.16: what the late impulse costs


def test_a_discrete_output_is_held_by_its_receivers(spec):
    # one step over the first contact (0.4515 s): the damper must see J = 0 throughout, not a
    # curve drawn towards the new value
    system = spec.system
    runner = cs.masters.Master(system.compile(), cs.MasterOptions("gauss-seidel", 2))
    y0 = runner.initialize(0.0)
    y = runner.step(0.0, 0.5, [0.0], y0[None, :])
    assert y[2] > 0  # the ball hit the ground inside the step
    assert np.all(y[3:] == 0.0)  # the damper never felt it


@pytest.mark.parametrize("resync", ["partial", "complete"])
def test_multirate_lands_each_sub_model_on_the_contacts(spec, resync):
    result = cs.simulate(spec.system, spec.until, cs.make_controller("pc", None, 1e-6),
                         cs.MasterOptions("multirate", 2, resync=resync),
                         reference=spec.reference)
    assert result.success, result.message
    times = np.array([e.t for e in result.events])
    exact = _exact(spec)
    # measured 1.6e-12 relative; 271 ball calls (most of them bisecting), 22 damper calls
    assert len(times) == 4 and np.max(np.abs(times - exact) / exact) < 1e-8
    ball, damper = result.models["ball"], result.models["damper"]
    for t in times:  # the ball keeps both sides of each jump; the damper lands on it
        i = np.flatnonzero(ball.times == t)
        assert len(i) == 2 and ball.values[i[1], 2] > ball.values[i[0], 2]
        assert t in damper.times
    assert result.error.max_scaled < 1e-6  # measured 1.9e-7


def test_partial_resync_leaves_the_branch_the_contacts_do_not_reach(examples):
    spec = cs.load_system(examples / "two_branches_events.toml")
    runs = {mode: cs.simulate(spec.system, spec.until, cs.make_controller("pc", None, 1e-4),
                              cs.MasterOptions("multirate", 2, resync=mode),
                              reference=spec.reference)
            for mode in ("partial", "complete")}
    for result in runs.values():
        assert result.success, result.message
        assert len(result.events) == 4
        assert result.error.max_scaled < 1e-6  # branch 1; measured 3.2e-10 in both
    partial, complete = runs["partial"].calls, runs["complete"].calls
    # the contacts reach the damper only: branch 1 runs the same either way
    assert (partial["ball"], partial["damper"]) == (complete["ball"], complete["damper"])
    # branch 2 goes back to every contact it ran past only under complete re-synchronization
    # (measured 46 against 79 calls), and lands on none of them under partial
    branch2 = ("pump", "coolant", "load")
    assert sum(partial[n] for n in branch2) < 0.8 * sum(complete[n] for n in branch2)
    contacts = [e.t for e in runs["partial"].events]
    for n in branch2:
        assert not set(contacts) & set(runs["partial"].models[n].times)
        assert set(contacts) <= set(runs["complete"].models[n].times)


def test_a_fixed_step_that_locates_events_lands_on_each_contact(spec):
    late = cs.simulate(spec.system, spec.until, cs.Fixed(0.01),
                       cs.MasterOptions("gauss-seidel", 2), reference=spec.reference)
    result = cs.simulate(spec.system, spec.until, cs.Fixed(0.01, locate_events=True),
                         cs.MasterOptions("gauss-seidel", 2), reference=spec.reference)
    assert result.success, result.message
    times = np.array([e.t for e in result.events])
    assert not any(e.late for e in result.events)
    assert np.max(np.abs(times - _exact(spec))) < 1e-9
    # the late impulse's error gone, for the calls that locate four contacts to 1e-12 s
    # (measured 682 calls against 400)
    assert result.error.max_scaled < 1e-2 * late.error.max_scaled
    assert result.calls_total < 2 * late.calls_total

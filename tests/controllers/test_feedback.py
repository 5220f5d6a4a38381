"""The step control tightened by the growth the run's own companion measures
(``StepPolicy.feedback``, opt-in): docs/concepts.md, "Limit cycles"."""

from __future__ import annotations

import pytest
from click.testing import CliRunner

import cosimstep as cs
from cosimstep import suite
from cosimstep.cli import main


def _van_der_pol(tol: float, feedback: bool, overrun: bool = False) -> cs.SimulationResult:
    problem = suite.get("van_der_pol")
    system, reference = problem.build()
    return cs.simulate(system, problem.until, cs.make_controller("pc", None, tol,
                                                                 feedback=feedback,
                                                                 overrun=overrun),
                       cs.MasterOptions("gauss-seidel", 2), reference=reference,
                       estimate="richardson", tighten=False)


def test_feedback_keeps_the_van_der_pol_oscillator_within_the_tolerance() -> None:
    """The summed local estimates miss the phase error that every jump of the cycle
    multiplies by its slope; the companion sees it. Measured at tol 1e-4: 14.7 x tol and 692
    calls without the feedback, 4.64 x tol and 1052 calls (+404 the companion's) with it.
    (``overrun``, opt-in, tightens the control by the run's own estimate instead; off here,
    and so is the repeat of a run past its tolerance, so that the plain run is the one
    feedback is for.)"""
    tol = 1e-4
    plain, tightened = _van_der_pol(tol, False), _van_der_pol(tol, True)
    assert plain.error.max_scaled / tol > 10.0  # the failure the option is for
    assert 0.1 <= tightened.error.max_scaled / tol <= 10.0
    assert tightened.calls_total > plain.calls_total


def test_feedback_needs_the_companion(examples) -> None:
    problem = suite.get("van_der_pol")
    system, _ = problem.build()
    with pytest.raises(ValueError, match="feedback reads the companion"):
        cs.simulate(system, 1.0, cs.make_controller("pc", None, 1e-3, feedback=True))
    res = CliRunner().invoke(main, ["run", str(examples / "double_pendulum_mixed.toml"),
                                    "--tol", "1e-3", "--opt", "feedback=true", "--json"])
    assert res.exit_code == 2 and "--estimate richardson" in res.output

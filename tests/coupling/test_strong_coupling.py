"""Strong coupling (issue 18): every communication step repeated from the saved states until
the exchanged values agree, with plain fixed-point passes, Aitken relaxation or IQN-ILS.

Measured on the two-mass oscillator of the suite with a coupling spring 10x stiffer than the
masses' own (kc = 100 N/m), Gauss-Seidel, quadratic interpolation, fixed step 0.05 s for 5 s:
explicit coupling is off by 1.01 m; every iterative scheme converges to the same step result
(the three agree to 4e-10) with error 0.27 m, at 4.98 (fixed point), 6.53 (Aitken) and 2.04
(IQN-ILS) passes per step.
"""

from __future__ import annotations

import numpy as np
import pytest

import cosimstep
from cosimstep.controllers import make_controller
from cosimstep.iteration import CouplingError
from cosimstep.suite.mechanical import two_mass

STIFF = {"m1": 1.0, "m2": 1.0, "k1": 10.0, "k2": 10.0, "c1": 0.1, "c2": 0.1, "kc": 100.0,
         "dc": 0.5}


def run(coupling: str, h: float = 0.05, **options: object) -> cosimstep.SimulationResult:
    system, reference = two_mass(STIFF, max_dt=1e-3)
    master = cosimstep.MasterOptions("gauss-seidel", 2, coupling=coupling,
                                     coupling_tol=options.pop("coupling_tol", 1e-10),
                                     max_iterations=options.pop("max_iterations", 100))
    controller = options.pop("controller", cosimstep.Fixed(h))
    return cosimstep.simulate(system, 5.0, controller, master, reference=reference)


@pytest.fixture(scope="module")
def runs() -> dict[str, cosimstep.SimulationResult]:
    return {c: run(c) for c in ("explicit", "fixed-point", "aitken", "iqn-ils")}


def test_the_iterations_converge_to_one_solution(runs: dict) -> None:
    explicit = runs["explicit"]
    assert explicit.coupling is None and explicit.calls_total == 200
    for name in ("fixed-point", "aitken", "iqn-ils"):
        r = runs[name]
        assert r.success, r.message
        assert np.max(np.abs(r.values - runs["iqn-ils"].values)) < 1e-8
        # every pass calls both masses once: the calls are the passes
        assert r.calls_total == 2 * r.coupling["iterations"]
        assert r.coupling["steps"] == 100 and r.coupling["residual_max"] <= 1e-10
    assert runs["iqn-ils"].error.max_abs < 0.3 < 1.0 < explicit.error.max_abs
    per_step = {n: runs[n].coupling["iterations_per_step"] for n in ("fixed-point", "iqn-ils")}
    assert per_step["iqn-ils"] < 2.5 < 4.0 < per_step["fixed-point"]


def test_a_fixed_step_that_does_not_converge_ends_failed_with_the_residual() -> None:
    r = run("fixed-point", h=0.2, max_iterations=3)
    assert r.status == "failed"
    assert "did not converge in 3 passes: residual" in r.message and "mass2" in r.message
    assert len(r.times) == 1 and r.times[0] == 0.0  # the start is kept


def test_an_adaptive_controller_retries_a_step_that_does_not_converge() -> None:
    """pc proposes steps the iteration cannot converge on in 2 passes: each such trial is
    rejected and retried at a quarter of its length, as a failed trial is."""
    r = run("fixed-point", max_iterations=2, controller=make_controller("pc", None, 1e-3))
    assert r.success, r.message
    assert r.steps_rejected > 0 and r.coupling["iterations_max"] <= 2


def test_a_sub_model_without_state_restore_is_refused() -> None:
    system, _ = two_mass(STIFF)
    model = system.models["mass1"]
    model.capabilities = type(model.capabilities)(can_save_state=False)
    with pytest.raises(ValueError, match="'iqn-ils' repeats every step from the saved states, "
                       "but mass1 cannot save and restore its state"):
        cosimstep.simulate(system, 1.0, cosimstep.Fixed(0.1),
                           cosimstep.MasterOptions(coupling="iqn-ils"))


def test_options_are_checked() -> None:
    problems = cosimstep.MasterOptions("multirate", coupling="newton", coupling_tol=0,
                                       max_iterations=0).problems()
    assert any("unknown coupling 'newton'" in p for p in problems)
    assert any("coupling_tol must be a positive number" in p for p in problems)
    assert any("max_iterations must be a whole number >= 1" in p for p in problems)
    assert "not multirate" in " ".join(cosimstep.MasterOptions(
        "multirate", coupling="aitken").problems())
    assert issubclass(CouplingError, cosimstep.SubModelError)


def test_the_command_line_and_the_system_file(tmp_path, examples) -> None:
    """`[master] coupling` in the file, `--coupling` on the command line; `--json` reports the
    passes and the residual."""
    import json

    from click.testing import CliRunner

    from cosimstep.cli import main

    source = (examples / "double_pendulum_slow.toml").read_text()
    text = source.replace("[master]", '[master]\ncoupling = "aitken"\ncoupling_tol = 1e-9', 1)
    assert text != source
    (tmp_path / "s.toml").write_text(text)
    args = ["run", str(tmp_path / "s.toml"), "--controller", "fixed", "--step", "0.05",
            "--until", "1", "--no-store", "--json"]
    out = json.loads(CliRunner().invoke(main, args).output)
    assert out["status"] == "ok" and out["residual_max"] <= 1e-9
    assert out["iterations"]["iterations"] * 2 == out["calls_total"]
    out = json.loads(CliRunner().invoke(main, [*args, "--coupling", "explicit"]).output)
    assert "iterations" not in out and out["calls_total"] == 40
    res = CliRunner().invoke(main, [*args, "--coupling", "iqn-ils", "--max-iterations", "0"])
    assert res.exit_code == 2 and "max_iterations must be a whole number" in res.output


def test_the_trapezoidal_input_is_refused_under_an_error_controlled_controller(examples) -> None:
    """`pc` with the held mean delivered 31-259 x tol with status ok on the stiff two-mass
    example (its step doubling judges inputs of the extrapolation's order): refused, with the
    reason, by `simulate` and by the command line (exit 2); a fixed step takes it."""
    from click.testing import CliRunner

    from cosimstep.cli import main

    master = cosimstep.MasterOptions("gauss-seidel", 1, coupling="iqn-ils",
                                     coupling_input="trapezoidal")
    system, _ = two_mass(STIFF, max_dt=1e-3)
    with pytest.raises(ValueError, match="controller 'pc' cannot keep its tolerance"):
        cosimstep.simulate(system, 1.0, make_controller("pc", None, 1e-3), master)
    assert cosimstep.simulate(system, 1.0, cosimstep.Fixed(0.05), master).success
    res = CliRunner().invoke(main, ["run", str(examples / "stiff_two_mass.toml"), "--tol",
                                    "1e-3", "--coupling-input", "trapezoidal", "--no-store"])
    assert res.exit_code == 2 and "coupling_input" in res.output
    assert "Traceback" not in res.output

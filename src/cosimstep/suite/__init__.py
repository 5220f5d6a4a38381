"""A public benchmark suite of coupled problems for co-simulation masters.

Every :class:`Problem` builds a split system (one sub-model per physical component, states as
outputs, no direct feedthrough) and its monolithic reference, with every exchanged output that
corresponds to a monolithic state mapped (both copies in ``duplicated_state``)::

    import cosimstep as cs
    from cosimstep import suite

    problem = suite.get("kpr_separated")
    system, reference = problem.build()
    result = cs.simulate(system, problem.until, cs.make_controller("pc", None, 1e-4),
                         cs.MasterOptions("gauss-seidel", 2), reference=reference)
    print(result.error.max_scaled)

Sub-models integrate accurately inside each step (RK4 with a small largest step for non-stiff
parts, Radau at rtol 1e-10 for the stiff partition), so what a run's error measures is the
coupling. ``benchmarks/suite.py`` runs every problem at several tolerances.
"""

from __future__ import annotations

from cosimstep.suite import classic, cycles, mechanical, rates
from cosimstep.suite.base import Problem, UnannouncedEvents

__all__ = ["PROBLEMS", "Problem", "UnannouncedEvents", "get"]

_QUARTER_CAR = ("adapted from the quarter-car ride model of T. D. Gillespie (1992), "
                "'Fundamentals of Vehicle Dynamics', SAE International, ch. 5 (our passenger-car "
                "parameters, a 5 cm road step)")

PROBLEMS: dict[str, Problem] = {p.name: p for p in (
    Problem("pendulum_mixed", "double pendulum split by bar, l1 = 1 m, l2 = 0.5 m",
            ("nonlinear", "mixed time scales"),
            f"{classic.THESIS}, section 4.2.1 (double pendulum, mixed case of table 5)",
            10.0, classic.pendulum_mixed, 2.0),
    Problem("linear_fast_slow", "fast oscillator (λ = 100) two-way coupled to a slow lag",
            ("multirate", "linear"),
            "cosimstep benchmark problem 6 (cosimstep.models.linear); a fast oscillator "
            "two-way coupled to a slow lag, the standard multirate situation (cf. C. W. Gear, "
            "D. R. Wells (1984), 'Multirate linear multistep methods', BIT 24:484–502)",
            2.0, classic.linear_fast_slow, 0.5),
    Problem("two_mass_stiff", "two-mass oscillator, coupling spring 10× stiffer than the others",
            ("stiff coupling", "linear"), mechanical.SCHWEIZER,
            10.0, mechanical.two_mass_stiff, 2.0),
    Problem("two_mass_damped", "two-mass oscillator with heavy damping (errors decay)",
            ("damped", "linear"), mechanical.SCHWEIZER,
            10.0, mechanical.two_mass_damped, 2.0),
    Problem("boundary_layer", "singularly perturbed pair (ε = 1e-4) starting off its manifold",
            ("stiff partition", "initial boundary layer", "nonlinear"),
            "adapted from the singular perturbation problems of E. Hairer, G. Wanner (1996), "
            "'Solving Ordinary Differential Equations II: Stiff and Differential-Algebraic "
            "Problems', 2nd ed., Springer, ch. VI (our equations)",
            2.0, rates.boundary_layer, 0.05),
    Problem("kpr_separated", "Kværnø–Prothero–Robinson problem, fast u (ω = 100) / slow v",
            ("multirate", "fast forcing", "singularity", "nonlinear"), rates.KPR_SOURCE,
            5.0, rates.kpr_separated, 0.5),
    Problem("kpr_chirp", "KPR problem with the fast frequency rising from 100 to 200 rad/s",
            ("fast forcing of changing frequency", "multirate", "singularity", "nonlinear"),
            rates.KPR_SOURCE + "; the chirped phase is our change",
            5.0, rates.kpr_chirp, 0.5),
    Problem("kpr_forced", "KPR problem with its forcing from a source sub-model; the slow part "
            "reads the fast residual (separated scales)",
            ("separated scales", "multirate", "fast forcing", "three sub-models", "nonlinear"),
            rates.KPR_SOURCE + "; the forcing as a sub-model of its own and the slow part "
            "reading the fast residual as a state are our split", 5.0, rates.kpr_forced, 0.5),
    Problem("quarter_car_announced", "quarter car, chassis | wheel, 5 cm road step at 1 s "
            "announced", ("discontinuous input", "announced", "linear"), _QUARTER_CAR,
            3.0, mechanical.quarter_car_announced, 1.5),
    Problem("quarter_car_unannounced", "quarter car, chassis | wheel, 5 cm road step at 1 s "
            "not announced", ("discontinuous input", "unannounced", "linear"), _QUARTER_CAR,
            3.0, mechanical.quarter_car_unannounced, 1.5),
    Problem("duplicated_state", "mass–spring–damper and an actuator holding its own copy of "
            "the position", ("duplicated state", "power bond", "linear"),
            "our construction: a force/velocity interface (a power bond, as in S. Sadjina, "
            "L. T. Kyllingstad, S. Skjong, E. Pedersen (2017), 'Energy conservation and power "
            "bonds in co-simulations: non-iterative adaptive step size control and error "
            "estimation', Engineering with Computers 33(3):607–620) where the actuator "
            "re-integrates the position it needs from the velocity it receives",
            10.0, mechanical.duplicated_state, 2.0),
    Problem("pendulum_strongly_mixed", "double pendulum, l2 = 0.05 m, m2 = 0.1 kg",
            ("nonlinear", "mixed time scales", "multirate"),
            f"{classic.THESIS}, section 4.2.1 (double pendulum; the strongly mixed lengths are "
            "cosimstep's benchmark problem 1 variant)", 10.0, classic.pendulum_strongly_mixed,
            1.0),
    Problem("triple_pendulum", "triple pendulum split by bar, m = l = 1, start 10°, −15°, 20°",
            ("nonlinear", "three sub-models"),
            f"{classic.THESIS}, section 4.2.7 and appendix D (triple pendulum base case)",
            10.0, classic.triple_pendulum, 2.0),
    Problem("linear_lambda1000", "problem 6 with λ = 1000 (time-scale ratio 1000)",
            ("multirate", "linear"),
            "cosimstep benchmark problem 9 (the λ = 1000 variant of problem 6)",
            2.0, classic.linear_lambda1000, 0.2),
    Problem("van_der_pol", "Van der Pol oscillator, μ = 3, x | y (relaxation limit cycle)",
            ("limit cycle", "nonlinear", "growing errors"), cycles.VDP_SOURCE,
            12.0, cycles.van_der_pol, 2.0),
    Problem("brusselator", "Brusselator, A = 1, B = 3, x | y (limit cycle with spikes)",
            ("limit cycle", "nonlinear", "growing errors"), cycles.BRUSSELATOR_SOURCE,
            20.0, cycles.brusselator, 2.0),
)}


def get(name: str) -> Problem:
    """The problem called ``name``; a :class:`KeyError` lists the known names otherwise."""
    try:
        return PROBLEMS[name]
    except KeyError:
        raise KeyError(f"no benchmark problem '{name}'; known: {', '.join(PROBLEMS)}") from None

"""Pendulum equations: appendix D, energy conservation, small-angle limit."""

from __future__ import annotations

from math import cos, sin

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from cosimstep.models.pendulum import chain_accelerations

from .appendix_d import ALPHA_DEN, ALPHA_NUM, GAMMA_DEN, GAMMA_NUM


def _params(m, ell, linear=0.0):
    p = {"g": 9.81, "linear": linear}
    for i, (mi, li) in enumerate(zip(m, ell), start=1):
        p[f"m{i}"], p[f"l{i}"] = mi, li
    return p


@pytest.mark.parametrize("seed", range(5))
def test_triple_chain_matches_appendix_d_for_unit_lengths(seed):
    """Appendix D (alpha'' and gamma'') equals the mass-matrix form at any masses, angles and
    velocities when the bars have unit length."""
    rng = np.random.default_rng(seed)
    a, b, gm, ad, bd, gd = rng.uniform(-1.5, 1.5, 6)
    m1, m2, m3 = rng.uniform(0.1, 10, 3)
    env = {"sin": sin, "cos": cos, "a": a, "b": b, "gm": gm, "ad": ad, "bd": bd, "gd": gd,
           "m1": m1, "m2": m2, "m3": m3, "l1": 1.0, "l2": 1.0, "l3": 1.0, "grav": 9.81}
    ours = chain_accelerations(np.array([a, b, gm]), np.array([ad, bd, gd]),
                               _params((m1, m2, m3), (1, 1, 1)), 3)
    assert ours[0] == pytest.approx(eval(ALPHA_NUM, env) / eval(ALPHA_DEN, env), rel=1e-10)
    assert ours[2] == pytest.approx(eval(GAMMA_NUM, env) / eval(GAMMA_DEN, env), rel=1e-10)


def _energy(x, m, ell, g=9.81):
    n = len(m)
    pos, vel, energy = np.zeros(2), np.zeros(2), 0.0
    for i in range(n):
        th, w = x[i], x[n + i]
        pos = pos + ell[i] * np.array([sin(th), -cos(th)])
        vel = vel + ell[i] * w * np.array([cos(th), sin(th)])
        energy += 0.5 * m[i] * vel @ vel + m[i] * g * pos[1]
    return energy


@pytest.mark.parametrize("m, ell", [((1.0, 1.0), (1.0, 0.5)), ((1.0, 0.1), (1.0, 0.05)),
                                    ((1.0, 2.0, 1.5), (0.1, 1.0, 10.0)),
                                    ((100.0, 1.0, 1.0), (1.0, 1.0, 1.0))])
def test_chain_conserves_energy(m, ell):
    """The equations are the Lagrangian ones for any masses and lengths: energy is conserved to
    the integration tolerance (this is what appendix D as printed fails for non-unit lengths)."""
    n = len(m)
    p = _params(m, ell)
    x0 = np.array([0.4, -0.3, 0.2][:n] + [0.0] * n)
    sol = solve_ivp(lambda t, x: np.concatenate([x[n:], chain_accelerations(x[:n], x[n:], p, n)]),
                    (0, 3), x0, method="DOP853", rtol=1e-12, atol=1e-12)
    e0 = _energy(x0, m, ell)
    assert abs(_energy(sol.y[:, -1], m, ell) - e0) < 1e-8 * max(1.0, abs(e0))


def test_small_angle_form_is_the_linearization():
    """At tiny amplitudes the linear and nonlinear accelerations agree to second order."""
    theta, omega = np.array([1e-4, -2e-4]), np.array([1e-4, 3e-4])
    lin = chain_accelerations(theta, omega, _params((1, 1), (1, 0.5), 1.0), 2)
    non = chain_accelerations(theta, omega, _params((1, 1), (1, 0.5), 0.0), 2)
    # relative difference of the order of the squared amplitude (1e-8), far below first order
    assert np.max(np.abs(lin - non)) < 1e-5 * np.max(np.abs(lin))


def test_a_jump_written_as_a_function_of_time_is_integrated_on_its_own_side() -> None:
    # x' = [t >= 1]: the last RK4 stage of a step ending at the announced event t = 1 must see
    # the value before the jump (measured 1.7e-3 instead of 0 without keeping stages on their
    # piece's side)
    import numpy as np

    from cosimstep import RK4, OdeSubModel, Port, Reference

    def rhs(t, x, u, p):
        return np.array([1.0 if t >= 1.0 else 0.0])

    model = OdeSubModel(rhs, [Port("x", "1", 0.0)], solver=RK4(max_dt=0.01), time_events=[1.0])
    assert model.time_events() == (1.0,)
    model.initialize(0.0)
    model.do_step(0.0, 1.0)
    assert model.get_outputs()[0] == 0.0
    model.do_step(1.0, 0.5)
    assert abs(model.get_outputs()[0] - 0.5) < 1e-14
    straddle = OdeSubModel(rhs, [Port("x", "1", 0.0)], solver=RK4(max_dt=0.01),
                           time_events=[1.0])
    straddle.initialize(0.0)
    straddle.do_step(0.0, 1.5)  # a step across the event is integrated piecewise
    assert abs(straddle.get_outputs()[0] - 0.5) < 1e-14
    reference = Reference(OdeSubModel(rhs, [Port("x", "1", 0.0)], time_events=[1.0]),
                          {"m.x": "x"})
    reference.solve(0.0, 2.0)
    values = reference.values(np.array([1.0, 2.0]), ["m.x"])[:, 0]
    assert abs(values[0]) < 1e-12 and abs(values[1] - 1.0) < 1e-12

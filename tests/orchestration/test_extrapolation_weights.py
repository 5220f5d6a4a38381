"""Input extrapolation's Lagrange weights: the written-out one- to five-point forms give
the very same floats (sign of zero included) as the general loop, on communication times like the
masters' (fixed steps, compensated sums, Gauss-Seidel's t + h) and on random ones."""

from __future__ import annotations

import random

from cosimstep.extrapolation import _weights, _weights_loop


def _bits(weights: list[list[float]]) -> list[list[str]]:
    return [[w.hex() for w in row] for row in weights]


def test_written_out_weights_equal_the_loop_bit_for_bit() -> None:
    rng = random.Random(5)
    cases = []
    for h in (1e-3, 0.0123, 0.5, 3e-7):
        for n in (0, 1, 2, 7, 1000, 123456):
            t = n * h
            times = [t - 2 * h, t - h, t, t + h]
            cases += [[ti - t for ti in [t - 3 * h, *times]],  # pc's quartic through t + h
                      [ti - t for ti in times],  # the corrector's cubic through t + h
                      [ti - t for ti in times[:3]],  # Jacobi at order 2: last three points
                      [ti - t for ti in (times[1], times[2], times[3])],  # Gauss-Seidel
                      [ti - t for ti in times[1:3]], [ti - t for ti in times[2:4]],
                      [ti - t for ti in times[2:3]]]
    for _ in range(3000):
        n = rng.choice((1, 2, 3, 4, 5))
        scale = 10.0 ** rng.uniform(-9, 3)
        cases.append([rng.uniform(-1, 1) * scale for _ in range(n)])
    cases += [[-0.0, 1.0, 2.0], [0.0, -1.0, -2.0], [-2.0, -1.0, 0.0], [1.0, -0.0],
              [-0.0, 1.0, 2.0, 3.0], [-3.0, -2.0, -1.0, 0.0], [-0.0, 1.0, 2.0, 3.0, 4.0],
              [-4.0, -3.0, -2.0, -1.0, 0.0]]
    for s in cases:
        assert _bits(_weights(s)) == _bits(_weights_loop(s)), s


def test_midstep_weights_are_the_general_steps_mid_step_value() -> None:
    """On uniform steps the lean loop's fixed weights give what Taylor coefficients from the
    stored points, evaluated at mid-step, give (Jacobi: last p + 1 points; Gauss-Seidel: last p
    points and the one at t + h)."""
    import numpy as np

    from cosimstep.extrapolation import evaluate, midstep_weights, taylor_coefficients

    rng = np.random.default_rng(3)
    h, t = 0.25, 2.0
    for p in (0, 1, 2):
        for through_end in (False, True):
            first = 1 - p if through_end else -p
            times = [t + h * i for i in range(first, first + p + 1)]
            values = rng.normal(size=(p + 1, 3))
            expected = evaluate(taylor_coefficients(times, values, t, p), 0.5 * h)
            w = midstep_weights(p, through_end)
            assert abs(sum(w) - 1.0) == 0.0
            assert np.allclose(np.array(w) @ values, expected, rtol=0, atol=1e-14)
    assert midstep_weights(2) == [0.375, -1.25, 1.875]
    assert midstep_weights(2, True) == [-0.125, 0.75, 0.375]


def test_step_derivative_weights_are_the_general_steps_derivatives() -> None:
    """On uniform steps of h the lean loop's fixed weights, divided by h**k, give derivative k at
    t of the polynomial through the stored points — rows 1 ... p of the general step's Taylor
    coefficients, which a sub-model taking input derivatives receives."""
    import numpy as np

    from cosimstep.extrapolation import step_derivative_weights, taylor_coefficients

    rng = np.random.default_rng(4)
    h, t = 0.25, 2.0
    for p in (1, 2):
        for through_end in (False, True):
            first = 1 - p if through_end else -p
            times = [t + h * i for i in range(first, first + p + 1)]
            values = rng.normal(size=(p + 1, 3))
            expected = taylor_coefficients(times, values, t, p)[1:]
            w = np.array(step_derivative_weights(p, through_end))
            assert w.shape == (p, p + 1) and np.all(w.sum(axis=1) == 0.0)
            got = (w / h ** np.arange(1, p + 1)[:, None]) @ values
            assert np.allclose(got, expected, rtol=0, atol=1e-13)
    assert step_derivative_weights(2) == [[0.5, -2.0, 1.5], [1.0, -2.0, 1.0]]
    assert step_derivative_weights(1, True) == [[-1.0, 1.0]]


def test_evaluating_at_many_offsets_is_evaluating_at_each_bit_for_bit() -> None:
    """``evaluate_at`` (one polynomial or a stack, several offsets) gives the very floats one
    ``evaluate`` per offset and polynomial gives: the step control's estimates use it, and any
    change of rounding there moves a whole adaptive run."""
    import numpy as np

    from cosimstep.extrapolation import evaluate, evaluate_at

    rng = np.random.default_rng(8)
    for rows in range(1, 6):
        for _ in range(500):
            dts = rng.uniform(-1, 1, size=4) * 10.0 ** rng.uniform(-7, 1)
            one = rng.normal(size=(rows, 3)) * 10.0 ** rng.uniform(-5, 5)
            expected = np.array([evaluate(one, dt) for dt in dts])
            assert np.array_equal(evaluate_at(one, dts), expected)
            stack = rng.normal(size=(5, rows, 2)) * 10.0 ** rng.uniform(-5, 5)
            got = evaluate_at(stack, dts)
            for i in range(5):
                expected = np.array([evaluate(stack[i], dt) for dt in dts])
                assert [v.hex() for v in got[i].ravel().tolist()] == \
                    [v.hex() for v in expected.ravel().tolist()]


def test_evaluating_a_few_signals_on_floats_is_evaluate_bit_for_bit() -> None:
    """``evaluate_small`` (the multi-rate master's partner trajectories) gives the floats
    ``evaluate`` gives, sign of zero included."""
    import numpy as np

    from cosimstep.extrapolation import evaluate, evaluate_small

    rng = np.random.default_rng(9)
    for rows in range(1, 6):
        for signals in (1, 2, 4):
            for _ in range(300):
                c = rng.normal(size=(rows, signals)) * 10.0 ** rng.uniform(-6, 6)
                dts = (rng.uniform(-1, 1, size=int(rng.integers(1, 6)))
                       * 10.0 ** rng.uniform(-6, 2))
                expected = np.array([evaluate(c, float(dt)) for dt in dts])
                got = evaluate_small(c, dts.tolist())
                assert got.shape == expected.shape
                assert [v.hex() for v in got.ravel().tolist()] == \
                    [v.hex() for v in expected.ravel().tolist()]

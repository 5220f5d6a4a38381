"""Input extrapolation's Lagrange weights: the written-out one-, two- and three-point forms give
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
            cases += [[ti - t for ti in times[:3]],  # Jacobi at order 2: last three points
                      [ti - t for ti in (times[1], times[2], times[3])],  # Gauss-Seidel
                      [ti - t for ti in times[1:3]], [ti - t for ti in times[2:4]],
                      [ti - t for ti in times[2:3]]]
    for _ in range(3000):
        n = rng.choice((1, 2, 3))
        scale = 10.0 ** rng.uniform(-9, 3)
        cases.append([rng.uniform(-1, 1) * scale for _ in range(n)])
    cases += [[-0.0, 1.0, 2.0], [0.0, -1.0, -2.0], [-2.0, -1.0, 0.0], [1.0, -0.0]]
    for s in cases:
        assert _bits(_weights(s)) == _bits(_weights_loop(s)), s

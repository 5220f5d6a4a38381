"""Input extrapolation over a communication step from the stored history.

A receiver needs its inputs over ``[t, t + h]`` but its sources have only produced values up to
``t`` (Jacobi) or up to ``t + h`` (Gauss–Seidel, for sources already stepped). The master fits a
polynomial of order ``p`` through the last ``p + 1`` stored points and hands the receiver its
Taylor coefficients at ``t``: value, slope and curvature. Order 0 holds the last value (zero-order
hold), order 1 extrapolates linearly, order 2 quadratically. With a receiver that follows the
input polynomial, the coupling error of a step shrinks like ``h^(p+2)`` and the global error like
``h^(p+1)``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np


def taylor_coefficients(times: Sequence[float], values: np.ndarray, t0: float,
                        order: int) -> np.ndarray:
    """Derivatives at ``t0`` of the polynomial through the given points.

    Parameters
    ----------
    times:
        The ``order + 1`` (or fewer: the order drops accordingly) abscissae.
    values:
        Array ``(len(times), n)``: one column per signal.
    t0:
        Expansion point.
    order:
        Requested polynomial order.

    Returns
    -------
    Array ``(order + 1, n)``: row ``k`` is the ``k``-th derivative at ``t0``; rows beyond what the
    number of points supports are zero.
    """
    values = np.asarray(values, dtype=float)
    n_points = min(len(times), order + 1)
    out = np.zeros((order + 1, values.shape[1]))
    rows = values[-n_points:]
    s = [float(ti) - t0 for ti in times[-n_points:]]
    # Lagrange form: derivative k at t0 of the basis polynomial of point i is
    # k! * coef_k(prod_{j != i} (x - s_j)) / prod_{j != i} (s_i - s_j). Pure-Python floats are
    # much faster than a linear solve for the <= 3 points used here (this runs every step).
    weights = [[0.0] * n_points for _ in range(n_points)]  # weights[k][i]
    for i in range(n_points):
        poly = [1.0]
        denominator = 1.0
        for j in range(n_points):
            if j != i:
                poly = [(poly[k - 1] if k > 0 else 0.0) - s[j] * (poly[k] if k < len(poly)
                                                                    else 0.0)
                        for k in range(len(poly) + 1)]
                denominator *= s[i] - s[j]
        for k in range(n_points):
            weights[k][i] = poly[k] * math.factorial(k) / denominator
    out[:n_points] = np.array(weights) @ rows
    return out


def evaluate(coefficients: np.ndarray, dt: float) -> np.ndarray:
    """Value of the Taylor polynomial ``Σ c_k dt^k / k!`` at ``t0 + dt``."""
    result = np.array(coefficients[0], dtype=float)
    term = 1.0
    for k in range(1, coefficients.shape[0]):
        term *= dt / k
        result = result + term * coefficients[k]
    return result

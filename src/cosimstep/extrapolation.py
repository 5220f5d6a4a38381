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

import functools
import math
from collections.abc import Sequence

import numpy as np

SHORTEST = 64
"""Ulps of ``t``: a step shorter than this many is too short to fit a polynomial over. Its
nodes ``t + NODES · h`` round onto each other (a re-run piece of one ulp at t = 200 s once ended
a run with a ZeroDivisionError), and its inputs are their value at ``t`` anyway."""


def negligible(t: float) -> float:
    """The length below which a step at ``t`` is too short for an input polynomial
    (:data:`SHORTEST` ulps of ``t``)."""
    return SHORTEST * math.ulp(t)


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
    rows = values[-n_points:]
    s = [float(ti) - t0 for ti in times[-n_points:]]
    # ``dot`` is ``@`` (the same BLAS product, bit for bit) without the ufunc machinery
    if n_points == order + 1:
        return weight_matrix(tuple(s)).dot(rows)
    out = np.zeros((order + 1, values.shape[1]))
    out[:n_points] = weight_matrix(tuple(s)).dot(rows)
    return out


@functools.lru_cache(maxsize=64)
def weight_matrix(s: tuple[float, ...]) -> np.ndarray:
    """:func:`_weights` as a read-only array, remembered: within one step the master's passes
    and ``pc``'s estimate fit curves through the same points two to four times."""
    w = np.array(_weights(list(s)))
    w.flags.writeable = False
    return w


def _weights(s: list[float]) -> list[list[float]]:
    """``weights[k][i]``: derivative ``k`` at 0 of the Lagrange basis polynomial of point ``i``.

    Lagrange form: derivative k at 0 of the basis polynomial of point i is
    k! * coef_k(prod_{j != i} (x - s_j)) / prod_{j != i} (s_i - s_j). Pure-Python floats are
    much faster than a linear solve for the <= 5 points used here (this runs every step). One
    to five points (extrapolation orders 0-2, the corrector's cubic, and the quartic ``pc``
    judges the corrector by) are written out: the same floating-point operations in the same
    order as :func:`_weights_loop` (bit-identical results, compared in
    tests/orchestration/test_extrapolation_weights.py), without its list building, which cost
    about half of a Gauss-Seidel step of two small FMUs at order 2.
    """
    n = len(s)
    if n == 5:  # the predictor-corrector's quartic, against which it judges the corrector
        s0, s1, s2, s3, s4 = s
        return _five(s0, s1, s2, s3, s4)
    if n == 4:  # the predictor-corrector's cubic
        s0, s1, s2, s3 = s
        return _four(s0, s1, s2, s3)
    if n == 3:
        s0, s1, s2 = s
        return _three(s0, s1, s2)
    if n == 2:
        s0, s1 = s
        d0, d1 = 1.0 * (s0 - s1), 1.0 * (s1 - s0)
        return [[(0.0 - s1 * 1.0) / d0, (0.0 - s0 * 1.0) / d1],
                [(1.0 - s1 * 0.0) / d0, (1.0 - s0 * 0.0) / d1]]
    if n == 1:
        return [[1.0 / 1.0]]
    return _weights_loop(s)


def _three(s0: float, s1: float, s2: float) -> list[list[float]]:
    columns = []
    for si, sa, sb in ((s0, s1, s2), (s1, s0, s2), (s2, s0, s1)):
        p0, p1 = 0.0 - sa * 1.0, 1.0 - sa * 0.0  # (x - sa)
        q0, q1, q2 = 0.0 - sb * p0, p0 - sb * p1, p1 - sb * 0.0  # times (x - sb)
        d = 1.0 * (si - sa) * (si - sb)
        columns.append((q0 / d, q1 / d, q2 * 2 / d))
    return [[c[k] for c in columns] for k in range(3)]


def _four(s0: float, s1: float, s2: float, s3: float) -> list[list[float]]:
    columns = []
    for si, sa, sb, sc in ((s0, s1, s2, s3), (s1, s0, s2, s3), (s2, s0, s1, s3),
                           (s3, s0, s1, s2)):
        p0, p1 = 0.0 - sa * 1.0, 1.0 - sa * 0.0  # (x - sa)
        q0, q1, q2 = 0.0 - sb * p0, p0 - sb * p1, p1 - sb * 0.0  # times (x - sb)
        r0, r1, r2, r3 = 0.0 - sc * q0, q0 - sc * q1, q1 - sc * q2, q2 - sc * 0.0  # (x - sc)
        d = 1.0 * (si - sa) * (si - sb) * (si - sc)
        columns.append((r0 / d, r1 / d, r2 * 2 / d, r3 * 6 / d))
    return [[c[k] for c in columns] for k in range(4)]


def _five(s0: float, s1: float, s2: float, s3: float, s4: float) -> list[list[float]]:
    columns = []
    for si, sa, sb, sc, sd in ((s0, s1, s2, s3, s4), (s1, s0, s2, s3, s4), (s2, s0, s1, s3, s4),
                               (s3, s0, s1, s2, s4), (s4, s0, s1, s2, s3)):
        p0, p1 = 0.0 - sa * 1.0, 1.0 - sa * 0.0  # (x - sa)
        q0, q1, q2 = 0.0 - sb * p0, p0 - sb * p1, p1 - sb * 0.0  # times (x - sb)
        r0, r1, r2, r3 = 0.0 - sc * q0, q0 - sc * q1, q1 - sc * q2, q2 - sc * 0.0  # (x - sc)
        v0, v1, v2, v3, v4 = (0.0 - sd * r0, r0 - sd * r1, r1 - sd * r2, r2 - sd * r3,
                              r3 - sd * 0.0)  # times (x - sd)
        d = 1.0 * (si - sa) * (si - sb) * (si - sc) * (si - sd)
        columns.append((v0 / d, v1 / d, v2 * 2 / d, v3 * 6 / d, v4 * 24 / d))
    return [[c[k] for c in columns] for k in range(5)]


def _weights_loop(s: list[float]) -> list[list[float]]:
    """:func:`_weights` for any number of points."""
    n_points = len(s)
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
    return weights


def evaluate(coefficients: np.ndarray, dt: float) -> np.ndarray:
    """Value of the Taylor polynomial ``Σ c_k dt^k / k!`` at ``t0 + dt``."""
    result = np.array(coefficients[0], dtype=float)
    term = 1.0
    for k in range(1, coefficients.shape[0]):
        term *= dt / k
        result = result + term * coefficients[k]
    return result


def evaluate_at(coefficients: np.ndarray, dts: np.ndarray) -> np.ndarray:
    """:func:`evaluate` at each of ``dts`` at once, for one polynomial (rows of coefficients,
    columns of signals) or a stack of them (``(curves, rows, signals)``, shorter ones padded
    with zero rows): ``[..., i, :]`` is the value at ``t0 + dts[i]``.

    The same floating-point operations in the same order as one :func:`evaluate` per offset
    and curve, broadcast (bit for bit: a padded zero row adds exact zeros; the estimators
    compare curves at several points of a step, and one call per point cost more than the
    sums themselves).
    """
    dts = np.asarray(dts, dtype=float)
    c = np.asarray(coefficients, dtype=float)
    order = c.shape[-2] - 1
    if order == 0:
        return np.repeat(c[..., :1, :], len(dts), axis=-2)
    # term k at each offset: ((dt/1)·(dt/2))···(dt/k), the running product evaluate forms
    # (on Python floats: the same roundings as NumPy's, without its cost per call)
    rows = []
    for dt in dts.tolist():
        row, term = [], 1.0
        for k in range(1, order + 1):
            term *= dt / k
            row.append(term)
        rows.append(row)
    terms = np.array(rows).reshape(len(rows), order)
    result = c[..., :1, :] + terms[:, :1] * c[..., 1:2, :]
    for k in range(2, order + 1):
        result = result + terms[:, k - 1:k] * c[..., k:k + 1, :]
    return result


def evaluate_small(coefficients: np.ndarray, dts: Sequence[float]) -> np.ndarray:
    """:func:`evaluate_at` for one polynomial of a few signals, on Python floats: the same
    operations in the same order (bit for bit), without NumPy's cost per operation on arrays
    of a few elements — the multi-rate master reads its partners' trajectories one signal at
    a time, several times per step."""
    columns = coefficients.T.tolist()
    rows = []
    for dt in dts:
        terms, term = [], 1.0
        for k in range(1, coefficients.shape[0]):
            term = term * (dt / k)
            terms.append(term)
        row = []
        for c in columns:
            value = c[0]
            for term, ck in zip(terms, c[1:]):
                value = value + term * ck
            row.append(value)
        rows.append(row)
    return np.array(rows, dtype=float).reshape(len(rows), coefficients.shape[1])


def midstep_weights(order: int, through_end: bool = False) -> list[float]:
    """Weights of the last ``order + 1`` values (oldest first) whose sum is the input
    polynomial's value at mid-step, when the points are one uniform step apart.

    ``through_end=False``: the polynomial through the points at ``t - order·h, …, t``
    (extrapolation, Jacobi); ``True``: through ``t - (order - 1)·h, …, t`` and ``t + h``
    (interpolation through a fresh value, Gauss–Seidel). Evaluated at ``t + h/2``: what a
    sub-model without input derivatives receives (:meth:`cosimstep.masters.Master.step`). The
    weights do not depend on ``h`` and are exact binary fractions (order 2, Jacobi: 3/8, −5/4,
    15/8; Gauss–Seidel: −1/8, 3/4, 3/8); they sum to 1.
    """
    first = 1 - order if through_end else -order
    s = [float(i) for i in range(first, first + order + 1)]
    w = _weights(s)
    return [sum(w[k][i] * 0.5**k / math.factorial(k) for k in range(order + 1))
            for i in range(order + 1)]


def step_derivative_weights(order: int, through_end: bool = False) -> list[list[float]]:
    """``weights[k - 1][i]``: the weight of the ``i``-th of the last ``order + 1`` values (oldest
    first) in the input polynomial's ``k``-th derivative at ``t`` (``k = 1 … order``), for
    points one unit step apart; for steps of ``h``, divide by ``h**k``.

    The points are those of :func:`midstep_weights`. With them, the rows ``1 …`` of
    :func:`taylor_coefficients` at ``t`` — what a sub-model taking input derivatives receives
    (:meth:`cosimstep.masters.Master.step`) — are these weighted sums (the ``k``-th derivative,
    ``k!`` included, as the FMI standard wants it). Each row sums to 0.
    """
    first = 1 - order if through_end else -order
    return _weights([float(i) for i in range(first, first + order + 1)])[1:]

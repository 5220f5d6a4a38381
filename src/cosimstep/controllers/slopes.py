"""Slopes of black-box output trajectories, for the RKF controllers (thesis 4.2.4.2, 4.3.2).

A black box returns values, not derivatives. The thesis fits a cubic through the previous,
current, half-step and full-step points and differentiates it; a cubic is the lowest degree for
which the RKF23 predictor and corrector differ (with a quadratic both are exact and no error is
ever seen). Alternatives here: a shape-preserving pchip and a not-a-knot spline through the
whole stored history. Grey-box sub-models give their derivatives directly (thesis 4.3.4).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
from scipy.interpolate import CubicSpline, PchipInterpolator

SlopeFn = Callable[[Sequence[float], np.ndarray, Sequence[float]], np.ndarray]


def cubic_fit(times: Sequence[float], values: np.ndarray, at: Sequence[float]) -> np.ndarray:
    """Derivative of the least-squares polynomial of degree ≤ 3 (MATLAB ``polyfit``)."""
    t = np.asarray(times, dtype=float)
    tc = t[-1]
    degree = min(3, len(t) - 1)
    coef = np.polyfit(t - tc, values, degree)  # centred: better conditioned
    d = np.polyder(coef) if coef.ndim == 1 else np.array([np.polyder(c) for c in coef.T]).T
    x = np.asarray(at, dtype=float) - tc
    if d.ndim == 1:
        return np.polyval(d, x)
    return np.stack([np.polyval(d[:, j], x) for j in range(d.shape[1])], axis=1)


def pchip(times: Sequence[float], values: np.ndarray, at: Sequence[float]) -> np.ndarray:
    """Derivative of the piecewise cubic Hermite interpolant (no overshoot)."""
    return PchipInterpolator(np.asarray(times, dtype=float), values, axis=0).derivative()(at)


def spline(times: Sequence[float], values: np.ndarray, at: Sequence[float]) -> np.ndarray:
    """Derivative of the not-a-knot cubic spline through the points."""
    t = np.asarray(times, dtype=float)
    if len(t) < 4:
        return cubic_fit(times, values, at)
    return CubicSpline(t, values, axis=0).derivative()(at)


SLOPES: dict[str, SlopeFn] = {"cubic": cubic_fit, "pchip": pchip, "spline": spline}
"""Slope estimators by name; ``"model"`` (grey box) is handled by the controllers."""

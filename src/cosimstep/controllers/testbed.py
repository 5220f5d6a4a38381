"""The step controllers alone, on functions with known solutions (thesis 2.4, appendix B).

Before the thesis applied RKF23 to black boxes it checked it as an ODE integrator with a known
slope: appendix B's test curve ``x(t) = sin(t·sin(t/23)) / (sin t + ff)`` and the stiff equation of
fig. 23, ``y' = −100 y + 100 t + 101``. These functions reproduce those checks, so the step rule
can be measured apart from any coupling: calls (slope evaluations), accepted and rejected steps
and the error against the exact solution.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

Slope = Callable[[float, float], float]


@dataclass
class Integration:
    t: np.ndarray
    x: np.ndarray
    h: np.ndarray
    calls: int
    rejected: int
    completed: bool


def rkf23(f: Slope, t0: float, t1: float, x0: float, tol: float, *, hmax: float | None = None,
          hmin: float | None = None, h0: float | None = None, pi: bool = False) -> Integration:
    """Appendix B's RKF23 (``pi=False``: exactly; ``pi=True``: with our PI step update and growth
    limits [0.2, 5] instead of ``min(hmax, 0.8·h·(τ/δ)^¼)``)."""
    span = t1 - t0
    hmax = span / 2.5 if hmax is None else hmax
    hmin = span / 1e12 if hmin is None else hmin
    h = span / 200 if h0 is None else h0
    t, x = t0, x0
    ts, xs, hs = [t], [x], []
    calls = rejected = 0
    previous = 1.0
    while t < t1 and h >= hmin:
        if t + h > t1:
            h = t1 - t
        k1 = f(t, x)
        k2 = f(t + 0.5 * h, x + 0.5 * h * k1)
        k3 = f(t + h, x + h * (-k1 + 2.0 * k2))
        calls += 3
        x2 = x + h * k2
        x3 = x + h * (k1 + 4.0 * k2 + k3) / 6.0
        delta = abs(x3 - x2)
        tau = tol * max(abs(x), 1.0)
        if delta <= tau:
            t, x = t + h, x3
            ts.append(t)
            xs.append(x)
            hs.append(h)
        else:
            rejected += 1
        delta = max(delta, 1e-16)
        if pi:
            r = delta / tau
            factor = 0.9 * r ** (-0.7 / 3) * previous ** (0.4 / 3) if delta <= tau \
                else 0.9 * r ** (-1 / 3)
            if delta <= tau:
                previous = r
            h = min(hmax, h * min(5.0, max(0.2, factor)))
        else:
            h = min(hmax, 0.8 * h * (tau / delta) ** 0.25)
    return Integration(np.array(ts), np.array(xs), np.array(hs), calls, rejected, t >= t1)


def fixed(f: Slope, t0: float, t1: float, x0: float, h: float, method: str) -> Integration:
    """Euler (``"euler"``) or Heun's RK2 (``"rk2"``) with a fixed step (fig. 23's foils)."""
    n = math.ceil((t1 - t0) / h - 1e-9)
    ts, xs = [t0], [x0]
    t, x = t0, x0
    for _ in range(n):
        if method == "euler":
            x = x + h * f(t, x)
        else:
            k1 = f(t, x)
            x = x + 0.5 * h * (k1 + f(t + h, x + h * k1))
        t += h
        ts.append(t)
        xs.append(x)
    calls = n * (1 if method == "euler" else 2)
    return Integration(np.array(ts), np.array(xs), np.full(n, h), calls, 0, True)


def test_curve(ff: float) -> tuple[Callable[[float], float], Slope]:
    """Appendix B's curve and its slope (the slope does not depend on ``x``)."""

    def x(t: float) -> float:
        return math.sin(math.sin(t / 23) * t) / (math.sin(t) + ff)

    def slope(t: float, _x: float) -> float:
        a = math.cos(t * math.sin(t / 23)) * (math.sin(t / 23) + t * math.cos(t / 23) / 23)
        return a / (math.sin(t) + ff) - math.sin(t * math.sin(t / 23)) * math.cos(t) \
            / (math.sin(t) + ff) ** 2

    return x, slope


def stiff() -> tuple[Callable[[float], float], Slope]:
    """Fig. 23: ``y' = −100 y + 100 t + 101``, ``y(0) = 0.99``; exact ``1 + t − 0.01 e^(−100t)``."""
    return (lambda t: 1.0 + t - 0.01 * math.exp(-100.0 * t),
            lambda t, y: -100.0 * y + 100.0 * t + 101.0)

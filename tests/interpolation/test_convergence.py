"""Observed convergence orders on sin(t) as the spacing halves, values and slopes.

Each method fits its default window of points ending at t = 1 with spacing h; the error is the
maximum over the window and half a step beyond the last point (where the master reads). Theory:
hold 1, linear 2, the natural spline and the Bézier 2 (their zero end curvature is wrong where
sin'' ≠ 0, and the master reads at that end; inside they are 4), cubic convolution 3 (Keys),
pchip and Akima 3 on uniform spacing (2 on irregular), the cubic interpolants 4. Slopes lose one.
"""

from __future__ import annotations

import numpy as np
import pytest

from cosimstep.interpolation import make_interpolator

SPACINGS = [0.04, 0.02, 0.01]
# Relative steps of an irregular grid; the pattern is kept while h halves.
PATTERN = 1.0 + 0.4 * np.sin(7.0 * np.arange(16))


def grid(n: int, h: float, irregular: bool) -> np.ndarray:
    steps = h * (PATTERN[: n - 1] if irregular else np.ones(n - 1))
    return 1.0 - np.concatenate([[0.0], np.cumsum(steps)])[::-1]


def errors(name: str, h: float, irregular: bool = False,
           interior: bool = False) -> tuple[float, float]:
    method = make_interpolator(name)
    if interior:  # all points of [0, 1], error on its middle fifth: far from both ends
        t = np.linspace(0.0, 1.0, round(1.0 / h) + 1)
        method = make_interpolator(name, window=len(t))
        q = np.linspace(0.4, 0.6, 200)
    else:
        t = grid(method.window, h, irregular)
        q = np.linspace(t[0], t[-1] + 0.5 * (t[-1] - t[-2]), 200)
    curve = method.fit(t, np.sin(t), np.cos(t) if method.uses_derivatives else None)
    return np.abs(curve(q) - np.sin(q)).max(), np.abs(curve(q, 1) - np.cos(q)).max()


def orders(name: str, **kwargs) -> tuple[float, float]:
    e = np.array([errors(name, h, **kwargs) for h in SPACINGS])
    observed = np.log2(e[:-1] / e[1:])
    return float(observed[-1, 0]), float(observed[-1, 1])


@pytest.mark.parametrize(("name", "value", "slope"), [
    ("linear", 2, 1),
    ("polyfit", 4, 3),
    ("spline-natural", 2, 1),
    ("spline-not-a-knot", 4, 3),
    ("cubic-convolution", 3, 2),
    ("akima", 3, 2),
    ("lagrange", 4, 3),
    ("rbf", 2, 1),
    ("bezier", 2, 1),
    ("hermite", 4, 3),
])
def test_orders_on_uniform_spacing(name: str, value: int, slope: int) -> None:
    p, q = orders(name)
    assert value - 0.15 < p < value + 0.15
    assert slope - 0.15 < q < slope + 0.15


def test_hold_and_pchip_orders() -> None:
    p, _ = orders("hold")
    assert 0.9 < p < 1.1
    p, q = orders("pchip")
    assert p >= 2.9 and q >= 1.85


@pytest.mark.parametrize(("name", "value"), [("spline-natural", 4), ("bezier", 4)])
def test_natural_end_condition_costs_only_at_the_ends(name: str, value: int) -> None:
    p, _ = orders(name, interior=True)
    assert value - 0.2 < p < value + 0.3


@pytest.mark.parametrize(("name", "value", "slope"), [
    ("linear", 2, 1),
    ("spline-not-a-knot", 4, 3),
    ("cubic-convolution", 3, 2),   # the parabola slopes stay second-order on any spacing
    ("lagrange", 4, 3),
    ("bezier", 2, 1),
    ("hermite", 4, 3),
])
def test_orders_on_irregular_spacing(name: str, value: int, slope: int) -> None:
    p, q = orders(name, irregular=True)
    assert value - 0.2 < p < value + 0.25
    assert slope - 0.2 < q < slope + 0.25


@pytest.mark.parametrize("name", ["pchip", "akima"])
def test_pchip_and_akima_lose_an_order_on_irregular_spacing(name: str) -> None:
    p, _ = orders(name, irregular=True)
    assert 1.5 < p < 2.5


def test_errors_are_small_in_absolute_terms() -> None:
    """At h = 0.01 the fourth-order methods are within 1e-9 of sin, second-order ones ~1e-5."""
    assert errors("spline-not-a-knot", 0.01)[0] < 2e-9
    assert errors("hermite", 0.01)[0] < 2e-10
    assert 1e-6 < errors("bezier", 0.01)[0] < 1e-4

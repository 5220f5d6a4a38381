"""Trajectory interpolation: exactness, shapes, windows, the Bézier and Keys definitions, errors."""

from __future__ import annotations

import numpy as np
import pytest

from cosimstep.interpolation import (
    INTERPOLATORS,
    Interpolator,
    bezier_control_points,
    make_interpolator,
)

ALL = list(INTERPOLATORS)
UNIFORM = np.linspace(0.0, 1.4, 8)
# Irregular spacing (ratios up to about 3 between neighbours).
IRREGULAR = np.array([0.0, 0.1, 0.4, 0.5, 0.75, 1.1, 1.2, 1.4])


def fit(name: str, t: np.ndarray, f, df, **options) -> object:
    method = make_interpolator(name, **options)
    derivatives = df(t) if method.uses_derivatives else None
    return method.fit(t, f(t), derivatives)


def queries(t: np.ndarray) -> np.ndarray:
    """Inside the window and up to half the last step beyond it (the master's extrapolation)."""
    return np.linspace(t[0], t[-1] + 0.5 * (t[-1] - t[-2]), 101)


@pytest.mark.parametrize("grid", [UNIFORM, IRREGULAR], ids=["uniform", "irregular"])
@pytest.mark.parametrize("name", ALL)
def test_reproduces_the_polynomials_it_claims(name: str, grid: np.ndarray) -> None:
    method = make_interpolator(name, window=8)
    degree = min(method.reproduces, 3)
    coef = [0.7, -1.3, 0.4, 0.25][: degree + 1]
    f = np.polynomial.Polynomial(coef)
    curve = fit(name, grid, f, f.deriv(), window=8)
    q = queries(grid)
    assert np.abs(curve(q) - f(q)).max() < 1e-12
    assert np.abs(curve(q, 1) - f.deriv()(q)).max() < 1e-10


@pytest.mark.parametrize("name", ["linear", "polyfit", "spline-natural", "spline-not-a-knot",
                                  "pchip", "akima", "cubic-convolution", "lagrange", "rbf",
                                  "bezier", "hermite"])
def test_every_method_but_hold_reproduces_a_line(name: str) -> None:
    curve = fit(name, IRREGULAR, lambda t: 2.0 - 3.0 * t, lambda t: -3.0 + 0 * t)
    q = queries(IRREGULAR)
    assert np.abs(curve(q) - (2.0 - 3.0 * q)).max() < 1e-12
    assert np.abs(curve(q, 1) + 3.0).max() < 1e-9


@pytest.mark.parametrize("name", ["spline-natural", "pchip", "akima", "cubic-convolution",
                                  "rbf", "bezier"])
def test_methods_that_do_not_reproduce_a_cubic_really_do_not(name: str) -> None:
    f = np.polynomial.Polynomial([0.0, 0.0, 0.0, 1.0])
    curve = fit(name, UNIFORM, f, f.deriv())
    assert np.abs(curve(queries(UNIFORM)) - f(queries(UNIFORM))).max() > 1e-4


def test_hold_holds_the_last_value_at_or_before_t() -> None:
    t = np.array([0.0, 1.0, 2.0])
    curve = make_interpolator("hold", window=3).fit(t, np.array([5.0, 6.0, 7.0]))
    assert curve([-1.0, 0.0, 0.5, 1.0, 1.999, 2.0, 2.5]).tolist() == [5, 5, 5, 6, 6, 7, 7]
    assert np.all(curve([0.5, 2.5], nu=1) == 0.0)


def test_shapes_follow_the_query_and_the_columns() -> None:
    t = np.linspace(0.0, 1.0, 6)
    for name in ALL:
        method = make_interpolator(name)
        one = method.fit(t, np.sin(t), np.cos(t) if method.uses_derivatives else None)
        two = method.fit(t, np.c_[np.sin(t), np.cos(t)],
                         np.c_[np.cos(t), -np.sin(t)] if method.uses_derivatives else None)
        assert one(0.3).shape == () and one([0.3, 0.4]).shape == (2,)
        assert two(0.3).shape == (2,) and two(np.zeros((3, 4)), nu=1).shape == (3, 4, 2)
        # columns are independent: column 0 of the 2-D fit is the 1-D fit
        assert np.allclose(two([0.3, 1.05])[:, 0], one([0.3, 1.05]), rtol=0, atol=1e-13)


def test_a_single_point_gives_a_constant_and_hermite_a_tangent() -> None:
    for name in ALL:
        method = make_interpolator(name)
        d = [[2.0, -1.0]] if method.uses_derivatives else None
        curve = method.fit([1.0], [[3.0, 4.0]], d)
        expected = [3.0 + 0.5 * 2.0, 4.0 - 0.5] if method.uses_derivatives else [3.0, 4.0]
        assert np.allclose(curve(1.5), expected)


def test_two_points_give_the_chord() -> None:
    for name in ALL:
        if name == "hold":
            continue
        method = make_interpolator(name)
        d = [1.0, 1.0] if method.uses_derivatives else None
        curve = method.fit([0.0, 2.0], [1.0, 3.0], d)
        assert curve(2.5) == pytest.approx(3.5, abs=1e-12)


def test_only_the_window_is_fitted() -> None:
    """A long history costs nothing: the fit equals the fit of the last `window` points."""
    t = np.cumsum(np.full(5000, 0.01))
    y = np.sin(3 * t) + 0.1 * np.cos(17 * t)
    q = t[-1] + np.array([-0.015, -0.002, 0.004])
    for name in ALL:
        method = make_interpolator(name)
        w = method.window
        d = np.cos(t) if method.uses_derivatives else None
        full = method.fit(t, y, d)
        tail = method.fit(t[-w:], y[-w:], None if d is None else d[-w:])
        assert np.array_equal(full(q), tail(q)) and np.array_equal(full(q, 1), tail(q, 1))
    # a list history is sliced before conversion too
    curve = make_interpolator("pchip").fit(list(t), list(y))
    assert curve(q[0]) == pytest.approx(make_interpolator("pchip").fit(t, y)(q[0]))


def test_bezier_control_points_satisfy_appendix_e_conditions() -> None:
    rng = np.random.default_rng(1)
    p0 = np.column_stack([np.cumsum(rng.uniform(0.5, 2.0, 7)), rng.normal(size=(7, 2))])
    p1, p2 = bezier_control_points(p0)
    n = len(p0) - 1
    assert np.allclose(p1[1:] + p2[:-1], 2 * p0[1:n])                    # C1 joints
    assert np.allclose(p1[:-1] + 2 * p1[1:], p2[1:] + 2 * p2[:-1])       # C2 joints
    assert np.allclose(2 * p1[0] - p2[0], p0[0])                         # B''(0) = 0
    assert np.allclose(2 * p2[-1] - p1[-1], p0[-1])                      # B''(end) = 0
    one1, one2 = bezier_control_points(p0[:2])                           # straight line
    assert np.allclose(one1[0], (2 * p0[0] + p0[1]) / 3)
    assert np.allclose(one2[0], (p0[0] + 2 * p0[1]) / 3)


def test_bezier_is_the_natural_spline_on_uniform_spacing_and_not_otherwise() -> None:
    q = np.linspace(0.0, 1.5, 77)
    for grid, same in ((UNIFORM, True), (IRREGULAR, False)):
        y = np.c_[np.exp(grid), np.sin(5 * grid)]
        bezier = make_interpolator("bezier").fit(grid, y)
        natural = make_interpolator("spline-natural").fit(grid, y)
        gap = np.abs(bezier(q) - natural(q)).max()
        assert (gap < 1e-12) if same else (gap > 1e-3)
        # the curve passes through the points and its slope is continuous across them
        assert np.abs(bezier(grid) - y).max() < 1e-12
        inner = grid[1:-1]
        assert np.abs(bezier(inner - 1e-9, 1) - bezier(inner + 1e-9, 1)).max() < 1e-6


def keys_kernel(x: np.ndarray, a: float = -0.5) -> np.ndarray:
    x = np.abs(x)
    near = (a + 2) * x**3 - (a + 3) * x**2 + 1
    far = a * x**3 - 5 * a * x**2 + 8 * a * x - 4 * a
    return np.where(x <= 1, near, np.where(x < 2, far, 0.0))


def test_cubic_convolution_is_keys_kernel_on_a_uniform_grid() -> None:
    """Keys (1981) with a = −1/2 and his end condition c₋₁ = 3c₀ − 3c₁ + c₂, written directly."""
    h, n = 0.1, 9
    t = 0.3 + h * np.arange(n)
    y = np.sin(4 * t) + t**2
    c = np.concatenate([[3 * y[0] - 3 * y[1] + y[2]], y, [3 * y[-1] - 3 * y[-2] + y[-3]]])
    q = np.linspace(t[0], t[-1], 201)
    k = np.arange(-1, n + 1)
    direct = (c[None, :] * keys_kernel((q[:, None] - t[0]) / h - k[None, :])).sum(axis=1)
    ours = make_interpolator("cubic-convolution", window=n).fit(t, y)(q)
    assert np.abs(ours - direct).max() < 1e-13


def test_polyfit_is_least_squares_over_a_longer_window() -> None:
    t = np.linspace(0.0, 1.0, 9)
    y = np.cos(3 * t)
    curve = make_interpolator("polyfit", degree=2, window=9).fit(t, y)
    expected = np.polyval(np.polyfit(t, y, 2), 0.37)
    assert curve(0.37) == pytest.approx(expected, abs=1e-12)


def test_akima_variant_is_passed_on() -> None:
    t = np.arange(6.0)
    y = np.array([0.0, 1.0, 0.5, 3.0, 2.0, 2.2])
    plain = make_interpolator("akima").fit(t, y)
    modified = make_interpolator("akima", variant="makima").fit(t, y)
    assert np.allclose(plain(t), y) and np.allclose(modified(t), y)
    assert np.abs(plain(np.linspace(1, 4, 31)) - modified(np.linspace(1, 4, 31))).max() > 1e-2


def test_the_registry_is_complete_and_names_match() -> None:
    assert set(INTERPOLATORS) == {
        "hold", "linear", "polyfit", "spline-natural", "spline-not-a-knot", "pchip", "akima",
        "cubic-convolution", "lagrange", "rbf", "bezier", "hermite"}
    for name, cls in INTERPOLATORS.items():
        assert issubclass(cls, Interpolator) and cls.name == name


# --- errors --------------------------------------------------------------------------------


def test_unknown_name_lists_the_valid_ones() -> None:
    with pytest.raises(ValueError, match=r"`name`='cubic'.*hold, linear, polyfit.*hermite"):
        make_interpolator("cubic")


@pytest.mark.parametrize(("name", "options", "message"), [
    ("pchip", {"window": 1}, r"`window` must be an integer ≥ 2 for method 'pchip', got 1"),
    ("linear", {"window": 2.5}, r"`window` must be an integer"),
    ("polyfit", {"degree": -1}, r"`degree` must be an integer ≥ 0"),
    ("polyfit", {"degree": 3, "window": 3}, r"`window` \(3\) must be ≥ `degree` \+ 1 = 4"),
    ("akima", {"variant": "spline"}, r"`variant` must be 'akima' or 'makima'"),
    ("rbf", {"kernel": "gaussian"}, r"method 'rbf': bad `kernel`/`epsilon`/`degree`"),
    ("pchip", {"degree": 3}, r"method 'pchip' has no option\(s\) `degree`; it takes `window`"),
])
def test_bad_options_name_the_argument(name: str, options: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        make_interpolator(name, **options)


def test_bad_data_names_the_argument() -> None:
    pchip = make_interpolator("pchip")
    with pytest.raises(ValueError, match="`times` must be finite and strictly increasing"):
        pchip.fit([0.0, 1.0, 1.0, 2.0], [1.0, 2.0, 3.0, 4.0])
    with pytest.raises(ValueError, match="`values` must have shape"):
        pchip.fit([0.0, 1.0, 2.0], [1.0, 2.0])
    with pytest.raises(ValueError, match="`times` must be a non-empty"):
        pchip.fit([], [])
    with pytest.raises(ValueError, match="does not use `derivatives`; use 'hermite'"):
        pchip.fit([0.0, 1.0], [1.0, 2.0], [0.0, 0.0])
    hermite = make_interpolator("hermite")
    with pytest.raises(ValueError, match="'hermite' needs `derivatives`"):
        hermite.fit([0.0, 1.0], [1.0, 2.0])
    with pytest.raises(ValueError, match="`derivatives` must have the shape of `values`"):
        hermite.fit([0.0, 1.0], [[1.0, 2.0], [3.0, 4.0]], [0.0, 0.0])
    with pytest.raises(ValueError, match=r"`nu` must be 0 .* or 1"):
        pchip.fit([0.0, 1.0], [1.0, 2.0])(0.5, nu=2)

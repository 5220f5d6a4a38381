"""Trajectory interpolation: value and slope of a stored output trajectory (thesis 4.3.1–4.3.3).

The multi-rate master runs the sub-model that is furthest behind; its inputs come from partners
that are already ahead, so they are *interpolated* in the partners' stored trajectories (and,
for the newest interval, slightly *extrapolated*). The RKF-type controllers also need slopes of
black-box outputs (thesis 4.3.2). One interface serves both::

    curve = make_interpolator("pchip").fit(times, values)
    x, dxdt = curve(t), curve(t, nu=1)

Every method fits only a *window* of the most recent points. The master asks for values near the
newest point, and all methods here are local or have influence that decays fast away from a point
(a cubic spline's by a factor 2 − √3 ≈ 0.27 per interval), so old points change nothing it reads,
while fitting them all would make each call cost O(run length) — the master calls this once per
partner per step. Queries before the window's first point are extrapolated backwards; pass a
larger ``window`` to read deep into the history.

Methods (:data:`INTERPOLATORS`), with the polynomial degree each reproduces exactly on any spacing:

``hold`` (0) · ``linear`` (1) · ``polyfit`` (its ``degree``) · ``spline-natural`` (1) ·
``spline-not-a-knot`` (3) · ``pchip`` (1) · ``akima`` (1) · ``cubic-convolution`` (2) ·
``lagrange`` (window − 1) · ``rbf`` (its polynomial ``degree``, 1) · ``bezier`` (1) ·
``hermite`` (3, from given derivatives: the grey-box case, thesis 4.3.4).

Every method accepts a trajectory of a single point (the master's first step): the curve is then
constant (``hermite``: a straight line along the given slope).
"""

from __future__ import annotations

import inspect
from abc import ABC, abstractmethod
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike
from scipy.interpolate import (
    Akima1DInterpolator,
    BarycentricInterpolator,
    CubicHermiteSpline,
    CubicSpline,
    PchipInterpolator,
    PPoly,
    RBFInterpolator,
    make_interp_spline,
)
from scipy.linalg import solve_banded


class Curve(ABC):
    """A fitted trajectory: value and first derivative at any time, beyond its ends too.

    Call it like a SciPy interpolant: ``curve(t)`` or ``curve(t, nu=1)``. The result has shape
    ``np.shape(t) + values.shape[1:]`` (one column per signal when the values were 2-D).
    """

    def __init__(self, tail: tuple[int, ...]) -> None:
        self._tail = tail

    def __call__(self, t: ArrayLike, nu: int = 0) -> np.ndarray:
        if nu not in (0, 1):
            raise ValueError(f"`nu` must be 0 (value) or 1 (first derivative), got {nu!r}")
        x = np.asarray(t, dtype=float)
        out = self._evaluate(x.reshape(-1), nu)
        return out.reshape(x.shape + self._tail)

    @abstractmethod
    def _evaluate(self, t: np.ndarray, nu: int) -> np.ndarray:
        """Values (``nu = 0``) or slopes (``nu = 1``) at the 1-D times ``t``, shape ``(q, m)``."""


class _Wrapped(Curve):
    """A SciPy interpolant that takes ``(x, nu)`` (PPoly and BSpline families)."""

    def __init__(self, tail: tuple[int, ...], fitted: Any) -> None:
        super().__init__(tail)
        self._fitted = fitted

    def _evaluate(self, t: np.ndarray, nu: int) -> np.ndarray:
        return self._fitted(t, nu)


class _Line(Curve):
    """``y0 + slope·(t − t0)``: one stored point (with a slope for ``hermite``, else flat)."""

    def __init__(self, tail: tuple[int, ...], t0: float, y0: np.ndarray,
                 slope: np.ndarray) -> None:
        super().__init__(tail)
        self._t0, self._y0, self._slope = t0, y0, slope

    def _evaluate(self, t: np.ndarray, nu: int) -> np.ndarray:
        if nu == 1:
            return np.broadcast_to(self._slope, (t.size, self._slope.size)).copy()
        return self._y0 + np.outer(t - self._t0, self._slope)


class Interpolator(ABC):
    """One interpolation method; :meth:`fit` turns stored points into a :class:`Curve`.

    Subclasses set the class attributes and write :meth:`_fit`; :meth:`fit` has already checked
    the data, cut the window and made the values 2-D ``(n, m)`` with ``n ≥ 2``.

    Parameters
    ----------
    window:
        Number of most recent points fitted; ``None`` picks the method's :attr:`default_window`.
    """

    name: ClassVar[str]
    default_window: ClassVar[int]
    min_window: ClassVar[int] = 2
    reproduces: ClassVar[int] = 1
    """Highest polynomial degree the method reproduces exactly, on any spacing."""
    uses_derivatives: ClassVar[bool] = False

    def __init__(self, window: int | None = None) -> None:
        window = self.default_window if window is None else window
        if isinstance(window, bool) or not isinstance(window, int | np.integer) \
                or window < self.min_window:
            raise ValueError(f"`window` must be an integer ≥ {self.min_window} for method "
                             f"'{self.name}', got {window!r}")
        self.window = int(window)

    def __repr__(self) -> str:
        return f"{type(self).__name__}(window={self.window})"

    def fit(self, times: ArrayLike, values: ArrayLike,
            derivatives: ArrayLike | None = None) -> Curve:
        """Fit the last :attr:`window` points.

        Parameters
        ----------
        times:
            Strictly increasing sample times, length ``n``. Only the window is read (and
            checked), so passing the whole history costs nothing extra.
        values:
            Shape ``(n,)`` or ``(n, m)``: one column per signal, all fitted in one go.
        derivatives:
            Time derivatives at the sample times, same shape as ``values``; only for methods
            with :attr:`uses_derivatives` (``hermite``), which require them.
        """
        if self.uses_derivatives and derivatives is None:
            raise ValueError(f"method '{self.name}' needs `derivatives` (the slopes at the "
                             "sample times); without them use 'pchip' or a spline")
        if not self.uses_derivatives and derivatives is not None:
            raise ValueError(f"method '{self.name}' does not use `derivatives`; use 'hermite' "
                             "to interpolate with given slopes")
        w = self.window
        t = np.asarray(times[-w:] if _sliceable(times) else np.asarray(times)[-w:], dtype=float)
        y = np.asarray(values[-w:] if _sliceable(values) else np.asarray(values)[-w:],
                       dtype=float)
        dy = None if derivatives is None else np.asarray(
            derivatives[-w:] if _sliceable(derivatives) else np.asarray(derivatives)[-w:],
            dtype=float)
        _check(t, y, dy, len(times), len(values),
               None if derivatives is None else len(derivatives))
        tail = y.shape[1:]
        y2 = y.reshape(len(t), -1)
        dy2 = None if dy is None else dy.reshape(len(t), -1)
        if len(t) == 1:
            slope = dy2[0] if dy2 is not None else np.zeros(y2.shape[1])
            return _Line(tail, float(t[0]), y2[0], slope)
        return self._fit(t, y2, dy2, tail)

    @abstractmethod
    def _fit(self, t: np.ndarray, y: np.ndarray, dy: np.ndarray | None,
             tail: tuple[int, ...]) -> Curve:
        """Build the curve from ``n ≥ 2`` checked points; ``y`` (and ``dy``) are ``(n, m)``."""


def _sliceable(a: Any) -> bool:
    return isinstance(a, list | tuple | np.ndarray)


def _check(t: np.ndarray, y: np.ndarray, dy: np.ndarray | None, n_times: int, n_values: int,
           n_derivatives: int | None) -> None:
    if t.ndim != 1 or len(t) == 0:
        raise ValueError(f"`times` must be a non-empty 1-D sequence, got shape {t.shape}")
    if n_values != n_times or y.ndim not in (1, 2):
        raise ValueError(f"`values` must have shape (n,) or (n, m) with n = len(times) = "
                         f"{n_times}, got length {n_values} and {y.ndim} dimension(s)")
    if dy is not None and (n_derivatives != n_times or dy.shape != y.shape):
        raise ValueError(f"`derivatives` must have the shape of `values` {y.shape}, got "
                         f"{dy.shape} (length {n_derivatives})")
    if not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0.0):
        raise ValueError("`times` must be finite and strictly increasing (within the window)")


# --- SciPy-backed methods ------------------------------------------------------------------


class Hold(Interpolator):
    """Zero-order hold: the last stored value at or before ``t`` (slope 0)."""

    name = "hold"
    default_window = 2
    min_window = 1
    reproduces = 0

    def _fit(self, t, y, dy, tail):
        # A piecewise constant PPoly; one extra breakpoint makes the last value the last piece,
        # so it is held beyond the last point (PPoly extrapolates its last piece).
        pad = t[-1] + (t[-1] - t[0])
        return _Wrapped(tail, PPoly(y[None, :, :], np.append(t, pad)))


class Linear(Interpolator):
    """Straight lines between points; extrapolates the last line (order 2, slope order 1)."""

    name = "linear"
    default_window = 2

    def _fit(self, t, y, dy, tail):
        return _Wrapped(tail, make_interp_spline(t, y, k=1, axis=0))


class _CubicSpline(Interpolator):
    bc_type: ClassVar[str]
    default_window = 8

    def _fit(self, t, y, dy, tail):
        return _Wrapped(tail, CubicSpline(t, y, axis=0, bc_type=self.bc_type, extrapolate=True))


class SplineNatural(_CubicSpline):
    """Cubic spline with zero curvature at both ends (MATLAB ``csape`` 'variational').

    Zero end curvature is wrong for most trajectories, and the error it causes (O(h²)) sits at
    the newest point — where the master reads.
    """

    name = "spline-natural"
    bc_type = "natural"


class SplineNotAKnot(_CubicSpline):
    """Cubic spline whose third derivative is continuous at the second and penultimate points
    (MATLAB ``spline`` and ``interp1(..., 'spline')``, the thesis's SPLINE)."""

    name = "spline-not-a-knot"
    bc_type = "not-a-knot"
    reproduces = 3


class Pchip(Interpolator):
    """Shape-preserving piecewise cubic Hermite (MATLAB ``pchip``): no overshoot at steep drops.

    Local (a point moves only its two neighbouring intervals), so a short window loses nothing.
    """

    name = "pchip"
    default_window = 4

    def _fit(self, t, y, dy, tail):
        return _Wrapped(tail, PchipInterpolator(t, y, axis=0, extrapolate=True))


class Akima(Interpolator):
    """Akima's local cubic (slopes from 5 points); ``variant='makima'`` for the modified one.

    Parameters
    ----------
    variant:
        ``'akima'`` (1970) or ``'makima'`` (MATLAB's modified Akima, no overshoot on flat runs).
    """

    name = "akima"
    default_window = 6

    def __init__(self, window: int | None = None, variant: str = "akima") -> None:
        super().__init__(window)
        if variant not in ("akima", "makima"):
            raise ValueError(f"`variant` must be 'akima' or 'makima', got {variant!r}")
        self.variant = variant

    def _fit(self, t, y, dy, tail):
        return _Wrapped(tail, Akima1DInterpolator(t, y, axis=0, method=self.variant,
                                                  extrapolate=True))


class Hermite(Interpolator):
    """Cubic Hermite through given values *and* slopes: the grey-box case (thesis 4.3.4).

    With exact slopes it is fourth-order accurate and needs only the interval's two end points,
    so the window is short.
    """

    name = "hermite"
    default_window = 4
    reproduces = 3
    uses_derivatives = True

    def _fit(self, t, y, dy, tail):
        return _Wrapped(tail, CubicHermiteSpline(t, y, dy, axis=0, extrapolate=True))


class CubicConvolution(Interpolator):
    """Keys' cubic convolution, kernel parameter a = −1/2 (MATLAB 5 ``interp1 'v5cubic'``).

    On uniform spacing Keys' kernel with a = −1/2 *is* the cubic Hermite interpolant whose slope
    at each point is the central difference, and Keys' end condition (a virtual point
    ``3y₀ − 3y₁ + y₂``) gives the one-sided three-point slope. Both are the slope of the parabola
    through the point and its two nearest neighbours. We use exactly that definition on any
    spacing — a *local* generalisation, not a resampling — so the method coincides with Keys'
    on uniform grids and keeps its properties everywhere: quadratics are reproduced, the error
    is O(h³) and no grid is invented (MATLAB 5 fell back to ``spline`` on non-uniform data).
    """

    name = "cubic-convolution"
    default_window = 6
    reproduces = 2

    def _fit(self, t, y, dy, tail):
        return _Wrapped(tail, CubicHermiteSpline(t, y, parabola_slopes(t, y), axis=0,
                                                 extrapolate=True))


def parabola_slopes(t: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Slope at each point of the parabola through it and its two nearest neighbours.

    Inside: the weighted mean ``(h₁δ₀ + h₀δ₁)/(h₀ + h₁)`` of the neighbouring divided
    differences; at the ends the one-sided three-point formula; with two points the chord slope.
    """
    h = np.diff(t)[:, None]
    d = np.diff(y, axis=0) / h
    if len(t) == 2:
        return np.vstack([d, d])
    s = np.empty_like(y)
    s[1:-1] = (h[1:] * d[:-1] + h[:-1] * d[1:]) / (h[:-1] + h[1:])
    s[0] = ((2 * h[0] + h[1]) * d[0] - h[0] * d[1]) / (h[0] + h[1])
    s[-1] = ((2 * h[-1] + h[-2]) * d[-1] - h[-1] * d[-2]) / (h[-1] + h[-2])
    return s


class Polyfit(Interpolator):
    """Least-squares polynomial of ``degree`` over the window (MATLAB ``polyfit``, thesis 4.3.1).

    With ``window = degree + 1`` (the default) it interpolates, as the thesis's cubic through
    four points; a longer window smooths. Fewer points than ``degree + 1`` lower the degree.

    Parameters
    ----------
    degree:
        Polynomial degree, ≥ 0.
    """

    name = "polyfit"
    default_window = 4
    min_window = 1

    def __init__(self, window: int | None = None, degree: int = 3) -> None:
        if isinstance(degree, bool) or not isinstance(degree, int | np.integer) or degree < 0:
            raise ValueError(f"`degree` must be an integer ≥ 0, got {degree!r}")
        self.degree = int(degree)
        super().__init__(self.degree + 1 if window is None else window)
        if self.window < self.degree + 1:
            raise ValueError(f"`window` ({self.window}) must be ≥ `degree` + 1 = "
                             f"{self.degree + 1} for method 'polyfit'")

    @property
    def reproduces(self) -> int:  # type: ignore[override]
        return self.degree

    def _fit(self, t, y, dy, tail):
        degree = min(self.degree, len(t) - 1)
        # Centre on the newest point and scale by the window length: the Vandermonde matrix
        # stays well conditioned however late in the run the window sits.
        scale = t[-1] - t[0]
        coef = np.polyfit((t - t[-1]) / scale, y, degree)  # (degree + 1, m), highest first
        return _PolyCurve(tail, coef, t[-1], scale)


class _PolyCurve(Curve):
    def __init__(self, tail: tuple[int, ...], coef: np.ndarray, t0: float, scale: float) -> None:
        super().__init__(tail)
        self._coef, self._t0, self._scale = coef, t0, scale
        deg = len(coef) - 1
        self._dcoef = coef[:-1] * np.arange(deg, 0, -1)[:, None] / scale

    def _evaluate(self, t: np.ndarray, nu: int) -> np.ndarray:
        x = ((t - self._t0) / self._scale)[:, None]
        coef = self._coef if nu == 0 else self._dcoef
        out = np.zeros((t.size, coef.shape[1]))
        for c in coef:  # Horner, all columns at once
            out = out * x + c
        return out


class Lagrange(Interpolator):
    """Interpolating polynomial through the window's points, in barycentric form.

    Only over a few points: a global polynomial through a long history oscillates wildly (Runge)
    and costs O(n²). Degree = window − 1; the default cubic is the thesis's polynomial.
    """

    name = "lagrange"
    default_window = 4

    @property
    def reproduces(self) -> int:  # type: ignore[override]
        return self.window - 1

    def _fit(self, t, y, dy, tail):
        # Scaled abscissae keep the barycentric weights O(1) for small steps; a fixed `rng`
        # (SciPy shuffles the points when computing the weights) makes refits reproducible.
        scale = t[-1] - t[0]
        return _Barycentric(tail, BarycentricInterpolator((t - t[-1]) / scale, y, axis=0,
                                                    rng=0),
                            t[-1], scale)


class _ScaledCurve(Curve):
    """A SciPy interpolant fitted on the normalised time ``(t − t0) / scale``."""

    def __init__(self, tail: tuple[int, ...], fitted: Any, t0: float, scale: float) -> None:
        super().__init__(tail)
        self._fitted, self._t0, self._scale = fitted, t0, scale


class _Barycentric(_ScaledCurve):

    def _evaluate(self, t: np.ndarray, nu: int) -> np.ndarray:
        x = (t - self._t0) / self._scale
        if nu == 0:
            return self._fitted(x)
        return self._fitted.derivative(x, 1) / self._scale


class Rbf(Interpolator):
    """Radial basis function interpolant (SciPy ``RBFInterpolator``) in one dimension.

    Times are scaled to the window, ``(t − t_last)/(t_last − t_first)``, so ``epsilon`` is
    relative to the window length. SciPy gives no derivative of the interpolant, so the slope is
    its central difference with a step of 10⁻⁵ window lengths; that error (≈10⁻¹⁰ relative) is far
    below the method's own.

    Parameters
    ----------
    kernel, epsilon, degree:
        As in ``scipy.interpolate.RBFInterpolator``; the default thin-plate spline with a linear
        polynomial needs no shape parameter and reproduces straight lines.
    """

    name = "rbf"
    default_window = 6
    _step = 1e-5

    def __init__(self, window: int | None = None, kernel: str = "thin_plate_spline",
                 epsilon: float | None = None, degree: int | None = None) -> None:
        super().__init__(window)
        self.kernel, self.epsilon, self.degree = kernel, epsilon, degree
        try:  # check the options now, not at the master's first call
            RBFInterpolator(np.linspace(0.0, 1.0, max(self.window, 4))[:, None],
                            np.zeros(max(self.window, 4)), kernel=kernel, epsilon=epsilon,
                            degree=degree)
        except ValueError as exc:
            raise ValueError(f"method 'rbf': bad `kernel`/`epsilon`/`degree`: {exc}") from exc

    @property
    def reproduces(self) -> int:  # type: ignore[override]
        if self.degree is not None:
            return self.degree
        return 1 if self.kernel in ("thin_plate_spline", "cubic") else 0

    def _fit(self, t, y, dy, tail):
        scale = t[-1] - t[0]
        degree = self.degree
        if degree is not None and len(t) < degree + 1:
            degree = len(t) - 1
        fitted = RBFInterpolator(((t - t[-1]) / scale)[:, None], y, kernel=self.kernel,
                                 epsilon=self.epsilon, degree=degree)
        return _RbfCurve(tail, fitted, t[-1], scale)


class _RbfCurve(_ScaledCurve):

    def _evaluate(self, t: np.ndarray, nu: int) -> np.ndarray:
        x = (t - self._t0) / self._scale
        if nu == 0:
            return self._fitted(x[:, None])
        d = Rbf._step
        both = self._fitted(np.concatenate([x + d, x - d])[:, None])
        return (both[: t.size] - both[t.size:]) / (2 * d * self._scale)


# --- Bézier (thesis appendix E) ------------------------------------------------------------


class Bezier(Interpolator):
    """The smooth cubic Bézier curve through the points of thesis appendix E ("external Bezier").

    The points ``(t_i, y_i)`` are joined by cubic Bézier segments, each with parameter
    ``s ∈ [0, 1]``; the inner control points make first and second derivatives with respect to
    ``s`` continuous at the joints and the second derivative zero at both ends
    (:func:`bezier_control_points`). Time is one coordinate of the curve like the values, so a
    query at time ``t`` first solves ``t(s) = t`` on its segment (Newton inside a bracket).

    On uniform spacing ``t(s)`` is linear and the curve *is* the natural cubic spline; on
    non-uniform spacing it differs (each segment gets the same parameter length, whatever its
    duration). Beyond the last point the last segment's cubics are extended.
    """

    name = "bezier"
    default_window = 8

    def _fit(self, t, y, dy, tail):
        p1, p2 = bezier_control_points(np.column_stack([t, y]))
        p0, p3 = np.column_stack([t, y])[:-1], np.column_stack([t, y])[1:]
        # Power basis per segment: B(s) = a + b s + c s² + d s³.
        coef = np.stack([p0, 3 * (p1 - p0), 3 * (p0 - 2 * p1 + p2), p3 - p0 + 3 * (p1 - p2)])
        return _BezierCurve(tail, t, coef)


def bezier_control_points(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inner control points ``P1``, ``P2`` of each segment of the smooth Bézier (appendix E).

    Segment ``i`` runs from point ``i`` (``P0``) to point ``i + 1`` (``P3``). Conditions, with
    ``n`` segments: C¹ joints ``P1[i+1] + P2[i] = 2 P0[i+1]``; C² joints
    ``P1[i] + 2 P1[i+1] = P2[i+1] + 2 P2[i]``; zero curvature at the ends ``2 P1[0] − P2[0] =
    P0[0]`` and ``2 P2[n−1] − P1[n−1] = P0[n]``. Eliminating ``P2`` leaves a tridiagonal system
    for ``P1`` with rows ``(2, 1)``, ``(1, 4, 1)`` … and ``(1, 3.5)``; every coordinate (time
    and each signal) is solved at once.

    Parameters
    ----------
    points:
        Array ``(n + 1, d)``, ``n ≥ 1``.

    Returns
    -------
    ``(P1, P2)``, each ``(n, d)``.
    """
    p = np.asarray(points, dtype=float)
    n = len(p) - 1
    if n == 1:  # one segment: the straight line, control points at thirds
        p1 = (2 * p[0] + p[1]) / 3
        return p1[None], (2 * p1 - p[0])[None]
    rhs = np.empty((n, p.shape[1]))
    rhs[0] = p[0] + 2 * p[1]
    rhs[1:n - 1] = 4 * p[1:n - 1] + 2 * p[2:n]
    rhs[n - 1] = (8 * p[n - 1] + p[n]) / 2
    bands = np.empty((3, n))
    bands[0], bands[2] = 1.0, 1.0
    bands[1] = 4.0
    bands[1, 0], bands[1, -1] = 2.0, 3.5
    p1 = solve_banded((1, 1), bands, rhs)
    p2 = np.empty_like(p1)
    p2[:-1] = 2 * p[1:n] - p1[1:]
    p2[-1] = (p[n] + p1[-1]) / 2
    return p1, p2


class _BezierCurve(Curve):
    _iterations = 30

    def __init__(self, tail: tuple[int, ...], knots: np.ndarray, coef: np.ndarray) -> None:
        super().__init__(tail)
        self._knots = knots
        self._ct = coef[:, :, 0]      # (4, n) time coordinate
        self._cy = coef[:, :, 1:]     # (4, n, m) signals
        span = knots[-1] - knots[0]
        # Uniform spacing: t(s) is exactly linear, no root finding needed.
        self._linear = bool(np.all(np.abs(self._ct[2:]) <= 1e-13 * span))
        self._last: tuple[np.ndarray, tuple[np.ndarray, np.ndarray]] | None = None

    def _parameter(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Segment index and parameter ``s`` with ``t(s) = t``."""
        k = self._knots
        seg = np.clip(np.searchsorted(k, t, side="right") - 1, 0, len(k) - 2)
        a, b, c, d = (ci[seg] for ci in self._ct)
        s = (t - k[seg]) / (k[seg + 1] - k[seg])
        if self._linear:
            return seg, s
        # Safeguarded Newton: inside a segment the root is bracketed by [0, 1] (t(0) < t < t(1)),
        # outside (extrapolation) plain Newton from the chord guess.
        inside = (s >= 0.0) & (s <= 1.0)
        lo = np.where(inside, 0.0, -np.inf)
        hi = np.where(inside, 1.0, np.inf)
        tol = 4 * np.finfo(float).eps * (abs(k[-1]) + (k[-1] - k[0]))
        for _ in range(self._iterations):
            f = a + s * (b + s * (c + s * d)) - t
            done = np.abs(f) <= tol
            if np.all(done):
                break
            lo = np.where(f < 0, s, lo)
            hi = np.where(f > 0, s, hi)
            fp = b + s * (2 * c + 3 * s * d)
            with np.errstate(divide="ignore", invalid="ignore"):
                step = s - f / fp
            bad = ~np.isfinite(step) | (inside & ((step < lo) | (step > hi)))
            step = np.where(bad, np.where(inside, 0.5 * (lo + hi), s), step)
            s = np.where(done, s, step)  # converged entries stay put
        return seg, s

    def _evaluate(self, t: np.ndarray, nu: int) -> np.ndarray:
        # The master reads value and slope at the same times: solve t(s) = t once for both.
        if self._last is not None and np.array_equal(self._last[0], t):
            seg, s = self._last[1]
        else:
            seg, s = self._parameter(t)
            self._last = (t.copy(), (seg, s))
        a, b, c, d = (ci[seg] for ci in self._cy)
        x = s[:, None]
        if nu == 0:
            return a + x * (b + x * (c + x * d))
        _, bt, ct, dt = (ci[seg] for ci in self._ct)
        dtds = bt + s * (2 * ct + 3 * s * dt)
        return (b + x * (2 * c + 3 * x * d)) / dtds[:, None]


# --- registry ------------------------------------------------------------------------------

INTERPOLATORS: dict[str, type[Interpolator]] = {
    c.name: c for c in (Hold, Linear, Polyfit, SplineNatural, SplineNotAKnot, Pchip, Akima,
                        CubicConvolution, Lagrange, Rbf, Bezier, Hermite)
}
"""Interpolation methods by name."""


def make_interpolator(name: str, **options: Any) -> Interpolator:
    """Build an interpolation method by name, e.g. ``make_interpolator("polyfit", degree=2)``.

    Raises
    ------
    ValueError
        For an unknown ``name`` (listing the valid ones) or an option the method does not take.
    """
    cls = INTERPOLATORS.get(name) if isinstance(name, str) else None
    if cls is None:
        raise ValueError(f"unknown interpolation method `name`={name!r}; choose one of "
                         f"{', '.join(INTERPOLATORS)}")
    accepted = [p for p in inspect.signature(cls.__init__).parameters if p != "self"]
    unknown = sorted(set(options) - set(accepted))
    if unknown:
        raise ValueError(f"interpolation method '{name}' has no option(s) "
                         f"{', '.join(f'`{u}`' for u in unknown)}; it takes "
                         f"{', '.join(f'`{a}`' for a in accepted)}")
    return cls(**options)


__all__ = ["INTERPOLATORS", "Curve", "Interpolator", "bezier_control_points",
           "make_interpolator", "parabola_slopes"]

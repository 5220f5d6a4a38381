"""Sub-models made from an ODE right-hand side and an internal solver (thesis 4.1).

The master chooses the communication step ``h`` (the thesis's ΔT); the internal solver takes its
own local steps Δt inside it. ``RK4`` uses a fixed number of equal sub-steps (Δt = ΔT / n, an
integer fraction as in thesis 4.1); ``SolveIvp`` uses SciPy's adaptive solvers with tolerances.

Inputs follow the polynomial the master sets (value and up to two derivatives), so higher-order
input extrapolation actually reaches the equations — the analogue of FMI's
``setRealInputDerivatives``. Parameters may change at given times; a step that straddles such a
time is integrated piecewise, so the sub-model stays exact even if a master does not land on it.
"""

from __future__ import annotations

import bisect
import dataclasses
import itertools
import math
import numbers
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from scipy.integrate import BDF, DOP853, LSODA, RK23, RK45, Radau
from scipy.optimize import approx_fprime

from cosimstep.errors import is_number
from cosimstep.submodel import Capabilities, Port, SubModel

Rhs = Callable[[float, np.ndarray, np.ndarray, Mapping[str, float]], np.ndarray]
"""``rhs(t, x, u, p) -> dx/dt`` with states ``x``, inputs ``u`` and parameters ``p``."""


INPUT_ORDER = 3  # input derivatives an ODE sub-model follows (the corrector's cubic needs 3)


def _taylor(value: np.ndarray, derivatives: np.ndarray, dt: float) -> np.ndarray:
    """``value + Σ_k derivatives[k-1]·dt^k/k!`` — an input polynomial evaluated ``dt`` ahead."""
    out = np.array(value, dtype=float)
    term = 1.0
    for k, d in enumerate(derivatives, start=1):
        term *= dt / k
        out = out + term * d
    return out


class InputPolynomial:
    """The inputs' polynomial over one step, evaluated where a right-hand side asks for it.

    Same values, bit for bit, as :func:`_taylor` (the same floating-point operations in the same
    order, one input at a time), but on Python floats: with a few inputs, NumPy's per-call cost
    made the input polynomial a third of a small ODE sub-model's step, as it runs on every
    right-hand-side evaluation. Every derivative row is kept, zero or not: adding a zero term
    turns a sum of ``-0.0`` into ``+0.0``, which ``arctan2`` and the like tell apart.
    """

    __slots__ = ("_columns", "_order")

    def __init__(self, value: np.ndarray, derivatives: np.ndarray) -> None:
        self._order = len(derivatives)
        self._columns = list(zip(np.asarray(value, dtype=float).tolist(),
                                 *np.asarray(derivatives[:self._order], dtype=float).tolist()))

    def __call__(self, dt: float) -> np.ndarray:
        order, columns = self._order, self._columns
        if order == 3:  # INPUT_ORDER rows, as the ODE adapter holds them: written out
            t1 = 1.0 * (dt / 1)
            t2 = t1 * (dt / 2)
            t3 = t2 * (dt / 3)
            return np.array([((u + t1 * a) + t2 * b) + t3 * c for u, a, b, c in columns])
        terms = [1.0]
        for k in range(1, order + 1):
            terms.append(terms[-1] * (dt / k))
        out = []
        for column in columns:
            o = column[0]
            for term, d in zip(terms[1:], column[1:]):
                o = o + term * d
            out.append(o)
        return np.array(out, dtype=float)


class ParameterSchedule:
    """Parameter values that change at given times (the thesis's "toggled" dynamics).

    ``changes`` is a sequence of ``(time, {name: value})``; a change holds from its time until the
    next one. Values at exactly a change time belong to the new segment.
    """

    def __init__(
        self,
        base: Mapping[str, float],
        changes: Sequence[tuple[float, Mapping[str, float]]] = (),
    ) -> None:
        ordered = sorted(changes, key=lambda c: c[0])
        self.times: list[float] = [float(t) for t, _ in ordered]
        self._segments: list[dict[str, float]] = [dict(base)]
        for _, values in ordered:
            self._segments.append({**self._segments[-1], **values})

    def at(self, t: float) -> dict[str, float]:
        return self._segments[bisect.bisect_right(self.times, t)]

    def breakpoints(self, t0: float, t1: float) -> list[float]:
        """Change times strictly inside ``(t0, t1)``."""
        return [t for t in self.times if t0 < t < t1]


def one_side(a: float, b: float, events: set[float] | frozenset[float]) -> tuple[float, float]:
    """The times a right-hand side is evaluated at on the piece ``[a, b]``, kept on the piece's
    own side of a time event at either end.

    A solver's stage at ``b`` would otherwise see the value after a jump at ``b`` written as a
    function of time (``0.05 if t >= 1 else 0``) — a wrong force for a whole stage (measured:
    x' = [t >= 1] integrated by RK4 to t = 1 with 0.01 s steps gave 1.7e-3 instead of 0).
    The shift is a few ulps of ``t``.
    """
    lo = math.nextafter(a, b) if a in events else a
    hi = math.nextafter(b, a) if b in events else b
    return lo, hi


class InternalSolver(Protocol):
    """Advances ``dx/dt = f(t, x)`` from ``t0`` to ``t1``; the sub-model's own business.

    ``jac(t, x)``, when the sub-model has one, is the Jacobian ``∂f/∂x`` (used by implicit
    methods; others ignore it)."""

    def advance(self, f: Callable[[float, np.ndarray], np.ndarray], t0: float, t1: float,
                x: np.ndarray, jac: Callable[[float, np.ndarray], np.ndarray] | None = None,
                ) -> np.ndarray: ...


@dataclass(frozen=True)
class RK4:
    """Classical Runge–Kutta with ``n`` equal local steps per communication step.

    ``n = max(substeps, ceil(h / max_dt))``: a fixed count, or a fixed largest local step.
    """

    substeps: int = 1
    max_dt: float | None = None

    def __post_init__(self) -> None:
        if not (isinstance(self.substeps, numbers.Integral)
                and not isinstance(self.substeps, bool) and self.substeps >= 1):
            raise ValueError(f"RK4 needs substeps >= 1, got {self.substeps!r}")
        if self.max_dt is not None and not self.max_dt > 0:
            raise ValueError(f"RK4 needs max_dt > 0, got {self.max_dt!r}")

    def advance(self, f: Callable[[float, np.ndarray], np.ndarray], t0: float, t1: float,
                x: np.ndarray, jac: Callable[[float, np.ndarray], np.ndarray] | None = None,
                ) -> np.ndarray:
        h = t1 - t0
        n = self.substeps
        if self.max_dt is not None:
            n = max(n, math.ceil(h / self.max_dt - 1e-9))
        dt = h / n
        for i in range(n):
            t = t0 + i * dt
            k1 = f(t, x)
            k2 = f(t + 0.5 * dt, x + 0.5 * dt * k1)
            k3 = f(t + 0.5 * dt, x + 0.5 * dt * k2)
            k4 = f(t + dt, x + dt * k3)
            x = x + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        return x


IMPLICIT = ("Radau", "BDF")
"""Methods that use a Jacobian (and so can be handed the one of the previous call)."""


@dataclass
class SolveIvp:
    """One of SciPy's adaptive solvers (``RK45``, ``RK23``, ``DOP853``, ``Radau``, ``BDF``,
    ``LSODA``) inside every communication step, with its own tolerances.

    The solver object lives for one communication step, but what it learnt does not have to
    die with it: the next step starts from the step size the last one ended with (instead of
    SciPy's fresh estimate and growth from a small step, which costs most of the right-hand
    side evaluations when the communication step holds few internal steps), and an implicit
    method starts from the last Jacobian (SciPy re-evaluates it if Newton's iteration stalls,
    so a Jacobian made stale by new inputs costs a retry, not accuracy). ``carry=False`` starts
    every step afresh, as ``solve_ivp`` does (the numbers of a model-exchange FMU integrated with
    the same settings). ``first_step`` is the very first internal step (default: SciPy's
    estimate), ``max_step`` the largest. A sub-model takes its own copy (:meth:`for_model`), so
    two sub-models never share what they learnt.
    """

    method: str = "RK45"
    rtol: float = 1e-8
    atol: float = 1e-10
    first_step: float | None = None
    max_step: float = math.inf
    carry: bool = True
    _step: float | None = field(default=None, init=False, repr=False, compare=False)
    _jacobian: np.ndarray | None = field(default=None, init=False, repr=False, compare=False)

    def for_model(self) -> SolveIvp:
        """A fresh copy with nothing learnt, for one sub-model."""
        return dataclasses.replace(self)

    def advance(self, f: Callable[[float, np.ndarray], np.ndarray], t0: float, t1: float,
                x: np.ndarray, jac: Callable[[float, np.ndarray], np.ndarray] | None = None,
                ) -> np.ndarray:
        if t1 <= t0:
            return np.asarray(x, dtype=float)
        if not self.carry:
            self._step = self._jacobian = None
        options: dict[str, Any] = {"rtol": self.rtol, "atol": self.atol,
                                   "max_step": self.max_step}
        first = self._step if self._step is not None else self.first_step
        if first is not None:
            options["first_step"] = min(first, t1 - t0)
        if self.method in IMPLICIT:
            options["jac"] = jac if jac is not None else self._reused_jacobian(f)
        solver = METHODS[self.method](f, t0, np.asarray(x, dtype=float), t1, **options)
        proposed = None  # the step size the solver chose before the last step was cut to t1
        while solver.status == "running":
            if solver.t > t0:
                proposed = getattr(solver, "h_abs", None)
            solver.step()
        if solver.status == "failed":
            raise RuntimeError(f"internal solver {self.method} failed at t = {solver.t}")
        last = proposed if proposed is not None else getattr(solver, "h_abs", None)
        if last is not None and last > 0:
            self._step = float(min(last, self.max_step))
        if self.method in IMPLICIT and jac is None:
            self._jacobian = np.array(solver.J.toarray() if hasattr(solver.J, "toarray")
                                      else solver.J)
        return solver.y

    def _reused_jacobian(self, f: Callable[[float, np.ndarray], np.ndarray]
                         ) -> Callable[[float, np.ndarray], np.ndarray] | None:
        """The last step's Jacobian the first time the solver asks, forward differences after
        (``None`` on the first step: SciPy's own finite differences)."""
        if self._jacobian is None:
            return None
        kept = [self._jacobian]

        def jacobian(t: float, y: np.ndarray) -> np.ndarray:
            if kept:
                return kept.pop()
            eps = np.sqrt(np.finfo(float).eps) * np.maximum(1.0, np.abs(y))
            return np.reshape(approx_fprime(y, lambda z: f(t, z), eps), (y.size, y.size))

        return jacobian


METHODS = {"RK45": RK45, "RK23": RK23, "DOP853": DOP853, "Radau": Radau, "BDF": BDF,
           "LSODA": LSODA}


SOLVER_OPTIONS = {"rk4": {"substeps": "int", "max_dt": "step"},
                  "scipy": {"rtol": "tolerance", "atol": "tolerance", "first_step": "step",
                            "max_step": "step", "carry": "bool"}}
"""The options of a configured internal solver and what each must be."""


def make_solver(spec: Mapping[str, Any] | None) -> InternalSolver:
    """Build an internal solver from a configuration mapping such as ``{"method": "rk4"}``.

    Every option is checked here — name, type and range — and every problem named in one
    ``ValueError``: a negative ``substeps`` or ``max_dt`` once ran without a word and returned
    an order-one error (issue 13's new-user trial)."""
    spec = dict(spec or {})
    method = str(spec.pop("method", "rk4")).lower()
    chosen = "rk4" if method == "rk4" else next((m for m in METHODS if m.lower() == method),
                                                None)
    if chosen is None:
        raise ValueError(f"unknown solver method '{method}'; choose rk4 or one of "
                         f"{', '.join(METHODS)}")
    known = SOLVER_OPTIONS["rk4" if chosen == "rk4" else "scipy"]
    spec = {k: v for k, v in spec.items() if v is not None}  # None: the option's default
    wrong = [_solver_option_problem(key, value, known) for key, value in spec.items()]
    wrong = [w for w in wrong if w]
    if wrong:
        raise ValueError(f"{chosen}: " + "; ".join(wrong))
    if "substeps" in spec:
        spec["substeps"] = int(spec["substeps"])  # 2.0 from a file is 2
    return RK4(**spec) if chosen == "rk4" else SolveIvp(method=chosen, **spec)


def _solver_option_problem(key: str, value: Any, known: Mapping[str, str]) -> str | None:
    """What is wrong with one solver option (``None``: nothing)."""
    kind = known.get(key)
    if kind is None:
        return f"no option '{key}' (its options: {', '.join(known)})"
    number = is_number(value)
    if kind == "bool":
        return None if isinstance(value, bool | np.bool_) else f"'{key}' must be true or false"
    if kind == "int":
        ok = number and float(value).is_integer() and value >= 1
        return None if ok else f"'{key}' must be a whole number >= 1, got {value!r}"
    ok = number and value > 0 and (kind == "step" or math.isfinite(value)) and value == value
    return None if ok else f"'{key}' must be a positive number, got {value!r}"


class OdeSubModel(SubModel):
    """A sub-model ``dx/dt = rhs(t, x, u(t), p(t))`` whose outputs are (some of) its states.

    Parameters
    ----------
    rhs:
        Right-hand side ``rhs(t, x, u, p)``.
    states:
        One port per state; ``start`` is the initial value and ``unit`` its unit.
    inputs:
        Input ports, in the order ``u`` is passed to ``rhs``.
    outputs:
        Names of the states exposed as outputs (default: all states).
    parameters:
        A :class:`ParameterSchedule` (or a plain mapping for constant parameters).
    solver:
        The internal solver, :class:`RK4` or :class:`SolveIvp`.
    time_events:
        Times where ``rhs`` itself is discontinuous in ``t`` (a step in a forcing term, say).
        They are announced to the master like parameter changes, and a step straddling one is
        integrated piecewise. Parameter change times are announced without being listed here.
    jac:
        ``jac(t, x, u, p) -> ∂rhs/∂x``, for implicit internal solvers (``Radau``, ``BDF``);
        without it they use finite differences.
    """

    def __init__(
        self,
        rhs: Rhs,
        states: Sequence[Port],
        inputs: Sequence[Port] = (),
        outputs: Sequence[str] | None = None,
        parameters: ParameterSchedule | Mapping[str, float] | None = None,
        solver: InternalSolver | None = None,
        time_events: Sequence[float] = (),
        jac: Rhs | None = None,
    ) -> None:
        self._rhs = rhs
        self._jac = jac
        self._events = tuple(sorted(float(e) for e in time_events))
        self._states = tuple(states)
        self.inputs = tuple(inputs)
        names = [s.name for s in self._states]
        chosen = list(outputs) if outputs is not None else names
        unknown = [o for o in chosen if o not in names]
        if unknown:
            raise ValueError(f"`outputs` names unknown states {unknown}; states are {names}")
        self._out_idx = np.array([names.index(o) for o in chosen], dtype=int)
        self.outputs = tuple(self._states[i] for i in self._out_idx)
        if not isinstance(parameters, ParameterSchedule):
            parameters = ParameterSchedule(parameters or {})
        self.parameters = parameters
        solver = solver or RK4()
        # an adaptive solver carries what it learnt from step to step: one copy per sub-model
        self.solver: InternalSolver = solver.for_model() if isinstance(solver, SolveIvp) \
            else solver
        self.capabilities = Capabilities(
            can_save_state=True, provides_derivatives=True, max_input_derivative_order=INPUT_ORDER
        )
        n_in = len(self.inputs)
        self._u = np.array([p.start if p.start is not None else 0.0 for p in self.inputs], float)
        self._du = np.zeros((INPUT_ORDER, n_in))
        self._x = np.array([s.start if s.start is not None else 0.0 for s in self._states], float)
        self._t = 0.0

    # -- SubModel API ----------------------------------------------------------------------
    def initialize(self, t0: float) -> None:
        if isinstance(self.solver, SolveIvp):
            # what the internal solver learnt (its step size, an implicit method's Jacobian)
            # belongs to the last run: kept, a second run of the same system started from it
            # and differed from the first (the ship plant at tol 1e-3: 14,104 calls, then
            # 14,048)
            self.solver = self.solver.for_model()
        self._t = float(t0)
        self._u = np.array([p.start if p.start is not None else 0.0 for p in self.inputs], float)
        self._du = np.zeros((INPUT_ORDER, len(self.inputs)))
        self._x = np.array([s.start if s.start is not None else 0.0 for s in self._states], float)

    def set_inputs(self, values: np.ndarray) -> None:
        self._u = np.array(values, dtype=float)
        self._du[:] = 0.0

    def set_input_derivatives(self, derivatives: np.ndarray) -> None:
        d = np.asarray(derivatives, dtype=float)
        self._du[:] = 0.0
        self._du[: d.shape[0]] = d[:INPUT_ORDER]

    def do_step(self, t: float, h: float) -> None:
        t_start, u0, du = self._t, self._u, self._du
        polynomial = InputPolynomial(u0, du) if du.any() else None

        def inputs_at(s: float) -> np.ndarray:
            if polynomial is None:
                return u0
            return polynomial(s - t_start)

        x = self._x
        rhs = self._rhs
        inner = self.breakpoints(t, t + h)
        cuts = [t, *inner, t + h]
        events = set(inner) | ({t} if t in self._events else set()) \
            | ({t + h} if t + h in self._events else set())
        for a, b in itertools.pairwise(cuts):
            p = self.parameters.at(a)
            lo, hi = one_side(a, b, events)
            jac = None if self._jac is None else (
                lambda s, y, p=p, lo=lo, hi=hi: self._jac(min(max(s, lo), hi), y, inputs_at(s), p))
            x = self.solver.advance(
                lambda s, y, p=p, lo=lo, hi=hi: rhs(min(max(s, lo), hi), y, inputs_at(s), p),
                a, b, x, jac)
        self._x = np.asarray(x, dtype=float)
        self._t = t + h
        # The input polynomial is re-expanded around the new time so outputs and derivatives
        # read now see the inputs valid now.
        dt = self._t - t_start
        self._u = _taylor(u0, du, dt)
        self._du = np.array([_taylor(du[j], du[j + 1:], dt) for j in range(len(du))])

    def get_outputs(self) -> np.ndarray:
        return self._x[self._out_idx]

    def get_output_derivatives(self) -> np.ndarray:
        dx = self._rhs(self._t, self._x, self._u, self.parameters.at(self._t))
        return np.asarray(dx, dtype=float)[self._out_idx]

    def save_state(self) -> Any:
        return (self._t, self._x.copy(), self._u.copy(), self._du.copy())

    def restore_state(self, token: Any) -> None:
        t, x, u, du = token
        self._t, self._x, self._u, self._du = t, x.copy(), u.copy(), du.copy()

    def time_events(self) -> Sequence[float]:
        return tuple(sorted({*self.parameters.times, *self._events}))

    def breakpoints(self, t0: float, t1: float) -> list[float]:
        """Discontinuities strictly inside ``(t0, t1)``: parameter changes and time events."""
        return [t for t in self.time_events() if t0 < t < t1]

    @property
    def state_ports(self) -> tuple[Port, ...]:
        return self._states

    def derivative(self, t: float, x: np.ndarray, u: np.ndarray,
                   p: Mapping[str, float]) -> np.ndarray:
        """The right-hand side itself (used by the monolithic reference solver)."""
        return np.asarray(self._rhs(t, x, u, p), dtype=float)

    @property
    def state(self) -> np.ndarray:
        """Current state vector (for inspection and tests)."""
        return self._x.copy()

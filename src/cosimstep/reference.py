"""The monolithic reference and the error a co-simulation reached against it (thesis 4.2.2.1).

The reference is the same system as one model, integrated by SciPy ``solve_ivp`` with DOP853 at
``rtol = atol = 1e-12``, piecewise between parameter changes so that a jump is never smoothed
over. Errors are evaluated at the communication points the co-simulation produced — the only
points where it has values of its own, so no interpolation error enters the measurement.
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.integrate import solve_ivp

from cosimstep.adapters.ode import OdeSubModel, one_side

RTOL = ATOL = 1e-12


@dataclass
class Reference:
    """A monolithic ODE model plus the map ``{"cosim.output": "monolithic_state"}``.

    ``derived``: the model's quantities that are no state (a coupling force), each computed
    from the states and the parameters at the time; the map may name them too, so that an
    output the split exchanges, and the tolerance bounds, is measured like the states.
    """

    model: OdeSubModel
    mapping: Mapping[str, str]
    derived: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        # checked now, not when the finished run's error is measured: a run that cannot be
        # measured should not be run first
        states = {p.name for p in self.model.state_ports}
        unknown = sorted(v for v in self.mapping.values() if v not in states
                         and v not in self.derived)
        if unknown:
            raise ValueError(f"the reference map names {', '.join(map(repr, unknown))}, neither "
                             f"a state ({', '.join(sorted(states))}) nor a quantity computed "
                             f"from them ({', '.join(sorted(self.derived)) or 'none given'})")
    _segments: list = field(default_factory=list, repr=False)
    _span: tuple[float, float] | None = field(default=None, repr=False)

    def solve(self, t0: float, t_end: float) -> None:
        if self._span == (t0, t_end):
            return
        model = self.model
        model.initialize(t0)
        x = model.state
        u = np.zeros(0)
        cuts = [t0, *model.breakpoints(t0, t_end), t_end]
        self._segments = []
        events = frozenset(model.breakpoints(t0, t_end))
        for a, b in itertools.pairwise(cuts):
            p = model.parameters.at(a)
            lo, hi = one_side(a, b, events)
            x = self._segment(a, b, x, lambda s, y, p=p, lo=lo, hi=hi:
                              model.derivative(min(max(s, lo), hi), y, u, p))
        self._span = (t0, t_end)

    def _segment(self, a: float, b: float, x: np.ndarray, f: Any) -> np.ndarray:
        """Integrate ``[a, b]``, stopping at each *state event* of a model that has them
        (``state_events()``: indicators whose rise through zero is an event;
        ``on_state_event(i, t, x)``: what it changes) and going on from there."""
        model = self.model
        while True:
            indicators = model.state_events() if hasattr(model, "state_events") else []
            watched = []
            for g in indicators:
                def crossing(s: float, y: np.ndarray, g: Any = g) -> float:
                    return g(s, y)
                crossing.terminal, crossing.direction = True, 1.0  # type: ignore[attr-defined]
                watched.append(crossing)
            sol = solve_ivp(f, (a, b), x, method=getattr(model, "reference_method", "DOP853"),
                            rtol=RTOL, atol=ATOL, dense_output=True, events=watched or None)
            if not sol.success:
                raise RuntimeError(f"reference solution failed on [{a}, {b}]: {sol.message}")
            hit = [i for i, te in enumerate(sol.t_events or []) if len(te)]
            if sol.status != 1 or not hit:
                self._segments.append((a, b, sol.sol))
                return sol.y[:, -1]
            t_e, x = float(sol.t_events[hit[0]][0]), sol.y_events[hit[0]][0]
            self._segments.append((a, t_e, sol.sol))
            model.on_state_event(hit[0], t_e, x)
            a = t_e

    def values(self, times: np.ndarray, names: list[str]) -> np.ndarray:
        """Reference values of the mapped co-simulation outputs ``names`` at ``times``."""
        states = self._states(times)
        state_names = [p.name for p in self.model.state_ports]
        out = np.empty((len(times), len(names)))
        for j, n in enumerate(names):
            target = self.mapping[n]
            if target in self.derived:
                out[:, j] = self._derived(self.derived[target], times, states)
            else:
                out[:, j] = states[state_names.index(target)]
        return out

    def _states(self, times: np.ndarray) -> np.ndarray:
        """Every state at ``times`` (one row each), from the dense output of its piece."""
        out = np.empty((len(self.model.state_ports), len(times)))
        edges = np.array([s[0] for s in self._segments[1:]])
        which = np.searchsorted(edges, times, side="right")
        for k, (_, _, dense) in enumerate(self._segments):
            mask = which == k
            if mask.any():
                out[:, mask] = dense(times[mask])
        return out

    def _derived(self, quantity: Any, times: np.ndarray, states: np.ndarray) -> np.ndarray:
        """A derived quantity at ``times``, with the parameters in force at each (piecewise)."""
        schedule = self.model.parameters
        which = np.searchsorted(np.asarray(schedule.times, dtype=float), times, side="right")
        out = np.empty(len(times))
        for k in np.unique(which):
            mask = which == k
            out[mask] = quantity(states[:, mask], schedule.at(float(times[mask][0])))
        return out


@dataclass(frozen=True)
class ErrorReport:
    """Max absolute error and RMSE over the mapped variables, plus each variable's maxima.

    ``max_scaled`` is the largest ``|error| / (1 + |reference|)``: the norm the adaptive
    controllers' ``tol`` bounds (with the default ``atol = rtol = tol``), so ``max_scaled / tol``
    says how well a run kept its promise.
    """

    max_abs: float
    rmse: float
    per_variable: dict[str, float]
    points: int
    max_scaled: float = float("nan")
    grid_max_scaled: float | None = None
    """Multi-rate runs only: ``max_scaled`` of the common grid, where each sub-model's values
    between its own points are interpolated (what ``SimulationResult.values`` holds). The
    other fields are at each sub-model's own points, what the sub-models computed; a consumer
    that reacts slowly lets its partner take steps whose in-between values are interpolated
    less accurately than its points (toggled pendulum, tol 1e-4: 7.0e-5 at the own points,
    3.4e-4 on the grid)."""

    def to_dict(self) -> dict:
        out = {"max_abs": self.max_abs, "rmse": self.rmse, "max_scaled": self.max_scaled,
               "per_variable": self.per_variable, "points": self.points}
        if self.grid_max_scaled is not None:
            out["grid_max_scaled"] = self.grid_max_scaled
        return out


def error_report(times: np.ndarray, values: np.ndarray, reference: np.ndarray,
                 names: list[str]) -> ErrorReport:
    diff = np.abs(values - reference)
    scaled = diff / (1.0 + np.abs(reference))
    return ErrorReport(
        max_abs=float(diff.max()) if diff.size else 0.0,
        rmse=float(np.sqrt(np.mean(diff**2))) if diff.size else 0.0,
        per_variable={n: float(diff[:, j].max()) for j, n in enumerate(names)},
        points=len(times), max_scaled=float(scaled.max()) if diff.size else 0.0)

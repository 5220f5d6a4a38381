"""The project's own benchmark problems: chain pendulums split by bar, the linear fast/slow pair.

They reuse :mod:`cosimstep.models.pendulum` and :mod:`cosimstep.models.linear`, so the suite runs
exactly the systems the examples and the thesis tables use.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

from cosimstep.adapters.ode import RK4, ParameterSchedule
from cosimstep.models import linear, pendulum
from cosimstep.reference import Reference
from cosimstep.system import System

THESIS = ("'Towards a comprehensive framework for co-simulation of dynamic models with an "
          "emphasis on time stepping', PhD thesis, 2011")


def _chain(n: int, params: Mapping[str, float], start: Mapping[str, float],
           max_dt: float) -> tuple[System, Reference]:
    """An ``n``-bar pendulum split by bar: bar ``i`` gets every other bar's angle and rate."""
    schedule = ParameterSchedule({**pendulum.default_parameters(n), **params})
    system = System()
    for i in range(1, n + 1):
        system.add(f"bar{i}", pendulum.bar(n, i, schedule, start, RK4(max_dt=max_dt)))
    for i in range(1, n + 1):
        for j in range(1, n + 1):
            if i != j:
                system.connect(f"bar{i}.theta", f"bar{j}.theta{i}")
                system.connect(f"bar{i}.omega", f"bar{j}.omega{i}")
    mapping = {f"bar{i}.{q}": f"{q}{i}" for i in range(1, n + 1) for q in ("theta", "omega")}
    return system, Reference(pendulum.monolithic(n, schedule, start), mapping)


_DOUBLE_START = {"theta1": 0.4, "theta2": -0.3, "omega1": 0.0, "omega2": 0.0}


def pendulum_mixed() -> tuple[System, Reference]:
    """Double pendulum split by bar, slow upper bar l1 = 1 m, faster lower bar l2 = 0.5 m.

    Unit masses, start θ1 = 0.4, θ2 = −0.3 rad at rest, 10 s. Time scales: the two normal modes
    of the linearized chain (periods about 2.3 s and 0.9 s) under moderate nonlinearity. What can
    go wrong: the bars exchange angles *and* angular velocities, the accelerations depend on the
    partner's velocity squared, so extrapolation errors feed back through both; the lower bar
    needs shorter steps than the upper one (the mixed case of thesis table 5).
    """
    return _chain(2, {"l1": 1.0, "l2": 0.5}, _DOUBLE_START, max_dt=1e-3)


def pendulum_strongly_mixed() -> tuple[System, Reference]:
    """Double pendulum with a very short, light lower bar: l1 = 1 m, l2 = 0.05 m, m2 = 0.1 kg.

    Start as :func:`pendulum_mixed`, 10 s. Time scales: the upper bar swings with a period of
    about 2 s, the lower bar at about 15 rad/s (period ≈ 0.43 s) riding on it. What can go
    wrong: a synchronous master must take the lower bar's steps for both; a multi-rate master
    must keep the light bar's reaction on the heavy one (small, but through ω2²) right while
    stretching the upper bar's steps.
    """
    return _chain(2, {"l1": 1.0, "l2": 0.05, "m2": 0.1}, _DOUBLE_START, max_dt=2.5e-4)


def triple_pendulum() -> tuple[System, Reference]:
    """Triple pendulum split into three bars, all masses 1 kg and lengths 1 m.

    Start 10°, −15°, 20° at rest, 10 s. Time scales: three normal modes with periods about
    3.1 s, 1.3 s and 0.8 s (linearized). What can go wrong: every bar receives the angles and
    rates of both others, so Gauss–Seidel ordering and extrapolation errors compound over a
    chain of three sub-models.
    """
    start = {"theta1": math.radians(10.0), "theta2": math.radians(-15.0),
             "theta3": math.radians(20.0), "omega1": 0.0, "omega2": 0.0, "omega3": 0.0}
    return _chain(3, {}, start, max_dt=1e-3)


def _linear(lam: float) -> tuple[System, Reference]:
    schedule = ParameterSchedule({"lam": lam})
    start = linear.start_values(lam)
    system = System()
    system.add("fast", linear.fast(schedule, start, RK4(max_dt=0.005 / lam)))
    system.add("slow", linear.slow(schedule, start, RK4(max_dt=1e-3)))
    system.connect("fast.u", "slow.u")
    system.connect("slow.w", "fast.w")
    mapping = {"fast.u": "u", "fast.v": "v", "slow.w": "w"}
    return system, Reference(linear.monolithic(schedule, start), mapping)


def linear_fast_slow() -> tuple[System, Reference]:
    """Benchmark problem 6: fast oscillator u' = λv + w, v' = −λu and slow lag w' = −w + u.

    λ = 100 rad/s, start u0 = 1 − w0/(λ² + 1), v0 = −w0 λ/(λ² + 1), w0 = 1000, 2 s. Time scales:
    the oscillation (period 0.063 s, amplitude about 1 in u) against the 1 s decay of w (from
    1000). What can go wrong: the slow sub-model's input u oscillates fast with a small
    amplitude; w is large, so the absolute error is dominated by w while the fast part sets the
    step; the scaled error measures both fairly.
    """
    return _linear(100.0)


def linear_lambda1000() -> tuple[System, Reference]:
    """Benchmark problem 9's λ = 1000 variant of problem 6 (start values for that λ), 2 s.

    Time scales: oscillation period 6.3 ms against the 1 s lag: a time-scale ratio of 1000.
    What can go wrong: a synchronous master must resolve the 6 ms oscillation for both
    sub-models; input extrapolation over steps longer than the period is meaningless.
    """
    return _linear(1000.0)

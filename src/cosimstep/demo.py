"""``cosimstep demo``: what cosimstep is for, in one figure.

The toggled double pendulum (the lower bar is fast for 1 s ≤ t < 2 s, thesis 4.2.1) run three
ways — a fixed step of 5 ms, and the default adaptive controller and the multi-rate master at tol
1e-4 — against its monolithic reference. The figure shows the states, each run's communication
steps (each sub-model's own for multirate), and the error over time, with each run's calls in
the legend: the adaptive runs spend their calls where the dynamics are fast, and stay within
their tolerance with fewer calls than the fixed step and less error.
"""

from __future__ import annotations

from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from cosimstep.config import load_system
from cosimstep.controllers import Controller, Fixed, make_controller
from cosimstep.masters import MasterOptions
from cosimstep.result import SimulationResult
from cosimstep.simulate import simulate

EXAMPLE = "double_pendulum_toggled.toml"


@dataclass
class DemoRun:
    label: str
    result: SimulationResult


def _runs() -> list[tuple[str, Controller, MasterOptions]]:
    # both adaptive runs at tol 1e-4 against a fixed step of 5 ms: less error for fewer calls
    return [
        ("fixed step 5 ms", Fixed(0.005), MasterOptions("gauss-seidel", 2)),
        ("adaptive pc, tol 1e-4", make_controller("pc", None, 1e-4),
         MasterOptions("gauss-seidel", 2)),
        ("multirate, tol 1e-4", make_controller("pc", None, 1e-4),
         MasterOptions("multirate", 2)),
    ]


def run_demo(folder: str | Path) -> tuple[list[DemoRun], Path, Path]:
    """The three runs (stored in one results file), the store and the figure."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    db = folder / "demo.db"
    db.unlink(missing_ok=True)
    with resources.as_file(resources.files("cosimstep") / "examples" / EXAMPLE) as path:
        spec = load_system(path)
    runs = []
    for label, controller, master in _runs():
        result = simulate(spec.system, spec.until, controller, master, reference=spec.reference,
                          store=db, name=f"{spec.name}: {label}")
        runs.append(DemoRun(label, result))
    return runs, db, plot_demo(runs, folder / "demo.png")


def plot_demo(runs: list[DemoRun], path: Path) -> Path:
    """States, steps and error over time of the runs, calls in the legend."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (states, steps, errors) = plt.subplots(3, 1, figsize=(9, 8.5), sharex=True,
                                                constrained_layout=True)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    first = runs[1].result  # the adaptive run's states; the others agree to plot width
    for name in ("bar1.theta", "bar2.theta"):
        states.plot(first.times, first[name], lw=1.2, label=name)
    states.set_ylabel("angle [rad]")
    states.set_title("toggled double pendulum (lower bar fast for 1 s ≤ t < 2 s): a fixed step "
                     "against adaptive steps at tol 1e-4", fontsize=10)
    for (run, colour) in zip(runs, colours):
        r = run.result
        label = f"{run.label}: {r.calls_spent} calls, max error {r.error.max_scaled:.1e}"
        _steps(steps, r, colour, run.label)
        if r.error.grid_max_scaled is None:
            errors.semilogy(r.times[1:], _error(r)[1:], color=colour, lw=1, label=label)
            continue
        # multirate: the error at each sub-model's own points, the ones its max is taken
        # over; between them its values are interpolated (the grid's max is in the legend)
        label += f" at own points ({r.error.grid_max_scaled:.1e} interpolated between them)"
        for style, (name, times, error) in zip(("-", "--", ":"), _own_errors(r)):
            errors.semilogy(times[1:], error[1:], color=colour, lw=1, ls=style,
                            label=f"{label}: {name}" if style == "-" else f"{run.label}: {name}")
    for ax in (states, steps, errors):
        ax.axvspan(1.0, 2.0, color="0.9", zorder=0)
        ax.grid(alpha=0.3)
    states.legend(fontsize=8, loc="upper right")
    steps.set_ylabel("step ΔT [s]")
    steps.legend(fontsize=7, loc="upper right", ncol=2)
    errors.set_ylabel("|e| / (1 + |y|)")
    errors.set_xlabel("T [s]")
    errors.legend(fontsize=8, loc="lower right")
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _steps(ax, result: SimulationResult, colour: str, label: str) -> None:
    if len(result.models) > 1 and any(m.corrections for m in result.models.values()):
        for style, (name, stats) in zip(("-", "--", ":"), result.models.items()):
            ax.step(stats.times[:-1], stats.step_sizes, where="post", color=colour, lw=1,
                    ls=style, label=f"{label}: {name}")
        return
    ax.step(result.times[:-1], result.step_sizes, where="post", color=colour, lw=1, label=label)


def _own_errors(result: SimulationResult) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """Per sub-model of a multirate result: its own points' times and largest scaled error
    over its mapped outputs (the reference read from the result's grid, the union of every
    sub-model's own points)."""
    mapped = result.error.per_variable if result.error else {}
    out = []
    for name, stats in result.models.items():
        outputs = [n for n in result.names if n.startswith(f"{name}.")]
        own = [n for n in outputs if n in mapped]
        if not own or result.reference is None:
            continue
        cols = [outputs.index(n) for n in own]
        # a run that stopped early: a sub-model that got ahead has points past the grid's end
        keep = np.asarray(stats.times) <= result.times[-1]
        stats_times, stats_values = np.asarray(stats.times)[keep], stats.values[keep]
        ref = np.column_stack([np.interp(stats_times, result.times,
                                         result.reference[:, list(mapped).index(n)])
                               for n in own])
        error = np.max(np.abs(stats_values[:, cols] - ref) / (1.0 + np.abs(ref)), axis=1)
        out.append((name, stats_times, error))
    return out


def _error(result: SimulationResult) -> np.ndarray:
    """The largest scaled error over the mapped outputs at each point of the result."""
    names = [n for n in result.names if n in (result.error.per_variable if result.error else {})]
    cols = [result.names.index(n) for n in names]
    ref = result.reference[:, :len(names)] if result.reference is not None else None
    if ref is None or not cols:
        return np.zeros(len(result.times))
    return np.max(np.abs(result.values[:, cols] - ref) / (1.0 + np.abs(ref)), axis=1)


SHIP = "ship_plant.toml"
SHIP_PLOTTED = ["zone1.T", "zone2.T", "zone3.T", "chiller.Ts", "network.q1", "network.q2",
                "network.q3", "network.dq", "zone_control.v1", "zone_control.v2",
                "zone_control.v3", "isolation.iso", "isolation.xc", "isolation.pump_b"]


def run_ship_demo(folder: str | Path) -> tuple[SimulationResult, Path, Path]:
    """The ship plant's scenario (normal operation, a hit at 200 s, isolation, recovery, a load
    step at 400 s) under the multi-rate master, ``pc`` at tol 1e-3 as the file sets it, against
    its monolithic reference; the run stored, and a figure of temperatures, flows, valve states
    and each sub-model's steps with the events marked. Multi-rate, because the plant is made
    for it: the zones and the chiller step past the 10 ms network (a fifth of its calls)."""
    from cosimstep.plotting import plot_run
    from cosimstep.store import read_run
    from cosimstep.sweep import prepare

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    db = folder / "ship.db"
    db.unlink(missing_ok=True)
    with resources.as_file(resources.files("cosimstep") / "examples" / SHIP) as path:
        spec, controller, master = prepare(str(path), {}, {"master": "multirate"})
    result = simulate(spec.system, spec.until, controller, master, reference=spec.reference,
                      store=db, name=spec.name)
    figure = plot_run(read_run(db), folder / "ship.png", SHIP_PLOTTED)
    return result, db, figure


__all__ = ["DemoRun", "plot_demo", "run_demo", "run_ship_demo"]

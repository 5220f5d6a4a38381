"""Figures in the style of the thesis: exchanged states above, communication step below."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from cosimstep.store import StoredRun


def plot_run(run: StoredRun, path: str | Path, variables: list[str] | None = None) -> Path:
    """Write a PNG/PDF/SVG of a stored run and return its path.

    Angles/positions and their rates get separate panels when units differ, the monolithic
    reference (if stored) is dashed, and rejected step attempts appear as crosses.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = variables or run.names
    units = list(dict.fromkeys(run.units[run.names.index(n)] for n in names))
    fig, axes = plt.subplots(len(units) + 1, 1, sharex=True, figsize=(9, 2.6 * (len(units) + 1)),
                             constrained_layout=True)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for ax, unit in zip(axes, units):
        _plot_unit_panel(ax, run, names, unit, colours)
    _plot_step_panel(axes[-1], run, colours)
    _mark_events(axes, run)
    axes[0].set_title(_title(run), fontsize=10)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def _plot_unit_panel(ax: Any, run: StoredRun, names: list[str], unit: str,
                     colours: list[str]) -> None:
    """One panel per unit, so angles and rates are not squeezed onto one scale."""
    for i, n in enumerate(names):
        j = run.names.index(n)
        if run.units[j] != unit:
            continue
        c = colours[i % len(colours)]
        ax.plot(run.times, run.values[:, j], color=c, lw=1.2, label=n)
        if run.reference is not None and not np.isnan(run.reference[:, j]).all():
            ax.plot(run.times, run.reference[:, j], color=c, lw=0.8, ls="--",
                    label=f"{n} (monolithic)")
    ax.set_ylabel(f"[{unit}]")
    ax.legend(fontsize=7, ncol=2, loc="upper right")
    ax.grid(alpha=0.3)


def _plot_step_panel(ax: Any, run: StoredRun, colours: list[str]) -> None:
    """The bottom panel: communication step length over time, rejected attempts as crosses."""
    att = run.attempts
    models = sorted({m for m in run.attempt_models if m is not None})
    if att.size and len(models) > 1:
        _plot_model_steps(ax, run, models, colours)
    elif att.size:
        ok = att[:, 2] > 0
        ax.step(att[ok, 0], att[ok, 1], where="post", lw=1, color="k", label="accepted step")
        if (~ok).any():
            ax.plot(att[~ok, 0], att[~ok, 1], "rx", ms=4, label="rejected attempt")
    if att.size:
        if att[:, 1].max() > 5 * att[:, 1].min():
            ax.set_yscale("log")
        else:
            ax.set_ylim(0, 1.3 * att[:, 1].max())
        ax.legend(fontsize=7, loc="upper right")
    ax.set_ylabel("step ΔT [s]")
    ax.set_xlabel("T [s]")
    ax.grid(alpha=0.3)


def _plot_model_steps(ax: Any, run: StoredRun, models: list[str], colours: list[str]) -> None:
    """Multi-rate: every sub-model's own step history in its own colour (thesis fig. 61)."""
    att = run.attempts
    who = np.array([m or "" for m in run.attempt_models])
    for i, m in enumerate(models):
        c = colours[i % len(colours)]
        ok = (who == m) & (att[:, 2] > 0)
        bad = (who == m) & (att[:, 2] == 0)
        ax.step(att[ok, 0], att[ok, 1], where="post", lw=1, color=c, label=f"{m} step")
        if bad.any():
            ax.plot(att[bad, 0], att[bad, 1], "x", color=c, ms=4,
                    label=f"{m} rejected")


def _mark_events(axes: Any, run: StoredRun) -> None:
    """A dotted line at every event on every panel, labelled once on the first."""
    for i, e in enumerate(run.events[:200]):  # a marker per event is unreadable beyond that
        for j, ax in enumerate(axes):
            ax.axvline(e["t"], color="0.4", lw=0.7, ls=":",
                       label="events" if i == 0 and j == 0 else None)
        axes[0].annotate(f"{e['source']}: {e['kind']}", (e["t"], 1.0),
                         xycoords=("data", "axes fraction"), rotation=90, fontsize=6,
                         va="top", ha="right", color="0.3")


def _title(run: StoredRun) -> str:
    """System, status and call count, plus the error against the reference when one was kept."""
    err = run.summary.get("error")
    title = f"{run.system} — {run.status}, {run.summary.get('calls_total', '?')} calls"
    if err:
        title += f", max error {err['max_abs']:.2e} vs monolithic"
    return title

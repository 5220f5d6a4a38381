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
    _legend(ax, ncol=2)
    ax.grid(alpha=0.3)


LEGEND_MAX = 16
"""Entries a panel's legend shows at most: past that it would cover the panel (a plant of
200 outputs in one unit drew a legend taller than the figure), so the panel says how many
lines it holds and how to choose them instead."""


def _legend(ax: Any, **kw: Any) -> None:
    labels = ax.get_legend_handles_labels()[1]
    if len(labels) <= LEGEND_MAX:
        ax.legend(fontsize=7, loc="upper right", **kw)
        return
    ax.text(0.99, 0.97, f"{len(labels)} lines: legend left out (choose outputs with "
            "--variables)", transform=ax.transAxes, ha="right", va="top", fontsize=7)


def _plot_step_panel(ax: Any, run: StoredRun, colours: list[str]) -> None:
    """The bottom panel: communication step length over time, rejected attempts as crosses."""
    att = run.attempts
    models = sorted({m for m in run.attempt_models if m is not None})
    if att.size and len(models) > 1:
        _plot_model_steps(ax, run, models, colours)
    elif att.size:
        ok = att[:, 2] > 0
        ax.step(*_through_last(att[ok, 0], att[ok, 1]), where="post", lw=1, color="k",
                label="accepted step")
        if (~ok).any():
            ax.plot(att[~ok, 0], att[~ok, 1], "rx", ms=4, label="rejected attempt")
    if att.size:
        if att[:, 1].max() > 5 * att[:, 1].min():
            ax.set_yscale("log")
        else:
            ax.set_ylim(0, 1.3 * att[:, 1].max())
        _legend(ax)
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
        ax.step(*_through_last(att[ok, 0], att[ok, 1]), where="post", lw=1, color=c,
                label=f"{m} step")
        if bad.any():
            ax.plot(att[bad, 0], att[bad, 1], "x", color=c, ms=4,
                    label=f"{m} rejected")


def _through_last(starts: np.ndarray, steps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Steps drawn ``where="post"`` from their starts, with one more point at the last
    step's end: a post-step line draws each level up to the next point only, so the last step
    was left out."""
    if not starts.size:
        return starts, steps
    return np.append(starts, starts[-1] + steps[-1]), np.append(steps, steps[-1])


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
    if err:  # in the norm --tol bounds, as `run` reports it (older stores: absolute)
        scaled = err.get("max_scaled")
        title += (f", max error {scaled:.2e} (|e| / (1 + |y|)) vs monolithic" if scaled
                  is not None else f", max |error| {err['max_abs']:.2e} vs monolithic")
    return title


def plot_sweep(frame: Any, path: str | Path, x: str, y: str | None, z: str,
               log: bool = True) -> Path:
    """A sweep's runs as a figure (thesis figs. 68–70): with ``y``, filled contours of ``z``
    over the plane of the swept ``x`` and ``y`` (any design: triangulated), the runs marked;
    without, ``z`` against ``x``, one line per value of the other swept names. Failed runs
    are left out (marked with crosses). ``log``: logarithmic axes and colour scale where the
    values are positive (steps, tolerances, calls and errors span decades)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ok = frame[(frame["status"] == "ok") & frame[z].notna()]
    failed = frame[frame["status"] != "ok"]
    fig, ax = plt.subplots(figsize=(7, 5), constrained_layout=True)
    if y is not None:
        _contours(fig, ax, ok, failed, x, y, z, log)
    else:
        _lines(ax, frame, ok, x, z, log)
    ax.set_title(f"{z} over {x}" + (f" and {y}" if y else "") + f" ({len(ok)} runs"
                 + (f", {len(failed)} failed)" if len(failed) else ")"), fontsize=10)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def _logged(values: np.ndarray, log: bool) -> bool:
    return log and values.size > 0 and bool(np.all(values > 0))


def _contours(fig: Any, ax: Any, ok: Any, failed: Any, x: str, y: str, z: str,
              log: bool) -> None:
    from matplotlib import colors, tri

    xs, ys, zs = (ok[n].to_numpy(float) for n in (x, y, z))
    lx, ly = _logged(xs, log), _logged(ys, log)

    def at(values: np.ndarray, logged: bool) -> np.ndarray:
        return np.log10(values) if logged else values

    norm = colors.LogNorm() if _logged(zs, log) else None
    shade = ax.tricontourf(tri.Triangulation(at(xs, lx), at(ys, ly)), zs,
                           levels=_levels(zs, norm), norm=norm, cmap="viridis")
    fig.colorbar(shade, ax=ax, label=z, format="%.2g")
    ax.plot(at(xs, lx), at(ys, ly), "k.", ms=3)
    bad_x, bad_y = failed[x].to_numpy(float), failed[y].to_numpy(float)
    ax.plot(at(bad_x, lx and _logged(bad_x, log)), at(bad_y, ly and _logged(bad_y, log)), "rx")
    ax.set_xlabel(f"log10 {x}" if lx else x)
    ax.set_ylabel(f"log10 {y}" if ly else y)


def _lines(ax: Any, frame: Any, ok: Any, x: str, z: str, log: bool) -> None:
    others = [c for c in _swept(frame) if c not in (x, z)]
    groups = ok.groupby(others) if others else [((), ok)]
    for key, rows in groups:
        rows = rows.sort_values(x)
        label = ", ".join(f"{n} = {v:g}" for n, v in zip(others, np.atleast_1d(key)))
        ax.plot(rows[x], rows[z], "o-", label=label or None)
    if _logged(ok[x].to_numpy(float), log):
        ax.set_xscale("log")
    if _logged(ok[z].to_numpy(float), log):
        ax.set_yscale("log")
    ax.set_xlabel(x)
    ax.set_ylabel(z)
    if others:
        ax.legend(fontsize=8)


def _levels(values: np.ndarray, norm: Any) -> Any:
    if norm is None:
        return 12
    low, high = np.log10(values.min()), np.log10(values.max())
    if high - low < 1e-9:
        high = low + 1.0
    return np.logspace(low, high, 13)


SUMMARY = ("status", "message", "calls_total", "steps", "error", "error_estimate", "wall_s",
           "store", "options")


def _swept(frame: Any) -> list[str]:
    """The swept names of a sweep's DataFrame (:meth:`~cosimstep.sweep.SweepTable.frame`
    lists them; a frame from elsewhere: its columns that are no summary's)."""
    if "swept" in frame.attrs:
        return [c for c in frame.attrs["swept"] if c in frame.columns]
    return [c for c in frame.columns if c not in SUMMARY
            and not c.startswith(("calls.", "min.", "max.")) and c not in ("rmse", "step_min")]


def plot_work_precision(frame: Any, path: str | Path) -> Path:
    """Calls against error, one line per sweep's run options (a controller, a master): the
    work–precision diagram of runs that swept ``tol`` or ``step``, cheapest curve lowest."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ok = frame[(frame["status"] == "ok") & frame["error"].notna() & (frame["error"] > 0)]
    fig, ax = plt.subplots(figsize=(7, 5), constrained_layout=True)
    swept = [c for c in _swept(frame) if c in ("tol", "step")]
    # one line per run options and per value of every other swept name (a sweep of tol and a
    # parameter: one curve per parameter value, not one zig-zag through them all)
    others = [c for c in _swept(frame) if c not in ("tol", "step")]
    for key, rows in ok.groupby(["options", *others], dropna=False):
        options, *values = key
        label = ", ".join([str(options), *(f"{n} = {v:g}" for n, v in zip(others, values))])
        rows = rows.sort_values("error")
        ax.loglog(rows["error"], rows["calls_total"], "o-", label=label)
        for _, row in rows.iterrows():
            if swept:
                ax.annotate(f"{row[swept[0]]:g}", (row["error"], row["calls_total"]),
                            fontsize=7, textcoords="offset points", xytext=(3, 3))
    ax.set_xlabel("error (max |e| / (1 + |y|) against the reference)")
    ax.set_ylabel("sub-model calls")
    ax.set_title(f"work–precision ({len(ok)} runs" + (f"; points labelled by {swept[0]})"
                                                       if swept else ")"), fontsize=10)
    ax.legend(fontsize=8)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path

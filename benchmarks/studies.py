"""The thesis's studies (4.2, tables 2–12, figs. 29, 68–70, 75) re-run on the sweep engine.

Writes docs/studies.md and its figures in docs/figures/. Every case is a point of a
:func:`cosimstep.sweep` on one Dask local cluster (two worker processes); every run's summary
goes to ``benchmarks/results/studies.db``, so a second start redoes only what is missing.

What is compared, per case (the thesis counted calls and never measured the error):

- **the thesis's numbers**: its fixed-step and RKF23 call counts;
- **fixed, thesis ΔT**: our split (Gauss–Seidel, quadratic extrapolation, the files' master)
  at the thesis's fixed step, recovered from its count (ΔT = bars · T / count), so the count is
  the thesis's and the error is now known;
- **rkf23**: our reproduction of the thesis's controller (all exchanged variables, tol 1e-6);
- **cosimstep**: the default adaptive controller ``pc`` at the thesis's tol 1e-6, under the
  multi-rate master wherever the thesis gave each bar its own step (tables 5–11, figs.
  68–70, 75), under Gauss–Seidel for tables 2–4 (one step for both bars, as there);
- **fixed at equal error**: the calls a fixed step needs for cosimstep's measured error,
  interpolated log–log between two fixed runs (the first at the thesis's ΔT, or where it gave
  none, at the fastest bar's mean adaptive step; the second where order 3 predicts the error).
  The ratio cosimstep / fixed at equal error is the thesis's question answered at equal
  accuracy; the thesis's own ratio compared its RKF23 with a fixed step at RKF23's smallest
  step, accuracy unmeasured.

Errors are ``max |error| / (1 + |reference|)`` over all exchanged variables at the run's
communication points, against the monolithic model (DOP853, rtol = atol = 1e-12): the norm
``tol`` bounds. Run: ``python benchmarks/studies.py [--only tables,grid,fig29,fig75]
[--no-write]`` (about an hour on 2 cores when nothing is stored yet).
"""

from __future__ import annotations

import argparse
import math
import platform
import sys
import time
from dataclasses import dataclass, field
from datetime import date
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from cosimstep import sweep

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"
DB = ROOT / "benchmarks" / "results" / "studies.db"
DOC = ROOT / "docs" / "studies.md"
FIGURES = ROOT / "docs" / "figures"
TOL = 1e-6
PC = {"controller": "pc", "tol": TOL}
RKF23 = {"controller": "rkf23", "tol": TOL, "master": "gauss-seidel"}
FIXED = {"controller": "fixed", "master": "gauss-seidel", "extrapolation": 2}
ORDER = 3.0  # Gauss-Seidel with quadratic extrapolation: error ~ ΔT^3 (docs/benchmarks.md)
TRIPLE_T = 5.0  # the thesis's triple pendulum runs (figs. 63-77) end at 5 s
DOUBLE_T = 4.0  # its double pendulum runs (figs. 50-61) end at 4 s


@dataclass
class Case:
    """One row of a thesis table: a system file, overrides, and the thesis's counts."""

    label: str
    system: str
    params: dict[str, float] = field(default_factory=dict)
    thesis_fixed: int | None = None
    thesis_rkf: int | str | None = None
    master: str = "multirate"
    until: float = TRIPLE_T
    bars: int = 3
    rkf23: bool = True

    @property
    def thesis_step(self) -> float | None:
        return None if not self.thesis_fixed else self.bars * self.until / self.thesis_fixed


def _triple(label: str, thesis: tuple[int, int], **params: float) -> Case:
    return Case(label, "triple_pendulum", dict(params), *thesis)


DOUBLE = [
    Case("slow (tables 2–4)", "double_pendulum_slow", thesis_fixed=1600,
         thesis_rkf="1478 / 1574", master="gauss-seidel", until=DOUBLE_T, bars=2),
    Case("fast (tables 2–4)", "double_pendulum_fast", thesis_fixed=2260,
         thesis_rkf="1856 / 1952", master="gauss-seidel", until=DOUBLE_T, bars=2),
    Case("toggled (tables 3–4)", "double_pendulum_toggled", thesis_fixed=2260,
         thesis_rkf="1604 / 1724", master="gauss-seidel", until=DOUBLE_T, bars=2),
    Case("slow upper, fast lower bar (table 5)", "double_pendulum_mixed", thesis_fixed=None,
         thesis_rkf=1732, until=DOUBLE_T, bars=2),
]
TRIPLE = [
    _triple("base case (table 6)", (5997, 6219)),
    _triple("m1 = 100 (table 7)", (5997, 4808), m1=100.0),
    Case("l1 = 0.1, l3 = 100 (table 8)", "triple_pendulum_table8", {}, 10002, 8800),
    Case("lengths changed at 2 s (table 11)", "triple_pendulum_table11", {}, 11727, 8215),
]
TABLE9 = [  # (m1, m2, m3, fixed counts, RKF counts), lengths 1
    (0.7, 1, 1, 5997, 6963), (0.5, 1, 1, 6033, 7748), (2, 1, 1, 5997, 5264),
    (1, 0.9, 1, 5997, 6301), (1, 0.8, 1, 5997, 6295), (1, 0.7, 1, 5997, 6339),
    (1, 2, 1, 5997, 6617), (1, 3, 1, 5997, 7248), (1, 5, 1, 6726, 8464),
    (1, 1, 0.9, 5997, 5888), (1, 1, 0.8, 5997, 5690), (1, 1, 10, 14790, 7824)]
TABLE10 = [  # (l1, l2, l3, fixed counts, RKF counts), masses 1
    (0.9, 1, 1, 5997, 6375), (0.8, 1, 1, 5997, 6622), (0.7, 1, 1, 5997, 6767),
    (0.6, 1, 1, 5997, 7075), (0.5, 1, 1, 5997, 7259), (0.1, 1, 1, 11214, 11433),
    (1.5, 1, 1, 12825, 9330), (1, 0.9, 1, 5997, 6658), (1, 0.8, 1, 6156, 7871),
    (1, 0.7, 1, 8895, 9658), (1, 2, 1, 5997, 6190), (1, 3, 1, 5997, 5995),
    (1, 5, 1, 8508, 6733), (1, 1, 0.9, 5997, 6357), (1, 1, 0.8, 5997, 6397),
    (1, 1, 0.5, 5997, 7318), (1, 1, 1.1, 5997, 6181), (1, 1, 2, 5997, 5748)]
GRID = [0.1, 0.316, 1.0, 3.16, 10.0]  # l1, l2 (figs. 68-70 used 0.1, 1, 10 and finer)
GRID_L3 = [0.1, 1.0, 10.0]


def _changed(values: tuple[float, float, float], names: tuple[str, str, str]) -> dict:
    return {n: float(v) for n, v in zip(names, values) if v != 1}


def mass_cases() -> list[Case]:
    return [_triple(f"{i}: " + ", ".join(f"{k} = {v:g}" for k, v in
                                         _changed(row[:3], ("m1", "m2", "m3")).items()),
                    row[3:], **_changed(row[:3], ("m1", "m2", "m3")))
            for i, row in enumerate(TABLE9, 1)]


def length_cases() -> list[Case]:
    return [_triple(f"{i}: " + ", ".join(f"{k} = {v:g}" for k, v in
                                         _changed(row[:3], ("l1", "l2", "l3")).items()),
                    row[3:], **_changed(row[:3], ("l1", "l2", "l3")))
            for i, row in enumerate(TABLE10, 1)]


def grid_cases() -> list[Case]:
    return [Case(f"l1 = {a:g}, l2 = {b:g}, l3 = {c:g}", "triple_pendulum",
                 {"l1": a, "l2": b, "l3": c}, rkf23=False)
            for c in GRID_L3 for a in GRID for b in GRID]


class Runner:
    """Runs groups of points as sweeps on one cluster, one sweep per (system, options)."""

    def __init__(self, scheduler: str) -> None:
        self.scheduler = scheduler

    def runs(self, cases: list[Case], options: list[dict[str, Any]],
             keep: str = "summary") -> list[dict[str, Any]]:
        """One run per case with that case's options; rows in the order of ``cases``."""
        groups: dict[tuple, list[int]] = {}
        for i, (case, opts) in enumerate(zip(cases, options)):
            fixed = {k: v for k, v in opts.items() if k not in ("step",)}
            groups.setdefault((case.system, tuple(sorted(fixed.items()))), []).append(i)
        rows: list[dict[str, Any]] = [{} for _ in cases]
        for (system, fixed), members in groups.items():
            points = [{**cases[i].params, "until": cases[i].until,
                       **({"step": options[i]["step"]} if "step" in options[i] else {})}
                      for i in members]
            frame = sweep(_path(system), points=points, out=DB,
                          scheduler=self.scheduler, keep=keep, progress=True, **dict(fixed))
            for i, (_, row) in zip(members, frame.iterrows()):
                rows[i] = row.to_dict()
        return rows


def _path(system: str) -> Path:
    """An example's name, or a file's path."""
    return Path(system) if system.endswith(".toml") else EXAMPLES / f"{system}.toml"


def compare(runner: Runner, cases: list[Case], keep: str = "summary") -> list[dict[str, Any]]:
    """The adaptive runs, the fixed pair and the equal-error interpolation of every case."""
    ours = runner.runs(cases, [{**PC, "master": c.master} for c in cases], keep)
    rkf = runner.runs([c for c in cases if c.rkf23], [RKF23 for c in cases if c.rkf23])
    rkf_rows = iter(rkf)
    first = [c.thesis_step or (c.until / max(_calls(r).values()) if _ok(r) else 0.01)
             for c, r in zip(cases, ours)]
    fixed1 = runner.runs(cases, [{**FIXED, "step": _round(h)} for h in first])
    second = []
    for h, f, r in zip(first, fixed1, ours):
        ratio = (r["error"] / f["error"]) ** (1 / ORDER) if _ok(r) and _ok(f) else 0.5
        second.append(h * min(max(ratio, 0.25), 4.0) if abs(ratio - 1) > 0.05 else h / 2)
    fixed2 = runner.runs(cases, [{**FIXED, "step": _round(h)} for h in second])
    out = []
    for c, r, f1, f2 in zip(cases, ours, fixed1, fixed2):
        row = {"case": c, "ours": r, "fixed": f1, "fixed2": f2,
               "rkf": next(rkf_rows) if c.rkf23 else None}
        row["equal"] = _fixed_calls_at(r, f1, f2, c) if _ok(r) else math.nan
        out.append(row)
    return out


def _round(h: float) -> float:
    """A step written with 4 significant digits: the same step, the same stored run."""
    return float(f"{h:.4g}")


def _ok(row: dict[str, Any]) -> bool:
    return row.get("status") == "ok" and row.get("error") is not None \
        and math.isfinite(row["error"]) and row["error"] > 0


def _calls(row: dict[str, Any]) -> dict[str, int]:
    return {k[len("calls."):]: int(v) for k, v in row.items()
            if k.startswith("calls.") and v == v}


def _fixed_calls_at(ours: dict, f1: dict, f2: dict, case: Case) -> float:
    """Fixed-step calls at ``ours``' error: log–log through the two fixed runs."""
    if not (_ok(f1) and _ok(f2)) or f1["step"] == f2["step"]:
        return math.nan
    p = math.log(f1["error"] / f2["error"]) / math.log(f1["step"] / f2["step"])
    if not 1.0 <= p <= 6.0:  # not in the asymptotic range: no honest interpolation
        return math.nan
    h = f1["step"] * (ours["error"] / f1["error"]) ** (1 / p)
    return case.bars * case.until / h


def _e(x: Any) -> str:
    return "—" if x is None or not isinstance(x, (int, float)) or not math.isfinite(x) \
        else f"{x:.1e}"


def _run_cell(row: dict | None) -> str:
    if row is None:
        return "—"
    if row.get("status") != "ok":
        return f"{row.get('status')}: {str(row.get('message'))[:40]}"
    return f"{int(row['calls_total'])}, {_e(row['error'])}"


def table_lines(rows: list[dict[str, Any]]) -> list[str]:
    lines = ["| case | thesis fixed / RKF23 | fixed at thesis ΔT: calls, error | "
             "rkf23 (ours): calls, error | cosimstep pc: calls per bar, total, error, err/tol | "
             "fixed at cosimstep's error: calls | cosimstep / fixed |",
             "|---|---|---|---|---|---|---|"]
    for row in rows:
        c, r = row["case"], row["ours"]
        thesis = f"{c.thesis_fixed or 'n/a'} / {c.thesis_rkf or 'n/a'}"
        fixed = _run_cell(row["fixed"]) if c.thesis_step else "—"
        if _ok(r):
            per = " / ".join(str(v) for v in _calls(r).values())
            ours = f"{per}, {int(r['calls_total'])}, {_e(r['error'])}, {r['error'] / TOL:.2g}"
        else:
            ours = _run_cell(r)
        eq = row["equal"]
        lines.append(f"| {c.label} | {thesis} | {fixed} | {_run_cell(row['rkf'])} | {ours} | "
                     + (f"{eq:.0f} | {r['calls_total'] / eq:.2f} |" if math.isfinite(eq)
                        else "— | — |"))
    return lines


def summary_line(rows: list[dict[str, Any]]) -> str:
    ok = [r for r in rows if _ok(r["ours"])]
    ratios = [r["ours"]["calls_total"] / r["equal"] for r in ok if math.isfinite(r["equal"])]
    band = [r["ours"]["error"] / TOL for r in ok]
    thesis = [float(r["case"].thesis_rkf) / r["case"].thesis_fixed for r in rows
              if r["case"].thesis_fixed and isinstance(r["case"].thesis_rkf, int)]
    parts = [f"{len(ok)} of {len(rows)} cosimstep runs ok"]
    if band:
        parts.append(f"err/tol {min(band):.2g} … {max(band):.2g} (median "
                     f"{np.median(band):.2g})")
    if ratios:
        parts.append(f"cosimstep / fixed at equal error {min(ratios):.2f} … {max(ratios):.2f}"
                     f", below 1 in {sum(x < 1 for x in ratios)} of {len(ratios)}")
    if thesis:
        parts.append(f"thesis RKF23 / fixed {min(thesis):.2f} … {max(thesis):.2f}, below 1 in "
                     f"{sum(x < 1 for x in thesis)} of {len(thesis)}")
    return "Summary: " + "; ".join(parts) + "."


def tables(runner: Runner) -> list[str]:
    lines = ["## Tables 2–11: calls, and the error the calls bought", ""]
    for title, cases in (("Double pendulum, tables 2–5 (4 s)", DOUBLE),
                         ("Triple pendulum, tables 6, 7, 8, 11 (5 s)", TRIPLE),
                         ("Table 9: masses varied (5 s, lengths 1)", mass_cases()),
                         ("Table 10: lengths varied (5 s, masses 1)", length_cases())):
        rows = compare(runner, cases)
        lines += [f"### {title}", "", *table_lines(rows), "", summary_line(rows), ""]
        print("\n".join(lines[-len(rows) - 5:]), file=sys.stderr, flush=True)
    lines += ["Thesis RKF23 counts for the double pendulum: upper bar's angle controlled "
              "(tables 2–3) / all variables (table 4). The thesis's fixed step for table 5's "
              "mixed case was not given.", ""]
    return lines


def grid(runner: Runner) -> list[str]:
    rows = compare(runner, grid_cases())
    frame = pd.DataFrame([{**r["case"].params, "ratio": r["ours"]["calls_total"] / r["equal"]
                           if math.isfinite(r["equal"]) else math.nan,
                           "err_over_tol": r["ours"]["error"] / TOL if _ok(r["ours"])
                           else math.nan,
                           "calls": r["ours"]["calls_total"],
                           "status": r["ours"]["status"]} for r in rows])
    figures = _grid_figures(frame)
    lines = ["## Figs. 68–70: l1 and l2 over 0.1 … 10 at l3 = 0.1, 1, 10 (5 s, tol 1e-6)", "",
             "The thesis's contours are of RKF23 calls / fixed calls at RKF23's smallest step "
             "(below 1: adaptive pays). Ours are of cosimstep's calls / a fixed step's calls "
             "at the same measured error, on a 5 × 5 grid per l3 (the thesis's 3 × 3 points "
             "and the half-decades between), and of cosimstep's err/tol.", "",
             *[f"![{name}](figures/{name})" for name in figures], "",
             "| l3 | cosimstep / fixed at equal error: min, median, max | below 1 | "
             "err/tol: min, median, max | failed |", "|---|---|---|---|---|"]
    for l3, part in frame.groupby("l3"):
        ratio, band = part["ratio"].dropna(), part["err_over_tol"].dropna()
        lines.append(f"| {l3:g} | {ratio.min():.2f}, {ratio.median():.2f}, {ratio.max():.2f} | "
                     f"{int((ratio < 1).sum())} of {len(ratio)} | {band.min():.2g}, "
                     f"{band.median():.2g}, {band.max():.2g} | "
                     f"{int((part['status'] != 'ok').sum())} |")
    lines += ["", "Every point:", "", *table_lines(rows), ""]
    return lines


def _grid_figures(frame: pd.DataFrame) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib import colors

    names = []
    for fig_no, (l3, part) in zip((68, 69, 70), frame.groupby("l3")):
        fig, axes = plt.subplots(1, 2, figsize=(11, 4.5), constrained_layout=True)
        for ax, z, title, levels in (
                (axes[0], "ratio", "cosimstep calls / fixed calls at equal error",
                 np.logspace(-1, 1, 17)),
                (axes[1], "err_over_tol", "cosimstep error / tol", np.logspace(-2, 2, 17))):
            ok = part.dropna(subset=[z])
            x, y = np.log10(ok["l1"].to_numpy(float)), np.log10(ok["l2"].to_numpy(float))
            if len(ok) >= 3:
                shade = ax.tricontourf(x, y, ok[z].to_numpy(float), levels=levels,
                                       norm=colors.LogNorm(levels[0], levels[-1]),
                                       cmap="viridis", extend="both")
                fig.colorbar(shade, ax=ax)
                if z == "ratio":
                    ax.tricontour(x, y, ok[z].to_numpy(float), levels=[1.0], colors="w")
            ax.plot(x, y, "k.", ms=5, clip_on=False)
            ax.set(xlabel="log10 l1", ylabel="log10 l2", title=f"{title}, l3 = {l3:g}")
        name = f"studies_fig{fig_no}.png"
        fig.savefig(FIGURES / name, dpi=110)
        plt.close(fig)
        names.append(name)
    return names


FIG29_F = [0.1, 0.316, 1.0, 3.16, 10.0]  # the faster normal mode's frequency, Hz
FIG29_STEPS = [1e-4, 3.16e-4, 1e-3, 3.16e-3, 1e-2, 3.16e-2, 1e-1, 3.16e-1]
FIG29_MAX_STEPS = 20000


def fig29_points() -> list[dict[str, float]]:
    """Equal bars l: normal modes ω² = (2 ± √2) g / l; ``f`` is the faster one's frequency.
    Each run lasts 10 periods of the slower mode (the thesis's "10 complete swings")."""
    points = []
    for f in FIG29_F:
        length = (2 + math.sqrt(2)) * 9.81 / (2 * math.pi * f) ** 2
        slow = math.sqrt((2 - math.sqrt(2)) * 9.81 / length) / (2 * math.pi)
        until = round(10 / slow, 4)
        for h in FIG29_STEPS:
            if until / h <= FIG29_MAX_STEPS and h * f <= 1.0:
                points.append({"l1": round(length, 6), "l2": round(length, 6),
                               "until": until, "step": h})
    return points


def fig29(runner: Runner) -> list[str]:
    points = fig29_points()
    frame = sweep(EXAMPLES / "double_pendulum_small_angle.toml", points=points, out=DB,
                  scheduler=runner.scheduler, progress=True, **FIXED)
    frame["f_hz"] = np.round(np.sqrt((2 + math.sqrt(2)) * 9.81 / frame["l1"]) / (2 * math.pi), 3)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib import colors

    ok = frame[(frame["status"] == "ok") & (frame["rmse"] > 0)]
    fig, ax = plt.subplots(figsize=(7, 5), constrained_layout=True)
    x, y = np.log10(ok["f_hz"].to_numpy(float)), np.log10(ok["step"].to_numpy(float))
    shade = ax.tricontourf(x, y, ok["rmse"].to_numpy(float), levels=np.logspace(-7, 1, 17),
                           norm=colors.LogNorm(), cmap="viridis", extend="both")
    fig.colorbar(shade, ax=ax, label="RMSE against the monolithic model [rad, rad/s]")
    ax.plot(x, y, "k.", ms=4)
    ax.set(xlabel="log10 f (faster mode) [Hz]", ylabel="log10 ΔT [s]",
           title="Fig. 29 re-measured: split double pendulum (small angle), 10 swings")
    fig.savefig(FIGURES / "studies_fig29.png", dpi=110)
    plt.close(fig)
    table = frame.pivot_table(index="step", columns="f_hz", values="rmse")
    lines = ["## Fig. 29: error against frequency and step", "",
             "The thesis's notional graph: RMSE of a pendulum against a small-step run, over its "
             "frequency and the step, 10 swings each. Here: the split double pendulum with equal "
             "bars (small-angle equations, as the thesis's double pendulum), fixed step, "
             "Gauss–Seidel with quadratic extrapolation, RMSE over θ1, ω1, θ2, ω2 against the "
             "monolithic model, each run 10 periods of the slower mode; the bar length sets "
             f"f. Points with more than {FIG29_MAX_STEPS} steps or ΔT · f > 1 are not run.", "",
             "![fig29](figures/studies_fig29.png)", "",
             "| ΔT \\ f [Hz] | " + " | ".join(f"{f:.3g}" for f in table.columns) + " |",
             "|---|" + "---|" * len(table.columns)]
    for h, values in table.iterrows():
        lines.append(f"| {h:g} | " + " | ".join(_e(v) for v in values) + " |")
    slopes = []
    for f, column in table.items():
        col = column.dropna()
        small = col[col < 1e-2]
        if len(small) >= 2:
            slopes.append((f, np.polyfit(np.log10(small.index), np.log10(small.values), 1)[0]))
    lines += ["", "Observed order in ΔT (least squares over the runs with RMSE < 1e-2), per "
              "frequency: " + ", ".join(f"{f:.3g} Hz: {p:.2f}" for f, p in slopes) + ". At a "
              "fixed ΔT the error grows with f: what matters is ΔT · f (steps per period).", ""]
    return lines


FINE_DT = 5e-5  # the fig. 75 bar's internal RK4 step: ω·dt ≈ 0.005, its own error ~1e-8


def _fine_solver_file() -> Path:
    """The triple pendulum file with every bar's internal RK4 step at most ``FINE_DT``."""
    text = (EXAMPLES / "triple_pendulum.toml").read_text()
    text = text.replace("\nuntil = 10.0\n", "\nuntil = 10.0\nsolver = { method = \"rk4\", "
                        f"max_dt = {FINE_DT:g} }}\n", 1)
    path = DB.parent / "studies_triple_pendulum_fine_solver.toml"
    path.parent.mkdir(parents=True, exist_ok=True)
    if not path.is_file() or path.read_text() != text:
        path.write_text(text)
    return path


def fig75(runner: Runner) -> list[str]:
    """One bar at ~16 Hz: first as the file builds it (internal RK4, Δt ≤ 1e-3), then with a
    fine internal step, to tell the sub-model's own error from the coupling error."""
    params = {"l1": 1000.0, "l2": 1000.0, "l3": 0.001}
    fine = str(_fine_solver_file())
    cases = [Case("multi-rate + pc, internal RK4 Δt ≤ 1e-3 (the file's)", "triple_pendulum",
                  params),
             Case("Gauss–Seidel + pc, internal RK4 Δt ≤ 1e-3", "triple_pendulum", params,
                  master="gauss-seidel", rkf23=False),
             Case(f"multi-rate + pc, internal RK4 Δt ≤ {FINE_DT:g}", fine, params,
                  rkf23=False),
             Case(f"Gauss–Seidel + pc, internal RK4 Δt ≤ {FINE_DT:g}", fine, params,
                  master="gauss-seidel", rkf23=False)]
    rows = compare(runner, cases[:1], keep="traces") + compare(runner, cases[1:])
    lines = ["## Fig. 75: one bar at very high frequency (l1 = l2 = 1000, l3 = 0.001, 5 s)", ""]
    store = rows[0]["ours"].get("store")
    if store and Path(store).is_file():
        lines += _fig75_figure(store)
    lines += [*table_lines(rows), "",
              "The thesis saw its RKF23 curve drift in phase against the fixed step (fig. 76) "
              "and could not tell which was right. Measured against the monolithic model, two "
              "errors add up here. With the file's internal solver (RK4, Δt ≤ 1e-3, so "
              "ω·Δt ≈ 0.1 on the lowest bar) most of it is the bar's own integration error: it "
              "grows with the internal step and so with the communication step the master "
              "chooses, a phase drift that depends on the step sequence as in fig. 76, and no "
              "coupling estimate can see it (a black box's own error is not a coupling error). "
              "With the internal step at 5e-5 that part is gone, and what is left, 3–7e-3 at tol "
              "1e-6, is coupling error that `pc` does not see: **error control fails on this "
              "system** (issue 13). Diagnosis: `pc` scales its estimate by how much better the "
              "corrector's input curves are than the predictor's, judged on the input that moved "
              "most relative to 1 + |u| — the fast bar's own angle and velocity, well resolved — "
              "while the error comes from the tiny, fast ripples in the long bars' velocities that "
              "the short bar feels with a gain of about l2 / l3 = 1e6; for those inputs the "
              "corrector is no better than the predictor (ratio 0.3–0.7 against 0.04 taken).", ""]
    return lines


def _fig75_figure(store: str) -> list[str]:
    from cosimstep import read_run
    from cosimstep.plotting import plot_run

    run = read_run(store)
    plot_run(run, FIGURES / "studies_fig75.png", ["bar1.theta", "bar2.theta", "bar3.theta"])
    theta = run.values[:, run.names.index("bar3.theta")]
    grid_t = np.linspace(0, run.times[-1], 2**14)
    spectrum = np.abs(np.fft.rfft(np.interp(grid_t, run.times, theta) - np.mean(theta)))
    peak = np.fft.rfftfreq(grid_t.size, grid_t[1] - grid_t[0])[np.argmax(spectrum)]
    return ["![fig75](figures/studies_fig75.png)", "",
            f"The lowest bar swings at {peak:.1f} Hz (FFT of the first run below; the thesis "
            "reports about 25 Hz).", ""]


def table12() -> list[str]:
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from interpolation import overhead

    lines, _ = overhead()
    return ["## Table 12: one sub-model step against one interpolation", "",
            "Measured by benchmarks/interpolation.py's own routine in this run.", "",
            *lines[2:], ""]


def _stored(what: str = "COUNT(*)") -> float:
    import sqlite3

    with sqlite3.connect(DB) as db:
        return db.execute(f"SELECT {what} FROM sweep_run").fetchone()[0] or 0


STUDIES = {"tables": tables, "grid": grid, "fig29": fig29, "fig75": fig75}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--only", default=",".join(STUDIES),
                        help="comma-separated: " + ", ".join(STUDIES))
    parser.add_argument("--no-write", action="store_true")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    chosen = [s.strip() for s in args.only.split(",") if s.strip()]
    from distributed import LocalCluster

    FIGURES.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    sections: list[str] = []
    with LocalCluster(n_workers=args.workers, threads_per_worker=1, processes=True,
                      dashboard_address=None) as cluster:
        runner = Runner(cluster.scheduler_address)
        for name in chosen:
            sections += STUDIES[name](runner)
    if "tables" in chosen:
        sections += table12()
    minutes = (time.perf_counter() - start) / 60
    head = ["# The thesis's studies, re-measured", "",
            f"Generated by benchmarks/studies.py on {date.today()} ({platform.machine()}, "
            f"Python {platform.python_version()}, {args.workers} Dask workers, "
            f"{minutes:.0f} min for this document; the {_stored()} runs it reads took "
            f"{_stored('SUM(wall_s)') / 3600:.1f} h of run time in all). Runs: "
            f"{DB.relative_to(ROOT)} (a sweep table; `cosimstep plot-sweep` reads it; delete "
            "it after changing the code, or the stored runs are reused).", "",
            *__doc__.split("What is compared", 1)[1].split("\n\nErrors are")[0]
            .replace(":func:`cosimstep.sweep`", "`cosimstep.sweep`").replace("``", "`")
            .join(["What is compared", ""]).splitlines(), "",
            "Errors: max |error| / (1 + |reference|) over every exchanged variable at the "
            "run's communication points, against the monolithic model; tol = 1e-6 "
            "throughout, the thesis's.", ""]
    text = "\n".join(head + sections) + "\n"
    print(text)
    if not args.no_write and set(chosen) == set(STUDIES):
        DOC.write_text(text)


if __name__ == "__main__":
    main()

"""Parameter sweeps: many runs of one system file, one Dask task per run (issue 16).

A sweep is a *design* — points in the space of the swept names — and a run per point. A name is
a system parameter of the file (``l2``, or one sub-model's ``bar2.l2``), a start value
(``start.theta1``) or a run option (``tol``, ``step``, ``until``). Designs: the full factorial
of listed values (``NAME=V1,V2,…``), or a Latin hypercube or a scrambled Sobol sequence of
``samples`` points over ranges (``NAME=LOW:HIGH``), from :mod:`scipy.stats.qmc`, seeded.

The runs go to Dask distributed: a :class:`~distributed.LocalCluster` of worker *processes* on
this machine by default (a co-simulation holds the GIL, so threads would not run side by side),
or an existing scheduler by address for a user who outgrows one machine. Every run's summary —
its point, status, message, calls per sub-model, steps, error against the reference, the run's
own error estimate, wall time — is written by this process, as each run finishes, to one table
``sweep_run`` of an SQLite file, keyed by the point and the run options. Hence:

- the same sweep started again skips every run already recorded (resumable);
- a run that fails is recorded with its message and the sweep goes on: a run never raises
  (:func:`run_point` turns every exception into a ``failed`` summary);
- a worker process that dies mid-run loses nothing: Dask gives its task to another worker
  (up to ``distributed.scheduler.allowed-failures`` times), and only finished runs are written.
"""

from __future__ import annotations

import itertools
import json
import math
import sqlite3
import time
import traceback
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from cosimstep.errors import RunInterrupted

DESIGNS = ("full", "lhs", "sobol")
KEEP = ("summary", "traces")
RUN_OPTIONS = ("tol", "step", "until")
"""Names a sweep may vary besides the file's parameters and start values."""

SCHEMA = """
CREATE TABLE IF NOT EXISTS sweep_run(
    key TEXT PRIMARY KEY, system TEXT, point_json TEXT, options_json TEXT, status TEXT,
    message TEXT, calls_json TEXT, calls_total INTEGER, steps INTEGER, error REAL,
    error_estimate REAL, wall_s REAL, finished REAL, store TEXT, rmse REAL, step_min REAL,
    extremes_json TEXT);
"""
ADDED_COLUMNS = {"store": "TEXT", "rmse": "REAL", "step_min": "REAL", "extremes_json": "TEXT"}
"""Columns a table written by an earlier version may lack (added on open)."""


@dataclass(frozen=True)
class Axis:
    """One swept name: listed ``values``, or a range ``low`` … ``high`` for sampled designs."""

    name: str
    values: tuple[float, ...] | None = None
    low: float | None = None
    high: float | None = None


def parse_axis(text: str) -> Axis:
    """``NAME=V1,V2,…`` or ``NAME=LOW:HIGH``; ``ValueError`` saying what is wrong."""
    name, sep, rest = text.partition("=")
    name = name.strip()
    if not sep or not name or not rest.strip():
        raise ValueError(f"'{text}': write NAME=V1,V2,... or NAME=LOW:HIGH")
    try:
        if ":" in rest:
            low, high = (float(v) for v in rest.split(":"))
            if not (math.isfinite(low) and math.isfinite(high) and low < high):
                raise ValueError
            return Axis(name, low=low, high=high)
        values = tuple(float(v) for v in rest.split(","))
        if not all(math.isfinite(v) for v in values):
            raise ValueError
        return Axis(name, values=values)
    except ValueError:
        raise ValueError(f"'{text}': values must be finite numbers, a range LOW:HIGH with "
                         "LOW < HIGH") from None


def design(axes: Sequence[Axis], kind: str = "full", samples: int | None = None,
           seed: int | None = None) -> list[dict[str, float]]:
    """The points of a sweep, in a fixed order (the same for the same arguments)."""
    if kind not in DESIGNS:
        raise ValueError(f"unknown design '{kind}'; choose one of {', '.join(DESIGNS)}")
    if kind == "full":
        ranged = [a.name for a in axes if a.values is None]
        if ranged:
            raise ValueError(f"the full design needs listed values (NAME=V1,V2,...), not a "
                             f"range, for {', '.join(ranged)}; or use --design lhs|sobol")
        return [dict(zip([a.name for a in axes], combo))
                for combo in itertools.product(*(a.values for a in axes))]
    listed = [a.name for a in axes if a.values is not None]
    if listed:
        raise ValueError(f"a sampled design needs ranges (NAME=LOW:HIGH), not listed values, "
                         f"for {', '.join(listed)}")
    if not samples or samples < 1:
        raise ValueError(f"the {kind} design needs --samples N (N >= 1)")
    return _sample(axes, kind, samples, seed)


def _sample(axes: Sequence[Axis], kind: str, samples: int, seed: int | None
            ) -> list[dict[str, float]]:
    """``samples`` points of a Latin hypercube or a scrambled Sobol sequence over the ranges."""
    from scipy.stats import qmc

    engine = qmc.LatinHypercube(d=len(axes), seed=seed) if kind == "lhs" \
        else qmc.Sobol(d=len(axes), scramble=True, seed=seed)
    if kind == "sobol" and samples & (samples - 1) == 0:
        unit = engine.random_base2(int(math.log2(samples)))
    else:  # Sobol's balance needs a power of two; any other count is still a valid sample
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)
            unit = engine.random(samples)
    scaled = qmc.scale(unit, [a.low for a in axes], [a.high for a in axes])
    return [{a.name: float(v) for a, v in zip(axes, row)} for row in scaled]


def run_key(system: str, point: Mapping[str, float], options: Mapping[str, Any]) -> str:
    """What identifies a run: the system file, the point and the run options."""
    return json.dumps({"system": system, "point": dict(sorted(point.items())),
                       "options": dict(sorted(options.items()))}, sort_keys=True)


def split_point(point: Mapping[str, float]) -> tuple[dict[str, Any], dict[str, float]]:
    """``(overrides for load_system, run options)`` of a point."""
    parameters, start, run = {}, {}, {}
    for name, value in point.items():
        if name in RUN_OPTIONS:
            run[name] = value
        elif name.startswith("start."):
            start[name[len("start."):]] = value
        else:
            parameters[name] = value
    return {"parameters": parameters, "start": start}, run


def run_point(system: str, point: Mapping[str, float], options: Mapping[str, Any],
              store: str | None = None) -> dict[str, Any]:
    """One run of the sweep; never raises: any failure is a ``failed`` summary.

    ``options``: ``master``, ``extrapolation``, ``controller``, ``tol``, ``step``, ``until``
    and ``coupling`` as on the command line (``None``: the file's), and ``controller_options``
    (a dict, as ``run --opt``); the point's run options come on top. ``store``: an SQLite
    file for the run's whole trajectory (``None``: none).
    """
    start = time.perf_counter()
    summary = _failed(point, "")
    summary["store"] = store
    try:
        try:
            result = _simulate(system, point, options, store)
        except RunInterrupted as exc:  # a worker told to stop: the point's run as it ended
            result = exc.result
        # a run repeated at a tighter tol (cosimstep.tighten) cost the pair's calls: the
        # point's work is both (`calls` stays the kept run's, per sub-model; options
        # {"tighten": False} for single runs)
        summary.update(status=result.status, message=result.message, calls=result.calls,
                       calls_total=result.calls_spent, steps=result.steps_accepted,
                       error=None if result.error is None else result.error.max_scaled,
                       rmse=None if result.error is None else result.error.rmse,
                       error_estimate=result.error_estimate, step_min=step_min(result),
                       extremes=extremes(result))
    except Exception as exc:  # a bad point must not end the sweep
        last = traceback.extract_tb(exc.__traceback__)[-1:]
        where = f" ({last[0].filename}:{last[0].lineno})" if last else ""
        summary["message"] = f"{type(exc).__name__}: {exc}{where}"
    summary["wall_s"] = time.perf_counter() - start
    return summary


def _failed(point: Mapping[str, float], message: str) -> dict[str, Any]:
    """The summary of a run that produced nothing."""
    return {"point": dict(point), "status": "failed", "message": message, "calls": {},
            "calls_total": 0, "steps": 0, "error": None, "rmse": None, "error_estimate": None,
            "step_min": None, "extremes": {}, "wall_s": float("nan"), "store": None}


def extremes(result: Any) -> dict[str, list[float]]:
    """Each real output's ``[min, max]`` over the run's points: what a Monte-Carlo study of a
    peak (the hottest zone, the largest force) needs, without keeping every trajectory."""
    values = np.asarray(result.values, dtype=float)
    if values.size == 0:
        return {}
    with np.errstate(invalid="ignore"):
        low, high = np.nanmin(values, axis=0), np.nanmax(values, axis=0)
    return {name: [float(lo), float(hi)] for name, lo, hi in zip(result.names, low, high)
            if np.isfinite(lo) and np.isfinite(hi)}


def step_min(result: Any) -> float | None:
    """The smallest communication step any sub-model took, not counting each one's last
    step (cut short to land on the end): what the thesis's fixed-step comparison runs at
    (4.2.7: "the smallest time step that the RKF algorithm has determined")."""
    series = [m.step_sizes for m in result.models.values()] or [result.step_sizes]
    inner = np.concatenate([np.asarray(h, dtype=float)[:-1] for h in series])
    inner = inner[inner > 0]
    return float(inner.min()) if inner.size else None


def prepare(system: str, point: Mapping[str, float], options: Mapping[str, Any]
            ) -> tuple[Any, Any, Any]:
    """``(spec, controller, master)`` of one run; raises what is wrong with them
    (:class:`~cosimstep.errors.ConfigurationError` for the file and the names)."""
    import dataclasses

    from cosimstep.config import load_system
    from cosimstep.controllers import make_controller, merged_settings

    overrides, run = split_point(point)
    opts = {k: v for k, v in options.items() if v is not None}
    opts.update(run)
    spec = load_system(system, opts.get("until"), overrides)
    master = spec.master
    if opts.get("master") is not None:
        master = dataclasses.replace(master, name=opts["master"])
    if opts.get("extrapolation") is not None:
        master = dataclasses.replace(master, extrapolation=int(opts["extrapolation"]))
    if opts.get("coupling") is not None:
        master = dataclasses.replace(master, coupling=opts["coupling"])
    settings = merged_settings(spec.controller, opts.get("controller"), opts.get("step"),
                               opts.get("tol"))
    settings.update(opts.get("controller_options") or {})  # as `run --opt KEY=VALUE`
    name = settings.pop("name", None)
    controller = make_controller(name, settings.pop("step", None), settings.pop("tol", None),
                                 **settings)
    problems = master.problems()
    if not (math.isfinite(spec.until) and spec.until > 0.0):  # a run starts at t = 0
        problems.append(f"`until` must be a positive number of seconds, got {spec.until}")
    if problems:
        raise ValueError("; ".join(problems))
    return spec, controller, master


def _simulate(system: str, point: Mapping[str, float], options: Mapping[str, Any],
              store: str | None) -> Any:
    from cosimstep.simulate import simulate

    spec, controller, master = prepare(system, point, options)
    return simulate(spec.system, spec.until, controller, master, reference=spec.reference,
                    name=spec.name, progress=False, store=store,
                    estimate=options.get("estimate", "sum"),
                    tighten=options.get("tighten", True),
                    config={"source": system, "point": dict(point), "options": dict(options)})


def _check_estimate(estimate: str, controller: Any, master: Any) -> None:
    """What :func:`~cosimstep.simulate` would refuse in every run, refused once up front."""
    from cosimstep.simulate import estimate_problems

    problems = estimate_problems(estimate, controller, master)
    if problems:
        raise ValueError("estimate: " + "; ".join(f"{w} ({fix})" for w, fix in problems))


class SweepTable:
    """The ``sweep_run`` table of an SQLite file (written by one process: the sweep's)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._db = sqlite3.connect(self.path)
        self._db.execute("PRAGMA journal_mode=WAL")
        self._db.executescript(SCHEMA)
        have = {row[1] for row in self._db.execute("PRAGMA table_info(sweep_run)")}
        for column, kind in ADDED_COLUMNS.items():
            if column not in have:
                self._db.execute(f"ALTER TABLE sweep_run ADD COLUMN {column} {kind}")

    def finished(self) -> dict[str, str | None]:
        """Each recorded run's key and its trajectory store (``None``: summary only)."""
        return dict(self._db.execute("SELECT key, store FROM sweep_run").fetchall())

    def add(self, key: str, system: str, options: Mapping[str, Any],
            summary: Mapping[str, Any]) -> None:
        self._db.execute(
            "INSERT OR REPLACE INTO sweep_run (key, system, point_json, options_json, status, "
            "message, calls_json, calls_total, steps, error, error_estimate, wall_s, finished, "
            "store, rmse, step_min, extremes_json) "
            "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
            (key, system, json.dumps(summary["point"], sort_keys=True),
             json.dumps(dict(options), sort_keys=True), summary["status"], summary["message"],
             json.dumps(summary["calls"], sort_keys=True), summary["calls_total"],
             summary["steps"], summary["error"], summary["error_estimate"], summary["wall_s"],
             time.time(), summary.get("store"), summary.get("rmse"), summary.get("step_min"),
             json.dumps(summary.get("extremes") or {}, sort_keys=True)))
        self._db.commit()

    def frame(self, keys: Sequence[str] | None = None) -> Any:
        """The runs (those of ``keys``, in that order) as a pandas DataFrame: one column per
        swept name, then status, message, calls per sub-model (``calls.NAME``), calls_total
        (all the point cost: with a run repeated at a tighter tol, both runs, where
        ``calls.NAME`` are the kept run's), steps, error, rmse, error_estimate, step_min,
        wall_s, store, the sweep's run options as a label (``options``: runs of sweeps with
        other options share a file), and each output's extremes over the run (``min.NAME``,
        ``max.NAME``). ``frame.attrs["swept"]`` lists the swept names."""
        import pandas as pd

        rows = {r[0]: r for r in self._db.execute(
            "SELECT key, point_json, status, message, calls_json, calls_total, steps, error, "
            "error_estimate, wall_s, store, options_json, rmse, step_min, extremes_json "
            "FROM sweep_run")}
        order = list(keys) if keys is not None else sorted(rows)
        records, swept = [], {}
        for key in order:
            if key not in rows:
                continue
            _, point, status, message, calls, total, steps, error, estimate, wall, store, \
                options, rmse, smallest, ranges = rows[key]
            record = dict(json.loads(point))
            swept.update(dict.fromkeys(record))
            record.update(status=status, message=message)
            record.update({f"calls.{m}": c for m, c in json.loads(calls).items()})
            record.update(calls_total=total, steps=steps, error=error, rmse=rmse,
                          error_estimate=estimate, step_min=smallest, wall_s=wall, store=store,
                          options=_label(json.loads(options)))
            for name, (low, high) in json.loads(ranges or "{}").items():
                record[f"min.{name}"], record[f"max.{name}"] = low, high
            records.append(record)
        frame = pd.DataFrame.from_records(records)
        # which columns are the swept names: a model may be called "min" or "calls", so the
        # summary's prefixes cannot tell them apart
        frame.attrs["swept"] = list(swept)
        return frame

    def close(self) -> None:
        self._db.close()


def sweep(system: str | Path, params: Sequence[str | Axis] = (), *, design_kind: str = "full",
          samples: int | None = None, seed: int | None = None,
          points: Sequence[Mapping[str, float]] | None = None, out: str | Path = "sweep.db",
          workers: int | None = None, scheduler: str | None = None,
          progress: bool | None = None, keep: str = "summary", **options: Any) -> Any:
    """Run ``system`` at every point of the design on Dask; return the runs as a DataFrame.

    ``params``: axes (``"l2=0.5,1,2"``, ``"tol=1e-6:1e-3"`` or :class:`Axis`); ``options``:
    ``master``, ``extrapolation``, ``controller``, ``tol``, ``step``, ``until``, ``coupling``,
    ``estimate`` (how each adaptive run estimates its own error: :func:`~cosimstep.simulate`)
    and ``tighten`` (``False``: no run repeated at a tighter tol, :mod:`cosimstep.tighten`).
    ``points``: the design written out instead of ``params`` (a study whose points are not a
    product of axes: each case with its own step, or ``until`` tied to a length).
    Runs already in ``out`` are not run again. ``workers``: worker processes of the local
    cluster (default: one per core); ``scheduler``: the address of an existing Dask scheduler
    instead. Each run's summary is written to ``out`` as it finishes. ``keep="traces"`` also
    stores each run's whole trajectory, in ``<out>_traces/run-<id>.db`` (column ``store``;
    read with :func:`cosimstep.read_run`); a recorded run without one is then run again.
    """
    if keep not in KEEP:
        raise ValueError(f"unknown keep '{keep}'; choose one of {', '.join(KEEP)}")
    system = str(Path(system).resolve())
    points = _points(params, design_kind, samples, seed, points)
    options = {k: v for k, v in options.items() if v is not None}
    keys = [run_key(system, p, options) for p in points]
    firsts: dict[tuple[str, ...], dict[str, float]] = {}
    for p in points:
        firsts.setdefault(tuple(sorted(p)), p)
    _check_ends(points)
    for first in firsts.values():  # a misspelt name fails here, not in every run
        _, controller, master = prepare(system, first, options)
        _check_estimate(options.get("estimate", "sum"), controller, master)
    if scheduler is not None:
        check_scheduler(scheduler)  # before anything is written
    table = SweepTable(out)
    try:
        done = table.finished()
        traces = Path(out).with_name(Path(out).stem + "_traces") if keep == "traces" else None
        todo = [(k, p, None if traces is None else str(traces / f"run-{_digest(k)}.db"))
                for k, p in zip(keys, points)
                if k not in done or (traces is not None and not _kept(done[k]))]
        if traces is not None:
            traces.mkdir(parents=True, exist_ok=True)
        if todo:
            _execute(todo, system, options, table, workers, scheduler, progress)
        return table.frame(keys)
    finally:
        table.close()


def _check_ends(points: Sequence[Mapping[str, float]]) -> None:
    """``ValueError`` where a swept ``until`` is no positive number: each point has its own,
    and :func:`prepare` sees only the first point of each kind."""
    ends = sorted({p["until"] for p in points if "until" in p
                   and not (math.isfinite(p["until"]) and p["until"] > 0.0)})
    if ends:
        raise ValueError(f"`until` must be a positive number of seconds, got {ends[0]:g}"
                         + (f" and {len(ends) - 1} more" if len(ends) > 1 else ""))


def _points(params: Sequence[str | Axis], design_kind: str, samples: int | None,
            seed: int | None, points: Sequence[Mapping[str, float]] | None
            ) -> list[dict[str, float]]:
    """The design's points: from the axes, or the ``points`` given (not both)."""
    if points is None:
        axes = [a if isinstance(a, Axis) else parse_axis(a) for a in params]
        return design(axes, design_kind, samples, seed)
    if params:
        raise ValueError("give the swept names as params or the points written out, not both")
    if not points:
        raise ValueError("points: the list is empty; give at least one point")
    out = []
    for i, point in enumerate(points):
        try:
            out.append({str(k): float(v) for k, v in point.items()})
        except (TypeError, ValueError):
            raise ValueError(f"points[{i}]: values must be numbers, got {dict(point)}") from None
    return out


def check_scheduler(address: str, timeout: float = 10.0) -> None:
    """``ValueError`` naming the address unless a Dask scheduler answers there in time."""
    import socket
    from urllib.parse import urlsplit

    from distributed import Client

    try:
        parts = urlsplit(address)
        if parts.scheme == "tcp" and parts.hostname and parts.port:
            # a refused port answers at once; Dask's client would retry until its timeout
            socket.create_connection((parts.hostname, parts.port), timeout=timeout).close()
        Client(address, timeout=timeout).close()
    except (OSError, TimeoutError, ValueError) as exc:
        raise ValueError(f"no Dask scheduler answers at {address} within {timeout:g} s "
                         f"({type(exc).__name__}); start one (`dask scheduler`) and give the "
                         "address it prints, or leave --scheduler out to use a local "
                         "cluster") from None


def _label(options: Mapping[str, Any]) -> str:
    """The run options of a sweep as one short label (``master=multirate tol=0.001``)."""
    return " ".join(f"{k}={v}" for k, v in sorted(options.items())) or "file defaults"


def _digest(key: str) -> str:
    import hashlib

    return hashlib.sha1(key.encode()).hexdigest()[:16]


def _kept(store: str | None) -> bool:
    return store is not None and Path(store).is_file()


def _execute(todo: list[tuple[str, dict[str, float], str | None]], system: str,
             options: dict[str, Any],
             table: SweepTable, workers: int | None, scheduler: str | None,
             progress: bool | None) -> None:
    from distributed import Client, LocalCluster, as_completed
    from tqdm import tqdm

    cluster = None
    if scheduler is None:
        import os

        n = workers or os.cpu_count() or 1
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                               dashboard_address=None)
    client = Client(scheduler or cluster)
    try:
        for _, _, store in todo:  # a run stored before (failed, or killed) starts afresh
            if store is not None:
                Path(store).unlink(missing_ok=True)
        futures = {client.submit(run_point, system, p, options, store, pure=False): k
                   for k, p, store in todo}
        # disable=None: tqdm shows the bar only on a terminal, as a run's progress bar
        with tqdm(total=len(futures), unit="run", desc="sweep",
                  disable=None if progress is None else not progress) as bar:
            for future in as_completed(futures):
                key = futures[future]
                try:
                    summary = future.result()
                except Exception as exc:  # the task itself was lost (workers kept dying)
                    summary = _failed(json.loads(key)["point"], f"{type(exc).__name__}: {exc}")
                table.add(key, system, options, summary)
                bar.update(1)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


__all__ = ["DESIGNS", "Axis", "SweepTable", "design", "parse_axis", "run_point", "sweep"]

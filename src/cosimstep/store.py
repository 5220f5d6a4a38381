"""The results database (thesis 3.2 "data storage"): an SQLite file anyone can query.

Tables (one file can hold many runs)::

    run(id, created, system, config_json, status, message, t_end, wall_s, summary_json,
        host, pid, heartbeat)                          -- who writes it, and when it last did
    variable(run_id, id, name, unit)                   -- one row per exchanged output
    point_block(run_id, first_step, n, data)           -- the communication points first_step …
                                                          first_step + n - 1: n rows of (t, value
                                                          of variable 0, 1, ...) as little-endian
                                                          float64 (read_run gives them as arrays)
    reference(run_id, step, variable_id, value)        -- the monolithic reference there, if any
    attempt(run_id, seq, model, t, h, accepted, error) -- step attempts, rejected ones too
    step_block(run_id, first_seq, n, data)             -- accepted synchronous steps without an
                                                          estimate, attempts first_seq … as rows
                                                          of (t, h), float64 like point_block
    calls(run_id, model, calls, time_in_model_s)
    own_point(run_id, variable_id, seq, t, value)      -- multi-rate: each output at its own
                                                          sub-model's communication points
    event(run_id, seq, t, source, kind, payload_json, late)  -- discrete events (late: a state
                                                          event fired a step late, not located)
    checkpoint(run_id, t, point, attempt_seq, created, state, note)  -- the newest checkpoint
                                                          a run can be resumed from (state:
                                                          pickled; NULL with a note when the
                                                          run could not take one)

Rows are buffered and committed at least every ``flush_seconds`` of wall time, so a run that is
interrupted or crashes keeps what it computed up to the last commit.

Why blocks for the points: a row per exchanged value cost 1-2 µs (SQLite's per-row work), which
made a cheap sub-model's run with the store 3-7 times as long as without it; a block of every
point written between two commits costs a copy. The values are then no longer one SQL row each:
``read_run`` (or ``run --json``, ``to_pandas``) reads them. Stores written before hold their
points in the tables ``point(run_id, step, t)`` and ``sample(run_id, step, variable_id, value)``,
which are still read.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import socket
import sqlite3
import time
from array import array
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

SCHEMA = """
CREATE TABLE IF NOT EXISTS run(
    id INTEGER PRIMARY KEY, created TEXT, system TEXT, config_json TEXT, status TEXT,
    message TEXT, t_end REAL, wall_s REAL, summary_json TEXT);
CREATE TABLE IF NOT EXISTS variable(
    run_id INTEGER, id INTEGER, name TEXT, unit TEXT, PRIMARY KEY(run_id, id));
CREATE TABLE IF NOT EXISTS point(
    run_id INTEGER, step INTEGER, t REAL, PRIMARY KEY(run_id, step)) WITHOUT ROWID;
CREATE TABLE IF NOT EXISTS sample(
    run_id INTEGER, step INTEGER, variable_id INTEGER, value REAL,
    PRIMARY KEY(run_id, variable_id, step)) WITHOUT ROWID;
CREATE TABLE IF NOT EXISTS point_block(
    run_id INTEGER, first_step INTEGER, n INTEGER, data BLOB,
    PRIMARY KEY(run_id, first_step)) WITHOUT ROWID;
CREATE TABLE IF NOT EXISTS step_block(
    run_id INTEGER, first_seq INTEGER, n INTEGER, data BLOB,
    PRIMARY KEY(run_id, first_seq)) WITHOUT ROWID;
CREATE TABLE IF NOT EXISTS reference(
    run_id INTEGER, step INTEGER, variable_id INTEGER, value REAL,
    PRIMARY KEY(run_id, variable_id, step)) WITHOUT ROWID;
CREATE TABLE IF NOT EXISTS attempt(
    run_id INTEGER, seq INTEGER, model TEXT, t REAL, h REAL, accepted INTEGER, error REAL,
    PRIMARY KEY(run_id, seq)) WITHOUT ROWID;
CREATE TABLE IF NOT EXISTS own_point(
    run_id INTEGER, variable_id INTEGER, seq INTEGER, t REAL, value REAL,
    PRIMARY KEY(run_id, variable_id, seq)) WITHOUT ROWID;
CREATE TABLE IF NOT EXISTS event(
    run_id INTEGER, seq INTEGER, t REAL, source TEXT, kind TEXT, payload_json TEXT,
    late INTEGER, PRIMARY KEY(run_id, seq)) WITHOUT ROWID;
CREATE TABLE IF NOT EXISTS calls(
    run_id INTEGER, model TEXT, calls INTEGER, time_in_model_s REAL,
    PRIMARY KEY(run_id, model));
CREATE TABLE IF NOT EXISTS symbol(
    run_id INTEGER, code INTEGER, value BLOB, PRIMARY KEY(run_id, code)) WITHOUT ROWID;
CREATE TABLE IF NOT EXISTS checkpoint(
    run_id INTEGER PRIMARY KEY, t REAL, point INTEGER, attempt_seq INTEGER, created REAL,
    state BLOB, note TEXT);
"""


ADDED_COLUMNS = (("host", "TEXT"), ("pid", "INTEGER"), ("heartbeat", "REAL"), ("kept", "INTEGER"))
"""Added to the run table (stores written before they existed get them on opening): the
writer's host, process and heartbeat, and ``kept = 0`` for a run that is not the result of its
call (the discarded one of a pair repeated at a tighter tol, :func:`amend_run`)."""
STALE_SECONDS = 60.0
"""A ``running`` run whose writer's heartbeat is older than this (and whose process is gone, when
it ran on this host) is ``abandoned``: killed, or its machine died."""


def _add_columns(db: sqlite3.Connection) -> None:
    have = {row[1] for row in db.execute("PRAGMA table_info(run)")}
    for name, kind in ADDED_COLUMNS:
        if name not in have:
            db.execute(f"ALTER TABLE run ADD COLUMN {name} {kind}")


class Store:
    """Writes one run incrementally."""

    def __init__(self, path: str | Path, flush_seconds: float = 0.5) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        # written by the run's worker thread when calls are watched (masters._Watchdog), then
        # by the caller once the worker has stopped: one thread at a time
        self._db = sqlite3.connect(self.path, check_same_thread=False)
        # Write-ahead log, synced at checkpoints only: a commit then costs no fsync (26 ms
        # each in rollback-journal mode), and a process that crashes or is killed still
        # loses nothing it committed; only a power cut can lose the last commits.
        self._db.execute("PRAGMA journal_mode=WAL")
        self._db.execute("PRAGMA synchronous=NORMAL")
        self._db.executescript(SCHEMA)
        _add_columns(self._db)
        self._flush_seconds = flush_seconds
        self._last_flush = time.monotonic()
        self._points = _Blocks()  # (t, values) of consecutive points
        self._steps = _Blocks()  # (t, h) of consecutive accepted synchronous steps
        self._attempts: list[tuple] = []
        self._n_vars = 0
        self._seq = 0
        self.run_id = -1

    def begin(self, system: str, config: dict[str, Any], names: Sequence[str],
              units: Sequence[str]) -> int:
        cur = self._db.execute(
            "INSERT INTO run(created, system, config_json, status, host, pid, heartbeat) "
            "VALUES (?, ?, ?, 'running', ?, ?, ?)",
            (datetime.now(UTC).isoformat(), system, json.dumps(config, default=str),
             socket.gethostname(), os.getpid(), time.time()))
        self.run_id = int(cur.lastrowid)
        self._n_vars = len(names)
        self._db.executemany("INSERT INTO variable VALUES (?, ?, ?, ?)",
                             [(self.run_id, i, n, u) for i, (n, u) in enumerate(zip(names, units))])
        self._db.commit()
        return self.run_id

    def reopen(self, run_id: int, config: dict[str, Any], names: Sequence[str]) -> Checkpoint:
        """Continue run ``run_id`` from its newest checkpoint: what it stored after it is
        removed, the run is ``running`` again under this process, and the checkpoint is
        returned. Raises ``ValueError`` (saying why) if it cannot be resumed, or if
        ``config`` (the settings of the run to be continued) differs from the stored one."""
        ck = read_checkpoint(self.path, run_id, self._db)
        row = self._db.execute("SELECT config_json FROM run WHERE id=?", (run_id,)).fetchone()
        given = json.loads(json.dumps(config, default=str))
        stored, given = _known_settings(json.loads(row[0]), given)
        differ = sorted(k for k in {*stored, *given} if stored.get(k) != given.get(k))
        if differ:
            raise ValueError(f"run {run_id} in {self.path} was run with other settings "
                             f"({', '.join(differ)}: {_differences(stored, given)}): resume it "
                             "with the same system file and options")
        have = [r[0] for r in self._db.execute(
            "SELECT name FROM variable WHERE run_id=? ORDER BY id", (run_id,))]
        if have != list(names):
            raise ValueError(f"run {run_id} in {self.path} exchanged other variables: resume "
                             "it with the same system")
        db, rid = self._db, run_id
        from cosimstep.symbols import SYMBOLS

        for (value,) in db.execute("SELECT value FROM symbol WHERE run_id=?", (rid,)):
            SYMBOLS.code(value)  # the codes of the stored points decode in this process
        db.execute("DELETE FROM point WHERE run_id=? AND step>?", (rid, ck.point))
        db.execute("DELETE FROM sample WHERE run_id=? AND step>?", (rid, ck.point))
        _truncate(db, "point_block", "first_step", rid, ck.point + 1, 1 + len(names))
        db.execute("DELETE FROM attempt WHERE run_id=? AND seq>=?", (rid, ck.attempt_seq))
        _truncate(db, "step_block", "first_seq", rid, ck.attempt_seq, 2)
        for table in ("calls", "event", "reference"):  # written again at the end
            db.execute(f"DELETE FROM {table} WHERE run_id=?", (rid,))
        db.execute("UPDATE run SET status='running', message=NULL, host=?, pid=?, heartbeat=? "
                   "WHERE id=?", (socket.gethostname(), os.getpid(), time.time(), rid))
        db.commit()
        self.run_id, self._n_vars, self._seq = rid, len(names), ck.attempt_seq
        return ck

    def points_before(self, step: int) -> tuple[np.ndarray, np.ndarray]:
        """The stored points ``0 … step - 1`` of this run: times and values (one row each)."""
        self.flush()
        times, values = _read_points(self._db, self.run_id, self._n_vars)
        return times[:step], values[:step]

    def add_symbols(self, symbols: Mapping[int, str | bytes]) -> None:
        """Values of String and Binary codes (:mod:`cosimstep.symbols`) the run used."""
        self._db.executemany("INSERT OR REPLACE INTO symbol VALUES (?, ?, ?)",
                             [(self.run_id, c, v) for c, v in symbols.items()])

    def add_checkpoint(self, t: float, point: int, state: bytes | None, note: str = "") -> None:
        """Everything up to point ``point`` (at ``t``) is committed with the state to go on
        from there, and the String and Binary values seen so far (a resuming process decodes
        the stored codes with them); a run keeps only its newest checkpoint. ``state``
        ``None``: the run could not take one, and ``note`` says why (``--resume`` repeats
        it)."""
        from cosimstep.symbols import SYMBOLS

        self.flush()
        self.add_symbols(SYMBOLS.known())
        self._db.execute("INSERT OR REPLACE INTO checkpoint VALUES (?, ?, ?, ?, ?, ?, ?)",
                         (self.run_id, t, point, self._seq, time.time(),
                          None if state is None else sqlite3.Binary(state), note))
        self._db.commit()

    def add_point(self, step: int, t: float, y: np.ndarray) -> None:
        row = np.empty((1, 1 + self._n_vars))
        row[0, 0] = t
        row[0, 1:] = y
        self._points.add(step, row)
        if time.monotonic() - self._last_flush > self._flush_seconds:
            self.flush()

    def add_attempt(self, model: str | None, t: float, h: float, accepted: bool,
                    error: float | None) -> None:
        self._attempts.append((self.run_id, self._seq, model, t, h, int(accepted), error))
        self._seq += 1

    def add_points(self, first_step: int, times: Sequence[float],
                   rows: Sequence[Sequence[float]] | np.ndarray) -> None:
        """Points ``first_step, first_step + 1, ...`` at once (what :meth:`add_point` would
        write one by one)."""
        values = np.asarray(rows, dtype=float).reshape(len(times), self._n_vars)
        self._points.add(first_step, np.column_stack([np.asarray(times, dtype=float), values]))
        if time.monotonic() - self._last_flush > self._flush_seconds:
            self.flush()

    def add_accepted_attempts(self, times: Sequence[float], steps: Sequence[float]) -> None:
        """Accepted synchronous attempts ``[t, t + h]`` in order, without an error estimate."""
        if len(times):
            self._steps.add(self._seq, np.column_stack([np.asarray(times, dtype=float),
                                                        np.asarray(steps, dtype=float)]))
            self._seq += len(times)

    def flush(self) -> None:
        """Write the buffered rows and blocks and commit. Every row is written idempotently
        (``INSERT OR REPLACE``, a block keyed by its first index): a signal (Ctrl-C, SIGTERM)
        can land after the rows were written and before the buffers were cleared, and the next
        flush then hands them again."""
        db, rid = self._db, self.run_id
        db.executemany("INSERT OR REPLACE INTO point_block VALUES (?, ?, ?, ?)",
                       [(rid, *b) for b in self._points.blocks()])
        db.executemany("INSERT OR REPLACE INTO step_block VALUES (?, ?, ?, ?)",
                       [(rid, *b) for b in self._steps.blocks()])
        db.executemany("INSERT OR REPLACE INTO attempt VALUES (?, ?, ?, ?, ?, ?, ?)",
                       self._attempts)
        db.execute("UPDATE run SET heartbeat=? WHERE id=?", (time.time(), rid))
        db.commit()
        self._points.written()
        self._steps.written()
        self._attempts.clear()
        self._last_flush = time.monotonic()

    def add_reference(self, values: np.ndarray, variable_ids: Sequence[int],
                      first_step: int = 0) -> None:
        """``values``: (n_points, len(variable_ids)) reference at the stored points from
        ``first_step`` on."""
        rows = [(self.run_id, first_step + step, vid, float(values[step, j]))
                for j, vid in enumerate(variable_ids) for step in range(values.shape[0])]
        self._db.executemany("INSERT OR REPLACE INTO reference VALUES (?, ?, ?, ?)", rows)

    def add_own_points(self, variable_ids: Sequence[int], times: np.ndarray,
                       values: np.ndarray) -> None:
        """One sub-model's own points: ``values`` has a column per id in ``variable_ids``."""
        rid = self.run_id
        self._db.executemany("INSERT INTO own_point VALUES (?, ?, ?, ?, ?)",
                             [(rid, vid, i, float(t), float(values[i, j]))
                              for j, vid in enumerate(variable_ids)
                              for i, t in enumerate(times)])

    def add_events(self, events: Sequence[Any]) -> None:
        """The run's events (:class:`cosimstep.events.Event`), in time order."""
        self._db.executemany("INSERT INTO event VALUES (?, ?, ?, ?, ?, ?, ?)",
                             [(self.run_id, i, float(e.t), e.source, e.kind,
                               json.dumps(e.payload), int(e.late))
                              for i, e in enumerate(events)])

    def finish(self, status: str, message: str, t_end: float, wall_s: float,
               summary: dict[str, Any], calls: dict[str, int],
               time_in_models: dict[str, float],
               symbols: Mapping[int, str | bytes] | None = None) -> None:
        """End the run: its status, summary and calls, and the values of the codes its
        String and Binary columns hold (:mod:`cosimstep.symbols`; text stored as TEXT, bytes
        as BLOB)."""
        self.flush()
        self.add_symbols(symbols or {})
        self._db.executemany("INSERT INTO calls VALUES (?, ?, ?, ?)",
                             [(self.run_id, m, calls[m], time_in_models[m]) for m in calls])
        self._db.execute(
            "UPDATE run SET status=?, message=?, t_end=?, wall_s=?, summary_json=? WHERE id=?",
            (status, message, t_end, wall_s, json.dumps(summary, default=float), self.run_id))
        self._db.commit()

    def close(self) -> None:
        self._db.close()


@dataclass
class Checkpoint:
    """A run's newest checkpoint: ``state`` is the pickled state of the run's loop and of every
    sub-model at point ``point`` (time ``t``); ``attempt_seq`` attempts were stored by then."""

    run_id: int
    t: float
    point: int
    attempt_seq: int
    state: bytes


def _known_settings(stored: dict[str, Any], given: dict[str, Any]
                    ) -> tuple[dict[str, Any], dict[str, Any]]:
    """``stored`` and ``given`` with their controller entries cut to the keys both record.
    An earlier version recorded what a run had measured into the controller among its
    settings (its error memory, noise floor, error estimate), which is no setting, and did
    not record the options of the controller that `switching` or `adaptive-tol` wrap, which
    such a record therefore cannot tell; a run stored so is resumed all the same. A setting
    that both record still has to agree, and so does the controller's name."""
    old, new = stored.get("controller"), given.get("controller")
    if isinstance(old, dict) and isinstance(new, dict):
        stored = {**stored, "controller": _shared_keys(old, new)}
        given = {**given, "controller": _shared_keys(new, old)}
    return stored, given


def _shared_keys(one: dict[str, Any], other: dict[str, Any]) -> dict[str, Any]:
    """``one``'s entries whose keys ``other`` has too, nested dicts alike."""
    return {k: _shared_keys(v, other[k]) if isinstance(v, dict) and isinstance(other[k], dict)
            else v for k, v in one.items() if k in other}


def _differences(stored: dict[str, Any], given: dict[str, Any], most: int = 4) -> str:
    """The settings that differ, each as ``path <stored> stored, <given> now`` (the first
    ``most``), so a refused resume says which option to give again, not only its group."""
    found: list[str] = []

    def walk(a: Any, b: Any, path: str) -> None:
        if isinstance(a, dict) and isinstance(b, dict):
            for k in sorted({*a, *b}, key=str):
                walk(a.get(k, "(none)"), b.get(k, "(none)"), f"{path}.{k}" if path else str(k))
        elif a != b:
            found.append(f"{path} {a!r} stored, {b!r} now")

    walk(stored, given, "")
    more = f"; {len(found) - most} more" if len(found) > most else ""
    return "; ".join(found[:most]) + more


def read_checkpoint(path: str | Path, run_id: int | None = None,
                    db: sqlite3.Connection | None = None) -> Checkpoint:
    """Run ``run_id``'s newest checkpoint (``None``: the newest run's that is a result, as
    :func:`read_run` picks it); ``ValueError`` saying why there is none to resume from."""
    own = db is None
    db = db if db is not None else sqlite3.connect(path)
    try:
        if run_id is None:
            try:
                run_id = _last_run_id(db, Path(path))
            except LookupError:
                raise ValueError(f"{path} holds no run to resume") from None
        _add_columns(db)
        run = db.execute("SELECT status, host, pid, heartbeat FROM run WHERE id=?",
                         (run_id,)).fetchone()
        if run is None:
            raise ValueError(f"{path} holds no run {run_id} (see `cosimstep runs {path}`)")
        if run[0] == "ok":
            raise ValueError(f"run {run_id} in {path} completed: nothing to resume")
        if run[0] == "running" and _alive(dict(zip(("host", "pid", "heartbeat"), run[1:]))):
            raise ValueError(f"run {run_id} in {path} is still running (process {run[2]} on "
                             f"{run[1]})")
        have = {r[1] for r in db.execute("PRAGMA table_info(checkpoint)")}
        row = db.execute("SELECT t, point, attempt_seq, state, note FROM checkpoint "
                         "WHERE run_id=?", (run_id,)).fetchone() if have else None
        if row is None or row[3] is None:
            why = f" ({row[4]})" if row is not None and row[4] else \
                " (synchronous runs that store every point take one every " \
                "--checkpoint-every seconds)"
            raise ValueError(f"run {run_id} in {path} has no checkpoint{why}")
        return Checkpoint(run_id, float(row[0]), int(row[1]), int(row[2]), bytes(row[3]))
    finally:
        if own:
            db.close()


@dataclass
class StoredRun:
    """A run read back from a store."""

    run_id: int
    system: str
    status: str
    message: str
    config: dict[str, Any]
    summary: dict[str, Any]
    names: list[str]
    units: list[str]
    times: np.ndarray
    values: np.ndarray
    reference: np.ndarray | None
    attempts: np.ndarray  # columns t, h, accepted
    attempt_models: list[str | None]
    own_points: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    """Multi-rate runs: ``{output: (times, values)}`` at its sub-model's own points (the
    common grid in ``times``/``values`` interpolates the other sub-models' outputs there)."""
    events: list[dict[str, Any]] = field(default_factory=list)
    """Events of discrete-event sub-models: ``{"t", "source", "kind", "payload"}``."""
    symbols: dict[int, str | bytes] = field(default_factory=dict)
    """Code → value of the run's String and Binary columns (:mod:`cosimstep.symbols`)."""

    def text(self, name: str) -> list[str | bytes]:
        """The values of a String or Binary output, decoded with the run's stored codes."""
        return [self.symbols[int(c)] for c in self.values[:, self.names.index(name)]]

    def to_pandas(self):
        """Exchanged values as a DataFrame indexed by time (needs pandas); String and Binary
        columns decoded."""
        from cosimstep.symbols import decoded_frame

        return decoded_frame(self.values, self.times, self.names, self.units, self.symbols)


def runs(path: str | Path) -> list[tuple[int, str, str]]:
    """``(id, system, status)`` of every run in a store; a ``running`` run whose writer is gone
    is ``abandoned`` (see :func:`run_table`)."""
    return [(r["id"], r["system"], r["status"]) for r in run_table(path)]


def run_table(path: str | Path) -> list[dict[str, Any]]:
    """Every run of a store: id, created, system, status, message, t_end, wall_s, host, pid,
    heartbeat, and kept (0 for the discarded run of a pair repeated at a tighter tol, else
    ``None``: :func:`amend_run`).

    ``running`` is told apart from ``abandoned`` (the writer was killed, or its machine died):
    on this host by whether the writing process still exists, elsewhere by a heartbeat older
    than :data:`STALE_SECONDS` (the store commits at least every half second while it runs).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no results store at {path}")
    with sqlite3.connect(path) as db:
        _add_columns(db)
        rows = db.execute("SELECT id, created, system, status, message, t_end, wall_s, host, "
                          "pid, heartbeat, kept FROM run ORDER BY id").fetchall()
    keys = ("id", "created", "system", "status", "message", "t_end", "wall_s", "host", "pid",
            "heartbeat", "kept")
    out = [dict(zip(keys, r)) for r in rows]
    for run in out:
        if run["status"] == "running" and not _alive(run):
            run["status"] = "abandoned"
    return out


def _alive(run: dict[str, Any]) -> bool:
    if run["host"] == socket.gethostname() and run["pid"]:
        try:
            os.kill(int(run["pid"]), 0)
        except ProcessLookupError:
            return False
        except PermissionError:
            return True  # someone else's live process
        return True
    return run["heartbeat"] is not None and time.time() - run["heartbeat"] < STALE_SECONDS


def delete_run(path: str | Path, run_id: int) -> None:
    """Remove a run and everything stored for it; ``LookupError`` if there is none, and
    ``RuntimeError`` for a run whose writer is still alive."""
    table = {r["id"]: r for r in run_table(path)}
    if run_id not in table:
        raise LookupError(f"no run {run_id} in {path} (its runs: "
                          f"{', '.join(map(str, table)) or 'none'})")
    if table[run_id]["status"] == "running":
        raise RuntimeError(f"run {run_id} is still being written by process "
                           f"{table[run_id]['pid']} on {table[run_id]['host']}")
    with sqlite3.connect(path) as db:
        db.executescript(SCHEMA)  # a store from before some tables existed
        for name in ("variable", "point", "sample", "point_block", "reference", "attempt",
                     "step_block", "own_point", "event", "calls", "symbol", "checkpoint"):
            db.execute(f"DELETE FROM {name} WHERE run_id=?", (run_id,))
        db.execute("DELETE FROM run WHERE id=?", (run_id,))


def amend_run(path: str | Path, run_id: int, text: str, kept: bool | None = None,
              updates: dict[str, Any] | None = None) -> None:
    """Append ``text`` to a finished run's stored message (the column and its summary), merge
    ``updates`` into its summary, and with ``kept = False`` mark it as not the result of its
    call: what became known after it ended (a run repeated at a tighter tol,
    :mod:`cosimstep.tighten`). A run so marked is passed over where a command reads "the
    newest run" (:func:`read_run` without an id)."""
    with contextlib.closing(sqlite3.connect(path)) as db, db:
        _add_columns(db)
        row = db.execute("SELECT message, summary_json FROM run WHERE id=?", (run_id,)).fetchone()
        if row is None:
            raise LookupError(f"no run {run_id} in {path}")
        message = (row[0] or "") + text
        summary = {**(json.loads(row[1]) if row[1] else {}), **(updates or {}),
                   "message": message}
        db.execute("UPDATE run SET message=?, summary_json=? WHERE id=?",
                   (message, json.dumps(summary, default=float), run_id))
        if kept is not None:
            db.execute("UPDATE run SET kept=? WHERE id=?", (int(kept), run_id))


def read_run(path: str | Path, run_id: int | None = None) -> StoredRun:
    """Read a run back into NumPy arrays (default: the last one that is a result, passing
    over the discarded run of a pair repeated at a tighter tol, :func:`amend_run`)."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"no results store at {path}")
    db = sqlite3.connect(path)
    try:
        if run_id is None:
            run_id = _last_run_id(db, path)
        meta = db.execute("SELECT system, status, message, config_json, summary_json FROM run "
                          "WHERE id=?", (run_id,)).fetchone()
        if meta is None:
            raise LookupError(f"{path} has no run {run_id}")
        var = db.execute("SELECT name, unit FROM variable WHERE run_id=? ORDER BY id",
                         (run_id,)).fetchall()
        times, values = _read_points(db, run_id, len(var))
        reference = _read_reference(db, run_id, len(var), len(times))
        attempts, attempt_models = _read_attempts(db, run_id)
        own_points = _read_own_points(db, run_id, var)
        events = [{"t": t, "source": src, "kind": kind, "payload": json.loads(payload),
                   "late": bool(late)}
                  for t, src, kind, payload, late in db.execute(
                      "SELECT t, source, kind, payload_json, late FROM event WHERE run_id=? "
                      "ORDER BY seq", (run_id,))]
        symbols = dict(db.execute("SELECT code, value FROM symbol WHERE run_id=?", (run_id,)))
    finally:
        db.close()
    return StoredRun(
        run_id=run_id, system=meta[0], status=meta[1], message=meta[2] or "",
        config=json.loads(meta[3] or "{}"), summary=json.loads(meta[4] or "{}"),
        names=[v[0] for v in var], units=[v[1] for v in var], times=times, values=values,
        reference=reference,
        attempts=attempts, attempt_models=attempt_models, own_points=own_points, events=events,
        symbols=symbols)


def _last_run_id(db: sqlite3.Connection, path: Path) -> int:
    """The newest run's id: what :func:`read_run` reads when not told which run — but not a
    run marked as not kept (:func:`amend_run`), the discarded one of a repeated pair."""
    have = {row[1] for row in db.execute("PRAGMA table_info(run)")}  # (read, never altered)
    row = db.execute("SELECT MAX(id) FROM run" + (" WHERE kept IS NULL OR kept != 0"
                                                  if "kept" in have else "")).fetchone()
    if row is None or row[0] is None:
        raise LookupError(f"{path} holds no runs")
    return int(row[0])


def _read_points(db: sqlite3.Connection, run_id: int,
                 n_vars: int) -> tuple[np.ndarray, np.ndarray]:
    """A run's point times and exchanged values (n_points, n_vars), from its blocks and, for
    points a store from before the blocks wrote, the per-value rows."""
    blocks = db.execute("SELECT first_step, n, data FROM point_block WHERE run_id=? "
                        "ORDER BY first_step", (run_id,)).fetchall()
    old = np.array(db.execute("SELECT step, t FROM point WHERE run_id=? ORDER BY step",
                              (run_id,)).fetchall(), dtype=float).reshape(-1, 2)
    size = max([first + n for first, n, _ in blocks]
               + [int(old[-1, 0]) + 1 if len(old) else 0])
    times, values = np.full(size, np.nan), np.full((size, n_vars), np.nan)
    if len(old):
        times[old[:, 0].astype(int)] = old[:, 1]
        rows = np.array(db.execute("SELECT step, variable_id, value FROM sample WHERE run_id=?",
                                   (run_id,)).fetchall(), dtype=float).reshape(-1, 3)
        values[rows[:, 0].astype(int), rows[:, 1].astype(int)] = rows[:, 2]
    for first, n, data in blocks:
        block = np.frombuffer(data, dtype="<f8").reshape(n, 1 + n_vars)
        times[first:first + n], values[first:first + n] = block[:, 0], block[:, 1:]
    return times, values


def _read_attempts(db: sqlite3.Connection, run_id: int) -> tuple[np.ndarray, list[str | None]]:
    """Every stored attempt in order, as rows (t, h, accepted), and the model of each (``None``
    for a synchronous step)."""
    rows = db.execute("SELECT seq, model, t, h, accepted FROM attempt WHERE run_id=?",
                      (run_id,)).fetchall()
    seq = [np.array([r[0] for r in rows], dtype=np.int64)]
    table = [np.array([r[2:] for r in rows], dtype=float).reshape(-1, 3)]
    models: list[str | None] = [r[1] for r in rows]
    for first, n, data in db.execute("SELECT first_seq, n, data FROM step_block WHERE run_id=?",
                                     (run_id,)):
        block = np.frombuffer(data, dtype="<f8").reshape(n, 2)
        seq.append(np.arange(first, first + n, dtype=np.int64))
        table.append(np.column_stack([block, np.ones(n)]))
        models += [None] * n
    order = np.argsort(np.concatenate(seq), kind="stable")
    return np.concatenate(table)[order], [models[i] for i in order]


def _truncate(db: sqlite3.Connection, table: str, key: str, run_id: int, keep: int,
              width: int) -> None:
    """Remove the rows from index ``keep`` on from ``table``'s blocks of ``width`` floats a
    row (a resumed run goes on from its checkpoint)."""
    for first, data in db.execute(f"SELECT {key}, data FROM {table} WHERE run_id=? AND "
                                  f"{key}<? AND {key}+n>?", (run_id, keep, keep)).fetchall():
        k = keep - first
        db.execute(f"UPDATE {table} SET n=?, data=? WHERE run_id=? AND {key}=?",
                   (k, data[:8 * k * width], run_id, first))
    db.execute(f"DELETE FROM {table} WHERE run_id=? AND {key}>=?", (run_id, keep))


class _Blocks:
    """Rows of floats with consecutive indices, gathered into one blob per run of indices
    between two writes (a gap or a rewritten index starts a new block)."""

    def __init__(self) -> None:
        self.first: int | None = None
        self.next = 0
        self._parts: list[np.ndarray] = []
        self._ready: list[tuple[int, int, bytes]] = []

    def add(self, first: int, rows: np.ndarray) -> None:
        if self.first is not None and first != self.next:
            self._cut()
        if self.first is None:
            self.first = first
        self._parts.append(rows)
        self.next = first + len(rows)

    def _cut(self) -> None:
        if self._parts and self.first is not None:
            data = np.concatenate(self._parts) if len(self._parts) > 1 else self._parts[0]
            self._ready.append((self.first, len(data),
                                np.ascontiguousarray(data, dtype="<f8").tobytes()))
        self._parts, self.first = [], None

    def blocks(self) -> list[tuple[int, int, bytes]]:
        """``(first index, rows, data)`` of everything added since the last :meth:`written`
        (the same blocks again if that write did not complete)."""
        self._cut()
        return self._ready

    def written(self) -> None:
        self._ready = []


def _read_reference(db: sqlite3.Connection, run_id: int, n_vars: int,
                    n_points: int) -> np.ndarray | None:
    """The monolithic reference as (n_points, n_vars), NaN where a variable has none; ``None``
    when the run stored no reference at all."""
    ref_rows = db.execute("SELECT variable_id, step, value FROM reference WHERE run_id=? "
                          "ORDER BY variable_id, step", (run_id,)).fetchall()
    if not ref_rows:
        return None
    reference = np.full((n_points, n_vars), np.nan)
    for vid, step, value in ref_rows:
        reference[step, vid] = value
    return reference


def _read_own_points(db: sqlite3.Connection, run_id: int,
                     var: list[tuple[str, str]]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Multi-rate runs: ``{output: (times, values)}`` at its own sub-model's points."""
    own: dict[str, list[tuple[float, float]]] = {}
    for vid, t, value in db.execute("SELECT variable_id, t, value FROM own_point WHERE "
                                    "run_id=? ORDER BY variable_id, seq", (run_id,)):
        own.setdefault(var[vid][0], []).append((t, value))
    return {n: (np.array([p[0] for p in pts]), np.array([p[1] for p in pts]))
            for n, pts in own.items()}


class GridStore:
    """A :class:`Store` that keeps the values on a time grid (``run --output-interval``).

    A five-million-step run wrote 1.14 GB of points; most users want the trajectory every
    ``interval`` seconds. Each grid time between two stored points gets the values linearly
    interpolated between them (what FMPy's output interval gives for a fixed-step run), and with
    ``keep_steps`` every accepted point is kept as well. The points are numbered in time order
    as written; the monolithic reference is interpolated onto them the same way. The step history
    is thinned alike (:meth:`add_attempt`); events, own points and the summary go to the store
    unchanged.
    """

    def __init__(self, store: Store, interval: float, t0: float,
                 keep_steps: bool = False) -> None:
        if not (math.isfinite(interval) and interval > 0):
            raise ValueError(f"`output_interval` must be positive, got {interval}")
        self._store, self.interval, self.t0 = store, float(interval), float(t0)
        self.keep_steps = keep_steps
        self._next = 0  # the next grid index to write
        self._count = 0  # points written
        self._last: tuple[float, np.ndarray] | None = None
        self._seen = array("d")  # every point's time handed in (for the reference), compact
        self.stored: list[float] = []  # the times written
        self._cells: dict[str | None, int] = {}  # last grid interval with an attempt kept

    def __getattr__(self, name: str) -> Any:
        return getattr(self._store, name)

    def add_point(self, step: int, t: float, y: np.ndarray) -> None:
        y = np.asarray(y, dtype=float)
        self._seen.append(t)
        eps = 1e-9 * self.interval
        if self._last is None:
            lo = -math.inf
        else:
            lo, y_lo = self._last
        while True:
            g = self.t0 + self._next * self.interval
            if g > t + eps:
                break
            if g > lo + eps or self._last is None:
                w = 0.0 if self._last is None or t == lo else (g - lo) / (t - lo)
                row = y if self._last is None or abs(g - t) <= eps else y_lo + w * (y - y_lo)
                self._write(g, row)
            self._next += 1
        if self.keep_steps and (not self.stored or t > self.stored[-1] + eps):
            self._write(t, y)
        self._last = (t, y)

    def add_points(self, first_step: int, times: Sequence[float],
                   rows: Sequence[Sequence[float]]) -> None:
        for i, (t, y) in enumerate(zip(times, rows)):
            self.add_point(first_step + i, float(t), np.array(y, dtype=float))

    def add_attempt(self, model: str | None, t: float, h: float, accepted: bool,
                    error: float | None) -> None:
        """Every rejected attempt; of the accepted ones (unless ``keep_steps``), the first in
        each grid interval per sub-model: the step history at the grid's resolution."""
        if accepted and not self.keep_steps and not self._new_interval(model, t):
            return
        self._store.add_attempt(model, t, h, accepted, error)

    def add_accepted_attempts(self, times: Sequence[float], steps: Sequence[float]) -> None:
        if self.keep_steps:
            self._store.add_accepted_attempts(times, steps)
            return
        kept = [(t, h) for t, h in zip(times, steps) if self._new_interval(None, t)]
        if kept:
            self._store.add_accepted_attempts(*zip(*kept))

    def _new_interval(self, model: str | None, t: float) -> bool:
        cell = math.floor((t - self.t0) / self.interval + 1e-9)
        if self._cells.get(model) == cell:
            return False
        self._cells[model] = cell
        return True

    def _write(self, t: float, y: np.ndarray) -> None:
        self._store.add_point(self._count, t, y)
        self.stored.append(t)
        self._count += 1

    def add_reference(self, values: np.ndarray, variable_ids: Sequence[int]) -> None:
        """``values`` at the points handed in; written at the points stored."""
        self._complete()
        seen = np.asarray(self._seen[:len(values)])
        at = np.asarray(self.stored)
        grid = np.column_stack([np.interp(at, seen, values[:, j])
                                for j in range(values.shape[1])]) if len(seen) else values
        self._store.add_reference(grid, variable_ids)

    def finish(self, *args: Any, **kwargs: Any) -> None:
        self._complete()
        self._store.finish(*args, **kwargs)

    def _complete(self) -> None:
        """The run's last point, where the grid does not reach it (written once)."""
        if self._last is not None and (not self.stored
                                       or self._last[0] > self.stored[-1] + 1e-9 * self.interval):
            self._write(*self._last)

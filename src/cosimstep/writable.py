"""Whether an output file can be written where the command line names it, asked before a run.

A results store that cannot be opened is otherwise found when the run starts writing, as an
SQLite or OS traceback, and a figure or a table that cannot be written only after the work that
made it. A path is checked for what is wrong *with the path*: a folder where a file is meant, a
file where a folder must be, a folder nothing can be written in (a read-only mount, ``/proc``),
or, for a store, an existing file that is not one (SQLite would refuse it, and the user's file
must not be touched). Missing folders are fine: the writers create them.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

from cosimstep.errors import Problem

SQLITE_HEADER = b"SQLite format 3\x00"


def output_problems(option: str, path: str | Path, *, store: bool = False,
                    folder: bool = False) -> list[Problem]:
    """What stops ``path`` (given as ``option``) from being written; empty when nothing does.

    ``store``: it is an SQLite results store (an existing file must be one); ``folder``: the
    path itself is a folder to write into (``export -o`` takes one)."""
    target = Path(path)
    if target.is_dir() and not folder:
        return [Problem(option, f"'{path}' is a folder", "give a file name (in it, if meant)")]
    if store and target.is_file() and not _is_sqlite(target):
        return [Problem(option, f"'{path}' exists and is not a results store (SQLite)",
                        "name a new file, or a store cosimstep wrote")]
    start = target if folder else target.parent
    existing = start
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if not existing.is_dir():
        return [Problem(option, f"'{existing}' is a file, not a folder",
                        "give a path through folders")]
    try:
        with tempfile.TemporaryFile(dir=existing):
            pass
    except OSError as exc:
        return [Problem(option, f"cannot create a file in '{existing}' "
                        f"({exc.strerror or exc})", "choose a folder you can write in")]
    return []


def _is_sqlite(path: Path) -> bool:
    """Whether ``path`` starts as an SQLite database does (an empty file will become one)."""
    try:
        with path.open("rb") as f:
            head = f.read(len(SQLITE_HEADER))
    except OSError:
        return False
    return head in (b"", SQLITE_HEADER)

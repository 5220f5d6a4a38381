"""Checks on zip archives (FMUs, SSPs) before anything is unpacked.

An archive is read from its central directory first: a member whose name points outside the
folder it is unpacked into is refused (zip slip), and so is an archive that would unpack into
more than :func:`unpack_limit` bytes, or a large member compressed beyond :data:`MAX_RATIO` — a
3 MB FMU holding 3 GiB of zeros took 15 s to unpack before a 0.01 s run, and a larger one fills
the disk. The sizes are those the archive declares; ``zipfile`` reads no more than the declared
size of a member, so a lying archive fails its CRC check instead of growing.

Unpacked folders carry their owner (host and process); a process killed before it could remove
its folders leaves them behind, and the next process that unpacks anything removes them.
"""

from __future__ import annotations

import os
import posixpath
import shutil
import socket
import tempfile
import zipfile
from collections.abc import Callable, Sequence
from pathlib import Path

DEFAULT_LIMIT = 2 * 1024**3
"""Bytes an archive may unpack into (2 GiB): far above any FMU's binaries and resources seen in
practice, far below a full disk. ``COSIMSTEP_UNPACK_LIMIT`` (bytes) overrides it."""
MAX_RATIO = 100.0
"""Uncompressed / compressed size beyond which a member larger than :data:`RATIO_FLOOR` is
refused: binaries compress 2–5×, text tables 5–20×; padding and zeros 1000×."""
RATIO_FLOOR = 16 * 1024**2
ENV = "COSIMSTEP_UNPACK_LIMIT"


OWNER_FILE = ".cosimstep-owner"
PREFIX = "cosimstep-"
_swept = False


def new_folder(label: str) -> Path:
    """A fresh temporary folder for an unpacked archive, marked with the owning process so that
    a later run can remove it if that process died without cleaning up (kill -9). The first
    call in a process sweeps such leftovers (:func:`sweep`)."""
    global _swept
    if not _swept:
        _swept = True
        sweep()
    return mark(Path(tempfile.mkdtemp(prefix=f"{PREFIX}{label}-")))


def mark(folder: Path) -> Path:
    """``folder`` (created if missing) marked with the owning process (:func:`new_folder`)."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / OWNER_FILE).write_text(f"{socket.gethostname()} {os.getpid()}\n")
    return folder


def sweep(root: str | Path | None = None) -> list[Path]:
    """Remove the unpacked folders of dead processes on this host; the removed folders."""
    removed = []
    host = socket.gethostname()
    for folder in Path(root or tempfile.gettempdir()).glob(f"{PREFIX}*"):
        try:
            owner_host, pid = (folder / OWNER_FILE).read_text().split()
        except (OSError, ValueError):
            continue  # not ours, or still being created
        if owner_host == host and not _alive(int(pid)):
            shutil.rmtree(folder, ignore_errors=True)
            removed.append(folder)
    return removed


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def unpack_limit() -> int:
    """The limit in force: ``COSIMSTEP_UNPACK_LIMIT`` if set to a positive integer, else
    :data:`DEFAULT_LIMIT`."""
    text = os.environ.get(ENV, "")
    return int(text) if text.isdigit() and int(text) > 0 else DEFAULT_LIMIT


def escapes(name: str) -> bool:
    """Whether a member name points outside the folder it is unpacked into."""
    if not name or "\\" in name or name.startswith("/") or (len(name) > 1 and name[1] == ":"):
        return True
    return ".." in posixpath.normpath(name).split("/")


def size_problems(infos: Sequence[zipfile.ZipInfo],
                  include: Callable[[str], bool] | None = None) -> list[str]:
    """Why the members (those ``include`` keeps) must not be unpacked: too much in all, or a
    member compressed beyond :data:`MAX_RATIO`. Empty when they may be."""
    chosen = [i for i in infos if include is None or include(i.filename)]
    problems = []
    limit = unpack_limit()
    total = sum(i.file_size for i in chosen)
    if total > limit:
        problems.append(f"would unpack into {_size(total)}, above the limit of {_size(limit)} "
                        f"(set {ENV} to a larger number of bytes if it really needs that)")
    for i in chosen:
        if i.file_size > RATIO_FLOOR and i.file_size > MAX_RATIO * max(i.compress_size, 1):
            problems.append(f"member '{i.filename}' unpacks {_size(i.file_size)} from "
                            f"{_size(i.compress_size)} (more than {MAX_RATIO:g}x: a zip bomb?)")
    return problems


def _size(n: int) -> str:
    for unit, scale in (("GiB", 1024**3), ("MiB", 1024**2), ("KiB", 1024)):
        if n >= scale:
            return f"{n / scale:.1f} {unit}"
    return f"{n} B"


__all__ = ["DEFAULT_LIMIT", "MAX_RATIO", "escapes", "new_folder", "size_problems", "sweep",
           "unpack_limit"]

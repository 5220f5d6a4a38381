"""Writing one generated section of docs/benchmarks.md, keeping the other sections."""

from __future__ import annotations

from pathlib import Path


def write_section(path: Path, section: str, begin: str, end: str) -> None:
    """Replace the text between ``begin`` and ``end`` (or append the section)."""
    text = path.read_text() if path.exists() else "# cosimstep benchmarks\n\nGenerated tables; "\
        "see each section's script.\n"
    if begin in text:
        head, rest = text.split(begin, 1)
        text = head + section + rest.split(end, 1)[1]
    else:
        text = text.rstrip() + "\n\n" + section + "\n"
    path.write_text(text)
    print(section)

"""What the small benchmark scripts share: the commit they ran on, a header line, and writing a table atomically."""

from __future__ import annotations

import os
import shlex
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def commit() -> str:
    """The checkout's short commit, ``+dirty`` when tracked files differ from it."""
    run = lambda *args: subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True).stdout.strip()  # noqa: E731
    head = run("rev-parse", "--short", "HEAD") or "unknown"
    return head + ("+dirty" if run("status", "--porcelain", "--untracked-files=no") else "")


def provenance(script: str, argv: list[str] | None) -> str:
    """An HTML comment naming the command, date, commit and machine load (times are under that load)."""
    args = shlex.join(argv if argv is not None else sys.argv[1:])
    return (f"<!-- python benchmarks/{script} {args} ({time.strftime('%Y-%m-%d')}, commit {commit()}, "
            f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f} at the end: times under that load) -->")


def write_table(path: Path | None, lines: list[str]) -> str:
    """Join ``lines``; when ``path`` is given write them there through a temporary file (never half-written)."""
    text = "\n".join(lines) + "\n"
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{path.name}.tmp")
        tmp.write_text(text)
        tmp.replace(path)
    return text


def grid_lines(by: dict, rows: list[str], filters: list[str], cell) -> list[str]:
    """One markdown line per filter, a cell per row: ``cell(c)`` for the measured cell ``by[(row, filter)]``,
    "fails: <error>" for a cell with an ``error``, "fails: not run" for a missing one."""
    lines = []
    for f in filters:
        out = []
        for r in rows:
            c = by.get((r, f))
            out.append("fails: " + (c or {}).get("error", "not run") if c is None or "error" in c else cell(c))
        lines.append(f"| {f} | " + " | ".join(out) + " |")
    return lines

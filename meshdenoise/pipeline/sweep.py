"""The results table of a run: one row per setting and input, written as CSV and JSON.

A ``sweep:`` block (``{mu: [0.5, 1, 2], iterations: [5, 10]}``) is expanded into the
grid of settings by :func:`meshdenoise.pipeline.schema.build_plan`; each setting is run
on every input and gives one row here.
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

from ..io import atomic_path

__all__ = ["write_results", "columns"]

_FIRST = ("input", "status")


def columns(rows: list[dict]) -> list[str]:
    """Column order: input, status, the sweep variables and measurements in first-seen order, error last."""
    cols: list[str] = list(_FIRST)
    for row in rows:
        for key in row:
            if key not in cols and key not in ("error", "traceback"):
                cols.append(key)
    if any("error" in r for r in rows):
        cols.append("error")
    return cols


def _json_value(v):
    if isinstance(v, float) and not math.isfinite(v):
        return str(v)  # JSON has no inf/nan; "inf" keeps the meaning
    if hasattr(v, "item"):
        return v.item()
    return v


def write_results(rows: list[dict], out_dir: Path, stem: str = "results") -> tuple[Path, Path]:
    """Write ``stem.csv`` and ``stem.json`` into ``out_dir`` atomically; returns both paths."""
    cols = columns(rows)
    csv_path = Path(out_dir) / f"{stem}.csv"
    json_path = Path(out_dir) / f"{stem}.json"
    with atomic_path(csv_path) as tmp:
        with open(tmp, "w", newline="", encoding="utf-8") as fh:
            writer = csv.DictWriter(fh, fieldnames=cols, extrasaction="ignore")
            writer.writeheader()
            for row in rows:
                writer.writerow({k: (";".join(v) if isinstance(v, list) else v) for k, v in row.items()})
    with atomic_path(json_path) as tmp:
        clean = [{k: _json_value(v) for k, v in row.items() if k != "traceback"} for row in rows]
        tmp.write_text(json.dumps(clean, indent=1) + "\n", encoding="utf-8")
    return csv_path, json_path

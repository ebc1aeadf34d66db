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

__all__ = ["write_results", "columns", "count_settings", "check_sweep_size", "MAX_SETTINGS", "MAX_TASKS"]

#: Most settings a ``sweep:`` may expand to, and most tasks (settings x inputs) of one run.
#: Counted before anything is expanded: a few bytes of YAML must not fill the memory.
MAX_SETTINGS = 10_000
MAX_TASKS = 100_000

_FIRST = ("input", "status")


def count_settings(sweep: dict) -> int:
    """Number of settings of a sweep (the product of the lengths of its value lists), without expanding it.

    >>> count_settings({"mu": [1, 2, 3], "iterations": [5, 10]}), count_settings({})
    (6, 1)
    """
    return math.prod(len(v) if isinstance(v, list) else 1 for v in sweep.values())


def check_sweep_size(sweep: dict, n_inputs: int, at: str) -> int:
    """The number of settings, or :class:`PipelineValidationError` above :data:`MAX_SETTINGS` / :data:`MAX_TASKS`."""
    from .errors import PipelineValidationError

    n = count_settings(sweep)
    sizes = " x ".join(f"{len(v) if isinstance(v, list) else 1} {k}" for k, v in sweep.items())
    if n > MAX_SETTINGS:
        raise PipelineValidationError(
            f"{at}: sweep: {sizes} = {n} settings, more than the limit {MAX_SETTINGS}; sweep fewer values"
        )
    if n * n_inputs > MAX_TASKS:
        raise PipelineValidationError(
            f"{at}: {n} setting(s) x {n_inputs} input(s) = {n * n_inputs} tasks, more than the limit {MAX_TASKS}; "
            "split the run"
        )
    return n


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

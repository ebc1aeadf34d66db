"""The whole reproduction: noisy copies, parameter searches, timings, results.json, table.md and figures."""

from __future__ import annotations

import time
from pathlib import Path

from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

from ..io import MeshFileError, load_arrays
from .batch import NoisyBatch, make_batch
from .paper import MESHES
from .strategies import available_methods, run_search
from .table import make_row, write_json, write_table
from .timing import TIME_CURVES, time_best, time_curve

__all__ = ["run_reproduction"]


def load_batches(data_dir: Path, mesh: str, seeds: tuple[int, ...]) -> list[NoisyBatch]:
    """The paper's noise levels of ``mesh``, read from ``data_dir``, one :class:`NoisyBatch` each."""
    if mesh not in MESHES:
        raise ValueError(f"reproduce: unknown mesh {mesh!r}; the paper's meshes are {', '.join(MESHES)}")
    filename, rhos = MESHES[mesh]
    path = Path(data_dir) / filename
    if not path.is_file():
        raise MeshFileError(f"{path}: not found; --data must be the folder holding the paper's {filename}")
    V, F = load_arrays(path)
    return [make_batch(mesh, V, F, rho, seeds) for rho in rhos]


def run_reproduction(
    data_dir: str | Path,
    out_dir: str | Path,
    seeds: int = 5,
    meshes: list[str] | None = None,
    methods: list[str] | None = None,
    quick: bool = False,
    console: Console | None = None,
) -> list[dict]:
    """Search every method's best parameter on the paper's meshes and noise levels, time it, write the outputs.

    Writes ``results.json``, ``table.md``, ``timing.json`` and the PNG figures to ``out_dir``
    and returns the rows of ``results.json``. ``quick``: a Sobolev grid of 3 values per decade
    instead of 6, timings with fewer repeats and no time-vs-parameter curves (a smoke run).

    Examples
    --------
    >>> run_reproduction("/no/such/folder", "/tmp/unused", meshes=["nefertiti"])  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    meshdenoise.io.MeshFileError: /no/such/folder/nefertiti.off: not found; --data must be the folder ...
    """
    if not (isinstance(seeds, int) and seeds >= 1):
        raise ValueError(f"reproduce: seeds must be a positive int, got {seeds!r}")
    started = time.perf_counter()
    out_dir = Path(out_dir)
    seed_list = tuple(range(seeds))
    meshes = list(meshes or MESHES)
    methods = list(methods or available_methods())
    console = console or Console(stderr=True)
    budget = 0.1 if quick else 0.5
    rows, results, noisy, curves = [], [], {}, {}
    with Progress(TextColumn("{task.description:<34}"), BarColumn(), TextColumn("{task.completed:.1f}/{task.total:.0f}"),
                  TimeElapsedColumn(), console=console, transient=False) as progress:
        total = sum(len(MESHES[m][1]) for m in meshes if m in MESHES) * len(methods)
        task = progress.add_task("loading", total=total)
        for mesh in meshes:
            progress.update(task, description=f"{mesh}: adding noise")
            batches = load_batches(data_dir, mesh, seed_list)
            for b in batches:
                noisy[(b.mesh, b.rho)] = (float(b.noisy_snr().mean()), float(b.noisy_snr().std(ddof=1)) if seeds > 1 else 0.0)
            for method in methods:
                progress.update(task, description=f"{mesh}: {method} search")
                found = run_search(method, batches, lambda f: progress.advance(task, f), quick)
                progress.update(task, description=f"{mesh}: {method} timing")
                for r, b in zip(found, batches):
                    rows.append(make_row(r, time_best(r, b, budget), b.noisy_snr(), seed_list))
                results += found
                if not quick and method in TIME_CURVES:
                    best = found[-1].best_params  # the largest noise level's best setting (heat keeps its tau)
                    curves.setdefault(mesh, {})[method] = time_curve(method, batches[-1], best)
        progress.update(task, description="writing figures")
        write_json(rows, out_dir / "results.json")
        write_json([{"mesh": m, "method": k, **v} for m, c in curves.items() for k, v in c.items()], out_dir / "timing.json")
        from .figures import write_figures  # matplotlib: imported when figures are drawn, not by every command

        write_figures(results, curves, out_dir)
        write_table(rows, noisy, out_dir / "table.md", time.perf_counter() - started, seeds)
        progress.update(task, description="done")
    return rows

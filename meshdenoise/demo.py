"""``make demo``: denoise a built-in mesh with the paper's three filters and print a table."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from .data import sample_mesh
from .io import load_arrays, save_arrays
from .metrics import snr
from .noise import add_normal_noise
from .registry import apply_filter
from .tuning import choose_parameters

DEMO_METHODS = ("filtering", "heat", "sobolev")
SHOWN = ("iterations", "tau", "time", "mu")  # the parameters that matter, in the table


def run_demo(out_dir: str | Path, mesh_path: str | Path | None = None, noise: float = 0.01, seed: int = 0) -> list[dict]:
    """Add normal noise (``noise`` x bounding-box diagonal) to a mesh, run each filter, write the results.

    Each filter's parameters are chosen from the noisy mesh alone (:func:`meshdenoise.choose_parameters`),
    as for a scan with no clean version to tune against; the clean mesh only scores the result.
    Returns one row per mesh written: method, parameters, SNR (dB), time (ms), file.
    """
    path = Path(mesh_path or sample_mesh("bunny.obj"))
    V, F = load_arrays(path)
    out = Path(out_dir)
    rho = noise * float(np.linalg.norm(V.max(axis=0) - V.min(axis=0)))
    Vn, _ = add_normal_noise((V, F), rho=rho, seed=seed)
    rows = [{"method": "noisy", "params": f"rho={rho:.4g}", "snr_db": snr(V, Vn), "ms": 0.0,
             "file": save_arrays(out / "noisy.ply", Vn, F)}]
    for name in DEMO_METHODS:
        params = choose_parameters((Vn, F), method=name)
        apply_filter(name, (Vn, F), **params)  # warm-up: operators and factorisation are cached per topology
        t0 = time.perf_counter()
        Y, _ = apply_filter(name, (Vn, F), **params)
        ms = (time.perf_counter() - t0) * 1e3
        rows.append({"method": name, "params": ", ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}"
                                                       for k, v in params.items() if k in SHOWN),
                     "snr_db": snr(V, Y), "ms": ms, "file": save_arrays(out / f"{name}.ply", Y, F)})
    return rows, path, V.shape[0]


def demo_table(rows: list[dict], path: Path, n_vertices: int, noise: float, seed: int, width: int = 80):
    """The demo's results as a rich ``Table``: title and caption never wrap inside a phrase.

    Parameters
    ----------
    rows : list of dict
        :func:`run_demo`'s rows.
    path : Path
        The mesh that was noised (its name goes in the title).
    n_vertices : int
        Its vertex count.
    noise, seed
        The noise amplitude (fraction of the bounding-box diagonal) and seed.
    width : int
        The console width: the table is made at least as wide as its title and caption, up to this.
    """
    from rich.table import Table
    from rich.text import Text

    title = f"{path.name}: {n_vertices:,} vertices"
    caption = f"noise {noise:g} x bbox diagonal, seed {seed}; parameters from the noisy mesh alone"
    table = Table(title=Text(title), caption=Text(caption), min_width=min(width, max(len(title), len(caption)) + 2))
    for col in ("method", "parameters", "SNR (dB)", "time (ms)", "written to"):
        table.add_column(col, justify="right" if col in ("SNR (dB)", "time (ms)") else "left")
    for r in rows:
        table.add_row(Text(r["method"]), Text(r["params"]), f"{r['snr_db']:.2f}", f"{r['ms']:.1f}" if r["ms"] else "-",
                      Text(r["file"].name))
    return table

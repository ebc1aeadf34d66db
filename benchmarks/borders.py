"""Open borders of a real range scan: how far border vertices move next to interior ones, free or along normals.

Usage::

    python benchmarks/borders.py [--out benchmarks/results/borders.md]

On pymeshlab's range scan ``rangemaps/face000.ply`` (85,849 vertices, 39 boundary loops), as
shipped and with ``add_scanner_noise`` (0.3 mean edge lengths, correlation length 1, seed 0),
each filter runs with a free boundary and with ``boundary_motion="normal"``; the table gives
the mean displacement of border and interior vertices (in mean edge lengths), their ratio
(issue 18's target: at most 2), and, for the noisy scan, the mean distance of border and
interior vertices from the scan as shipped (the "clean" reference of this test).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from tables import provenance, write_table  # noqa: E402

RUNS = (("sobolev", {"mu": 2.0}), ("sobolev_bilaplacian", {"mu": 3.0}), ("taubin", {"iterations": 20}),
        ("two_stage", {}), ("default", {}))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=None, help="also write the table (markdown) here")
    a = ap.parse_args(argv)
    import warnings

    import meshdenoise as md
    from meshdenoise.data import sample_mesh
    from meshdenoise.io import load_arrays
    from meshdenoise.operators import get_operators
    from meshdenoise.tuning.noise_level import mean_edge_length

    V, F = load_arrays(sample_mesh("rangemaps/face000.ply"))
    ops = get_operators(F, V.shape[0])
    h = mean_edge_length(V, ops)
    b = ops.boundary_vertices
    inner = ~b & ~ops.isolated
    noisy = md.add_scanner_noise((V, F), 0.3 * h, correlation_length=1.0, seed=0)[0]
    rows = ["| scan | filter | boundary | border move | interior move | ratio | border error | interior error | s |",
            "|---|---|---|---|---|---|---|---|---|"]
    for label, X in (("as shipped", V), ("+ scanner noise", noisy)):
        for name, params in RUNS:
            for motion in ("free", "normal"):
                t = time.perf_counter()
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", UserWarning)
                    if name == "default":
                        Y = md.denoise((X, F), boundary_motion=motion)[0]
                    else:
                        Y = md.apply_filter(name, (X, F), boundary_motion=motion, **params)[0]
                dt = time.perf_counter() - t
                move = np.linalg.norm(Y - X, axis=1) / h
                err = np.linalg.norm(Y - V, axis=1) / h
                ratio = move[b].mean() / move[inner].mean() if move[inner].mean() > 0 else float("nan")
                errors = f"{err[b].mean():.3f} | {err[inner].mean():.3f}" if X is noisy else "| "
                setting = ", ".join(f"{k}={v}" for k, v in params.items()) or "auto"
                rows.append(f"| {label} | {name} ({setting}) | {motion} | {move[b].mean():.3f} | {move[inner].mean():.3f} "
                            f"| {ratio:.2f} | {errors} | {dt:.1f} |")
                print(rows[-1], flush=True)
    head = [provenance("borders.py", argv), "",
            "# Open borders of a range scan (face000.ply, 85,849 vertices, 4,111 border vertices)", "",
            "Moves and errors in mean edge lengths (mean over border / interior vertices); ratio = border move / "
            "interior move (target: at most 2). Errors are distances from the scan as shipped.", ""]
    write_table(a.out, head + rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())

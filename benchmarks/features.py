"""Feature preservation on the Guided-Mesh-Normal-Filtering benchmark: mean face-normal error in degrees.

Prints, for Fandisk0.3 and Block0.4: the noisy input; ``two_stage`` with its defaults and with
the best of a small (sigma_r, iterations) grid (oracle); the bilateral variant; and MeshLab's
Laplacian, HC Laplacian, Taubin and two-step smoothing and Open3D's simple, Laplacian and
Taubin filters, each with its number of iterations chosen against the clean mesh (oracle),
run through pymeshlab and Open3D themselves: the quality benchmark's filters and oracle
search (``quality.LIBRARY``, ``quality.library_oracle``, the tuning floor's walk scored by
the normal error); MeshLab's Laplacian with its default cotangent weights.

Run:  PYTHONPATH=. python benchmarks/features.py
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from quality import LIBRARY, library_oracle, meshlab_steps  # noqa: E402

from meshdenoise.data import data_dir  # noqa: E402
from meshdenoise.io import load_arrays  # noqa: E402
from meshdenoise.metrics import normal_error_deg  # noqa: E402
from meshdenoise.plugins.two_stage import two_stage  # noqa: E402

MESHES = ("Fandisk0.3", "Block0.4")
# the quality benchmark's library filters, MeshLab's Laplacian with its default cotangent weights (as measured here before)
FILTERS = {**LIBRARY, "MeshLab Laplacian": meshlab_steps({"stepsmoothnum": 1}, "apply_coord_laplacian_smoothing")}


def main() -> None:
    root = data_dir() / "benchmark"
    for name in MESHES:
        Vn, F = load_arrays(root / name / "Noisy.obj")
        V0, _ = load_arrays(root / name / "Original.obj")
        err = lambda X: normal_error_deg((V0, F), X)  # noqa: E731
        rows = [("noisy input", err(Vn), "")]
        t = time.perf_counter()
        ours = err(two_stage((Vn, F))[0])
        rows.append(("two_stage defaults (guided)", ours, f"{time.perf_counter() - t:.1f} s"))
        rows.append(("two_stage bilateral defaults", err(two_stage((Vn, F), guidance="bilateral")[0]), ""))
        grid = [(sr, it) for sr in (0.25, 0.3, 0.35, 0.45) for it in (2, 3, 5)]
        e, (sr, it) = min((err(two_stage((Vn, F), sigma_r=sr, iterations=it)[0]), (sr, it)) for sr, it in grid)
        rows.append(("two_stage oracle", e, f"sigma_r={sr}, iterations={it}"))
        best_other = np.inf
        for label, run in FILTERS.items():
            k, X = library_oracle(run, V0, Vn, F, ("normal",))["normal"]
            best_other = min(best_other, err(X))
            rows.append((label + " (oracle)", err(X), f"{k} iterations"))
        print(f"\n{name}: mean face-normal angular error (degrees)")
        for label, value, note in rows:
            print(f"  {label:34s} {value:7.2f}   {note}")
        print(f"  ours (defaults) / best MeshLab-Open3D = {ours / best_other:.2f}")
        sys.stdout.flush()


if __name__ == "__main__":
    main()

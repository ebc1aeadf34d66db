"""Feature preservation on the Guided-Mesh-Normal-Filtering benchmark: mean face-normal error in degrees.

Prints, for Fandisk0.3 and Block0.4: the noisy input; ``two_stage`` with its defaults and with
the best of a small (sigma_r, iterations) grid (oracle); the bilateral variant; and MeshLab's
Laplacian, HC Laplacian, Taubin and two-step smoothing and Open3D's simple, Laplacian and
Taubin filters, each with its number of iterations chosen against the clean mesh (oracle),
run through pymeshlab and Open3D themselves.

Run:  PYTHONPATH=. python benchmarks/features.py
"""

from __future__ import annotations

import sys
import time

import numpy as np

from meshdenoise.data import data_dir
from meshdenoise.io import load_arrays
from meshdenoise.plugins.two_stage import two_stage
from meshdenoise.quality_metrics import normal_error_deg

MESHES = ("Fandisk0.3", "Block0.4")


def oracle_chain(step, X0, max_steps, error):
    """Best error over 1..max_steps applications of a one-iteration filter ``step`` (filters compose)."""
    best, state = (np.inf, 0), X0
    for k in range(1, max_steps + 1):
        state = step(state)
        best = min(best, (error(state), k))
    return best


def meshlab_step(name, F, **kw):
    import pymeshlab

    def step(X):
        ms = pymeshlab.MeshSet()
        ms.add_mesh(pymeshlab.Mesh(vertex_matrix=X, face_matrix=F.astype(np.int32)))
        getattr(ms, name)(**kw)
        return ms.current_mesh().vertex_matrix().copy()

    return step


def open3d_step(name, F, **kw):
    import open3d as o3d

    def step(X):
        m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(X), o3d.utility.Vector3iVector(F.astype(np.int32)))
        return np.asarray(getattr(m, name)(1, **kw).vertices).copy()

    return step


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
        others = {
            "MeshLab Laplacian": (meshlab_step("apply_coord_laplacian_smoothing", F, stepsmoothnum=1), 10),
            "MeshLab HC Laplacian": (meshlab_step("apply_coord_hc_laplacian_smoothing", F), 10),
            "MeshLab Taubin": (meshlab_step("apply_coord_taubin_smoothing", F, stepsmoothnum=1), 60),
            "MeshLab two-step": (meshlab_step("apply_coord_two_steps_smoothing", F, stepsmoothnum=1), 20),
            "Open3D simple": (open3d_step("filter_smooth_simple", F), 10),
            "Open3D Laplacian": (open3d_step("filter_smooth_laplacian", F), 15),
            "Open3D Taubin": (open3d_step("filter_smooth_taubin", F), 60),
        }
        best_other = np.inf
        for label, (step, max_steps) in others.items():
            e, k = oracle_chain(step, Vn, max_steps, err)
            best_other = min(best_other, e)
            rows.append((label + " (oracle)", e, f"{k} iterations"))
        print(f"\n{name}: mean face-normal angular error (degrees)")
        for label, value, note in rows:
            print(f"  {label:34s} {value:7.2f}   {note}")
        print(f"  ours (defaults) / best MeshLab-Open3D = {ours / best_other:.2f}")
        sys.stdout.flush()


if __name__ == "__main__":
    main()

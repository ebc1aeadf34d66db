"""Why estimate_noise over-reads weak noise on a coarse curved mesh: the clean mesh's own residual.

For each mesh: the normalised normal residual of ``(I - P)^k X`` (k = 1..4) of the *clean*
mesh with its own normals (rms and MAD, in edge lengths), the graph-Fourier energy of the
clean coordinates in the top half of the exact spectrum (in units of rho^2) and the
spectral estimate it leads to, and estimate_noise / rho over seeds, next to the quadrature
prediction ``sqrt(rho^2 + s^2) / rho`` from the clean MAD ``s`` at k = 2.

    PYTHONPATH=. python benchmarks/noise_floor.py --seeds 5
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import scipy.sparse as sp

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from meshdenoise import add_normal_noise  # noqa: E402
from meshdenoise.tuning.noise_level import MAD as _MAD, estimate_noise, mean_edge_length as _mean_edge_length  # noqa: E402
from meshdenoise.data import data_file  # noqa: E402
from meshdenoise.geometry import vertex_normals  # noqa: E402
from meshdenoise.io import load_arrays  # noqa: E402
from meshdenoise.operators import get_operators  # noqa: E402
from meshdenoise.shapes import icosphere, torus  # noqa: E402


def clean_levels(V, F, ops, K=4):
    """(rms, MAD) of t_i = <(B_k X)_i, N_i> / c_i for B_k = (I - P)^k, k = 1..K (clean normals N)."""
    n, N = ops.n, vertex_normals(V, F)
    A = sp.identity(n, format="csr") - ops.P
    B, out = sp.identity(n, format="csr"), []
    for _ in range(K):
        B = sp.csr_matrix(B @ A)
        Bc = B.tocoo()
        g = np.einsum("ij,ij->i", N[Bc.row], N[Bc.col])
        c = np.sqrt(np.bincount(Bc.row, weights=(Bc.data * g) ** 2, minlength=n))
        t = np.einsum("ij,ij->i", np.asarray(B @ V), N) / c
        out.append((float(np.sqrt(np.mean(t**2))), float(np.median(np.abs(t)) / _MAD)))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5)
    args = ap.parse_args()
    cases = [
        ("nefertiti", load_arrays(data_file("nefertiti.off")), (0.0075, 0.015)),
        ("torus(24, 12)", torus(24, 12), (0.01,)),
        ("icosphere(3)", icosphere(3), (0.01,)),
    ]
    for name, (V, F), rhos in cases:
        ops = get_operators(F, len(V))
        h = _mean_edge_length(V, ops)
        lv = clean_levels(V, F, ops)
        print(f"{name} ({len(V)} vertices, edge {h:.4g}): clean rms/MAD per order k=1..4 in edge lengths: "
              + ", ".join(f"{r / h:.4f}/{m / h:.4f}" for r, m in lv))
        k, U = np.linalg.eigh(ops.L.toarray())
        e0 = np.sum((U.T @ V) ** 2, axis=1)[len(V) // 2:]
        for rho in rhos:
            est, spec = [], []
            for s in range(args.seeds):
                Vn, _ = add_normal_noise((V, F), rho, seed=s)
                est.append(estimate_noise((Vn, F)) / rho)
                spec.append(float(np.sqrt(np.mean(np.sum((U.T @ Vn) ** 2, axis=1)[len(V) // 2:]))) / rho)
            pred = np.sqrt(rho**2 + lv[1][1] ** 2) / rho
            print(f"  rho {rho:g}: estimate_noise/rho {min(est):.3f}-{max(est):.3f} (mean {np.mean(est):.3f}), "
                  f"quadrature prediction {pred:.3f}; clean top-half spectral energy {e0.mean() / rho**2:.2f} rho^2 "
                  f"per mode, spectral estimate/rho {min(spec):.2f}-{max(spec):.2f}")


if __name__ == "__main__":
    main()

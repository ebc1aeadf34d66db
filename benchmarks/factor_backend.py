"""Sparse Cholesky back ends on the systems the filters factorise: cholespy against CHOLMOD (scikit-sparse) with
METIS's ordering and with CHOLMOD's default (AMD, METIS tried when AMD's fill is large), the choice behind
``SolverConfig.cholmod_max_rows`` and ``SolverConfig.cholmod_metis_max_rows`` (``meshdenoise/solvers/config.py``).

For each mesh: the one-ring matrix ``L + 0.3 I`` and the two-ring ``L^2 + 0.5 L + 0.3 I`` (the shapes of the
factors of ``I + mu L^p``), ``L = D - W``. Per back end: the symbolic analysis, the numeric factor and a solve of
three right-hand sides (wall seconds, one run each, after a warm-up solve), and each time's ratio to cholespy's.
Meshes: benchmark rows (``benchmarks/peers.py``), optionally midpoint-subdivided once (``ROW*2``, about four times
the vertices), and the scale benchmark's elephant at 400k (``400k``, ``benchmarks/scale.py``'s cache).

Run:  PYTHONPATH=. python benchmarks/factor_backend.py [--meshes "face000 scanner" "elephant rho=0.2*2" 400k]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

MESHES = ("face000 scanner", "elephant rho=0.2*2", "Bunny0.2*2", "400k")


def faces_of(name: str) -> tuple[np.ndarray, int]:
    """``(F, n)`` of a mesh name (see the module's docstring)."""
    if name == "400k":
        import scale

        mesh = scale.prepare("400k", scale.cache_dir(None))
        with np.load(mesh["npz"]) as z:
            return z["F"], len(z["V"])
    import peers

    row, twice = (name[:-2], True) if name.endswith("*2") else (name, False)
    m = peers.MESHES[row]()
    F, n = m["F"], len(m["Vn"])
    if twice:
        import open3d as o3d

        mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(m["Vn"]),
                                         o3d.utility.Vector3iVector(F.astype(np.int32))).subdivide_midpoint(1)
        F, n = np.asarray(mesh.triangles).astype(np.int64), len(mesh.vertices)
    return F, n


def time_backends(A: sp.csr_matrix, B: np.ndarray) -> dict[str, tuple[float, float, float]]:
    """``{back end: (analysis s, factor s, 3-column solve s)}`` for the SPD ``A`` (sorted CSR)."""
    from cholespy import CholeskySolverD, MatrixType
    from sksparse.cholmod import analyze

    out = {}
    t = time.perf_counter()
    s = CholeskySolverD(A.shape[0], A.indptr.astype(np.int32), A.indices.astype(np.int32), A.data, MatrixType.CSR)
    factor = time.perf_counter() - t
    X = np.empty_like(B)
    s.solve(B, X)
    t = time.perf_counter()
    s.solve(B, X)
    out["cholespy"] = (0.0, factor, time.perf_counter() - t)
    del s
    C = A.tocsc()
    Bf = np.asfortranarray(B)
    for order in ("metis", "default"):
        t = time.perf_counter()
        symbolic = analyze(C, mode="simplicial", ordering_method=order)
        analysis = time.perf_counter() - t
        t = time.perf_counter()
        f = symbolic.cholesky(C)
        factor = time.perf_counter() - t
        f(Bf)
        t = time.perf_counter()
        f(Bf)
        out[f"CHOLMOD {order}"] = (analysis, factor, time.perf_counter() - t)
        del f, symbolic
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--meshes", nargs="*", default=list(MESHES))
    args = ap.parse_args(argv)
    from meshdenoise.operators import Operators

    print("| mesh (rows) | matrix | back end | analysis s | factor s | analysis + factor s (/ cholespy) | 3-column solve s "
          "(/ cholespy) |")
    print("|---|---|---|---|---|---|---|")
    for name in args.meshes:
        F, n = faces_of(name)
        L = Operators(F, n).L.tocsr()
        identity = sp.identity(n, format="csr")
        B = np.random.default_rng(0).random((n, 3))
        for label, A in (("one-ring", L + 0.3 * identity), ("two-ring", L @ L + 0.5 * L + 0.3 * identity)):
            A = sp.csr_matrix(A)
            A.sort_indices()
            times = time_backends(A, B)
            base = times["cholespy"]
            for backend, (analysis, factor, solve) in times.items():
                print(f"| {name} ({n:,}) | {label} | {backend} | {analysis:.3f} | {factor:.3f} | "
                      f"{analysis + factor:.3f} ({(analysis + factor) / base[1]:.2f}) | {solve:.4f} "
                      f"({solve / base[2]:.2f}) |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

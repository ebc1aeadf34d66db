"""Sobolev (I + mu L) Y = X by block CG against the Cholesky factorisation, on one benchmark mesh.

Times, wall and CPU (median of ``--repeats``): ``sobolev(solver="cg")`` from scratch
(operators already built, as in ``speed.py``); a warm-started CG re-solve of slightly moved
coordinates (the iterative analogue of a re-solve with a cached factor); the Cholesky
factorisation plus solve (once: it takes tens of seconds at 1.6M). Then the SNR of both
results on the noisy mesh and their maximum relative difference.

Usage::

    python benchmarks/sobolev_cg.py --size 1.6M
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from speed import SIZES, benchmark_mesh, cache_dir, timed  # noqa: E402

from meshdenoise.metrics import snr  # noqa: E402
from meshdenoise.noise import add_normal_noise  # noqa: E402
from meshdenoise.operators import Operators  # noqa: E402
from meshdenoise.plugins.sobolev import SobolevSolver, cg_iteration_cap, sobolev  # noqa: E402
from meshdenoise.solvers import shifted_solver  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", default="1.6M", choices=list(SIZES))
    ap.add_argument("--mu", type=float, default=1.0)
    ap.add_argument("--tol", type=float, default=1e-8)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--cache-dir", default=None)
    args = ap.parse_args(argv)
    V, F = benchmark_mesh(args.size, cache_dir(args.cache_dir))
    n = len(V)
    Vn, _ = add_normal_noise((V, F), rho=0.2, seed=0)
    ops = Operators(F, n)
    ops.L
    mu, tol = args.mu, args.tol
    print(f"{args.size}: n = {n:,}, mu = {mu:g}, tol = {tol:g}, max degree {ops.degree.max():.0f}, "
          f"iteration cap {cg_iteration_cap(ops, mu, tol)}")

    def line(name, t):
        print(f"  {name:58s} {t['wall']:8.3f} s wall {t['cpu']:8.3f} s cpu")

    t = timed(lambda: sobolev((Vn, F), mu=mu, solver="cg", tol=tol, operators=ops), args.repeats)
    line("CG: sobolev(solver='cg') call, median (1st builds I + mu L)", t)
    Y_cg = sobolev((Vn, F), mu=mu, solver="cg", tol=tol, operators=ops)[0]
    cg = shifted_solver(ops, mu, 1, None, "cg")
    print(f"  CG iterations from x0 = X: {cg.iterations}, relative residuals {np.array2string(cg.relres, precision=2)}")
    line("CG: one solve, system cached", timed(lambda: cg.solve(Vn, tol=tol, x0=Vn), args.repeats))
    moved = Vn + 1e-3 * np.random.default_rng(1).normal(size=Vn.shape)  # coordinates close to the last ones
    line("CG: warm-started re-solve of moved X (x0 = last Y)", timed(lambda: cg.solve(moved, tol=tol, x0=Y_cg), args.repeats))
    print(f"  CG warm re-solve iterations: {cg.iterations}")

    w0, c0 = time.perf_counter(), time.process_time()
    chol = SobolevSolver(ops, mu)
    Y_chol = chol.solve(Vn)
    print(f"  {'Cholesky: factorisation + solve (once)':58s} {time.perf_counter() - w0:8.3f} s wall "
          f"{time.process_time() - c0:8.3f} s cpu")
    line("Cholesky: re-solve, cached factor", timed(lambda: chol.solve(moved), args.repeats))
    rel = np.abs(Y_cg - Y_chol).max() / np.abs(Y_chol).max()
    fro = np.linalg.norm(Y_cg - Y_chol) / np.linalg.norm(Y_chol)
    print(f"  SNR noisy {snr(V, Vn):.4f} dB, Cholesky {snr(V, Y_chol):.6f} dB, CG {snr(V, Y_cg):.6f} dB")
    print(f"  CG vs Cholesky: max |diff| / max |Y| = {rel:.3g}, Frobenius relative {fro:.3g}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

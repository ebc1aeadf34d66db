"""Speed and memory of meshdenoise at 25k to 6M vertices, against MeshLab and Open3D in the same process.

Meshes: the elephant (24,955 vertices) Loop-subdivided 0, 2, 3 and 4 times (25k, 399k,
1.6M, 6.4M vertices), made at run time by a vectorised Loop subdivision and cached as
``.npz`` under ``~/.cache/meshdenoise`` (``--cache-dir``), outside the repository.

Timings run in this one process, the median of ``--repeats`` runs (MeshLab and Open3D:
at most 3 runs, 1 above 2M vertices, as one of their steps takes seconds). Each timing
reports wall-clock and CPU seconds: on a shared machine the CPU time is the steadier of
the two (it leaves out time the process waited for a core; for threaded work it adds the
threads' times). Peak memory is measured in a fresh subprocess per measurement (spawned,
so it inherits nothing): the mesh is loaded, then the measured call runs, and we report
the growth of the resident-set high-water mark (``ru_maxrss``) and tracemalloc's peak of
numpy/Python allocations, per vertex.

Usage::

    python benchmarks/speed.py --sizes 25k,400k,1.6M --out speed.json
    python benchmarks/speed.py              # all four sizes (about 15 minutes on 2 cores)
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing as mp
import os
import platform
import resource
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np
import scipy.sparse as sp

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from meshdenoise.data import data_file  # noqa: E402
from meshdenoise.io import load_arrays  # noqa: E402
from meshdenoise.operators import Operators, spmm  # noqa: E402

SIZES = {"25k": 0, "400k": 2, "1.6M": 3, "6M": 4}  # label -> Loop subdivision levels
HEAT_TIME, HEAT_TAU = 40.0, 0.5


# --- meshes -------------------------------------------------------------------------------
def loop_subdivide(V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One step of Loop subdivision (Loop 1987; Warren's weights), vectorised.

    Every edge gets a new vertex: ``3/8 (a + b) + 1/8 (c + d)`` inside, the midpoint on a
    boundary or non-manifold edge. An old vertex of valence k moves to
    ``(1 - k beta) v + beta sum(neighbours)``, ``beta = (5/8 - (3/8 + cos(2 pi / k) / 4)^2) / k``;
    on the boundary to ``3/4 v + 1/8 (two boundary neighbours)``. Each face becomes four.
    Returns ``(V', F')`` with ``n + e`` vertices and ``4 m`` faces.
    """
    n, m = len(V), len(F)
    a, b, c = F.T.reshape(3, m)
    a, b, c = np.concatenate([a, b, c]), np.concatenate([b, c, a]), np.concatenate([c, a, b])
    keys, side_edge, counts = np.unique(np.minimum(a, b) * n + np.maximum(a, b), return_inverse=True, return_counts=True)
    e0, e1 = keys // n, keys % n
    E = len(keys)
    inner = counts == 2
    opposite = np.where(inner[side_edge], 1.0 / 8.0, 0.0)
    odd = np.where(inner, 3.0 / 8.0, 0.5)[:, None] * (V[e0] + V[e1])
    for k in range(3):
        odd[:, k] += np.bincount(side_edge, weights=opposite * V[c, k], minlength=E)
    W = sp.csr_matrix((np.ones(2 * E), (np.concatenate([e0, e1]), np.concatenate([e1, e0]))), shape=(n, n))
    k_ = np.maximum(np.diff(W.indptr), 1).astype(np.float64)
    beta = (5.0 / 8.0 - (3.0 / 8.0 + np.cos(2.0 * np.pi / k_) / 4.0) ** 2) / k_
    even = (1.0 - k_ * beta)[:, None] * V + beta[:, None] * (W @ V)
    if (~inner).any():
        bnd = ~inner
        Wb = sp.csr_matrix(
            (np.ones(2 * bnd.sum()), (np.concatenate([e0[bnd], e1[bnd]]), np.concatenate([e1[bnd], e0[bnd]]))),
            shape=(n, n),
        )
        on_b = np.diff(Wb.indptr) > 0
        even[on_b] = 0.75 * V[on_b] + 0.125 * (Wb @ V)[on_b]
    ea, eb, ec = (side_edge[i * m : (i + 1) * m] + n for i in range(3))  # new vertices on sides 01, 12, 20
    F2 = np.concatenate(
        [np.stack([F[:, 0], ea, ec], 1), np.stack([F[:, 1], eb, ea], 1), np.stack([F[:, 2], ec, eb], 1), np.stack([ea, eb, ec], 1)]
    )
    return np.vstack([even, odd]), F2


def cache_dir(arg: str | None = None) -> Path:
    return Path(arg or os.environ.get("MESHDENOISE_CACHE") or Path.home() / ".cache" / "meshdenoise")


def benchmark_mesh(label: str, folder: Path) -> tuple[np.ndarray, np.ndarray]:
    """The elephant subdivided for ``label``, from the cache or made and cached (temp file, then rename)."""
    levels = SIZES[label]
    path = folder / f"elephant-loop{levels}.npz"
    if path.is_file():
        with np.load(path) as z:
            return z["V"], z["F"]
    V, F = load_arrays(data_file("elephant-50kv.off"))
    for _ in range(levels):
        V, F = loop_subdivide(V, F)
    folder.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + f".tmp{os.getpid()}.npz")
    np.savez(tmp, V=V, F=F)
    os.replace(tmp, path)
    return V, F


# --- timing -------------------------------------------------------------------------------
def timed(fn, repeats: int) -> dict:
    """Median wall and CPU seconds of ``fn()`` over ``repeats`` runs."""
    wall, cpu = [], []
    for _ in range(repeats):
        w0, c0 = time.perf_counter(), time.process_time()
        fn()
        wall.append(time.perf_counter() - w0)
        cpu.append(time.process_time() - c0)
    return {"wall": float(np.median(wall)), "cpu": float(np.median(cpu)), "min_wall": float(min(wall))}


def stream_bound(nbytes_read: int, nbytes_written: int, repeats: int) -> dict:
    """A numpy stream reading and writing as many bytes as the sparse product must (one thread)."""
    src = np.ones(max(1, nbytes_read // 8))
    dst = np.empty(max(1, nbytes_written // 8))
    return timed(lambda: (src.sum(), dst.fill(1.0)), max(repeats, 5))


def fit_exponent(ns: list[int], ts: list[float]) -> float | None:
    """Slope of log(time) against log(n) by least squares (None with fewer than two sizes)."""
    if len(ns) < 2:
        return None
    return float(np.polyfit(np.log(ns), np.log(ts), 1)[0])


# --- peak memory, one fresh process per measurement -----------------------------------------
def _memory_child(path: str, what: str, queue) -> None:
    from meshdenoise.plugins.filtering import filtering
    from meshdenoise.plugins.heat import heat

    with np.load(path) as z:
        V, F = z["V"], z["F"]
    base = _reset_peak_rss()
    tracemalloc.start()
    if what == "filtering":
        filtering((V, F), iterations=1)  # operators built inside, as a user's first call
    elif what == "heat_euler":
        heat((V, F), time=HEAT_TIME, tau=HEAT_TAU)
    elif what == "heat_chebyshev":
        heat((V, F), time=HEAT_TIME, method="chebyshev")
    elif what == "sobolev":
        from meshdenoise.plugins.sobolev import sobolev

        sobolev((V, F), mu=1.0)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    queue.put({"maxrss_delta": _peak_rss() - base, "tracemalloc_peak": peak})


def _proc_status(field: str) -> int | None:
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith(field + ":"):
                return int(line.split()[1]) * 1024
    except OSError:
        pass
    return None


def _reset_peak_rss() -> int:
    """Reset the kernel's RSS high-water mark to the current RSS (Linux) and return that RSS.

    ``ru_maxrss`` is no good here: Linux carries it across fork and exec, so a child of a
    process holding a 6M-vertex mesh starts with that process's peak. ``VmHWM`` belongs to
    the child's own address space, and writing 5 to ``clear_refs`` resets it.
    """
    try:
        Path("/proc/self/clear_refs").write_text("5")
    except OSError:
        pass
    rss = _proc_status("VmRSS")
    return rss if rss is not None else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def _peak_rss() -> int:
    hwm = _proc_status("VmHWM")
    return hwm if hwm is not None else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def peak_memory(path: Path, what: str) -> dict:
    ctx = mp.get_context("spawn")
    queue = ctx.Queue()
    proc = ctx.Process(target=_memory_child, args=(str(path), what, queue))
    proc.start()
    result = queue.get()
    proc.join()
    return result


# --- one size -----------------------------------------------------------------------------
def run_size(label: str, folder: Path, repeats: int, external: bool, memory: bool) -> dict:
    from meshdenoise.plugins.filtering import filtering
    from meshdenoise.plugins.heat import heat
    from meshdenoise.plugins.sobolev import SobolevSolver

    V, F = benchmark_mesh(label, folder)
    n = len(V)
    r = {"label": label, "n": n, "faces": len(F)}
    X = np.ascontiguousarray(V)

    r["build"] = timed(lambda: Operators(F, n).P, repeats)
    ops = Operators(F, n)
    P = ops.P
    out = np.zeros_like(X)
    r["spmm_input_order"] = timed(lambda: spmm(P, X, out), max(repeats, 5))
    r["spmm_scipy"] = timed(lambda: P @ X, max(repeats, 5))

    def relabel():
        fresh = Operators(F, n)
        fresh.P
        fresh.permuted(fresh.P, "uniform-True")

    r["locality_order"] = timed(relabel, repeats)  # minus the build time: see the table
    r["locality_order"] = {k: max(0.0, v - r["build"][k]) for k, v in r["locality_order"].items()}
    Pp = ops.permuted(P, "uniform-True")  # what filtering and heat iterate on for n >= 65536
    Xp = np.ascontiguousarray(X[ops.locality_order])
    r["spmm_1thread"] = timed(lambda: spmm(Pp, Xp, out, threads=1), max(repeats, 5))
    r["spmm"] = timed(lambda: spmm(Pp, Xp, out), max(repeats, 5))
    read = P.indptr.nbytes + P.indices.nbytes + P.data.nbytes + X.nbytes
    r["bytes"] = read + out.nbytes
    r["bandwidth_bound"] = stream_bound(read, out.nbytes, repeats)
    r["filtering_call"] = timed(lambda: filtering((V, F), iterations=1, operators=ops), repeats)
    for w in ("meshlab", "open3d", "inverse_distance"):
        r[f"filtering_{w}"] = timed(lambda w=w: filtering((V, F), iterations=1, weights=w, operators=ops), repeats)

    def textbook_euler():  # the loop heat ran before: X + tau (P X - X), 80 times, temporaries each step
        Y = X.copy()
        for _ in range(int(HEAT_TIME / HEAT_TAU)):
            Y = Y + HEAT_TAU * (P @ Y - Y)

    r["heat_euler_textbook"] = timed(textbook_euler, repeats)
    r["heat_euler"] = timed(lambda: heat((V, F), time=HEAT_TIME, tau=HEAT_TAU, operators=ops), repeats)
    r["heat_chebyshev"] = timed(lambda: heat((V, F), time=HEAT_TIME, method="chebyshev", operators=ops), repeats)
    if label == "25k":  # the accuracy target: SNR of both methods on the noisy elephant
        from meshdenoise.metrics import snr
        from meshdenoise.noise import add_normal_noise

        Vn, _ = add_normal_noise((V, F), rho=0.2, seed=0)
        r["snr_db"] = {
            "noisy": snr(V, Vn),
            "euler": snr(V, heat((Vn, F), time=HEAT_TIME, tau=HEAT_TAU)[0]),
            "chebyshev": snr(V, heat((Vn, F), time=HEAT_TIME, method="chebyshev")[0]),
        }
    if n < 500_000:  # scipy's expm_multiply (truncated Taylor with scaling), the off-the-shelf alternative
        from scipy.sparse.linalg import expm_multiply

        A = sp.csr_matrix(sp.identity(n) - P) * -HEAT_TIME
        r["heat_expm_multiply"] = timed(lambda: expm_multiply(A, X), 1)

    ops.L
    solver = []
    r["sobolev_factor"] = timed(lambda: solver.append(SobolevSolver(ops, 1.0)), repeats)
    r["sobolev_solve"] = timed(lambda: solver[-1].solve(X), repeats)
    r["sobolev_resolve"] = timed(lambda: solver[-1].solve(X + 1e-3), repeats)
    Y_chol = solver[-1].solve(X)
    del solver
    from meshdenoise.plugins.sobolev import sobolev

    r["sobolev_cg"] = timed(lambda: sobolev((V, F), mu=1.0, solver="cg", tol=1e-8, operators=ops), repeats)
    Y_cg = sobolev((V, F), mu=1.0, solver="cg", tol=1e-8, operators=ops)[0]
    r["sobolev_cg_maxrel"] = float(np.abs(Y_cg - Y_chol).max() / np.abs(Y_chol).max())
    del Y_chol, Y_cg

    if external:
        ext_repeats = min(repeats, 3) if n < 2_000_000 else 1
        import open3d as o3d
        import pymeshlab

        ms = pymeshlab.MeshSet()
        ms.add_mesh(pymeshlab.Mesh(V, F))
        ms.apply_coord_laplacian_smoothing(stepsmoothnum=1)  # first call: MeshLab builds its adjacency
        r["meshlab_laplacian"] = timed(lambda: ms.apply_coord_laplacian_smoothing(stepsmoothnum=1), ext_repeats)
        del ms
        m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(V), o3d.utility.Vector3iVector(F.astype(np.int32)))
        r["open3d_simple"] = timed(lambda: m.filter_smooth_simple(1), ext_repeats)
        r["open3d_laplacian"] = timed(lambda: m.filter_smooth_laplacian(1), ext_repeats)
        del m

    if memory:
        path = folder / f"elephant-loop{SIZES[label]}.npz"
        r["memory"] = {w: peak_memory(path, w) for w in ("filtering", "heat_euler", "heat_chebyshev", "sobolev")}
    return r


# --- report -------------------------------------------------------------------------------
def ratios(r: dict) -> dict:
    q = {
        "filter/bandwidth_bound": r["spmm"]["wall"] / r["bandwidth_bound"]["wall"],
        "filter_1thread/bandwidth_bound": r["spmm_1thread"]["wall"] / r["bandwidth_bound"]["wall"],
        "chebyshev/euler": r["heat_chebyshev"]["wall"] / r["heat_euler"]["wall"],
        "chebyshev/euler_cpu": r["heat_chebyshev"]["cpu"] / r["heat_euler"]["cpu"],
        "chebyshev/textbook_euler": r["heat_chebyshev"]["wall"] / r["heat_euler_textbook"]["wall"],
    }
    if "sobolev_cg_maxrel" in r:  # max |Y_cg - Y_chol| / max |Y_chol|, not a ratio of times
        q["sobolev_cg: max rel. difference from Cholesky"] = r["sobolev_cg_maxrel"]
    if "meshlab_laplacian" in r:
        q["ours_meshlab/meshlab"] = r["filtering_meshlab"]["wall"] / r["meshlab_laplacian"]["wall"]
        q["ours_uniform/meshlab"] = r["filtering_call"]["wall"] / r["meshlab_laplacian"]["wall"]
        q["ours_open3d/open3d_simple"] = r["filtering_open3d"]["wall"] / r["open3d_simple"]["wall"]
        q["ours_invdist/open3d_laplacian"] = r["filtering_inverse_distance"]["wall"] / r["open3d_laplacian"]["wall"]
    return q


ROWS = [
    ("operator build (W, D, P)", "build"),
    ("locality order (RCM) + relabelled P, once per mesh", "locality_order"),
    ("filtering iteration: P @ X kernel, threaded", "spmm"),
    ("filtering iteration: P @ X kernel, 1 thread", "spmm_1thread"),
    ("  same kernel, input vertex order", "spmm_input_order"),
    ("  scipy P @ X, input vertex order", "spmm_scipy"),
    ("  memory-bandwidth bound (numpy stream)", "bandwidth_bound"),
    ("filtering(iterations=1) call, uniform", "filtering_call"),
    ("filtering(iterations=1) call, weights=meshlab", "filtering_meshlab"),
    ("filtering(iterations=1) call, weights=open3d", "filtering_open3d"),
    ("filtering(iterations=1) call, inverse_distance", "filtering_inverse_distance"),
    ("MeshLab apply_coord_laplacian_smoothing, 1 step", "meshlab_laplacian"),
    ("Open3D filter_smooth_simple(1)", "open3d_simple"),
    ("Open3D filter_smooth_laplacian(1)", "open3d_laplacian"),
    ("heat T=40: Euler tau=0.5 (80 fused steps)", "heat_euler"),
    ("heat T=40: textbook Euler loop (before)", "heat_euler_textbook"),
    ("heat T=40: Chebyshev (default tol 1e-3)", "heat_chebyshev"),
    ("heat T=40: scipy expm_multiply (n < 500k only)", "heat_expm_multiply"),
    ("Sobolev mu=1: factorisation", "sobolev_factor"),
    ("Sobolev: one solve", "sobolev_solve"),
    ("Sobolev: re-solve, cached factor", "sobolev_resolve"),
    ("Sobolev CG (mu=1, tol 1e-8), no factorisation", "sobolev_cg"),
]


def print_table(results: list[dict]) -> None:
    labels = [r["label"] for r in results]
    head = f"{'seconds, median wall (cpu)':52s}" + "".join(f"{lab + ' n=' + format(r['n'], ','):>26s}" for lab, r in zip(labels, results))
    print(head)
    print("-" * len(head))
    for name, key in ROWS:
        cells = []
        for r in results:
            t = r.get(key)
            cells.append(f"{t['wall']:.4g} ({t['cpu']:.3g})" if t else "not run")
        print(f"{name:52s}" + "".join(f"{c:>26s}" for c in cells))
    print()
    for key in ratios(results[0]):
        print(f"{key:52s}" + "".join(f"{ratios(r).get(key, float('nan')):>26.3g}" for r in results))
    if all("memory" in r for r in results):
        print()
        for what in results[0]["memory"]:
            cells = [
                f"{r['memory'][what]['maxrss_delta'] / r['n']:.0f} / {r['memory'][what]['tracemalloc_peak'] / r['n']:.0f}"
                for r in results
            ]
            print(f"{'peak bytes/vertex (maxrss / tracemalloc) ' + what:52s}" + "".join(f"{c:>26s}" for c in cells))


def scaling_exponents(results: list[dict]) -> dict:
    ns = [r["n"] for r in results]
    keys = ("spmm", "spmm_1thread", "heat_euler", "heat_chebyshev", "build", "sobolev_factor")
    return {key: fit_exponent(ns, [r[key]["cpu"] for r in results]) for key in keys}


def write_json(path: str, results: list[dict], total: float) -> None:
    """The results so far, written to a temporary file and renamed."""
    doc = {
        "results": [dict(r, ratios=ratios(r)) for r in results],
        "scaling_exponent_cpu": scaling_exponents(results),
        "total_seconds": total,
        "machine": {"cpus": os.cpu_count(), "platform": platform.platform(), "loadavg": os.getloadavg()},
        "numpy": np.__version__,
    }
    tmp = Path(path).with_name(Path(path).name + ".tmp")
    tmp.write_text(json.dumps(doc, indent=1))
    os.replace(tmp, path)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", default=",".join(SIZES), help=f"comma-separated subset of {', '.join(SIZES)}")
    ap.add_argument("--repeats", type=int, default=3, help="runs per timing; the median is reported")
    ap.add_argument("--out", default=None, help="write the results as JSON here")
    ap.add_argument("--cache-dir", default=None, help="where the subdivided meshes are kept (default ~/.cache/meshdenoise)")
    ap.add_argument("--no-external", action="store_true", help="skip MeshLab and Open3D")
    ap.add_argument("--no-memory", action="store_true", help="skip the peak-memory subprocesses")
    ap.add_argument("--memory-only", action="store_true", help="only the peak-memory subprocesses (no timings)")
    args = ap.parse_args(argv)
    labels = [s.strip() for s in args.sizes.split(",") if s.strip()]
    for lab in labels:
        if lab not in SIZES:
            ap.error(f"--sizes: {lab!r} is not one of {', '.join(SIZES)}")
    if args.repeats < 1:
        ap.error(f"--repeats must be at least 1, got {args.repeats}")
    folder = cache_dir(args.cache_dir)
    t0 = time.perf_counter()
    if args.memory_only:
        doc = {}
        for lab in labels:
            V, F = benchmark_mesh(lab, folder)
            n = len(V)
            del V, F
            path = folder / f"elephant-loop{SIZES[lab]}.npz"
            doc[lab] = {"n": n}
            for what in ("filtering", "heat_euler", "heat_chebyshev", "sobolev"):
                m = peak_memory(path, what)
                doc[lab][what] = m
                print(f"{lab:5s} n={n:>9,d} {what:15s} peak RSS growth {m['maxrss_delta'] / n:7.0f} B/vertex, "
                      f"tracemalloc peak {m['tracemalloc_peak'] / n:7.0f} B/vertex", flush=True)
        if args.out:
            tmp = Path(args.out).with_name(Path(args.out).name + ".tmp")
            tmp.write_text(json.dumps(doc, indent=1))
            os.replace(tmp, args.out)
        return 0
    results = []
    for lab in labels:
        print(f"[{time.perf_counter() - t0:7.1f} s] {lab} ...", file=sys.stderr, flush=True)
        results.append(run_size(lab, folder, args.repeats, not args.no_external, not args.no_memory))
        if args.out:  # after every size, so a long run that dies at 6M keeps the others
            write_json(args.out, results, time.perf_counter() - t0)
    scaling = scaling_exponents(results)
    print_table(results)
    print()
    for key, e in scaling.items():
        print(f"fitted exponent of CPU time vs n, {key:20s}: {'n/a' if e is None else format(e, '.3f')}")
    for r in results:
        if "snr_db" in r:
            q = r["snr_db"]
            print(
                f"SNR on the elephant, rho = 0.2, seed 0: noisy {q['noisy']:.3f} dB, Euler {q['euler']:.4f} dB, "
                f"Chebyshev {q['chebyshev']:.4f} dB (difference {q['chebyshev'] - q['euler']:+.4f} dB)"
            )
    total = time.perf_counter() - t0
    print(f"total run time {total:.0f} s; load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs")
    if args.out:
        write_json(args.out, results, total)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""two_stage's pass kernels against the memory-bandwidth bound of the bytes they move.

In one process: the machine's bandwidth (numpy copy and two-step triad on 256 MB arrays, and a
threaded triad, best of several), the throughput of the pair kernels' exponential, then per mesh
(the elephant Loop-subdivided 2 and 3 times, ``benchmarks/scale.py``'s meshes and cache) each
kernel's best time per pass and the bytes it must move per pass: every array it reads or writes,
counted once (index arrays at their stored width; gathered rows counted once, as if the caches
held the neighbours). ``bound = bytes / bandwidth``; ``ratio = measured / bound``. The kernels
of ``--baseline`` (the commit before the pair kernels were vectorised and fused) are loaded from
that commit's ``meshdenoise/kernels/`` package (``meshdenoise/kernels.py`` before it was one) and timed
in the same process, alternating with the current ones. Then the whole ``two_stage(iterations=19,
normal_iterations=1, vertex_iterations=5, sigma_r=2.0, keep_tangential=False)`` at each of
``--whole-sizes``, in subprocesses alternating between the baseline's package and the same package
with ``--current``'s ``meshdenoise/kernels/`` (both unpacked with ``git archive``: only the kernels
differ, and uncommitted edits elsewhere in the checkout play no part), and the largest difference
of the two results relative to the mesh's extent.

Usage::

    python benchmarks/kernel_bound.py --sizes 400k,1.6M --whole-sizes 400k,1.6M --out benchmarks/results/kernel-bound.md
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import shutil
import subprocess
import sys
import tarfile
import time
from io import BytesIO
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

BASELINE = "6339954"  # the last commit with two exponentials a pair in the fused pass and every spacing twice
WHOLE = dict(iterations=19, normal_iterations=1, vertex_iterations=5, sigma_r=2.0, sigma_s=1.0, guidance="bilateral",
             keep_tangential=False)
COMMAND = ("python benchmarks/kernel_bound.py --sizes 400k,1.6M --whole-sizes 400k,1.6M "
           "--out benchmarks/results/kernel-bound.md")


def best_of(fn, repeat: int) -> float:
    """Least wall seconds of ``repeat`` calls of ``fn``."""
    out = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t)
    return min(out)


def bandwidth(repeat: int) -> dict:
    """Bytes per second of numpy's copy and two-step triad (``a = b * s``, ``a += c``) on 256 MB arrays, and of a
    threaded triad (numba, every thread); each the best of ``repeat``."""
    from meshdenoise.kernels import njit, prange, set_threads

    @njit(parallel=True)
    def triad(a, b, c, s):  # pragma: no cover - compiled
        for i in prange(a.shape[0]):
            a[i] = b[i] + s * c[i]

    size = 32 * 2**20  # doubles: 256 MB
    a, b, c = np.ones(size), np.full(size, 2.0), np.full(size, 3.0)
    set_threads()
    triad(a, b, c, 0.5)
    copy = 2 * a.nbytes / best_of(lambda: np.copyto(a, b), repeat)

    def numpy_triad():
        np.multiply(b, 0.5, out=a)
        np.add(a, c, out=a)

    numpy_triad_rate = 5 * a.nbytes / best_of(numpy_triad, repeat)  # read b, write a; read a and c, write a
    threaded = 3 * a.nbytes / best_of(lambda: triad(a, b, c, 0.5), repeat)
    return {"copy": copy, "numpy_triad": numpy_triad_rate, "threaded_triad": threaded,
            "best": max(copy, numpy_triad_rate, threaded)}


def exp_rate(kernels, repeat: int) -> float:
    """Seconds per argument of the pair kernels' exponential on every thread (arguments in cache), compiled with
    the pair kernels' math flags (``PAIR_MATH``: FMA contraction, where the module has it)."""
    from meshdenoise.kernels import njit, prange

    exp_one = kernels.exp_one

    @njit(parallel=True, fastmath=getattr(kernels, "PAIR_MATH", False))
    def many(buf, reps):  # pragma: no cover - compiled
        for b in prange(buf.shape[0]):
            for _ in range(reps):
                for t in range(buf.shape[1]):
                    buf[b, t] = exp_one(-buf[b, t] * 0.5)

    buf = np.full((64, 4096), 0.3)
    many(buf, 1)
    reps = 40
    return best_of(lambda: many(buf, reps), repeat) / (buf.size * reps)


def load_baseline_kernels(commit: str, folder: Path):
    """The baseline's kernels as a module of their own (its numba cache beside it in ``folder``): its
    ``meshdenoise/kernels/`` package, or its ``meshdenoise/kernels.py`` from before the package."""
    folder.mkdir(parents=True, exist_ok=True)
    name = f"kernels_{commit}"
    listed = subprocess.run(["git", "ls-tree", "--name-only", commit, "meshdenoise/kernels/"], cwd=ROOT, check=True,
                            capture_output=True, text=True).stdout.split()
    if listed:
        package = folder / name
        if not (package / "__init__.py").is_file():
            package.mkdir(parents=True, exist_ok=True)
            for path in listed:
                if path.endswith(".py"):
                    text = subprocess.run(["git", "show", f"{commit}:{path}"], cwd=ROOT, check=True,
                                          capture_output=True, text=True).stdout
                    (package / Path(path).name).write_text(text)
        spec = importlib.util.spec_from_file_location(name, package / "__init__.py",
                                                      submodule_search_locations=[str(package)])
    else:
        path = folder / f"{name}.py"
        if not path.is_file():
            text = subprocess.run(["git", "show", f"{commit}:meshdenoise/kernels.py"], cwd=ROOT, check=True,
                                  capture_output=True, text=True).stdout
            path.write_text(text)
        spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # numba's cache finds a kernel's module by name
    spec.loader.exec_module(module)
    return module


def commit_tree(commit: str, folder: Path) -> Path:
    """The package at ``commit``, unpacked once into ``folder`` (its numba cache kept there between runs)."""
    tree = folder / f"tree_{commit}"
    if not (tree / "meshdenoise" / "__init__.py").is_file():
        data = subprocess.run(["git", "archive", "--format=tar", commit, "meshdenoise"], cwd=ROOT, check=True,
                              capture_output=True).stdout
        tree.mkdir(parents=True, exist_ok=True)
        with tarfile.open(fileobj=BytesIO(data)) as tar:
            tar.extractall(tree)
    return tree


def mesh_state(label: str, folder: Path):
    """Topology, relabelled and scaled noisy positions and the run's buffers at the state of a first outer iteration."""
    from meshdenoise import kernels
    from meshdenoise.operators import gather_rows, get_operators
    from meshdenoise import normal_filter as ts
    from scale import load, prepare

    info = prepare(label, folder)
    _, F, Vn = load(info["npz"])
    ops = get_operators(F, len(Vn))
    topo = ts.two_stage_topology(ops)
    X = gather_rows(np.asarray(Vn, dtype=np.float64), topo.vertex_order)
    np.ldexp(X, -ts.power_of_two_scale(X), out=X)
    m = topo.F.shape[0]
    st = {"ops": ops, "topo": topo, "X": X, "n": X.shape[0], "m": m, "nnz": topo.nb.indices.size,
          "N": np.empty((m, 3)), "A": np.empty(m), "C": np.empty((m, 3)), "out": np.empty((m, 3)),
          "S": np.empty(topo.nb.indices.size), "sums": np.empty(m), "scale": ts.fit_scale(topo.corner_ptr, None)}
    kernels.set_threads()
    kernels.face_geometry(X, topo.F, st["N"], st["A"], st["C"])
    count = kernels.centroid_spacing_sums(st["C"], topo.nb.indptr, topo.nb.indices, st["sums"])
    st["denom_s"] = 2.0 * (float(st["sums"].sum()) / count) ** 2
    st["denom_r"] = 2.0 * WHOLE["sigma_r"] ** 2
    return st


def kernel_rows(st: dict, new, old, repeat: int) -> list[dict]:
    """Per kernel: bytes per pass, and the best time per pass of the baseline's and the current kernel."""
    from meshdenoise.operators import spmm
    from meshdenoise.plugins.taubin import pass_matrix

    topo, nb, F = st["topo"], st["topo"].nb, st["topo"].F
    n, m, nnz = st["n"], st["m"], st["nnz"]
    X, N, A, C, out, S, sums, scale = (st[k] for k in ("X", "N", "A", "C", "out", "S", "sums", "scale"))
    Xw, Y = X.copy(), X.copy()
    ip, ix = nb.indptr.itemsize, nb.indices.itemsize
    pattern = ip * (m + 1) + ix * nnz  # the face pairs' CSR pattern
    corners = topo.corner_ptr.itemsize * (n + 1) + topo.corners.itemsize * 3 * m
    fw = F.itemsize * 3 * m
    M = pass_matrix(st["ops"].P, 0.5)
    matmat = M.indptr.itemsize * (n + 1) + (M.indices.itemsize + 8) * M.nnz + 2 * 24 * n
    Z = np.empty_like(X)
    dr, ds = st["denom_r"], st["denom_s"]
    rows = [
        ("face_geometry", fw + 24 * n + 56 * m, "normals, areas, centroids",
         lambda k: k.face_geometry(X, F, N, A, C)),
        ("centroid_spacing_sums", pattern + 24 * m + 8 * m, "",
         lambda k: k.centroid_spacing_sums(C, nb.indptr, nb.indices, sums)),
        ("spatial_weights", pattern + 32 * m + 8 * nnz, "S written",
         lambda k: k.spatial_weights(C, A, nb.indptr, nb.indices, ds, S)),
        ("bilateral_pass", pattern + 8 * nnz + 48 * m, "S read",
         lambda k: k.bilateral_pass(N, N, S, nb.indptr, nb.indices, dr, out)),
        ("bilateral_spatial_pass", pattern + 80 * m, "both, S never stored",
         lambda k: k.bilateral_spatial_pass(N, N, C, A, nb.indptr, nb.indices, ds, dr, out)),
        # the face pass writes n_f . c_f (8 bytes a face), the vertex pass reads it back with the normals
        ("fit_vertices (1 step)", fw + 8 * m + corners + 24 * m + 8 * m + 48 * n + 8 * n, "n . c per face, then vertices",
         lambda k: k.fit_vertices(Xw, F, N, topo.corner_ptr, topo.corners, scale, 1, C)),
        ("restore_tangential", corners + 24 * m + 72 * n, "after face_geometry",
         lambda k: k.restore_tangential(Xw, Y, N, topo.corner_ptr, topo.corners)),
        ("csr_matmat3 (Taubin pass)", matmat, f"{M.nnz / n:.1f} non-zeros a row",
         lambda k: spmm(M, X, out=Z)),
    ]
    result = []
    for name, nbytes, note, call in rows:
        attr = name.split(" ")[0]
        # spmm is the current module's; a kernel the baseline lacks has no "before"
        modules = [(tag, k) for tag, k in (("before", old), ("after", new))
                   if hasattr(k, attr) and not (tag == "before" and attr == "csr_matmat3")]
        for _, k in modules:
            call(k)  # compiled or loaded before timing
        times = {}
        for _ in range(2):  # alternating: the load drifts between the two
            for tag, k in modules:
                t = best_of(lambda: call(k), repeat)
                times[tag] = min(times.get(tag, t), t)
        result.append({"kernel": name, "bytes": nbytes, "note": note, **times})
    return result


def whole_call(tree: Path, label: str, folder: Path, result: Path) -> float:
    """Wall seconds of the whole two_stage call (:data:`WHOLE`) in a fresh process on the package unpacked in
    ``tree``, after a warm-up call on a small mesh (the kernels loaded from numba's cache) and the topology built;
    the result is saved to ``result`` (``.npy``)."""
    code = f"""
import sys, time, json
sys.path.insert(0, {str(tree)!r})
import numpy as np
import meshdenoise as md
from meshdenoise.operators import get_operators
from meshdenoise.shapes import box
md.two_stage(box(4), **{WHOLE!r})
with np.load({str(folder / ('elephant-o3dloop%d.npz' % {'400k': 2, '1.6M': 3}[label]))!r}) as z:
    F, Vn = z["F"], z["Vn"]
ops = get_operators(F, len(Vn))
md.two_stage((Vn, F), operators=ops, **{dict(WHOLE, iterations=1)!r})  # the topology cached
t = time.perf_counter()
Y = md.two_stage((Vn, F), operators=ops, **{WHOLE!r})[0]
seconds = time.perf_counter() - t
np.save({str(result)!r}, Y)
print(json.dumps({{"seconds": seconds, "module": md.__file__}}))
"""
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    env.pop("PYTHONPATH", None)
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd="/")
    if proc.returncode:
        raise RuntimeError(proc.stderr[-2000:])
    record = json.loads(proc.stdout.strip().splitlines()[-1])
    expected = str(tree / "meshdenoise")
    if not record["module"].startswith(expected):
        raise RuntimeError(f"the call imported {record['module']}, not {expected}")
    return record["seconds"]


def kernels_tree(baseline: Path, commit: str, folder: Path) -> Path:
    """A copy of the package unpacked in ``baseline`` whose ``meshdenoise/kernels/`` is ``commit``'s."""
    tree = folder / f"{baseline.name}_kernels_{commit}"
    if not (tree / "meshdenoise" / "__init__.py").is_file():
        shutil.copytree(baseline / "meshdenoise", tree / "meshdenoise", dirs_exist_ok=True,
                        ignore=shutil.ignore_patterns("__pycache__"))
        shutil.rmtree(tree / "meshdenoise" / "kernels")
        data = subprocess.run(["git", "archive", "--format=tar", commit, "meshdenoise/kernels"], cwd=ROOT, check=True,
                              capture_output=True).stdout
        with tarfile.open(fileobj=BytesIO(data)) as tar:
            tar.extractall(tree)
    return tree


def relative_difference(a: Path, b: Path, label: str, folder: Path) -> float:
    """The largest coordinate difference of two saved results over the noisy mesh's extent (its largest side)."""
    with np.load(folder / ("elephant-o3dloop%d.npz" % {"400k": 2, "1.6M": 3}[label])) as z:
        Vn = z["Vn"]
    extent = float(np.max(Vn.max(axis=0) - Vn.min(axis=0)))
    return float(np.abs(np.load(a) - np.load(b)).max()) / extent


def markdown(bw: dict, exp_s: float, threads: int, sizes: dict, whole: dict, baseline: str, current: str,
             load: tuple) -> str:
    gb = bw["best"]
    lines = [
        "# two_stage's pass kernels against the memory-bandwidth bound",
        "",
        f"Made by `{COMMAND}` (baseline {baseline}: two exponentials a pair in the fused pass, each spacing summed "
        f"twice; current: the kernels of {current}).",
        "",
        f"Bandwidth, best of 5 on 256 MB arrays: numpy copy {bw['copy'] / 1e9:.1f} GB/s, numpy two-step triad "
        f"{bw['numpy_triad'] / 1e9:.1f} GB/s, threaded triad ({threads} threads) {bw['threaded_triad'] / 1e9:.1f} GB/s; "
        f"the bound uses the best, {gb / 1e9:.1f} GB/s. The pair kernels' exponential: {exp_s * 1e9:.2f} ns an "
        f"argument on {threads} threads (arguments in cache): the *exp floor* column is pairs x the current "
        "kernel's exponentials a pair x that.",
        "",
        "Bytes per pass: every array the kernel reads or writes, counted once at its stored width (gathered rows "
        "once, as if the caches held the neighbours). Times: best of several calls, alternating baseline and "
        f"current kernels in one process. Load average at the start and end: {load[0]:.2f}, {load[1]:.2f} "
        "(2 cores, shared: ratios move with it).",
        "",
        "What the current kernels do differently from the baseline's: `bilateral_spatial_pass` takes one exponential "
        "of the sum of the two exponents (two exponentials before); the pair kernels multiply by the reciprocal of the "
        "denominators and are compiled with FMA contraction (`PAIR_MATH`: the exponential's polynomial in half the "
        "operations, still within 1 ulp of numpy's); `centroid_spacing_sums` visits each unordered pair once (the "
        "pattern is symmetric: half the square roots); `fit_vertices` stores n . c per face (8 bytes, not the "
        "centroid's 24) and, with `restore_tangential`, finds a corner's face by an unsigned division by 3. What "
        "is left over the bound in the fused pass (400k, each part left out in turn) is about a third each: the exponents "
        "(gathered rows), the exponentials and the sums (gathered rows): scalar code on gathers, not the memory.",
        "",
    ]
    for label, (dims, rows) in sizes.items():
        n, m, nnz = dims
        lines += [f"## {label}: {n:,} vertices, {m:,} faces, {nnz:,} face pairs", "",
                  "| kernel | MB/pass | bound ms | exp floor ms | before ms | ratio | after ms | ratio | note |",
                  "|---|---:|---:|---:|---:|---:|---:|---:|---|"]
        for r in rows:
            bound = r["bytes"] / gb * 1e3
            exps = {"spatial_weights": 1, "bilateral_pass": 1, "bilateral_spatial_pass": 1}.get(r["kernel"], 0)
            floor = f"{exps * nnz * exp_s * 1e3:.1f}" if exps else ""
            cells = []
            for tag in ("before", "after"):
                t = r.get(tag)
                cells += [f"{t * 1e3:.1f}", f"{t * 1e3 / bound:.1f}"] if t is not None else ["", ""]
            lines.append(f"| {r['kernel']} | {r['bytes'] / 1e6:.1f} | {bound:.2f} | {floor} | " + " | ".join(cells)
                         + f" | {r['note']} |")
        lines.append("")
    if whole:
        lines += ["## The whole call", "",
                  "`two_stage(iterations=19, normal_iterations=1, vertex_iterations=5, sigma_r=2.0, "
                  "keep_tangential=False)`, topology cached, kernels loaded, each in a fresh process, alternating, on the baseline's "
                  "package and on it with the current kernels; "
                  "*difference*: the largest coordinate difference of the two results over the noisy mesh's extent:",
                  "", "| mesh | tree | seconds (each run) | best | difference |", "|---|---|---|---:|---:|"]
        for label, (runs, diff) in whole.items():
            for i, (tag, times) in enumerate(runs.items()):
                cell = f"{diff:.1e}" if i == len(runs) - 1 else ""
                lines.append(f"| {label} | {tag} | {', '.join(f'{s:.2f}' for s in times)} | {min(times):.2f} | {cell} |")
        lines.append("")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", default="400k,1.6M")
    ap.add_argument("--baseline", default=BASELINE)
    ap.add_argument("--current", default="HEAD", help="the commit whose package the whole calls run as 'current'")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--whole-sizes", default="400k,1.6M", help="meshes of the whole call, comma-separated ('': none)")
    ap.add_argument("--whole-runs", type=int, default=3, help="runs of the whole call per tree and mesh (0: none)")
    ap.add_argument("--cache-dir", default=None)
    ap.add_argument("--out", default=None, help="markdown file to write")
    args = ap.parse_args(argv)

    import numba

    from meshdenoise import kernels
    from scale import cache_dir, prepare

    folder = cache_dir(args.cache_dir)
    work = folder.parent / "kernel-bound"
    load0 = os.getloadavg()
    threads = kernels.set_threads()
    bw = bandwidth(args.repeat)
    exp_s = exp_rate(kernels, args.repeat)
    print(f"bandwidth {bw['best'] / 1e9:.1f} GB/s, exp {exp_s * 1e9:.2f} ns, threads {threads} "
          f"(numba {numba.get_num_threads()})", flush=True)
    old = load_baseline_kernels(args.baseline, work)
    sizes = {}
    for label in [s for s in args.sizes.split(",") if s]:
        st = mesh_state(label, folder)
        rows = kernel_rows(st, kernels, old, args.repeat)
        sizes[label] = ((st["n"], st["m"], st["nnz"]), rows)
        for r in rows:
            print(label, r["kernel"], {k: round(v * 1e3, 2) for k, v in r.items() if k in ("before", "after")}, flush=True)
        del st
    current = subprocess.run(["git", "rev-parse", "--short", args.current], cwd=ROOT, check=True, capture_output=True,
                             text=True).stdout.strip()
    whole = {}
    if args.whole_runs:
        base = commit_tree(args.baseline, work)
        trees = {f"baseline {args.baseline}": base, f"kernels of {current}": kernels_tree(base, current, work)}
        for label in [s for s in args.whole_sizes.split(",") if s]:
            prepare(label, folder)
            runs, results = {}, {}
            for _ in range(args.whole_runs):
                for tag, tree in trees.items():
                    results[tag] = work / f"whole_{tree.name}_{label}.npy"
                    s = whole_call(tree, label, folder, results[tag])
                    runs.setdefault(tag, []).append(s)
                    print("whole", label, tag, round(s, 2), flush=True)
            diff = relative_difference(*results.values(), label, folder)
            whole[label] = (runs, diff)
    load1 = os.getloadavg()
    text = markdown(bw, exp_s, threads, sizes, whole, args.baseline, current, (load0[0], load1[0]))
    print(text)
    if args.out:
        Path(args.out).write_text(text)


if __name__ == "__main__":
    main()

"""Quality benchmark: our filters with automatic and oracle parameters against MeshLab and Open3D.

Usage::

    python benchmarks/quality.py [--quick] [--seeds 5] [--jobs 2] [--rows ...] [--methods ...]
                                 [--out DIR] [--resume [--redo METHOD ...]]

Rows: the paper's meshes at its noise levels (elephant 0.015, 0.2; Nefertiti 0.015, 0.2, 1),
pymeshlab's sample bunny with normal noise at 0.5 % and 2 % of its bounding-box diagonal
(these with ``--seeds`` noise seeds: mean and std), and the Guided Mesh Normal Filtering
benchmark pairs (Fandisk0.3, Block0.4, Bunny0.2, Twelve0.5Impulsive; their own noise).

Columns, per method: SNR (dB) and, when the metrics registry has them, mean face-normal
angular error (deg) and volume change (%). Methods: every filter with an automatic rule
(``meshdenoise.auto_filters()``) with automatic parameters (``auto``) and with the
parameters that are best in hindsight over the same search space (``oracle``);
MeshLab's Laplacian, HC Laplacian (repeated k times), Taubin and two-step smoothing
and Open3D's simple, Laplacian and Taubin filters, each with its number of iterations
tuned on the clean mesh (oracle), the libraries themselves being called one
iteration at a time on one MeshSet / TriangleMesh (all are memoryless from one
iteration to the next), by the tuning floor's oracle search
(:func:`meshdenoise.tuning.walk.walk`: it stops at twice the best count plus 20). On the
benchmark pairs each library filter also gets its normal-error oracle (the iteration
count with the least mean face-normal error, read along the same run), the reference
for the feature targets. ``two_stage`` (built for sharp features; two Monte-Carlo
SURE runs of a nonlinear filter) runs on the benchmark pairs only.

``--jobs 2`` measures the (row, seed) tasks in 2 processes, a fresh one per task (so the
caches of one task do not pile up in a long-lived worker; ``--isolate`` does the same with
one process): no timing is reported in the table, so parallel runs do not distort it; wall
and CPU time are printed.

Each (row, seed) task is written to ``OUT/tasks/`` when it completes. ``--resume`` takes
what is stored there and measures only what is missing (after a killed run, or to add
rows); ``--resume --redo METHOD`` measures one method again after a change to it and
keeps the rest. Every measurement records the commit it ran on, and each row of the
table names them.

The summary gives, per row, the margin of our best automatic method over the paper's
best (its Table 1) and over the best oracle-tuned MeshLab/Open3D filter, and each
method's auto-vs-oracle loss. Writes quality.md, quality.json and quality.csv to --out.
"""

from __future__ import annotations

import argparse
import csv
import itertools
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from meshdenoise import tuning as auto  # noqa: E402  (estimate_noise, choose_parameters, auto_filters)
from meshdenoise.data import data_file, sample_mesh  # noqa: E402
from meshdenoise.io import atomic_path, load_arrays  # noqa: E402
from meshdenoise.metrics import METRICS, snr  # noqa: E402
from meshdenoise.noise import add_normal_noise  # noqa: E402
from meshdenoise.registry import apply_filter  # noqa: E402
from meshdenoise.tuning.walk import walk  # noqa: E402

PAPER_BEST = {  # Table 1 of the paper: best SNR (dB) over its three methods, and the noisy input's SNR
    ("elephant", 0.015): 39.82,
    ("elephant", 0.2): 26.81,
    ("nefertiti", 0.015): 41.83,
    ("nefertiti", 0.2): 24.17,
    ("nefertiti", 1.0): 14.62,
}
EXTRA_METRICS = [("normal_error_deg", "normal err (deg)"), ("volume_change", "vol change (%)")]
FEATURE_ONLY = {"two_stage"}  # methods measured on the benchmark pairs only
MAX_LIB_ITERS = 300  # cap of the oracle search for MeshLab / Open3D iterations


# ----------------------------------------------------------------------------- rows
def _rows(quick: bool, seeds: int) -> list[dict]:
    rows = []
    el = load_arrays(data_file("elephant-50kv.off"))
    ne = load_arrays(data_file("nefertiti.off"))
    bu = load_arrays(sample_mesh("bunny.obj"))
    diag = float(np.linalg.norm(bu[0].max(0) - bu[0].min(0)))
    synth = [("elephant", el, 0.015), ("elephant", el, 0.2), ("nefertiti", ne, 0.015), ("nefertiti", ne, 0.2), ("nefertiti", ne, 1.0)]
    synth += [("bunny 0.5%", bu, 0.005 * diag), ("bunny 2%", bu, 0.02 * diag)]
    bench = ["Fandisk0.3", "Block0.4", "Bunny0.2", "Twelve0.5Impulsive"]
    if quick:
        synth = [synth[1], synth[3], synth[4], synth[5]]
        bench = ["Fandisk0.3", "Block0.4"]
    for name, (V, F), rho in synth:
        key = (name, rho)
        noisy = [add_normal_noise((V, F), rho, seed=s)[0] for s in range(seeds)]
        label = f"{name} rho={rho:g}" if not name.startswith("bunny") else f"{name} (rho={rho:.4g})"
        rows.append({"row": label, "V": V, "F": F, "noisy": noisy, "paper": PAPER_BEST.get(key), "features": False})
    for b in bench:
        Vo, F = load_arrays(data_file(f"benchmark/{b}/Original.obj"))
        Vn, Fn = load_arrays(data_file(f"benchmark/{b}/Noisy.obj"))
        if not np.array_equal(F, Fn):
            raise ValueError(f"benchmark/{b}: Noisy.obj and Original.obj have different faces")
        rows.append({"row": b, "V": Vo, "F": F, "noisy": [Vn], "paper": None, "features": True})
    return rows


_ROWS_CACHE: dict = {}


def _cached_rows(quick: bool, seeds: int) -> list[dict]:
    """The rows, built once per process (workers rebuild them: noise is seeded, so identical)."""
    key = (quick, seeds)
    if key not in _ROWS_CACHE:
        _ROWS_CACHE[key] = _rows(quick, seeds)
    return _ROWS_CACHE[key]


# ----------------------------------------------------------------------------- library filters
def meshlab_steps(step_kwargs: dict, filter_name: str):
    import pymeshlab

    def run(V, F):
        ms = pymeshlab.MeshSet()
        ms.add_mesh(pymeshlab.Mesh(vertex_matrix=V, face_matrix=F.astype(np.int32)))
        while True:
            getattr(ms, filter_name)(**step_kwargs)
            yield np.array(ms.current_mesh().vertex_matrix(), dtype=np.float64)

    return run


def open3d_steps(method: str):
    import open3d as o3d

    def run(V, F):
        m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(V), o3d.utility.Vector3iVector(F.astype(np.int32)))
        while True:
            m = getattr(m, method)(1)
            yield np.asarray(m.vertices, dtype=np.float64).copy()

    return run


LIBRARY = {
    "MeshLab Laplacian": meshlab_steps({"stepsmoothnum": 1, "cotangentweight": False}, "apply_coord_laplacian_smoothing"),
    "MeshLab HC Laplacian": meshlab_steps({}, "apply_coord_hc_laplacian_smoothing"),
    "MeshLab Taubin": meshlab_steps({"stepsmoothnum": 1}, "apply_coord_taubin_smoothing"),
    "MeshLab two-step": meshlab_steps({"stepsmoothnum": 1}, "apply_coord_two_steps_smoothing"),
    "Open3D simple": open3d_steps("filter_smooth_simple"),
    "Open3D Laplacian": open3d_steps("filter_smooth_laplacian"),
    "Open3D Taubin": open3d_steps("filter_smooth_taubin"),
}


def library_oracle(run, V0, Vn, F, scores: tuple[str, ...] = ("snr",)) -> dict:
    """Best iteration counts of a library filter against the clean mesh: ``{score: (iterations, coordinates)}``.

    ``scores``: ``"snr"`` (the highest SNR) and/or ``"normal"`` (the least mean face-normal
    error). The tuning floor's oracle search (:func:`meshdenoise.tuning.walk.walk`) along one
    run of the filter, one library call per iteration on the same mesh object, every score
    read at every iteration; it stops when each score is past its minimum (the one rule:
    twice the best count and 20 more), or at ``MAX_LIB_ITERS``.
    """
    from meshdenoise.metrics import normal_error_deg

    measures = {"snr": lambda X: -snr(V0, X), "normal": lambda X: normal_error_deg((V0, F), X)}
    unknown = set(scores) - set(measures)
    if unknown or not scores:
        raise ValueError(f"library_oracle: scores must be among {sorted(measures)}, got {scores!r}")
    chosen = [measures[name] for name in scores]
    found = walk(itertools.chain([Vn], run(Vn, F)), lambda X: [m(X) for m in chosen], max_steps=MAX_LIB_ITERS)
    return {name: (b.step, b.item) for name, b in zip(scores, found.best)}


# ----------------------------------------------------------------------------- measuring
def _metrics(V0, X, F) -> dict:
    out = {"snr": snr(V0, X)}
    for name, _ in EXTRA_METRICS:
        if name in METRICS:
            value = float(METRICS[name]((V0, F), (X, F)))
            out[name] = 100.0 * value if name == "volume_change" else value
    return out


def _fmt_params(p: dict) -> str:
    return ", ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}" for k, v in p.items())


def _task_file(store: Path, row_label: str, seed_idx: int) -> Path:
    slug = "".join(c if c.isalnum() else "_" for c in row_label).strip("_")
    return store / f"{slug}-seed{seed_idx}.json"


def _commit() -> str:
    """The code version a measurement comes from: the last commit changing the package or the benchmarks
    (commits to the documentation alone do not change it), marked ``+dirty`` with local changes there."""
    import subprocess

    root = Path(__file__).resolve().parent.parent
    try:
        head = subprocess.run(["git", "log", "-1", "--format=%h", "--", "meshdenoise", "benchmarks"],
                              cwd=root, capture_output=True, text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no", "meshdenoise", "benchmarks"],
                               cwd=root, capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return head + ("+dirty" if dirty else "")


def _measure(task: tuple) -> tuple:
    """One (row, seed): the labels not taken from the store, measured; the task's CPU seconds and peak memory.

    ``stored`` holds the labels measured earlier (``--resume``); those are not measured again.
    The task is written to the store as soon as it is complete, so a killed run loses one task.
    """
    import resource

    row_idx, seed_idx, quick, seeds, ours, stored, store = task
    cpu0 = time.process_time()
    commit = _commit()
    row = _cached_rows(quick, seeds)[row_idx]
    V0, F, Vn = row["V"], row["F"], row["noisy"][seed_idx]
    per = dict(stored)

    def put(label, X, params):
        per[label] = (_metrics(V0, X, F), params, commit)

    if "noisy" not in per:
        put("noisy", Vn, {})
    rho = auto.estimate_noise((Vn, F))
    for m in ours:
        if m in FEATURE_ONLY and not row["features"]:
            continue
        if f"{m} auto" not in per:
            p_auto = auto.choose_parameters((Vn, F), m, noise=rho)
            put(f"{m} auto", apply_filter(m, (Vn, F), **p_auto)[0], p_auto)
        if f"{m} oracle" not in per:
            p_or = auto.choose_parameters((Vn, F), m, criterion="oracle", reference=V0)
            put(f"{m} oracle", apply_filter(m, (Vn, F), **p_or)[0], p_or)
    for name, steps in LIBRARY.items():
        if f"{name} oracle" in per:
            continue
        found = library_oracle(steps, V0, Vn, F, ("snr", "normal") if row["features"] else ("snr",))
        k, X = found["snr"]
        put(f"{name} oracle", X, {"iterations": k})
        if "normal" in found:
            k, X = found["normal"]
            put(f"{name} normal-oracle", X, {"iterations": k})
    task_cpu = time.process_time() - cpu0
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    if store is not None:
        record = {"row": row["row"], "seed": seed_idx, "rho_estimated": rho, "per": per}
        with atomic_path(_task_file(store, row["row"], seed_idx)) as tmp:
            Path(tmp).write_text(json.dumps(record, indent=1))
    return row_idx, seed_idx, per, rho, task_cpu, peak_mb


def _load_stored(store: Path, row_label: str, seed_idx: int, redo: set[str]) -> dict:
    """Labels stored for this (row, seed), without those of the methods in ``redo``."""
    path = _task_file(store, row_label, seed_idx)
    if not path.exists():
        return {}
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise SystemExit(f"--resume: cannot read the stored task {path}: {exc}") from exc
    return {label: tuple(v) for label, v in data["per"].items() if label.rsplit(" ", 1)[0] not in redo}


def run(quick: bool, seeds: int, methods: list[str] | None, jobs: int = 1, only: list[str] | None = None,
        store: Path | None = None, resume: bool = False, redo: list[str] | None = None, isolate: bool = False) -> dict:
    ours = methods or auto.auto_filters()
    rows = _cached_rows(quick, seeds)
    keep = [r for r, row in enumerate(rows) if not only or any(o.lower() in row["row"].lower() for o in only)]
    if not keep:
        raise SystemExit(f"--rows {only}: no row matches; rows are: {', '.join(row['row'] for row in rows)}")
    unknown = sorted(set(redo or ()) - set(ours))
    if unknown:
        raise SystemExit(f"--redo {unknown}: not among the methods measured ({', '.join(ours)})")
    if store is not None:
        store.mkdir(parents=True, exist_ok=True)
    tasks = []
    for r in keep:
        for s in range(len(rows[r]["noisy"])):
            stored = _load_stored(store, rows[r]["row"], s, set(redo or ())) if resume and store is not None else {}
            tasks.append((r, s, quick, seeds, ours, stored, store))
    tasks.sort(key=lambda t: -rows[t[0]]["V"].shape[0])  # largest first: better balance over processes
    done: dict[int, dict] = {}
    cpu, peak = 0.0, 0.0
    pooled = jobs > 1 or isolate
    if not pooled:
        outputs = map(_measure, tasks)
    else:
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor

        # a fresh process per task: a worker's caches (factorisations, pymeshlab and Open3D state) do not pile
        # up across tasks (a long-lived forked worker reached 11 GB on the elephant rows and was killed)
        pool = ProcessPoolExecutor(max_workers=jobs, mp_context=mp.get_context("spawn"), max_tasks_per_child=1)
        outputs = pool.map(_measure, tasks)
    for row_idx, seed_idx, per, rho, task_cpu, peak_mb in outputs:
        cpu += task_cpu
        peak = max(peak, peak_mb)
        done.setdefault(row_idx, {})[seed_idx] = (per, rho, task_cpu)
        row = rows[row_idx]
        if len(done[row_idx]) == len(row["noisy"]):
            entry = _entry(row, [done[row_idx][s] for s in range(len(row["noisy"]))], ours)
            done[row_idx] = entry
            print(_row_markdown(entry), flush=True)
    if pooled:
        pool.shutdown()
    results = [done[r] for r in keep]
    return {"rows": results, "methods": ours, "cpu_seconds_tasks": cpu, "peak_rss_mb": peak}


def _entry(row: dict, measured: list, ours: list[str]) -> dict:
    V0 = row["V"]
    wanted = ["noisy"] + [f"{m} {kind}" for m in ours for kind in ("auto", "oracle")]
    wanted += [f"{n} {kind}" for n in LIBRARY for kind in ("oracle", "normal-oracle")]
    labels = [label for label in wanted if all(label in m[0] for m in measured)]  # stored extras left out
    entry = {"row": row["row"], "seeds": len(measured), "paper_best": row["paper"], "features": row["features"], "methods": {}}
    for label in labels:
        runs = [m[0][label] for m in measured]
        keys = runs[0][0].keys()
        entry["methods"][label] = {
            **{f"{k}_mean": float(np.mean([r[0][k] for r in runs])) for k in keys},
            **{f"{k}_std": float(np.std([r[0][k] for r in runs])) for k in keys},
            "params": _fmt_params(runs[0][1]) + (" (seed 0)" if len(runs) > 1 and runs[0][1] else ""),
        }
    entry["rho_estimated"] = float(np.mean([m[1] for m in measured]))
    entry["rho_true_rms"] = float(np.sqrt(np.mean(np.sum((row["noisy"][0] - V0) ** 2, axis=1))))
    entry["cpu_seconds"] = float(sum(m[2] for m in measured))
    entry["commits"] = sorted({m[0][label][2] for m in measured for label in labels})
    _summarise(entry, [m for m in ours if f"{m} auto" in entry["methods"]])
    return entry


def _summarise(entry: dict, ours: list[str]) -> None:
    M = entry["methods"]
    auto_best = max(ours, key=lambda m: M[f"{m} auto"]["snr_mean"])
    lib_best = max(LIBRARY, key=lambda n: M[f"{n} oracle"]["snr_mean"])
    if entry["features"] and "two_stage auto" in M:
        lib_n = min(LIBRARY, key=lambda n: M[f"{n} normal-oracle"]["normal_error_deg_mean"])
        entry["features_summary"] = {
            "two_stage_auto": M["two_stage auto"]["normal_error_deg_mean"],
            "two_stage_oracle": M["two_stage oracle"]["normal_error_deg_mean"],
            "noisy": M["noisy"]["normal_error_deg_mean"],
            "library_best": lib_n,
            "library_best_deg": M[f"{lib_n} normal-oracle"]["normal_error_deg_mean"],
        }
    a = M[f"{auto_best} auto"]["snr_mean"]
    entry["auto_best"] = auto_best
    entry["auto_best_snr"] = a
    entry["library_best"] = lib_best
    entry["margin_vs_library"] = a - M[f"{lib_best} oracle"]["snr_mean"]
    entry["margin_vs_paper"] = None if entry["paper_best"] is None else a - entry["paper_best"]
    entry["auto_loss"] = {m: M[f"{m} oracle"]["snr_mean"] - M[f"{m} auto"]["snr_mean"] for m in ours}


def _row_markdown(entry: dict) -> str:
    lines = [f"\n### {entry['row']}  ({entry['seeds']} seed(s); rho estimated {entry['rho_estimated']:.4g}, "
             f"true rms {entry['rho_true_rms']:.4g}; {entry['cpu_seconds']:.0f} s CPU; "
             f"code {', '.join(entry['commits'])})\n"]
    extra = [(k, h) for k, h in EXTRA_METRICS if f"{k}_mean" in entry["methods"]["noisy"]]
    head = "| method | SNR (dB) | " + " | ".join(h for _, h in extra) + (" | " if extra else "") + "parameters |"
    lines += [head, "|" + "---|" * (3 + len(extra))]
    for label, m in entry["methods"].items():
        cells = [f"{m['snr_mean']:.2f} ± {m['snr_std']:.2f}" if entry["seeds"] > 1 else f"{m['snr_mean']:.2f}"]
        for k, _ in extra:
            cells.append(f"{m[k + '_mean']:.2f}" + (f" ± {m[k + '_std']:.2f}" if entry["seeds"] > 1 else ""))
        lines.append(f"| {label} | " + " | ".join(cells) + f" | {m['params']} |")
    paper = "n/a" if entry["margin_vs_paper"] is None else f"{entry['margin_vs_paper']:+.2f} dB (paper {entry['paper_best']:.2f})"
    lines.append(
        f"\nbest auto: {entry['auto_best']} {entry['auto_best_snr']:.2f} dB; vs paper: {paper}; "
        f"vs best MeshLab/Open3D oracle ({entry['library_best']}): {entry['margin_vs_library']:+.2f} dB; "
        "auto loss vs oracle: " + ", ".join(f"{k} {v:+.2f}" for k, v in entry["auto_loss"].items())
    )
    return "\n".join(lines)


def _summary_table(res: dict) -> str:
    lines = ["| row | noisy SNR | best auto (dB) | vs paper | vs best MeshLab/Open3D oracle | worst auto loss |", "|---|---|---|---|---|---|"]
    for e in res["rows"]:
        paper = "n/a" if e["margin_vs_paper"] is None else f"{e['margin_vs_paper']:+.2f}"
        worst = max(e["auto_loss"], key=lambda m: e["auto_loss"][m])
        lines.append(
            f"| {e['row']} | {e['methods']['noisy']['snr_mean']:.2f} | {e['auto_best']} {e['auto_best_snr']:.2f} | {paper} | "
            f"{e['margin_vs_library']:+.2f} ({e['library_best']}) | {e['auto_loss'][worst]:+.2f} ({worst}) |"
        )
    feats = [e for e in res["rows"] if "features_summary" in e]
    if feats:
        lines += ["", "| row (mean face-normal error, deg) | noisy | two_stage auto | two_stage oracle | best MeshLab/Open3D (normal-error oracle) | ratio |",
                  "|---|---|---|---|---|---|"]
        for e in feats:
            f = e["features_summary"]
            lines.append(
                f"| {e['row']} | {f['noisy']:.2f} | {f['two_stage_auto']:.2f} | {f['two_stage_oracle']:.2f} | "
                f"{f['library_best']} {f['library_best_deg']:.2f} | {f['two_stage_auto'] / f['library_best_deg']:.2f} |"
            )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="1 seed and 5 rows: a fast check")
    ap.add_argument("--seeds", type=int, default=5, help="noise seeds for the rows with our noise (default 5)")
    ap.add_argument("--methods", nargs="*", help="our methods (default: every one with an automatic rule)")
    ap.add_argument("--rows", nargs="*", help="only the rows whose label contains one of these (case-insensitive)")
    ap.add_argument("--jobs", type=int, default=1, help="processes over (row, seed) tasks (default 1)")
    ap.add_argument("--isolate", action="store_true",
                    help="with --jobs 1 too, measure each (row, seed) in a fresh process (always so with --jobs > 1)")
    ap.add_argument("--out", default="benchmark_results/quality", help="output folder")
    ap.add_argument("--resume", action="store_true",
                    help="take the (row, seed, method) results already in OUT/tasks (a killed run, or other methods "
                         "measured earlier) and measure only what is missing; each row names the commits its numbers come from")
    ap.add_argument("--redo", nargs="*", default=[], metavar="METHOD",
                    help="with --resume: measure these methods again (after a change to them) and keep the rest")
    args = ap.parse_args(argv)
    if args.redo and not args.resume:
        raise SystemExit("--redo only makes sense with --resume")
    if args.seeds < 1:
        raise SystemExit(f"--seeds must be >= 1, got {args.seeds}")
    seeds = 1 if args.quick else args.seeds
    if args.jobs < 1:
        raise SystemExit(f"--jobs must be >= 1, got {args.jobs}")
    t0, c0 = time.perf_counter(), time.process_time()
    res = run(args.quick, seeds, args.methods, args.jobs, args.rows, store=Path(args.out) / "tasks",
              resume=args.resume, redo=args.redo, isolate=args.isolate)
    res["seconds"] = time.perf_counter() - t0
    res["cpu_seconds"] = res["cpu_seconds_tasks"] + (time.process_time() - c0 if args.jobs > 1 or args.isolate else 0.0)
    res["command"] = "python benchmarks/quality.py " + " ".join(argv if argv is not None else sys.argv[1:])
    summary = _summary_table(res)
    timing = (f"total {res['seconds']:.0f} s wall, {res['cpu_seconds']:.0f} s CPU of the tasks measured in this run "
              f"({args.jobs} process(es)); peak memory of a measuring process {res['peak_rss_mb']:.0f} MB")
    print("\n## Summary\n\n" + summary + "\n\n" + timing)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    md = "# Quality benchmark\n\n" + summary + "\n" + "\n".join(_row_markdown(e) for e in res["rows"]) + f"\n\n{timing}\n"
    with atomic_path(out / "quality.md") as tmp:
        Path(tmp).write_text(md)
    with atomic_path(out / "quality.json") as tmp:
        Path(tmp).write_text(json.dumps(res, indent=1))
    with atomic_path(out / "quality.csv") as tmp:
        with open(tmp, "w", newline="") as fh:
            w = csv.writer(fh)
            keys = ["snr"] + [k for k, _ in EXTRA_METRICS]
            w.writerow(["row", "method"] + [f"{k}_{s}" for k in keys for s in ("mean", "std")] + ["params"])
            for e in res["rows"]:
                for label, m in e["methods"].items():
                    w.writerow([e["row"], label] + [m.get(f"{k}_{s}", "") for k in keys for s in ("mean", "std")] + [m["params"]])
    print(f"wrote {out}/quality.md, quality.json, quality.csv")


if __name__ == "__main__":
    main()

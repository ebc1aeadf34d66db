"""Quality benchmark: our filters with automatic and oracle parameters against MeshLab and Open3D.

Usage::

    python benchmarks/quality.py [--quick] [--seeds 5] [--out DIR]

Rows: the paper's meshes at its noise levels (elephant 0.015, 0.2; Nefertiti 0.015, 0.2, 1),
pymeshlab's sample bunny with normal noise at 0.5 % and 2 % of its bounding-box diagonal
(these with ``--seeds`` noise seeds: mean and std), and the Guided Mesh Normal Filtering
benchmark pairs (Fandisk0.3, Block0.4, Bunny0.2, Twelve0.5Impulsive; their own noise).

Columns, per method: SNR (dB) and, when the metrics registry has them, mean face-normal
angular error (deg) and volume change (%). Methods: every filter with an automatic rule
(``meshdenoise.auto.AUTO_METHODS``) with automatic parameters (``auto``) and with the
parameters that are best in hindsight over the same search space (``oracle``);
MeshLab's Laplacian, HC Laplacian (repeated k times), Taubin and two-step smoothing
and Open3D's simple, Laplacian and Taubin filters, each with its number of iterations
tuned on the clean mesh (oracle), the libraries themselves being called one
iteration at a time (all are memoryless from one iteration to the next).

The summary gives, per row, the margin of our best automatic method over the paper's
best (its Table 1) and over the best oracle-tuned MeshLab/Open3D filter, and each
method's auto-vs-oracle loss. Writes quality.md, quality.json and quality.csv to --out.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from meshdenoise import auto  # noqa: E402
from meshdenoise.data import data_file, sample_mesh  # noqa: E402
from meshdenoise.io import atomic_path, load_arrays  # noqa: E402
from meshdenoise.metrics import METRICS, snr  # noqa: E402
from meshdenoise.noise import add_normal_noise  # noqa: E402
from meshdenoise.registry import apply_filter, get_filter  # noqa: E402

PAPER_BEST = {  # Table 1 of the paper: best SNR (dB) over its three methods, and the noisy input's SNR
    ("elephant", 0.015): 39.82,
    ("elephant", 0.2): 26.81,
    ("nefertiti", 0.015): 41.83,
    ("nefertiti", 0.2): 24.17,
    ("nefertiti", 1.0): 14.62,
}
EXTRA_METRICS = [("normal_error", "normal err (deg)"), ("volume_change", "vol change (%)")]
MAX_LIB_ITERS = 300  # cap of the oracle search for MeshLab / Open3D iterations
PATIENCE = 8  # stop a library's oracle search this many iterations after the best SNR


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
        bench = ["Fandisk0.3"]
    for name, (V, F), rho in synth:
        key = (name, rho)
        noisy = [add_normal_noise((V, F), rho, seed=s)[0] for s in range(seeds)]
        label = f"{name} rho={rho:g}" if not name.startswith("bunny") else f"{name} (rho={rho:.4g})"
        rows.append({"row": label, "V": V, "F": F, "noisy": noisy, "paper": PAPER_BEST.get(key)})
    for b in bench:
        Vo, F = load_arrays(data_file(f"benchmark/{b}/Original.obj"))
        Vn, Fn = load_arrays(data_file(f"benchmark/{b}/Noisy.obj"))
        if not np.array_equal(F, Fn):
            raise ValueError(f"benchmark/{b}: Noisy.obj and Original.obj have different faces")
        rows.append({"row": b, "V": Vo, "F": F, "noisy": [Vn], "paper": None})
    return rows


# ----------------------------------------------------------------------------- library filters
def _meshlab_steps(step_kwargs: dict, filter_name: str):
    import pymeshlab

    def run(V, F):
        ms = pymeshlab.MeshSet()
        ms.add_mesh(pymeshlab.Mesh(vertex_matrix=V, face_matrix=F.astype(np.int32)))
        while True:
            getattr(ms, filter_name)(**step_kwargs)
            yield np.array(ms.current_mesh().vertex_matrix(), dtype=np.float64)

    return run


def _open3d_steps(method: str):
    import open3d as o3d

    def run(V, F):
        m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(V), o3d.utility.Vector3iVector(F.astype(np.int32)))
        while True:
            m = getattr(m, method)(1)
            yield np.asarray(m.vertices, dtype=np.float64).copy()

    return run


LIBRARY = {
    "MeshLab Laplacian": _meshlab_steps({"stepsmoothnum": 1, "cotangentweight": False}, "apply_coord_laplacian_smoothing"),
    "MeshLab HC Laplacian": _meshlab_steps({}, "apply_coord_hc_laplacian_smoothing"),
    "MeshLab Taubin": _meshlab_steps({"stepsmoothnum": 1}, "apply_coord_taubin_smoothing"),
    "MeshLab two-step": _meshlab_steps({"stepsmoothnum": 1}, "apply_coord_two_steps_smoothing"),
    "Open3D simple": _open3d_steps("filter_smooth_simple"),
    "Open3D Laplacian": _open3d_steps("filter_smooth_laplacian"),
    "Open3D Taubin": _open3d_steps("filter_smooth_taubin"),
}


def _library_oracle(run, V0, Vn, F) -> tuple[int, np.ndarray]:
    """Best number of iterations by SNR against the clean mesh, one library call per iteration."""
    best_k, best_X, best_s = 0, Vn, snr(V0, Vn)
    for k, X in enumerate(run(Vn, F), start=1):
        s = snr(V0, X)
        if s > best_s:
            best_k, best_X, best_s = k, X, s
        if k - best_k >= PATIENCE or k >= MAX_LIB_ITERS:
            break
    return best_k, best_X


# ----------------------------------------------------------------------------- measuring
def _metrics(V0, X, F) -> dict:
    out = {"snr": snr(V0, X)}
    for name, _ in EXTRA_METRICS:
        if name in METRICS:
            out[name] = float(METRICS[name]((V0, F), (X, F)))
    return out


def _fmt_params(p: dict) -> str:
    return ", ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}" for k, v in p.items())


def run(quick: bool, seeds: int, methods: list[str] | None) -> dict:
    ours = methods or sorted(auto.AUTO_METHODS)
    results = []
    for row in _rows(quick, seeds):
        V0, F = row["V"], row["F"]
        t_row = time.perf_counter()
        per = {}  # method label -> list of metric dicts (one per seed), plus params
        for s_idx, Vn in enumerate(row["noisy"]):
            per.setdefault("noisy", []).append((_metrics(V0, Vn, F), {}))
            rho = auto.estimate_noise((Vn, F))
            for m in ours:
                p_auto = auto.choose_parameters((Vn, F), m, noise=rho)
                X = apply_filter(m, (Vn, F), **p_auto)[0]
                per.setdefault(f"{m} auto", []).append((_metrics(V0, X, F), p_auto))
                p_or = auto.choose_parameters((Vn, F), m, criterion="oracle", reference=V0)
                X = apply_filter(m, (Vn, F), **p_or)[0]
                per.setdefault(f"{m} oracle", []).append((_metrics(V0, X, F), p_or))
            for name, steps in LIBRARY.items():
                k, X = _library_oracle(steps, V0, Vn, F)
                per.setdefault(f"{name} oracle", []).append((_metrics(V0, X, F), {"iterations": k}))
            per.setdefault("_rho", []).append(rho)
        entry = {"row": row["row"], "seeds": len(row["noisy"]), "paper_best": row["paper"], "methods": {}}
        for label, runs in per.items():
            if label == "_rho":
                continue
            keys = runs[0][0].keys()
            entry["methods"][label] = {
                **{f"{k}_mean": float(np.mean([r[0][k] for r in runs])) for k in keys},
                **{f"{k}_std": float(np.std([r[0][k] for r in runs])) for k in keys},
                "params": _fmt_params(runs[0][1]) + (" (seed 0)" if len(runs) > 1 and runs[0][1] else ""),
            }
        true_rho = float(np.sqrt(np.mean(np.sum((row["noisy"][0] - V0) ** 2, axis=1))))
        entry["rho_estimated"] = float(np.mean(per["_rho"]))
        entry["rho_true_rms"] = true_rho
        entry["seconds"] = time.perf_counter() - t_row
        _summarise(entry, ours)
        results.append(entry)
        print(_row_markdown(entry), flush=True)
    return {"rows": results, "methods": ours}


def _summarise(entry: dict, ours: list[str]) -> None:
    M = entry["methods"]
    auto_best = max(ours, key=lambda m: M[f"{m} auto"]["snr_mean"])
    lib_best = max(LIBRARY, key=lambda n: M[f"{n} oracle"]["snr_mean"])
    a = M[f"{auto_best} auto"]["snr_mean"]
    entry["auto_best"] = auto_best
    entry["auto_best_snr"] = a
    entry["library_best"] = lib_best
    entry["margin_vs_library"] = a - M[f"{lib_best} oracle"]["snr_mean"]
    entry["margin_vs_paper"] = None if entry["paper_best"] is None else a - entry["paper_best"]
    entry["auto_loss"] = {m: M[f"{m} oracle"]["snr_mean"] - M[f"{m} auto"]["snr_mean"] for m in ours}


def _row_markdown(entry: dict) -> str:
    lines = [f"\n### {entry['row']}  ({entry['seeds']} seed(s); rho estimated {entry['rho_estimated']:.4g}, "
             f"true rms {entry['rho_true_rms']:.4g}; {entry['seconds']:.0f} s)\n"]
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
    ours = res["methods"]
    lines = ["| row | noisy SNR | best auto (dB) | vs paper | vs best MeshLab/Open3D oracle | worst auto loss |", "|---|---|---|---|---|---|"]
    for e in res["rows"]:
        paper = "n/a" if e["margin_vs_paper"] is None else f"{e['margin_vs_paper']:+.2f}"
        worst = max(ours, key=lambda m: e["auto_loss"][m])
        lines.append(
            f"| {e['row']} | {e['methods']['noisy']['snr_mean']:.2f} | {e['auto_best']} {e['auto_best_snr']:.2f} | {paper} | "
            f"{e['margin_vs_library']:+.2f} ({e['library_best']}) | {e['auto_loss'][worst]:+.2f} ({worst}) |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="1 seed and 5 rows: a fast check")
    ap.add_argument("--seeds", type=int, default=5, help="noise seeds for the rows with our noise (default 5)")
    ap.add_argument("--methods", nargs="*", help="our methods (default: every one with an automatic rule)")
    ap.add_argument("--out", default="benchmark_results/quality", help="output folder")
    args = ap.parse_args(argv)
    if args.seeds < 1:
        raise SystemExit(f"--seeds must be >= 1, got {args.seeds}")
    seeds = 1 if args.quick else args.seeds
    t0 = time.perf_counter()
    res = run(args.quick, seeds, args.methods)
    res["seconds"] = time.perf_counter() - t0
    summary = _summary_table(res)
    print("\n## Summary\n\n" + summary + f"\n\ntotal {res['seconds']:.0f} s")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    md = "# Quality benchmark\n\n" + summary + "\n" + "\n".join(_row_markdown(e) for e in res["rows"]) + f"\n\ntotal {res['seconds']:.0f} s\n"
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

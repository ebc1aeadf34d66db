"""``two_stage``'s automatic parameters against a position-SURE rule and against the oracles.

Per row: the noisy mesh; the position-SURE rule (column "position SURE"; Monte-Carlo SURE on positions over the
outer iterations only, other parameters at their defaults, reimplemented here as
:func:`previous_rule`); the automatic rule (column "auto"; ``choose_parameters(mesh, "two_stage", criterion="normals")``: the least
held-out face-normal loss along the sweeps of ``two_stage.TWO_STAGE_NORMALS``, with the time of the choice); the
generic oracle (``criterion="oracle"``: the same sweeps on the whole mesh, scored by squared position error against
the clean mesh); and the normal-error oracle: the least mean face-normal error over a grid of the guided filter
(``GRID_SIGMA_R`` x ``GRID_NORMAL_ITERATIONS`` x ``GRID_VERTEX_ITERATIONS`` x 1..``GRID_MAX_ITERATIONS`` outer
iterations, ``keep_tangential`` on), with the SNR-best of that grid beside it. Columns: mean face-normal error (deg), SNR (dB), time (s).

Rows: the four pairs of the Guided Mesh Normal Filtering benchmark (``benchmark/*``; noisy and
clean given), pymeshlab's sample bunny with normal noise of 0.5 % of its bounding-box diagonal
and the elephant with rho = 0.015 (seed 0; smooth meshes, where the rule must not do worse
than before).

Run:  PYTHONPATH=. python benchmarks/two_stage_auto.py [--rows NAME ...] [--no-grid [--grid-from OLD.json]] [--out FILE.md]

The grid oracles depend on the filter only (not on the rule): after a change of the rule,
``--no-grid --grid-from benchmarks/results/two-stage-auto.json`` measures the rule and the
position oracle again and copies the grid columns of the earlier run.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

import numpy as np

from meshdenoise import add_normal_noise, apply_filter
from meshdenoise.data import data_dir, data_file, sample_mesh
from meshdenoise.geometry import vertex_normals
from meshdenoise.io import load_arrays
from meshdenoise.metrics import normal_error_deg, snr
from meshdenoise.operators import get_operators
from meshdenoise.plugins import two_stage as ts
from meshdenoise.tuning import choose_parameters, estimate_noise
from meshdenoise.tuning.risk import MC_SURE_STEP
from meshdenoise.tuning.search import sure_smoothed

PAIRS = ("Fandisk0.3", "Block0.4", "Twelve0.5Impulsive", "Bunny0.2")
SMOOTH = ("bunny 0.5%", "elephant rho=0.015")
# the grid oracles' guided filter: sigma_s 1, guided normals, keep_tangential on
GRID_SIGMA_R = (0.2, 0.25, 0.3, 0.35, 0.45)
GRID_NORMAL_ITERATIONS = (5, 10, 20)
GRID_VERTEX_ITERATIONS = (20, 10, 40)
GRID_MAX_ITERATIONS = 8


def load_row(name: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(clean V, noisy V, F) of a row."""
    if name in PAIRS:
        V0, F = load_arrays(data_dir() / "benchmark" / name / "Original.obj")
        Vn, _ = load_arrays(data_dir() / "benchmark" / name / "Noisy.obj")
        return V0, Vn, F
    if name == "bunny 0.5%":
        V0, F = load_arrays(sample_mesh("bunny.obj"))
        rho = 0.005 * float(np.linalg.norm(V0.max(0) - V0.min(0)))
    elif name == "elephant rho=0.015":
        V0, F = load_arrays(data_file("elephant-50kv.off"))
        rho = 0.015
    else:
        raise SystemExit(f"two_stage_auto.py: unknown row {name!r}; rows: {', '.join(PAIRS + SMOOTH)}")
    return V0, add_normal_noise((V0, F), rho, seed=0)[0], F


def previous_rule(V: np.ndarray, F: np.ndarray, rho: float) -> dict:
    """The position-SURE rule: outer iterations by Monte-Carlo SURE on positions, the rest at defaults."""
    n = V.shape[0]
    ops = get_operators(F, n)
    N = vertex_normals(sure_smoothed(V, ops, rho).X, F)
    b = np.random.default_rng(0).choice([-1.0, 1.0], size=n)[:, None] * N
    delta = MC_SURE_STEP * rho
    X, Xp = V, V + delta * b
    best_k, best = 0, float(n) * rho**2
    for k in range(1, GRID_MAX_ITERATIONS + 1):
        X = apply_filter("two_stage", (X, F), iterations=1)[0]
        Xp = apply_filter("two_stage", (Xp, F), iterations=1)[0]
        score = float(np.sum((X - V) ** 2)) - n * rho**2 + 2 * rho**2 * float(np.sum(b * (Xp - X))) / delta
        if score < best:
            best_k, best = k, score
        elif k >= best_k + 2:
            break
    return {"iterations": best_k}


def measure(V0, Vn, F, params) -> dict:
    X = apply_filter("two_stage", (Vn, F), **params)[0]
    return {"ne": normal_error_deg((V0, F), (X, F)), "snr": snr(V0, X), "params": params}


def grid_oracles(V0, Vn, F) -> tuple[dict, dict]:
    """The normal-error-best and the SNR-best candidate of the rule's whole grid."""
    best_ne, best_snr = None, None
    ops = get_operators(F, Vn.shape[0])
    for sr in GRID_SIGMA_R:
        for ni in GRID_NORMAL_ITERATIONS:
            for vi in GRID_VERTEX_ITERATIONS:
                step = {"sigma_r": sr, "normal_iterations": ni, "vertex_iterations": vi, "keep_tangential": True}
                params = {**step, "iterations": GRID_MAX_ITERATIONS, "sigma_s": 1.0, "guidance": "guided"}
                for k, X in enumerate(ts.outer_iterates(Vn, ops, None, **params), start=1):
                    r = {"ne": normal_error_deg((V0, F), (X, F)), "snr": snr(V0, X), "params": {**step, "iterations": k}}
                    if best_ne is None or r["ne"] < best_ne["ne"]:
                        best_ne = r
                    if best_snr is None or r["snr"] > best_snr["snr"]:
                        best_snr = r
    return best_ne, best_snr


def run_row(name: str, grid: bool) -> dict:
    V0, Vn, F = load_row(name)
    rho = estimate_noise((Vn, F))
    out = {"row": name, "n": int(V0.shape[0]), "rho": rho}
    out["noisy"] = {"ne": normal_error_deg((V0, F), (Vn, F)), "snr": snr(V0, Vn)}
    t = time.perf_counter()
    p = previous_rule(Vn, F, rho)
    out["previous"] = {**measure(V0, Vn, F, p), "time": time.perf_counter() - t}
    t = time.perf_counter()
    p = choose_parameters((Vn, F), "two_stage", criterion="normals")
    out["auto"] = {**measure(V0, Vn, F, p), "time": time.perf_counter() - t}
    t = time.perf_counter()
    p = choose_parameters((Vn, F), "two_stage", noise=rho, criterion="oracle", reference=V0)
    out["oracle"] = {**measure(V0, Vn, F, p), "time": time.perf_counter() - t}
    if grid:
        out["grid_ne"], out["grid_snr"] = grid_oracles(V0, Vn, F)
    return out


def fmt_params(p: dict) -> str:
    short = {"sigma_r": "sr", "normal_iterations": "ni", "vertex_iterations": "vi", "iterations": "it", "keep_tangential": "kt"}
    return " ".join(f"{short.get(k, k)}={int(v) if isinstance(v, bool) else v}" for k, v in p.items())


def table(results: list[dict], command: str, load: str) -> str:
    lines = [
        "# two_stage automatic parameters",
        "",
        f"Command: `{command}`  ",
        f"Load average when started: {load} (2 cores, shared). `position SURE`: outer iterations by Monte-Carlo SURE",
        "(rho by `estimate_noise`), the rest at the defaults; `auto`: `choose_parameters(criterion=\"normals\")`, held-out",
        "vertices, time = the choice. Cells: mean face-normal error (deg) / SNR (dB). `ne-best` and `snr-best` are the",
        "best of a grid of the guided filter against the clean mesh (benchmarks/two_stage_auto.py's GRID_*).",
        "",
        "| row | n | noisy | position SURE | auto | auto time (s) | oracle (position, same search) | ne-best of grid | snr-best of grid | auto / ne-best |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        cell = lambda m: f"{m['ne']:.2f} / {m['snr']:.2f}"  # noqa: E731
        g_ne = cell(r["grid_ne"]) if "grid_ne" in r else "n/a"
        g_snr = cell(r["grid_snr"]) if "grid_snr" in r else "n/a"
        ratio = f"{r['auto']['ne'] / r['grid_ne']['ne']:.3f}" if "grid_ne" in r else "n/a"
        lines.append(
            f"| {r['row']} | {r['n']} | {cell(r['noisy'])} | {cell(r['previous'])} | {cell(r['auto'])} | "
            f"{r['auto']['time']:.2f} | {cell(r['oracle'])} | {g_ne} | {g_snr} | {ratio} |"
        )
    lines += ["", "Parameters:", ""]
    for r in results:
        lines.append(f"- {r['row']}: position SURE {fmt_params(r['previous']['params'])}; auto {fmt_params(r['auto']['params'])}; "
                     f"oracle {fmt_params(r['oracle']['params'])}"
                     + (f"; ne-best {fmt_params(r['grid_ne']['params'])}; snr-best {fmt_params(r['grid_snr']['params'])}"
                        if "grid_ne" in r else ""))
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", nargs="*", default=list(PAIRS + SMOOTH))
    ap.add_argument("--no-grid", action="store_true", help="skip the whole-grid oracles (slow on large meshes)")
    ap.add_argument("--out", help="write the markdown table here (and FILE.json)")
    ap.add_argument("--grid-from", metavar="JSON",
                    help="with --no-grid: take the whole-grid oracles (ne-best, snr-best: the filter's, not the rule's) "
                         "from this earlier run's JSON, row by row")
    ap.add_argument("--one", help=argparse.SUPPRESS)  # internal: measure one row in this process, print JSON
    args = ap.parse_args()
    if args.one:
        print(json.dumps(run_row(args.one, not args.no_grid)))
        return
    load = open("/proc/loadavg").read().split()[:3] if os.path.exists("/proc/loadavg") else ["?"]
    results = []
    for name in args.rows:  # one process per row: numba compiled code and caches start the same way
        cmd = [sys.executable, __file__, "--one", name] + (["--no-grid"] if args.no_grid else [])
        res = subprocess.run(cmd, capture_output=True, text=True, check=False)
        if res.returncode != 0:
            raise SystemExit(f"two_stage_auto.py: row {name!r} failed:\n{res.stderr}")
        results.append(json.loads(res.stdout.strip().splitlines()[-1]))
        print(f"{name}: done", file=sys.stderr, flush=True)
    if args.grid_from:
        with open(args.grid_from) as f:
            earlier = {r["row"]: r for r in json.load(f)}
        for r in results:
            if r["row"] in earlier and "grid_ne" in earlier[r["row"]]:
                r["grid_ne"], r["grid_snr"] = earlier[r["row"]]["grid_ne"], earlier[r["row"]]["grid_snr"]
    command = "PYTHONPATH=. python benchmarks/two_stage_auto.py " + " ".join(
        a if " " not in a else repr(a) for a in sys.argv[1:])
    text = table(results, command, " ".join(load))
    print(text)
    if args.out:
        with open(args.out, "w") as f:
            f.write(text)
        with open(os.path.splitext(args.out)[0] + ".json", "w") as f:
            json.dump(results, f, indent=1)


if __name__ == "__main__":
    main()

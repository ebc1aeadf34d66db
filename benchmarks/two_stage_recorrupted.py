"""Recorrupted pairs as ``two_stage``'s criterion, replayed on the rule's region (issue 22).

Per row of ``benchmarks/two_stage_auto.py``: the rule's sampled region and its noise level; every run of
the rule's grid (``TWO_STAGE_SIGMA_R`` x ``TWO_STAGE_NORMAL_ITERATIONS`` x ``TWO_STAGE_VERTEX_ITERATIONS``,
1..``TWO_STAGE_MAX_ITERATIONS`` outer iterations, ``keep_tangential``) is scored

* by the rule's consistency criterion (its synthetic copy: the pilot plus 1.3 rho along the pilot's
  normals, median face-normal angle to the pilot), and
* on recorrupted pairs (:mod:`meshdenoise.tuning.recorrupted`): the run filters ``Y + a Z`` (``Z`` drawn
  along the normals of the SURE-smoothed mesh, as the rule's guard probes are) and is scored against
  ``Y - Z / a``: on face normals ``-sum_f u_f . c_f(Y-) / |c_f(pilot)|`` (an unbiased ranking by the mean
  of ``1 - cos`` at noise ``sqrt(1 + a^2) rho``), on positions ``||f(Y+) - Y-||^2``; beside them the
  region's true mean angle of the same outputs (an oracle at the inflated level).

The rule's staged search (:func:`meshdenoise.plugins.two_stage._staged_search`, the same stages,
patience and revisit span) is then replayed on each score's stored curves, and the point it chooses is
read off the whole-mesh truth (every run of the grid on the whole noisy mesh, mean face-normal error
against the clean mesh). The guard, the lighter runs and the fine run of the rule are not replayed: this
compares the criteria that choose the consistency point.

Run:  PYTHONPATH=. python benchmarks/two_stage_recorrupted.py [--rows ...] [--a 0.5 0.7 1.0] [--draws 3]
      [--truth-from FILE.json] --out benchmarks/results/two-stage-recorrupted.md
      PYTHONPATH=. python benchmarks/two_stage_recorrupted.py --replay benchmarks/results/two-stage-recorrupted.json
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from two_stage_auto import PAIRS, SMOOTH, load_row  # noqa: E402

from meshdenoise.geometry import face_normals, vertex_normals  # noqa: E402
from meshdenoise.metrics import normal_error_deg, snr  # noqa: E402
from meshdenoise.operators import get_operators  # noqa: E402
from meshdenoise.plugins import two_stage as ts  # noqa: E402
from meshdenoise.registry import get_filter  # noqa: E402
from meshdenoise.tuning import estimate_noise  # noqa: E402
from meshdenoise.tuning.recorrupted import cross_normals, normal_score, position_score, recorrupted_scores  # noqa: E402
from meshdenoise.tuning.risk import Point  # noqa: E402
from meshdenoise.tuning.search import sure_smoothed  # noqa: E402

K = ts.TWO_STAGE_MAX_ITERATIONS
SCORES = ("normals", "positions", "oracle")  # the stored scores of one output on a recorrupted pair


def keys() -> list[tuple[float, int, int]]:
    return list(itertools.product(ts.TWO_STAGE_SIGMA_R, ts.TWO_STAGE_NORMAL_ITERATIONS, ts.TWO_STAGE_VERTEX_ITERATIONS))


def key_of(sr: float, ni: int, vi: int) -> str:
    return f"{sr},{ni},{vi}"


def step_of(sr: float, ni: int, vi: int) -> dict:
    return {"sigma_r": sr, "normal_iterations": ni, "vertex_iterations": vi, "keep_tangential": True, "sigma_s": 1.0,
            "guidance": "guided"}


def truth(V0: np.ndarray, Vn: np.ndarray, F: np.ndarray) -> dict:
    """Whole-mesh curves over the grid: key -> [normal errors (deg), SNR (dB)] along 1..K outer iterations."""
    ops = get_operators(F, Vn.shape[0])
    out = {}
    for sr, ni, vi in keys():
        ne, sn = [], []
        for X in ts.outer_iterates(Vn, ops, None, iterations=K, **step_of(sr, ni, vi)):
            ne.append(normal_error_deg((V0, F), (X, F)))
            sn.append(snr(V0, X))
        out[key_of(sr, ni, vi)] = [ne, sn]
    return out


def region_curves(name: str, a_values: list[float], draws: int) -> dict:
    """The consistency criterion's and the recorrupted scores' curves on the rule's region."""
    V0, Vn, F = load_row(name)
    rho = estimate_noise((Vn, F))
    ops_full = get_operators(F, Vn.shape[0])
    region = ts.SampledRegion(F, ops_full, ts.TWO_STAGE_SAMPLE, ts.TWO_STAGE_PATCHES, ts.TWO_STAGE_MARGIN)
    Fr, faces, inner = region.F, region.scored, region.inner
    ops = get_operators(Fr, region.vertices.size)
    Y = np.ascontiguousarray(Vn[region.vertices])
    X0 = np.ascontiguousarray(V0[region.vertices])
    spec = get_filter("two_stage")
    full = spec.resolve({}, where="two_stage_recorrupted")
    pilot = spec.core(Y, Fr, ops=ops, pinned=None, **{**full, **ts.TWO_STAGE_PILOT,
                                                       "iterations": ts.TWO_STAGE_PILOT_ITERATIONS, "keep_tangential": True})
    Np = vertex_normals(pilot, Fr)
    pilot_normals = face_normals(pilot, Fr)[faces]
    synthetic = pilot + ts.synthetic_noise(Np, ts.TWO_STAGE_SYNTHETIC_SCALE * rho)
    N = vertex_normals(sure_smoothed(Vn, ops_full, rho).X, F)[region.vertices]  # the guard's probe directions
    w = 1.0 / np.linalg.norm(cross_normals(pilot, Fr)[faces], axis=1)
    n0 = face_normals(X0, Fr)[faces]
    out = {"row": name, "rho": rho, "n": int(Vn.shape[0]), "region": int(region.vertices.size), "consistency": {},
           "region_truth": {}, "recorrupted": {}}
    for sr, ni, vi in keys():
        out["consistency"][key_of(sr, ni, vi)] = [
            ts.median_angle(X, None, Fr, faces, pilot_normals)
            for X in ts.outer_iterates(synthetic, ops, None, iterations=K, **step_of(sr, ni, vi))]
        out["region_truth"][key_of(sr, ni, vi)] = [  # the best any criterion on this region can do (input Y itself)
            ts.mean_angle(X, None, Fr, faces, n0)
            for X in ts.outer_iterates(Y, ops, None, iterations=K, **step_of(sr, ni, vi))]

    def scores(X: np.ndarray, minus: np.ndarray) -> tuple[float, float, float]:
        u = face_normals(X, Fr)[faces]
        angle = float(np.mean(np.arctan2(np.linalg.norm(np.cross(u, n0), axis=1), np.einsum("ij,ij->i", u, n0))))
        return (normal_score(X, Fr, cross_normals(minus, Fr)[faces], faces, w), position_score(X, minus, inner), angle)

    sampler = lambda rng: rho * rng.standard_normal(Y.shape[0])[:, None] * N  # noqa: E731
    t = time.perf_counter()
    for a in a_values:
        per_key = {}
        for sr, ni, vi in keys():
            run = lambda Yp, s=step_of(sr, ni, vi): ts.outer_iterates(Yp, ops, None, iterations=K, **s)  # noqa: E731
            # one call per draw with its own seed: the same Z for every a (draw d: seed 1000 + d)
            per_key[key_of(sr, ni, vi)] = [recorrupted_scores(run, Y, sampler, scores, a=a, draws=1, seed=1000 + d)[0].tolist()
                                           for d in range(draws)]
        out["recorrupted"][f"{a:g}"] = per_key
    out["seconds_recorrupted"] = time.perf_counter() - t
    return out


def replay(curves: dict) -> tuple[str, int, float, int]:
    """The rule's staged search on stored curves (key -> scores along 1..K): (key, outer iterations, score, runs)."""
    runs = []

    def path(params: dict) -> Point:
        key = key_of(params["sigma_r"], params["normal_iterations"], params["vertex_iterations"])
        runs.append(key)
        c = curves[key]
        best = 0
        for k in range(len(c)):  # the rule's walk: stop TWO_STAGE_PATIENCE iterations after the minimum
            if c[k] < c[best]:
                best = k
            if k >= best + ts.TWO_STAGE_PATIENCE:
                break
        p = Point(best + 1, 0.0, 0.0, np.zeros((0, 3)))
        p.score = float(c[best])
        return p

    chosen, best = ts._staged_search(path, ts._search_grid({}), ts.TWO_STAGE_REVISIT_SPAN)
    key = key_of(chosen["sigma_r"], chosen["normal_iterations"], chosen["vertex_iterations"])
    return key, int(best.value), float(best.score), len(set(runs))


def variants(r: dict) -> dict[str, list[dict]]:
    """Variant name -> the curves replayed (one per draw, then the mean over the draws)."""
    out = {"consistency (the rule's criterion, before its guard)": [r["consistency"]],
           "oracle: the region's true mean angle, input Y (no recorruption)": [r["region_truth"]]}
    names = {"normals": "recorrupted normals", "positions": "recorrupted positions",
             "oracle": "oracle: the region's true mean angle, input Y+"}
    for a, per_key in r["recorrupted"].items():
        for j, s in enumerate(SCORES):
            draws = len(next(iter(per_key.values())))
            per_draw = [{k: [x[j] for x in v[d]] for k, v in per_key.items()} for d in range(draws)]
            mean = {k: list(np.mean([[x[j] for x in v[d]] for d in range(draws)], axis=0)) for k, v in per_key.items()}
            out[f"{names[s]}, a = {a}"] = per_draw + ([mean] if draws > 1 else [])
    a_values = sorted(r["recorrupted"], key=float)
    if len(a_values) >= 2:  # linear in a^2 through the two smallest a: the estimate at a = 0
        a1, a2 = float(a_values[0]), float(a_values[1])
        for j, s in enumerate(SCORES[:2]):
            c = [{k: np.mean([[x[j] for x in d] for d in v], axis=0) for k, v in r["recorrupted"][a].items()}
                 for a in a_values[:2]]
            ex = {k: list(c[0][k] - (c[1][k] - c[0][k]) * a1**2 / (a2**2 - a1**2)) for k in c[0]}
            out[f"{names[s]}, extrapolated to a = 0 from a = {a_values[0]}, {a_values[1]} (mean of the draws)"] = [ex]
    return out


def table(results: list[dict], truths: dict, command: str, load: str) -> str:
    rows = [r["row"] for r in results]
    lines = ["# two_stage's criterion on recorrupted pairs (issue 22)", "", f"Command: `{command}`  ",
             f"Load average when started: {load} (2 cores, shared).", "",
             "Cells: the mean face-normal error (deg, whole mesh, against the clean mesh) of the point the rule's staged "
             "search chooses on each score's curves; per draw, then (bold) on the mean of the draws' curves. The "
             "rule's guard, lighter and fine runs are not replayed.", ""]
    best = {name: min(min(v[0]) for v in t.values()) for name, t in truths.items()}
    lines.append("| variant | " + " | ".join(f"{r} (grid's best {best[r]:.2f})" for r in rows) + " |")
    lines.append("|---|" + "---|" * len(rows))
    per_row = {r["row"]: variants(r) for r in results}
    for v in per_row[rows[0]]:
        cells = []
        for r in rows:
            curves = per_row[r].get(v, [])
            got = []
            for c in curves:
                key, k, _, _ = replay(c)
                got.append(truths[r][key][0][k - 1])
            if not got:
                cells.append("")
            elif len(got) == 1:
                cells.append(f"**{got[0]:.2f}**")
            else:
                cells.append(" / ".join(f"{g:.2f}" for g in got[:-1]) + f" (**{got[-1]:.2f}**)")
        lines.append(f"| {v} | " + " | ".join(cells) + " |")
    lines += ["", "Choices (mean of the draws; key = sigma_r, normal passes, vertex steps; k = outer iterations):", ""]
    for r in rows:
        for v, curves in per_row[r].items():
            key, k, score, runs = replay(curves[-1])
            lines.append(f"- {r}, {v}: {key} k={k} -> {truths[r][key][0][k - 1]:.3f} deg / {truths[r][key][1][k - 1]:.2f} dB "
                         f"({runs} runs)")
    lines += ["", "Seconds of the recorrupted runs per row (all a, all draws, the whole grid): "
              + ", ".join(f"{r['row']} {r['seconds_recorrupted']:.1f}" for r in results)]
    return "\n".join(lines) + "\n"


def rounded(x):
    """``x`` with every float to 9 significant digits (the stored curves; ties between candidates are far above it)."""
    if isinstance(x, float):
        return float(f"{x:.9g}")
    if isinstance(x, dict):
        return {k: rounded(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [rounded(v) for v in x]
    return x


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", nargs="*", default=list(PAIRS + SMOOTH))
    ap.add_argument("--a", nargs="*", type=float, default=[0.5, 0.7, 1.0])
    ap.add_argument("--draws", type=int, default=3)
    ap.add_argument("--truth-from", metavar="JSON", help="the whole-mesh truth curves of an earlier run (they depend on the filter only)")
    ap.add_argument("--replay", metavar="JSON", help="no runs: the table again from this earlier run's stored curves")
    ap.add_argument("--out", help="markdown table here, curves in FILE.json")
    args = ap.parse_args()
    load = " ".join(open("/proc/loadavg").read().split()[:3]) if os.path.exists("/proc/loadavg") else "?"
    if args.replay:
        with open(args.replay) as f:
            stored = json.load(f)
        print(table(stored["results"], stored["truth"], f"(replayed from {args.replay})", load), end="")
        return
    if not args.out:
        ap.error("--out is required unless --replay is given")
    earlier = {}
    if args.truth_from:
        with open(args.truth_from) as f:
            earlier = json.load(f)["truth"]
    results, truths = [], {}
    for name in args.rows:
        results.append(region_curves(name, args.a, args.draws))
        if name in earlier:
            truths[name] = earlier[name]
        else:
            V0, Vn, F = load_row(name)
            truths[name] = truth(V0, Vn, F)
        print(f"{name}: done", file=sys.stderr, flush=True)
    command = "PYTHONPATH=. python benchmarks/two_stage_recorrupted.py " + " ".join(
        a if " " not in a else repr(a) for a in sys.argv[1:])
    text = table(results, truths, command, load)
    print(text)
    with open(args.out, "w") as f:
        f.write(text)
    with open(os.path.splitext(args.out)[0] + ".json", "w") as f:
        json.dump(rounded({"results": results, "truth": truths}), f)


if __name__ == "__main__":
    main()

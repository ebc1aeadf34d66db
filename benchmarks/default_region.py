"""The default's estimates on a sampled region against the whole mesh and the truth, at scan size (issues 17 and 22).

From ``meshdenoise.default.REGION_FROM`` vertices :func:`meshdenoise.default.choose_default`
runs three estimates on a :class:`meshdenoise.default.RiskRegion` instead of the whole mesh: the
feature test's pre-smoothing, the candidates' Monte-Carlo SURE (``feature_risk``) and the smooth
prior's post-step (``choose_post_step``). This script measures, on ``benchmarks/scale.py``'s
subdivided elephants (noise 0.5 mean edge length along the normals, cached by that script):

- the feature test: shares of sharp and creased edges, whole mesh and region, and seconds;
- the candidates: each one's estimated risk (rms in mean edge lengths) on the whole mesh
  (``feature_risk`` for ``two_stage``, the rule's SURE for the smooth prior, as below
  ``REGION_FROM``) and on the region (both by ``feature_risk`` on its scored vertices), the
  pick of each, and each candidate's true normal error and SNR against the clean mesh;
- the post-step: the truth (normal error, SNR) of all nine candidates, the choice on a region
  for several ball counts, and (``--whole``) on the whole mesh, with seconds.

Usage::

    python benchmarks/default_region.py --sizes 400k --whole --out benchmarks/results/default-region
    python benchmarks/default_region.py --sizes 1.6M --out benchmarks/results/default-region-1.6M

The load average is printed: seconds are comparable within a run only.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import meshdenoise as md  # noqa: E402
from meshdenoise import default  # noqa: E402
from meshdenoise.geometry import vertex_normals  # noqa: E402
from meshdenoise.operators import get_operators  # noqa: E402
from meshdenoise.registry import get_filter  # noqa: E402
from meshdenoise.tuning.covariance import NoiseModel  # noqa: E402
from meshdenoise.tuning.noise_level import mean_edge_length  # noqa: E402

SIZES = {"100k": 1, "400k": 2, "1.6M": 3}


def load(label: str, cache: Path):
    path = cache / f"elephant-o3dloop{SIZES[label]}.npz"
    if not path.exists():
        raise SystemExit(f"default_region: {path} is missing: run benchmarks/scale.py --sizes {label} first (it makes it)")
    d = np.load(path)
    return d["V"], d["F"], d["Vn"], float(d["rho"])


def timed(f):
    t = time.perf_counter()
    out = f()
    return out, time.perf_counter() - t


def run(label: str, cache: Path, whole: bool, patches: list[int]) -> list[str]:
    V0, F, Vn, rho = load(label, cache)
    n = len(Vn)
    ops = get_operators(F, n)
    h = mean_edge_length(Vn, ops)
    model = NoiseModel(rho)
    rms = lambda r: math.sqrt(max(r, 0.0) / n) / h  # noqa: E731
    truth = lambda X: (md.normal_error_deg((V0, F), (X, F)), md.snr(V0, X))  # noqa: E731
    lines = [f"## {label} ({n:,} vertices, rho {rho / h:.3g} mean edge lengths; load {os.getloadavg()[0]:.1f} at the start)", ""]

    # the feature test
    lines += ["| feature test | sharp share | sharp fraction | verdict | s |", "|---|---|---|---|---|"]
    saved = default.REGION_FROM
    for name, cap in (("whole mesh", 10**12), ("region", saved)):
        default.REGION_FROM = cap
        test, s = timed(lambda: default._feature_test(Vn, F, ops))
        verdict = "too noisy" if test.too_noisy else ("sharp" if test.sharp else "no sharp features")
        lines.append(f"| {name} | {test.share:.3f} | {test.sharp_fraction:.5f} | {verdict} | {s:.1f} |")
    default.REGION_FROM = saved
    lines.append("")

    # the candidates
    scored = {m: list(md.choose_parameters((Vn, F), m, noise=model, return_risk=True))
              for m in (default.FEATURE_METHOD, default.SMOOTH_METHOD)}
    results = {m: np.asarray(md.apply_filter(m, (Vn, F), **p)[0]) for m, (p, _) in scored.items()}
    lines += ["| candidate | parameters | true normal error (deg) | true SNR (dB) | risk, whole mesh (h rms) | "
              "risk, region (h rms) |", "|---|---|---|---|---|---|"]
    whole_risk, region_risk, seconds = {}, {}, {}
    normals = vertex_normals(results[default.SMOOTH_METHOD], F)
    (whole_risk[default.FEATURE_METHOD], _), seconds["whole"] = timed(lambda: default.feature_risk(
        Vn, F, scored[default.FEATURE_METHOD][0], model, normals, ops=ops))
    whole_risk[default.SMOOTH_METHOD] = scored[default.SMOOTH_METHOD][1]

    def on_region():
        region = default.RiskRegion.cut(Vn, F, ops, default.risk_margin(scored[default.SMOOTH_METHOD][0]["mu"]))
        smooth = np.asarray(get_filter(default.SMOOTH_METHOD).public((region.V, region.F), operators=region.ops,
                                                                    **scored[default.SMOOTH_METHOD][0])[0])
        N = vertex_normals(smooth, region.F)
        return {m: region.scale * default.feature_risk(region.V, region.F, scored[m][0], model, N, ops=region.ops,
                                                       method=m, rows=region.rows)[0] for m in scored}, region

    (region_risk, region), seconds["region"] = timed(on_region)
    for m, (p, _) in scored.items():
        err, snr = truth(results[m])
        said = ", ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}" for k, v in p.items())
        lines.append(f"| {m} | {said} | {err:.3f} | {snr:.2f} | {rms(whole_risk[m]):.4f} | {rms(region_risk[m]):.4f} |")
    pick = lambda risk: min(risk, key=risk.get)  # noqa: E731
    best = min(scored, key=lambda m: truth(results[m])[0])
    lines += ["", f"Pick: whole mesh {pick(whole_risk)} ({seconds['whole']:.1f} s for two_stage's Monte-Carlo SURE), "
                  f"region {pick(region_risk)} ({seconds['region']:.1f} s for both, {int(region.rows.sum()):,} scored "
                  f"of {region.V.shape[0]:,} region vertices, margin {default.risk_margin(scored[default.SMOOTH_METHOD][0]['mu'])} "
                  f"rings); the smaller true normal error: {best}.", ""]
    del results

    # the post-step
    params = scored[default.SMOOTH_METHOD][0]
    real = {}
    for c in default.POST_SCALES:
        X = md.apply_filter(default.SMOOTH_METHOD, (Vn, F), mu=params["mu"] * c)
        for k in default.POST_STEPS:
            Y = md.apply_filter("taubin", X, iterations=k, **default.POST_TAUBIN) if k else X
            real[c, k] = truth(np.asarray(Y[0]))
    chosen = {}
    for b in patches:
        default.RISK_PATCHES = b
        post, s = timed(lambda: default.choose_post_step(Vn, F, default.SMOOTH_METHOD, params, model, ops=ops))
        chosen[f"region, {b} balls"] = (post, s)
    if whole:
        default.REGION_FROM = 10**12
        chosen["whole mesh"] = timed(lambda: default.choose_post_step(Vn, F, default.SMOOTH_METHOD, params, model, ops=ops))
        default.REGION_FROM = saved
    snr0 = real[1.0, 0][1]
    lines += [f"Post-step after {default.SMOOTH_METHOD} (mu = {params['mu']:.4g}): each candidate's truth, and the "
              "choices (the estimated SNR loss against mu as chosen, dB, two standard errors up; * chosen)", "",
              "| mu x | Taubin steps | true normal error (deg) | true SNR (dB) | true loss (dB) | "
              + " | ".join(f"{k}: est. loss" for k in chosen) + " |",
              "|---|---|---|---|---|" + "---|" * len(chosen)]
    for (c, k), (err, snr) in real.items():
        cells = []
        for post, _ in chosen.values():
            cand = {(p.scale, p.steps): p for p in post.candidates}.get((c, k))
            mark = "*" if (post.scale, post.steps) == (c, k) else ""
            cells.append(f"{cand.loss_db:.2f}{mark}" if cand else mark or "-")
        lines.append(f"| {c:g} | {k} | {err:.3f} | {snr:.2f} | {snr0 - snr:.2f} | " + " | ".join(cells) + " |")
    allowed = {ck: v for ck, v in real.items() if snr0 - v[1] < default.POST_MAX_LOSS_DB}
    oracle = min(allowed, key=lambda ck: allowed[ck][0])
    lines += ["", "Seconds: " + ", ".join(f"{k} {s:.1f}" for k, (_, s) in chosen.items())
              + f"; the best true normal error losing under {default.POST_MAX_LOSS_DB:g} dB: mu x {oracle[0]:g}, "
              f"{oracle[1]} steps.", ""]
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="400k")
    ap.add_argument("--whole", action="store_true", help="also choose the post-step on the whole mesh (slow)")
    ap.add_argument("--patches", default="8,12,24", help="ball counts of the post-step's region")
    ap.add_argument("--cache-dir", default=str(Path.home() / ".cache" / "meshdenoise" / "scale"))
    ap.add_argument("--out", default=None, help="write OUT.md too")
    a = ap.parse_args()
    lines = ["# The default's estimates on a sampled region (benchmarks/default_region.py)", "",
             f"`python benchmarks/default_region.py {' '.join(sys.argv[1:])}`", ""]
    for label in a.sizes.split(","):
        lines += run(label, Path(a.cache_dir), a.whole, [int(b) for b in a.patches.split(",")])
        print("\n".join(lines), flush=True)
    if a.out:
        out = Path(a.out if a.out.endswith(".md") else a.out + ".md")  # "-1.6M" is no suffix to replace
        tmp = out.with_name(out.name + ".tmp")
        tmp.write_text("\n".join(lines) + "\n")
        tmp.replace(out)


if __name__ == "__main__":
    main()

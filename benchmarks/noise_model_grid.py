"""The noise-model estimate against the truth, and what the default does to clean meshes, before and after the detail fit.

Usage::

    python benchmarks/noise_model_grid.py [--part grid default effect] [--meshes icosphere elephant bunny Bunny0.2 Fandisk0.3 face]
                                          [--sigmas 0.1 0.25 0.5 1] [--lengths 0 1 2 3 4] [--seed 1] [--no-as-is]
                                          [--effect-lengths 0 1] [--no-peers]
                                          [--out benchmarks/results/noise-model-grid.md]

**grid**: every mesh clean (sigma 0) and with :func:`meshdenoise.add_scanner_noise` along the
normals, ``sigma`` mean edge lengths (h), correlation length ``l`` (h), one seed; also, as they
are, the clean meshes Block0.4/Original and pymeshlab's bunny10k_textured, and the real range
scan face000. Meshes: icosphere(5) (no detail), the paper's elephant, pymeshlab's bunny.obj, the
benchmark's Bunny0.2/Original and Fandisk0.3/Original, and face000 smoothed
(``sobolev_bilaplacian`` mu = 30, boundary pinned; ``benchmarks/correlated.py``). Columns: the
band-only estimate (:func:`estimate_noise_model`, what the default used before the detail fit),
the detail fit on the whole mesh (:func:`meshdenoise.tuning.detail.separate_detail`: its verdict
and its own model, and its correlation test: the best misfit with independent noise, the best
overall, the answer), and the default's model, measured (:func:`meshdenoise.default.default_noise`
itself, with its verdict), each as rho/h at l, and rho / sigma.

**default**: ``meshdenoise.denoise(mesh)`` (the default) on the clean meshes, on face000 and on
four noisy rows, once with the noise model of before (``meshdenoise.default.default_noise``
replaced by the band-only estimate) and once as it is (the policy). Columns: mean face-normal
change from the input (deg), rms move (h), whether the not-smoothing warning was raised, and on
noisy rows the mean normal error against the clean mesh (deg) of the input and of both outputs.

**effect**: ``meshdenoise.denoise(mesh)`` against the clean mesh (mean normal error, SNR) on
``--meshes`` x ``--sigmas`` x ``--effect-lengths`` and the peers/quality benchmarks'
independent-noise meshes (:data:`PEER_ROWS`, unless ``--no-peers``), before (the default's noise
step keeping every reading of independent noise: :func:`old_default_noise`) and now (the detail
fit's correlation test, :func:`meshdenoise.default.noise_policy`); the seconds of both noise steps
and of the choice. Where both noise models are the same the (deterministic) result is computed once.

**test-sample**: the detail fit's correlation test where the default asks it (the fine bands read
independent noise after their own fit reached ``ELL_MIN``), with its probes read on a sampled region
of each of ``--test-samples`` vertices (``separate_detail(..., sample=)``; the default's is
``FIT_SAMPLE``), on every cell of the grid (``--meshes`` x ``--sigmas`` x ``--lengths``, clean,
and the meshes as they are), the peers/quality rows (:data:`PEER_ROWS`) and the correlated
table's rows (``benchmarks/correlated.py``: sigma 0.3 h, l 0, 1, 2, 4, seed 0, elephant, bunny,
face): the test's answer, the verdict, the misfits, the model the policy then takes, and the
process CPU seconds of the fit. Cells where the test is not asked are counted, not listed.
"""

from __future__ import annotations

import argparse
import datetime
import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from correlated import face_clean  # noqa: E402
from tables import write_table  # noqa: E402

import meshdenoise.default as default  # noqa: E402
from meshdenoise.data import data_file, sample_mesh  # noqa: E402
from meshdenoise.io import load_arrays  # noqa: E402
from meshdenoise.metrics import normal_error_deg, snr  # noqa: E402
from meshdenoise.noise import add_normal_noise, add_scanner_noise, mean_edge_length  # noqa: E402
from meshdenoise.shapes import icosphere  # noqa: E402
from meshdenoise.tuning.covariance import estimate_noise_model  # noqa: E402
from meshdenoise.tuning.detail import separate_detail  # noqa: E402

GRID_MESHES = ["icosphere", "elephant", "bunny", "Bunny0.2", "Fandisk0.3", "face"]
AS_IS = ["Block0.4", "bunny10k", "face000"]  # taken as they are (no added noise)
NOISY_DEFAULT_ROWS = [("elephant", 0.25, 3.0), ("face", 0.25, 3.0), ("bunny", 0.25, 3.0), ("elephant", 0.5, 2.0)]


def face_raw() -> tuple[np.ndarray, np.ndarray]:
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.load_new_mesh(str(sample_mesh("rangemaps/face000.ply")))
    ms.meshing_remove_unreferenced_vertices()
    m = ms.current_mesh()
    return m.vertex_matrix().astype(np.float64), m.face_matrix().astype(np.int64)


def load(name: str) -> tuple[np.ndarray, np.ndarray]:
    if name == "icosphere":
        return icosphere(5)
    if name == "elephant":
        return load_arrays(data_file("elephant-50kv.off"))
    if name == "bunny":
        return load_arrays(sample_mesh("bunny.obj"))
    if name == "bunny10k":
        return load_arrays(sample_mesh("bunny10k_textured.obj"))
    if name == "face":
        return face_clean()
    if name == "face000":
        return face_raw()
    if name in ("Bunny0.2", "Fandisk0.3", "Block0.4"):
        return load_arrays(data_file(f"benchmark/{name}/Original.obj"))
    raise SystemExit(f"--meshes: unknown mesh {name!r}")


def noisy(V0: np.ndarray, F: np.ndarray, sigma: float, ell: float, seed: int) -> np.ndarray:
    if sigma == 0:
        return V0
    h = mean_edge_length(V0, F)
    return add_scanner_noise((V0, F), sigma * h, correlation_length=ell, seed=seed)[0]


def estimate_row(name: str, V: np.ndarray, F: np.ndarray, sigma: float | None, ell: float | None) -> dict:
    h = mean_edge_length(V, F)
    t = time.perf_counter()
    band = estimate_noise_model((V, F))
    t_band = time.perf_counter() - t
    t = time.perf_counter()
    v = separate_detail((V, F))
    t_detail = time.perf_counter() - t
    t = time.perf_counter()
    policy, _, _, decided, _ = default.default_noise(V, F, h)  # the default's own noise step, measured
    t_policy = time.perf_counter() - t
    return {"mesh": name, "n": V.shape[0], "sigma": sigma, "ell": ell,
            "band_rho": band.rho / h, "band_ell": band.correlation_length,
            "verdict": v.verdict, "rho": v.model.rho / h, "rho_ell": v.model.correlation_length,
            "correlated": v.correlated, "misfit": v.misfit, "misfit_white": v.misfit_white,
            "low": v.rho_range[0] / h, "high": v.rho_range[1] / h, "joint": v.rho_joint / h, "joint_ell": v.ell_joint,
            "t_band": t_band, "t_detail": t_detail, "t_policy": t_policy, "decided": decided,
            "policy": policy.rho / h, "policy_ell": policy.correlation_length}


def ratio(rho: float, sigma: float | None) -> str:
    return "" if not sigma else f"{rho / sigma:.2f}"


def grid_table(rows: list[dict]) -> list[str]:
    out = ["| mesh | sigma/h | l | band only: rho/h @ l | ratio | detail fit: verdict | rho/h @ l | ratio | allowed rho/h | "
           "best joint rho/h @ l | misfit: independent, best (test) | default (policy): verdict, rho/h @ l | ratio | "
           "s (band, detail, default's noise step) |",
           "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        sig = "as is" if r["sigma"] is None else f"{r['sigma']:g}"
        ell = "" if r["ell"] is None else f"{r['ell']:g}"
        out.append(f"| {r['mesh']} | {sig} | {ell} | {r['band_rho']:.3f} @ {r['band_ell']:.2f} | "
                   f"{ratio(r['band_rho'], r['sigma'])} | {r['verdict']} | {r['rho']:.3f} @ {r['rho_ell']:.2f} | "
                   f"{ratio(r['rho'], r['sigma'])} | {r['low']:.3f} to {r['high']:.3f} | "
                   f"{r['joint']:.3f} @ {r['joint_ell']:.1f} | {r['misfit_white']:.3f}, {r['misfit']:.3f} "
                   f"({'correlated' if r['correlated'] else 'no'}) | {r['decided']}, "
                   f"{r['policy']:.3f} @ {r['policy_ell']:.2f} | "
                   f"{ratio(r['policy'], r['sigma'])} | {r['t_band']:.1f}, {r['t_detail']:.1f}, {r['t_policy']:.1f} |")
    return out


def run_default(V: np.ndarray, F: np.ndarray, patched: bool) -> tuple[np.ndarray, object, bool]:
    """``denoise(mesh)``: as it is (the policy), or with ``patched`` the band-only estimate (the default before)."""
    original = default.default_noise

    def band_only(V, F, h):  # the default before the detail fit: estimate_noise_model's reading alone
        model, info = estimate_noise_model((V, F), details=True)
        return model, "the noise is " + info["reason"], [], "", (float("nan"), float("nan"))

    if patched:
        default.default_noise = band_only
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            (Vd, _), choice = default.denoise((V.copy(), F), return_params=True)
        warned = any("not smoothing" in str(w.message) for w in caught)
    finally:
        default.default_noise = original
    return Vd, choice, warned


def default_rows(meshes: dict, seed: int) -> list[dict]:
    cases = [(name, 0.0, 0.0) for name in ("icosphere", "elephant", "bunny", "Bunny0.2", "Fandisk0.3", "Block0.4",
                                            "bunny10k")]
    cases += [("face000", None, None)] + NOISY_DEFAULT_ROWS
    rows = []
    for name, sigma, ell in cases:
        if name not in meshes:
            meshes[name] = load(name)
        V0, F = meshes[name]
        V = noisy(V0, F, sigma or 0.0, ell or 0.0, seed)
        h = mean_edge_length(V, F)
        row = {"mesh": name, "sigma": sigma, "ell": ell}
        if sigma:
            row["input_err"] = normal_error_deg((V0, F), (V, F))
        for tag, patched in (("today", True), ("detail", False)):
            t = time.perf_counter()
            Vd, choice, warned = run_default(V, F, patched)
            row[tag] = {"change": normal_error_deg((V, F), (Vd, F)),
                        "move": float(np.sqrt(np.mean(np.sum((Vd - V) ** 2, axis=1)))) / h,
                        "warned": warned, "method": choice.method, "noise": choice.noise_in_edges,
                        "verdict": choice.verdict,
                        "ell": choice.correlation_length, "seconds": time.perf_counter() - t,
                        "err": normal_error_deg((V0, F), (Vd, F)) if sigma else None}
        rows.append(row)
        print(default_table([row])[-1], flush=True)
    return rows


def default_table(rows: list[dict]) -> list[str]:
    out = ["| mesh | sigma/h @ l | input error (deg) | before: noise/h @ l, method | change (deg) | move (h) | warned | "
           "error (deg) | default (policy): verdict, noise/h @ l, method | change (deg) | move (h) | warned | error (deg) | "
           "s (before, default) |",
           "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        what = "as is" if not r["sigma"] else f"{r['sigma']:g} @ {r['ell']:g}"
        cells = [r["mesh"], what, f"{r['input_err']:.2f}" if r.get("input_err") is not None else ""]
        for tag in ("today", "detail"):
            d = r[tag]
            said = f"{d['verdict']}, " if tag == "detail" else ""
            cells += [f"{said}{d['noise']:.3f} @ {d['ell']:.2f}, {d['method']}", f"{d['change']:.2f}", f"{d['move']:.3f}",
                      "yes" if d["warned"] else "no", f"{d['err']:.2f}" if d["err"] is not None else ""]
        cells.append(f"{r['today']['seconds']:.0f}, {r['detail']['seconds']:.0f}")
        out.append("| " + " | ".join(cells) + " |")
    return out


PEER_ROWS = ["Bunny0.2/Noisy", "Fandisk0.3/Noisy", "Block0.4/Noisy", "elephant rho=0.2", "nefertiti rho=0.2"]


def peer_pair(name: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The peers/quality benchmarks' independent-noise rows: (clean V, noisy V, F)."""
    if name.endswith("/Noisy"):
        bench = name.split("/")[0]
        V0, F = load_arrays(data_file(f"benchmark/{bench}/Original.obj"))
        V, F2 = load_arrays(data_file(f"benchmark/{bench}/Noisy.obj"))
        if not np.array_equal(F, F2):
            raise SystemExit(f"{name}: the noisy mesh's faces are not the original's")
        return V0, V, F
    mesh, rho = name.split(" rho=")
    V0, F = load_arrays(data_file("elephant-50kv.off" if mesh == "elephant" else "nefertiti.off"))
    return V0, add_normal_noise((V0, F), float(rho), seed=0)[0], F  # the quality table's rows (seed 0)


def old_default_noise(V: np.ndarray, F: np.ndarray, h: float):
    """The default's noise step before the detail fit's correlation test: a reading of independent noise is kept."""
    band, info = estimate_noise_model((V, F), details=True, spectrum=(default.DETAIL_BANDS, default.DETAIL_LENGTHS))
    if not band.correlated:
        return band, "the noise is " + info["reason"], [], "independent", (float("nan"), float("nan"))
    verdict = separate_detail((V, F), smooth=info["smooth"], rho_white=info["rho_white"], spectrum=info.get("spectrum"))
    model, reason, caveats = default.noise_policy(band, verdict, h, info.get("reason", ""))
    return model, reason, caveats, verdict.verdict, verdict.rho_range


def effect_rows(meshes: dict, names: list[str], sigmas: list[float], lengths: list[float], seed: int,
                peers: bool) -> list[dict]:
    """The default before (``old_default_noise``) and with the detail fit's correlation test, against the clean mesh."""
    cases = [(name, s, l) for name in names for s in sigmas for l in lengths] + (
        [(p, None, None) for p in PEER_ROWS] if peers else [])
    rows = []
    for name, sigma, ell in cases:
        if sigma is None:
            V0, V, F = peer_pair(name)
        else:
            if name not in meshes:
                meshes[name] = load(name)
            V0, F = meshes[name]
            V = noisy(V0, F, sigma, ell, seed)
        h = mean_edge_length(V, F)
        row = {"mesh": name, "n": V.shape[0], "sigma": sigma, "ell": ell, "input_err": normal_error_deg((V0, F), (V, F)),
               "input_snr": snr(V0, V)}
        models = {}
        for tag, fn in (("before", old_default_noise), ("after", default.default_noise)):
            t = time.perf_counter()
            model, _, _, decided, _ = fn(V, F, h)
            models[tag] = model
            row[tag] = {"noise_s": time.perf_counter() - t, "rho": model.rho / h, "ell": model.correlation_length,
                        "decided": decided}
        same = (models["before"].rho == models["after"].rho
                and models["before"].correlation_length == models["after"].correlation_length)
        original = default.default_noise
        for tag, fn in (("after", None), ("before", old_default_noise)):
            if tag == "before" and same:  # the same model, the same (deterministic) result
                row["before"].update({k: row["after"][k] for k in ("err", "snr", "method", "choice_s")})
                continue
            if fn is not None:
                default.default_noise = fn
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    (Vd, _), choice = default.denoise((V.copy(), F), return_params=True)
            finally:
                default.default_noise = original
            row[tag].update({"err": normal_error_deg((V0, F), (Vd, F)), "snr": snr(V0, Vd), "method": choice.method,
                             "choice_s": choice.seconds})
        row["same"] = same
        rows.append(row)
        print(effect_table([row])[-1], flush=True)
    return rows


def effect_table(rows: list[dict]) -> list[str]:
    out = ["| mesh | vertices | sigma/h @ l | input: error (deg), SNR (dB) | before: noise/h @ l | error | SNR | "
           "after: verdict, noise/h @ l | error | SNR | method (before, after) | noise step s (before, after) | "
           "choice s (after) |",
           "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        what = "own noise" if r["sigma"] is None else f"{r['sigma']:g} @ {r['ell']:g}"
        b, a = r["before"], r["after"]
        out.append(f"| {r['mesh']} | {r['n']:,} | {what} | {r['input_err']:.2f}, {r['input_snr']:.2f} | "
                   f"{b['rho']:.3f} @ {b['ell']:.2f} | {b['err']:.2f} | {b['snr']:.2f} | "
                   f"{a['decided']}, {a['rho']:.3f} @ {a['ell']:.2f}{' (same)' if r['same'] else ''} | {a['err']:.2f} | "
                   f"{a['snr']:.2f} | {b['method']}, {a['method']} | {b['noise_s']:.1f}, {a['noise_s']:.1f} | "
                   f"{a['choice_s']:.1f} |")
    return out


CORRELATED_ROWS = [(name, 0.3, ell) for name in ("elephant", "bunny", "face") for ell in (0.0, 1.0, 2.0, 4.0)]


def test_sample_rows(meshes: dict, names: list[str], sigmas: list[float], lengths: list[float], seed: int,
                     samples: list[int], as_is: bool, peers: bool) -> tuple[list[dict], int]:
    """The correlation test with its probes on regions of each size in ``samples``, where the default asks it."""
    from meshdenoise.tuning.covariance import ELL_MIN as BAND_ELL_MIN

    cases = [(name, s, l, seed) for name in names for s, l in [(0.0, 0.0)] + [(s, l) for s in sigmas for l in lengths]]
    cases += [] if not as_is else [(name, None, None, None) for name in AS_IS]
    cases += [] if not peers else [(p, None, None, "peer") for p in PEER_ROWS]
    cases += [(name, s, l, 0) for name, s, l in CORRELATED_ROWS]
    rows, skipped = [], 0
    for name, sigma, ell, how in cases:
        if how == "peer":
            _, V, F = peer_pair(name)
        else:
            if name not in meshes:
                meshes[name] = load(name)
            V, F = meshes[name]
            if sigma is not None:
                V = noisy(V, F, sigma, ell, how)
        h = mean_edge_length(V, F)
        band, info = estimate_noise_model((V, F), details=True, spectrum=(default.DETAIL_BANDS, default.DETAIL_LENGTHS))
        if band.correlated or float(info.get("ell_fit", 0.0)) < BAND_ELL_MIN:
            skipped += 1
            continue
        row = {"mesh": name, "n": V.shape[0], "sigma": sigma, "ell": ell, "seed": how, "band": band.rho / h,
               "ell_fit": float(info["ell_fit"]), "runs": []}
        for size in samples:
            t = time.process_time()
            v = separate_detail((V, F), smooth=info["smooth"], rho_white=info["rho_white"], sample=int(size))
            cpu = time.process_time() - t
            model, _, _ = default.noise_policy(band, v, h, info.get("reason", ""))
            row["runs"].append({"sample": int(size), "cpu": cpu, "correlated": v.correlated, "verdict": v.verdict,
                                "misfit": v.misfit, "misfit_white": v.misfit_white, "ell_joint": v.ell_joint,
                                "taken": model is not band, "rho": model.rho / h, "model_ell": model.correlation_length})
        rows.append(row)
        print(test_sample_table([row])[-1], flush=True)
    return rows, skipped


def test_sample_table(rows: list[dict]) -> list[str]:
    sizes = [r["sample"] for r in rows[0]["runs"]] if rows else []
    head = "| mesh | vertices | sigma/h @ l (seed) | fine bands: rho/h (fit's l) | " + " | ".join(
        f"sample {s:,}: test (ratio, gain, l), verdict -> model rho/h @ l | CPU s" for s in sizes) + " | same decision |"
    out = [head, "|" + "---|" * (5 + 2 * len(sizes))]
    for r in rows:
        what = ("as is" if r["seed"] is None else "own noise") if r["sigma"] is None else (
            f"{r['sigma']:g} @ {r['ell']:g} ({r['seed']})")
        cells = [r["mesh"], f"{r['n']:,}", what, f"{r['band']:.3f} ({r['ell_fit']:.2f})"]
        for u in r["runs"]:
            ratio_ = u["misfit_white"] / u["misfit"] if u["misfit"] > 0 else float("inf")
            cells += [f"{'correlated' if u['correlated'] else 'no'} ({ratio_:.2f}, {u['misfit_white'] - u['misfit']:.3f}, "
                      f"{u['ell_joint']:.1f}), {u['verdict']} -> "
                      f"{'taken ' if u['taken'] else 'kept '}{u['rho']:.3f} @ {u['model_ell']:.2f}", f"{u['cpu']:.2f}"]
        first = r["runs"][0]
        same = all(u["taken"] == first["taken"] for u in r["runs"])
        cells.append("yes" if same else "**no**")
        out.append("| " + " | ".join(cells) + " |")
    return out


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--part", nargs="+", default=["grid", "default"], choices=["grid", "default", "effect", "test-sample"])
    ap.add_argument("--test-samples", nargs="+", type=int, default=[30_000, 10_000],
                    help="test-sample: the region sizes of the detail fit's probes to compare (the first: the default's)")
    ap.add_argument("--effect-lengths", nargs="+", type=float, default=[0.0, 1.0],
                    help="effect: the correlation lengths of its rows (with --meshes and --sigmas)")
    ap.add_argument("--no-peers", action="store_true", help="effect: skip the peers/quality independent-noise rows")
    ap.add_argument("--meshes", nargs="+", default=GRID_MESHES)
    ap.add_argument("--sigmas", nargs="+", type=float, default=[0.1, 0.25, 0.5, 1.0])
    ap.add_argument("--lengths", nargs="+", type=float, default=[0.0, 1.0, 2.0, 3.0, 4.0])
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--no-as-is", action="store_true", help="skip the meshes taken as they are (Block0.4, bunny10k, face000)")
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    start = time.perf_counter()
    load_before = os.getloadavg()[0]
    meshes: dict = {}
    lines = [f"# Noise model: today's band-only estimate and the detail fit ({datetime.date.today().isoformat()})", "",
             f"Command: `python benchmarks/noise_model_grid.py {' '.join(argv if argv is not None else sys.argv[1:])}`",
             "", "rho and sigma in mean edge lengths h, correlation lengths l in h; ratio = estimated rho / true sigma.",
             "s: seconds of each estimate (under load; see the load average below).", ""]
    if "grid" in args.part:
        rows = []
        for name in args.meshes:
            meshes[name] = load(name)
            V0, F = meshes[name]
            for sigma, ell in [(0.0, 0.0)] + [(s, l) for s in args.sigmas for l in args.lengths]:
                r = estimate_row(name, noisy(V0, F, sigma, ell, args.seed), F, sigma, ell)
                rows.append(r)
                print(grid_table([r])[-1], flush=True)
        for name in [] if args.no_as_is else AS_IS:
            meshes[name] = load(name)
            r = estimate_row(name, *meshes[name], None, None)
            rows.append(r)
            print(grid_table([r])[-1], flush=True)
        lines += ["## Estimates", ""] + grid_table(rows) + [""]
    if "default" in args.part:
        rows = default_rows(meshes, args.seed)
        lines += ["## The default (`meshdenoise.denoise(mesh)`): before (band-only estimate) and now (the policy)", "",
                  "change: mean face-normal angle between input and output; move: rms vertex move; warned: the "
                  "not-smoothing warning; error: mean face-normal error against the clean mesh (noisy rows); "
                  "verdict: the detail fit's (independent: the fine bands read independent noise, no fit); "
                  "s: seconds of each denoise call (under load).", ""]
        lines += default_table(rows) + [""]
    if "effect" in args.part:
        rows = effect_rows(meshes, args.meshes, args.sigmas, args.effect_lengths, args.seed, not args.no_peers)
        lines += ["## The default's result: before and with the detail fit's correlation test", "",
                  "before: a reading of independent noise by the fine bands is kept (the policy before the test); "
                  "after: the policy now. error: mean face-normal error against the clean mesh (deg); SNR against "
                  "the clean mesh (dB); (same): the same noise model, so the same result (run once); noise step: "
                  "seconds of the default's noise step; choice: `choose_default`'s seconds (under load).", ""]
        lines += effect_table(rows) + [""]
    if "test-sample" in args.part:
        rows, skipped = test_sample_rows(meshes, args.meshes, args.sigmas, args.lengths, args.seed, args.test_samples,
                                         not args.no_as_is, not args.no_peers)
        same = sum(all(u["taken"] == r["runs"][0]["taken"] for u in r["runs"]) for r in rows)
        cpu = [[r["runs"][k]["cpu"] for r in rows] for k in range(len(args.test_samples))]
        lines += ["## The correlation test's probes on a smaller region", "",
                  f"Cells where the default asks the test: {len(rows)} (not asked: {skipped}: the fine bands read "
                  f"correlated noise, or independent noise with their own fit under ELL_MIN). The same decision "
                  f"(the policy takes the detail fit's model or keeps the fine bands'): {same} of {len(rows)}. CPU "
                  "seconds of the fit summed over the asked cells: " + ", ".join(
                      f"sample {s:,}: {sum(c):.1f}" for s, c in zip(args.test_samples, cpu)) + " (under load).", "",
                  "test: the correlation test's answer (misfit ratio independent / correlated, gain, best l); "
                  "taken/kept: the policy takes the detail fit's model or keeps the fine bands' reading.", ""]
        lines += test_sample_table(rows) + [""]
    lines.append(f"Total {time.perf_counter() - start:.0f} s; load average {load_before:.1f} at the start, "
                 f"{os.getloadavg()[0]:.1f} at the end (2 cores shared).")
    print(write_table(Path(args.out) if args.out else None, lines))  # atomic: never half-written


if __name__ == "__main__":
    main()

"""Automatic parameters under spatially correlated noise: auto SNR against the oracle of the same filter.

Usage::

    python benchmarks/correlated.py [--meshes elephant bunny face] [--lengths 0 1 2 4] [--sigma 0.3]
                                    [--methods sobolev sobolev_bilaplacian taubin filtering] [--seed 0]
                                    [--out benchmarks/results/correlated.md]

Rows: each mesh with :func:`meshdenoise.add_scanner_noise` along the normals, ``sigma``
mean edge lengths, correlation length 0, 1, 2 and 4 mean edge lengths (one seed). Meshes:
the paper's elephant (``$MESHDENOISE_DATA/elephant-50kv.off``), pymeshlab's sample bunny,
and a scan-like mesh: pymeshlab's range map ``rangemaps/face000.ply`` smoothed strongly
(``sobolev_bilaplacian`` with ``mu`` = 30, boundary pinned) taken as the clean mesh.

Columns per filter: SNR of the automatic choice as it was before the noise model
(``noise`` = :func:`estimate_noise`, independent noise), of the automatic choice now
(:func:`estimate_noise_model`: level and correlation length, coloured SURE), and of the
oracle over the same filter's parameter (``choose_parameters(..., criterion="oracle",
reference=clean)``); ``loss`` = oracle - auto now. Also the estimate: rho / sigma and the
correlation length read.
"""

from __future__ import annotations

import argparse
import datetime
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from meshdenoise.data import data_file, sample_mesh  # noqa: E402
from tables import write_table  # noqa: E402
from meshdenoise.io import load_arrays  # noqa: E402
from meshdenoise.metrics import snr  # noqa: E402
from meshdenoise.noise import add_scanner_noise, mean_edge_length  # noqa: E402
from meshdenoise.registry import apply_filter  # noqa: E402
from meshdenoise.tuning import choose_parameters, estimate_noise, estimate_noise_model  # noqa: E402

METHODS = ["sobolev", "sobolev_bilaplacian", "taubin", "filtering"]
FACE_SMOOTHING = 30.0  # sobolev_bilaplacian mu making face000 the "clean" scan-like mesh


def face_clean() -> tuple[np.ndarray, np.ndarray]:
    """pymeshlab's face000.ply range map, smoothed strongly (boundary pinned): a clean surface with a scan's sampling."""
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.load_new_mesh(str(sample_mesh("rangemaps/face000.ply")))
    ms.meshing_remove_unreferenced_vertices()
    m = ms.current_mesh()
    V, F = m.vertex_matrix().astype(np.float64), m.face_matrix().astype(np.int64)
    Y, F = apply_filter("sobolev_bilaplacian", (V, F), mu=FACE_SMOOTHING, pinned="boundary")
    return Y, F


def load(name: str) -> tuple[np.ndarray, np.ndarray]:
    if name == "elephant":
        return load_arrays(data_file("elephant-50kv.off"))
    if name == "bunny":
        return load_arrays(sample_mesh("bunny.obj"))
    if name == "face":
        return face_clean()
    raise SystemExit(f"--meshes: unknown mesh {name!r}; choose from elephant, bunny, face")


def run_row(name: str, V0: np.ndarray, F: np.ndarray, ell: float, sigma: float, methods: list[str],
            seed: int) -> list[dict]:
    h = mean_edge_length(V0, F)
    Vn, _ = add_scanner_noise((V0, F), sigma * h, correlation_length=ell, seed=seed)
    t = time.perf_counter()
    model = estimate_noise_model((Vn, F))
    t_est = time.perf_counter() - t
    rho_white = estimate_noise((Vn, F))
    out = []
    for method in methods:
        res = {"mesh": name, "n": V0.shape[0], "ell": ell, "method": method, "noisy": snr(V0, Vn),
               "rho": model.rho / (sigma * h), "ell_hat": model.correlation_length,
               "rho_white": rho_white / (sigma * h), "t_est": t_est}
        p_old = choose_parameters((Vn, F), method, noise=rho_white)
        t = time.perf_counter()
        p_new = choose_parameters((Vn, F), method)
        res["t_auto"] = time.perf_counter() - t
        p_orc = choose_parameters((Vn, F), method, criterion="oracle", reference=V0)
        runs = [("old", p_old), ("auto", p_new), ("oracle", p_orc)]
        for key, p in runs:
            X, _ = apply_filter(method, (Vn, F), **p)
            res[key] = snr(V0, X)
            res[key + "_params"] = p
        res["loss"] = res["oracle"] - res["auto"]
        out.append(res)
        print(f"{name} ell={ell:g} {method}: noisy {res['noisy']:.2f} old {res['old']:.2f} auto {res['auto']:.2f} "
              f"oracle {res['oracle']:.2f} (loss {res['loss']:.2f}); rho/sigma {res['rho']:.3f} "
              f"ell_hat {res['ell_hat']:.2f}; {p_new} vs oracle {p_orc}", flush=True)
    return out


def _commit() -> str:
    """The checkout's commit (short hash, ``+dirty`` when the tree has uncommitted changes)."""
    root = Path(__file__).resolve().parent.parent
    try:
        head = subprocess.run(["git", "-C", str(root), "rev-parse", "--short", "HEAD"], capture_output=True,
                              text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return head + ("+dirty" if dirty else "")


def fmt(p: dict) -> str:
    return ", ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in p.items())


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--meshes", nargs="*", default=["elephant", "bunny", "face"])
    ap.add_argument("--lengths", nargs="*", type=float, default=[0.0, 1.0, 2.0, 4.0])
    ap.add_argument("--sigma", type=float, default=0.3, help="noise sigma in mean edge lengths (default 0.3)")
    ap.add_argument("--methods", nargs="*", default=METHODS)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", help="markdown table to write")
    args = ap.parse_args(argv)
    t0 = time.time()
    load0 = os.getloadavg()
    commit = _commit()  # at the start: the code that ran
    rows = []
    for name in args.meshes:
        V0, F = load(name)
        for ell in args.lengths:
            rows += run_row(name, V0, F, ell, args.sigma, args.methods, args.seed)
    wall = time.time() - t0
    load1 = os.getloadavg()
    cmd = "python benchmarks/correlated.py " + " ".join(argv if argv is not None else sys.argv[1:])
    lines = [f"<!-- {cmd}",
             f"     {datetime.date.today()}, {wall:.0f} s wall on 2 cores shared with other jobs; load average "
             f"(1/5/15 min) {load0[0]:.1f}/{load0[1]:.1f}/{load0[2]:.1f} at the start, "
             f"{load1[0]:.1f}/{load1[1]:.1f}/{load1[2]:.1f} at the end; code {commit} -->", "",
             "# Automatic parameters under correlated noise", "",
             f"add_scanner_noise along the normals, sigma = {args.sigma:g} mean edge lengths, seed {args.seed}. "
             "SNR in dB. *before*: SURE with estimate_noise's level, independent noise (the rule before the noise "
             "model); *auto*: estimate_noise_model (level and correlation length) and coloured SURE; *oracle*: the "
             "same filter's parameter chosen against the clean mesh. rho/sigma and ell: what the estimate read.", "",
             "| mesh | ell | filter | noisy | before | auto | oracle | oracle - auto | rho/sigma | ell read "
             "| auto params | oracle params |", "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['mesh']} ({r['n']}) | {r['ell']:g} | {r['method']} | {r['noisy']:.2f} | {r['old']:.2f} | "
                     f"{r['auto']:.2f} | {r['oracle']:.2f} | {r['loss']:.2f} | {r['rho']:.3f} | {r['ell_hat']:.2f} | "
                     f"{fmt(r['auto_params'])} | {fmt(r['oracle_params'])} |")
    losses = np.array([r["loss"] for r in rows])
    lines += ["", f"Rows within 1 dB of the oracle: {int(np.sum(losses <= 1.0))} of {len(rows)}; "
              f"worst loss {losses.max():.2f} dB; mean {losses.mean():.2f} dB."]
    worst = [max((r for r in rows if r["ell"] == e), key=lambda r: r["loss"]) for e in args.lengths]
    lines += ["Worst loss per correlation length: " + "; ".join(
        f"ell {r['ell']:g}: {r['loss']:.2f} dB ({r['mesh']}, {r['method']})" for r in worst) + "."]
    print(write_table(Path(args.out) if args.out else None, lines))  # atomic: never half-written


if __name__ == "__main__":
    main()

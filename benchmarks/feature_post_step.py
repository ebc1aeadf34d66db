"""The default's Taubin steps after ``two_stage`` (:func:`meshdenoise.default.feature_post_step`): with and without.

Usage::

    python benchmarks/feature_post_step.py [--meshes icosphere elephant bunny Bunny0.2 Fandisk0.3 face]
                                           [--sigmas 0.25 0.5 1] [--lengths 0 2 4] [--seed 1] [--no-peers]
                                           [--out benchmarks/results/feature-post-step.md]

Rows: every mesh of ``benchmarks/noise_model_grid.py``'s grid with :func:`meshdenoise.add_scanner_noise`
along the normals (``sigma`` mean edge lengths h, correlation length ``l`` h, one seed), and the peers
benchmark's rows (``benchmarks/peers.py``, unless ``--no-peers``). On each, ``meshdenoise.denoise(mesh)`` (the
default, no clean mesh): its filter's result, then the Taubin steps it chose after it. Where it chose
``two_stage``, columns: the feature test's verdict, the count chosen, the mean face-normal error (deg) and SNR
(dB) of ``two_stage`` alone (the default before the post-step) and with the steps (now), and the count of
least normal error among :data:`meshdenoise.default.FEATURE_POST_STEPS` against the clean mesh (the oracle,
with its error and SNR). Rows where the default chose a smooth prior are counted, not listed (the change does
not touch them). One subprocess per mesh.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from tables import write_table  # noqa: E402

GRID = ["icosphere", "elephant", "bunny", "Bunny0.2", "Fandisk0.3", "face"]


def with_and_without(V0: np.ndarray, F: np.ndarray, Vn: np.ndarray) -> dict:
    """The default on ``Vn``: its filter's result alone and with the Taubin steps it chose, and the oracle count."""
    import meshdenoise.default as default
    from meshdenoise.metrics import normal_error_deg, snr
    from meshdenoise.registry import apply_filter

    t0 = time.perf_counter()
    choice = default.choose_default((Vn.copy(), F))
    seconds = time.perf_counter() - t0
    out = {"method": choice.method, "sharp": bool(choice.features.sharp), "steps": int(choice.post_steps),
           "seconds": seconds, "n": int(Vn.shape[0])}
    if choice.method != default.FEATURE_METHOD:
        return out
    X, _ = apply_filter(choice.method, (Vn.copy(), F), **choice.params, boundary_motion="normal")
    quality = lambda Y: (normal_error_deg((V0, F), Y), snr(V0, Y))  # noqa: E731
    out["before"] = quality(X)
    curve, done, Y = {0: out["before"]}, 0, X
    for k in default.FEATURE_POST_STEPS[1:]:  # Taubin run on from the previous count, as the estimate runs it
        Y, _ = apply_filter("taubin", (Y, F), iterations=k - done, **default.POST_TAUBIN, boundary_motion="normal")
        done = k
        curve[k] = quality(Y)
    out["curve"] = {str(k): v for k, v in curve.items()}
    if choice.post_steps in curve:
        out["after"] = curve[choice.post_steps]
    else:  # a count outside the table's (the constant changed): run it
        Z, _ = apply_filter("taubin", (X, F), iterations=choice.post_steps, **default.POST_TAUBIN, boundary_motion="normal")
        out["after"] = quality(Z)
    best = min(curve, key=lambda k: curve[k][0])
    out["oracle"] = (best, *curve[best])
    return out


def cells(args: argparse.Namespace) -> list[tuple[str, float, float]]:
    rows = [(m, s, ell) for m in args.meshes for s in args.sigmas for ell in args.lengths]
    if not args.no_peers:
        import peers

        rows += [(name, -1.0, -1.0) for name in peers.DEFAULT_MESHES]
    return rows


def measure(mesh: str, sigma: float, ell: float, seed: int) -> dict:
    if sigma < 0:  # a peers row: its own clean and noisy meshes
        import peers

        m = peers.MESHES[mesh]()
        V0, F, Vn = m["V0"], m["F"], m["Vn"]
    else:
        from noise_model_grid import load, noisy

        V0, F = load(mesh)
        Vn = noisy(V0, F, sigma, ell, seed)
    return {"mesh": mesh, "sigma": sigma, "ell": ell, **with_and_without(V0, F, Vn)}


def _commit() -> str:
    try:
        out = subprocess.run(["git", "describe", "--always", "--dirty"], capture_output=True, text=True,
                             cwd=Path(__file__).resolve().parent)
        return out.stdout.strip() or "unknown"
    except OSError:
        return "unknown"


def table(rows: list[dict], command: str) -> list[str]:
    ts = [r for r in rows if "before" in r]
    other = len(rows) - len(ts)
    fmt = lambda q: f"{q[0]:.2f} / {q[1]:.2f}"  # noqa: E731
    out = [f"# Taubin steps after two_stage in the default ({datetime.date.today()})", "",
           f"Command: `{command}`; commit {_commit()}; load average {os.getloadavg()[0]:.1f} at the end (rows "
           "measured at that commit's code, or kept from the JSON beside this table by a resumed run).", "",
           "Mean face-normal error (deg) / SNR (dB) against the clean mesh; sigma and l in mean edge lengths "
           "(`add_scanner_noise` along the normals, one seed), 'peers' the peers benchmark's own noise. "
           f"{len(ts)} rows where the default chose two_stage; {other} where it chose a smooth prior (unchanged, not "
           "listed). Oracle: the count of least normal error among FEATURE_POST_STEPS, against the clean mesh.", "",
           "| mesh | sigma | l | n | sharp features | steps chosen | two_stage alone (before) | with the steps (now) | "
           "change (deg, dB) | oracle count: error / SNR |",
           "|---|---|---|---|---|---|---|---|---|---|"]
    for r in ts:
        sig = "peers" if r["sigma"] < 0 else f"{r['sigma']:g}"
        ell = "" if r["ell"] < 0 else f"{r['ell']:g}"
        b, a, o = r["before"], r["after"], r["oracle"]
        out.append(f"| {r['mesh']} | {sig} | {ell} | {r['n']:,} | {'yes' if r['sharp'] else 'no'} | {r['steps']} | "
                   f"{fmt(b)} | {fmt(a)} | {a[0] - b[0]:+.2f}, {a[1] - b[1]:+.2f} | {o[0]}: {fmt(o[1:])} |")
    if ts:
        d = np.array([r["after"][0] - r["before"][0] for r in ts])
        s = np.array([r["after"][1] - r["before"][1] for r in ts])
        chosen = [r for r in ts if r["steps"]]
        out += ["", f"Steps chosen on {len(chosen)} of {len(ts)} rows. Normal error change: mean {d.mean():+.3f} deg, "
                    f"best {d.min():+.3f}, worst {d.max():+.3f}; SNR change: mean {s.mean():+.3f} dB, worst {s.min():+.3f}."]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--meshes", nargs="+", default=GRID)
    ap.add_argument("--sigmas", nargs="+", type=float, default=[0.25, 0.5, 1.0])
    ap.add_argument("--lengths", nargs="+", type=float, default=[0.0, 2.0, 4.0])
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--no-peers", action="store_true")
    ap.add_argument("--out", default="benchmarks/results/feature-post-step.md")
    ap.add_argument("--one", nargs=3, metavar=("MESH", "SIGMA", "L"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one:
        print(json.dumps(measure(args.one[0], float(args.one[1]), float(args.one[2]), args.seed)))
        return
    store = Path(args.out).with_suffix(".json")
    store.parent.mkdir(parents=True, exist_ok=True)
    done = json.loads(store.read_text()) if store.exists() else []
    have = {(r["mesh"], r["sigma"], r["ell"]) for r in done}
    for mesh, sigma, ell in cells(args):
        if (mesh, sigma, ell) in have:
            continue
        p = subprocess.run([sys.executable, __file__, "--one", mesh, str(sigma), str(ell), "--seed", str(args.seed)],
                           capture_output=True, text=True)
        if p.returncode != 0:
            print(f"{mesh} {sigma} {ell}: failed: {p.stderr.strip().splitlines()[-1:]}", file=sys.stderr)
            continue
        r = json.loads(p.stdout.strip().splitlines()[-1])
        done.append(r)
        tmp = store.with_name(f".{store.name}.tmp")  # never half-written
        tmp.write_text(json.dumps(done, indent=1))
        tmp.replace(store)
        print(r["mesh"], r["sigma"], r["ell"], r["method"], r["steps"], r.get("before"), r.get("after"), flush=True)
    command = "python benchmarks/feature_post_step.py " + " ".join(sys.argv[1:])
    write_table(Path(args.out), table(done, command))


if __name__ == "__main__":
    main()

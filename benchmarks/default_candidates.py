"""The default's candidates side by side: each filter's automatic choice, and what ``denoise(mesh)`` picks.

Usage::

    python benchmarks/default_candidates.py [--methods two_stage sobolev_bilaplacian ...] [--meshes NAME ...]
                                            [--out benchmarks/results/default-candidates.md]

Meshes: the shared benchmark's pairs (CAD parts Fandisk0.3, Block0.4, Twelve0.5Impulsive; the scanned Bunny0.2), pymeshlab's bunny and range scan
``face000.ply`` with ``add_scanner_noise`` (0.5 mean edge lengths; correlation length 0, 1 and 2),
the paper's Nefertiti (rho = 0.2) and elephant (rho = 0.015) with normal noise. For each, every
candidate runs as ``meshdenoise.denoise(mesh, method=M)`` (parameters chosen from the noisy mesh
alone, caches cleared before each call) and is scored against the clean mesh: mean face-normal
error (deg), SNR (dB), time (s, one call including the automatic choice).
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from tables import provenance, write_table  # noqa: E402

CANDIDATES = ("two_stage", "sobolev_bilaplacian", "sobolev_normal", "taubin")


def _meshes():
    import meshdenoise as md
    from meshdenoise.data import data_file, sample_mesh
    from meshdenoise.io import load_arrays
    from meshdenoise.operators import get_operators
    from meshdenoise.tuning.noise_level import mean_edge_length

    def pair(name):
        def build():
            V0, F = load_arrays(data_file(f"benchmark/{name}/Original.obj"))
            return V0, load_arrays(data_file(f"benchmark/{name}/Noisy.obj"))[0], F
        return build

    def scanner(file, ell):
        def build():
            V0, F = load_arrays(sample_mesh(file))
            h = mean_edge_length(V0, get_operators(F, V0.shape[0]))
            return V0, md.add_scanner_noise((V0, F), 0.5 * h, correlation_length=ell, seed=0)[0], F
        return build

    def paper(file, rho):
        def build():
            V0, F = load_arrays(data_file(file))
            return V0, md.add_normal_noise((V0, F), rho, seed=0)[0], F
        return build

    return {
        "Fandisk0.3": pair("Fandisk0.3"),
        "Block0.4": pair("Block0.4"),
        "Twelve0.5Impulsive": pair("Twelve0.5Impulsive"),
        "Bunny0.2": pair("Bunny0.2"),
        **{f"bunny scanner l={ell}": scanner("bunny.obj", ell) for ell in (0, 1, 2)},
        **{f"face000 scanner l={ell}": scanner("rangemaps/face000.ply", ell) for ell in (0, 1, 2)},
        "nefertiti rho=0.2": paper("nefertiti.off", 0.2),
        "elephant rho=0.015": paper("elephant-50kv.off", 0.015),
        "elephant rho=0.2": paper("elephant-50kv.off", 0.2),
    }


def post_study(names: list[str], methods: list[str], out: Path | None, argv: list[str] | None) -> int:
    """Every candidate of the smooth-prior post-step: its estimates (no clean mesh) beside its true errors."""
    import meshdenoise as md
    from meshdenoise import default
    from meshdenoise.operators import get_operators
    from meshdenoise.geometry import face_normals, vertex_normals
    from meshdenoise.registry import get_filter
    from meshdenoise.tuning.noise_level import mean_edge_length

    meshes = _meshes()
    rows = ["| mesh | prior | mu x | Taubin steps | est. normal risk change (rad^2 per face) | true mean squared angle "
            "change (rad^2) | true mean normal error (deg) | est. SNR loss (dB, +2 s.e.) | true SNR (dB) | allowed | picked |",
            "|---|---|---|---|---|---|---|---|---|---|---|"]
    for name in names:
        V0, Vn, F = meshes[name]()
        ops = get_operators(F, Vn.shape[0])
        model = default.default_noise(Vn, F, mean_edge_length(Vn, ops))[0]
        smooth = md.apply_filter(default.SMOOTH_METHOD, (Vn, F),
                                 **md.choose_parameters((Vn, F), default.SMOOTH_METHOD, noise=model))[0]
        normals = vertex_normals(smooth, F)  # the probes' directions, as choose_default takes them
        for method in methods:
            params = md.choose_parameters((Vn, F), method, noise=model)
            t = time.perf_counter()
            post = default.choose_post_step(Vn, F, method, params, model, ops=ops, normals=normals)
            dt = time.perf_counter() - t
            print(name, method, params, post.reason, f"({dt:.1f} s)", flush=True)
            for p in post.candidates:
                X = np.asarray(get_filter(method).public((Vn, F), operators=ops, **{**params, "mu": params["mu"] * p.scale})[0])
                if p.steps:
                    X = np.asarray(md.apply_filter("taubin", (X, F), iterations=p.steps, **default.POST_TAUBIN)[0])
                n0, n1 = face_normals(V0, F), face_normals(X, F)
                ang = np.degrees(np.arctan2(np.linalg.norm(np.cross(n0, n1), axis=1), np.einsum("ij,ij->i", n0, n1)))
                picked = "**yes**" if (p.scale, p.steps) == (post.scale, post.steps) else ""
                sq = float(np.mean(np.radians(ang) ** 2))
                if (p.scale, p.steps) == (1.0, 0):
                    g0, sq0 = p.normal_risk, sq
                rows.append(f"| {name} | {method} | {p.scale:g} | {p.steps} | {p.normal_risk - g0:+.4f} | {sq - sq0:+.4f} | "
                            f"{md.normal_error_deg((V0, F), (X, F)):.2f} | "
                            f"{p.loss_db:+.2f} | {md.snr(V0, X):.2f} | {'yes' if p.allowed else 'no'} | {picked} |")
                print(rows[-1], flush=True)
            rows.append(f"| | | | | | | | | | | ({dt:.1f} s) |")
    head = [provenance("default_candidates.py", argv), "",
            "# The smooth-prior post-step: every candidate's estimates (noisy mesh only) and true errors", ""]
    print(write_table(out, head + rows))
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--methods", nargs="+", default=list(CANDIDATES), help="filters, or 'default' (denoise(mesh))")
    ap.add_argument("--meshes", nargs="+", default=None)
    ap.add_argument("--post-study", action="store_true",
                    help="the smooth-prior post-step's candidates for --methods (smooth priors) against the clean mesh")
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args(argv)
    import meshdenoise as md

    meshes = _meshes()
    names = a.meshes or list(meshes)
    if a.post_study:
        return post_study(names, a.methods, a.out, argv)
    rows = ["| mesh | vertices | noisy (deg / dB) | " + " | ".join(a.methods) + " |",
            "|---|---|---|" + "---|" * len(a.methods)]
    for name in names:
        V0, Vn, F = meshes[name]()
        cells = []
        for method in a.methods:
            md.clear_caches()
            t = time.perf_counter()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                if method == "default":  # what denoise(mesh) picks: its method and parameters
                    (Y, _), choice = md.denoise((Vn, F), return_params=True)
                    params = {"method": choice.method, **choice.params}
                else:
                    (Y, _), params = md.denoise((Vn, F), method=method, return_params=True)
            dt = time.perf_counter() - t
            picked = f", {params['method']}" if method == "default" else ""
            cells.append(f"{md.normal_error_deg((V0, F), (Y, F)):.2f} / {md.snr(V0, Y):.2f} ({dt:.1f} s{picked})")
            print(name, method, params, cells[-1], flush=True)
        rows.append(f"| {name} | {V0.shape[0]:,} | {md.normal_error_deg((V0, F), (Vn, F)):.2f} / {md.snr(V0, Vn):.2f} | "
                    + " | ".join(cells) + " |")
    head = [provenance("default_candidates.py", argv), "",
            "# The default's candidates, each with its automatic parameters, and what `denoise(mesh)` picks", "",
            "Each cell: mean face-normal error (deg) / SNR (dB) (time of one `denoise(mesh, method=M)` call).", ""]
    print(write_table(a.out, head + rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())

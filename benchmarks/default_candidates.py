"""The default's candidates side by side: each filter's automatic choice, and what ``denoise(mesh)`` picks.

Usage::

    python benchmarks/default_candidates.py [--methods two_stage sobolev_bilaplacian ...] [--meshes NAME ...]
                                            [--out benchmarks/results/default-candidates.md]

Meshes: the shared benchmark's pairs (CAD parts Fandisk0.3, Block0.4, Twelve0.5Impulsive; the scanned Bunny0.2), pymeshlab's bunny and range scan
``face000.ply`` with ``add_scanner_noise`` (0.5 mean edge lengths; correlation length 0 and 2),
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
        "bunny scanner l=0": scanner("bunny.obj", 0),
        "bunny scanner l=2": scanner("bunny.obj", 2),
        "face000 scanner l=0": scanner("rangemaps/face000.ply", 0),
        "face000 scanner l=2": scanner("rangemaps/face000.ply", 2),
        "nefertiti rho=0.2": paper("nefertiti.off", 0.2),
        "elephant rho=0.015": paper("elephant-50kv.off", 0.015),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--methods", nargs="+", default=list(CANDIDATES), help="filters, or 'default' (denoise(mesh))")
    ap.add_argument("--meshes", nargs="+", default=None)
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args(argv)
    import meshdenoise as md

    meshes = _meshes()
    names = a.meshes or list(meshes)
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

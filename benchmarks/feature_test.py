"""The default's feature test on many meshes: the share of sharp edges among creased ones after pre-smoothing.

Usage::

    python benchmarks/feature_test.py [--out benchmarks/results/feature-test.md]

For each mesh (the shared benchmark pairs, noisy and clean; pymeshlab's sample meshes, raw
and with scanner-like noise; the paper's elephant and Nefertiti with normal noise) prints
:func:`meshdenoise.default.detect_features`'s share (sharp / creased edges after two
``two_stage`` iterations), the fraction of sharp edges among all, the verdict and the time,
and whether the verdict is the expected one (CAD parts: sharp features; scans and organic
shapes: none; noise of several edge lengths: none, as the test cannot see features there).
Meshes whose files are missing are listed as such.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path


sys.path.insert(0, str(Path(__file__).resolve().parent))
from tables import provenance, write_table  # noqa: E402


def _cases():
    """(name, expected sharp, loader) for every mesh of the table."""
    from meshdenoise.data import data_file, sample_mesh
    from meshdenoise.io import load_arrays
    from meshdenoise.noise import add_normal_noise, add_scanner_noise
    from meshdenoise.operators import get_operators
    from meshdenoise.tuning.noise_level import mean_edge_length

    def pair(name, which):
        return lambda: load_arrays(data_file(f"benchmark/{name}/{which}.obj"))

    def sample(file):
        return lambda: load_arrays(sample_mesh(file))

    def scanner(file, ell):
        def build():
            V, F = load_arrays(sample_mesh(file))
            h = mean_edge_length(V, get_operators(F, V.shape[0]))
            return add_scanner_noise((V, F), 0.5 * h, correlation_length=ell, seed=0)[0], F
        return build

    def paper(file, rho):
        def build():
            V, F = load_arrays(data_file(file))
            return add_normal_noise((V, F), rho, seed=0)[0], F
        return build

    cases = []
    for name, cad in (("Fandisk0.3", True), ("Block0.4", True), ("Twelve0.5Impulsive", True), ("Bunny0.2", False)):
        cases.append((f"{name} noisy", cad, pair(name, "Noisy")))
        cases.append((f"{name} clean", cad, pair(name, "Original")))
    for file in ("rangemaps/face000.ply", "bunny.obj", "bone.ply", "cow.obj", "airplane.obj"):
        cases.append((f"{file} (as shipped)", False, sample(file)))
    for file in ("bunny.obj", "rangemaps/face000.ply"):
        for ell in (0, 2, 4):
            cases.append((f"{file} + scanner noise 0.5 h, l={ell}", False, scanner(file, ell)))
    cases.append(("nefertiti rho=0.2", False, paper("nefertiti.off", 0.2)))
    cases.append(("elephant rho=0.015", False, paper("elephant-50kv.off", 0.015)))
    cases.append(("elephant rho=0.2", False, paper("elephant-50kv.off", 0.2)))
    return cases


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=None, help="also write the table (markdown) here")
    a = ap.parse_args(argv)
    from meshdenoise.default import SHARP_SHARE, TOO_NOISY, detect_features
    from meshdenoise.operators import get_operators
    from meshdenoise.tuning.noise_level import estimate_noise, mean_edge_length

    rows = ["| mesh | vertices | noise (edge lengths) | share sharp/creased | sharp / all edges | verdict | expected | s |",
            "|---|---|---|---|---|---|---|---|"]
    wrong = 0
    for name, expected, build in _cases():
        try:
            V, F = build()
        except (FileNotFoundError, OSError) as exc:
            rows.append(f"| {name} | missing: {exc} | | | | | | |")
            continue
        ops = get_operators(F, V.shape[0])
        noise = estimate_noise((V, F)) / mean_edge_length(V, ops)
        t = time.perf_counter()
        test = detect_features((V, F), ops=ops)
        dt = time.perf_counter() - t
        ok = test.sharp == expected
        wrong += not ok
        rows.append(f"| {name} | {V.shape[0]:,} | {noise:.3f} | {test.share:.2f} | {test.sharp_fraction:.2%} | "
                    f"{'sharp' if test.sharp else 'smooth'} | {'sharp' if expected else 'smooth'}{'' if ok else ' (WRONG)'} "
                    f"| {dt:.2f} |")
        print(rows[-1], flush=True)
    head = [provenance("feature_test.py", argv), "",
            "# The default's feature test", "",
            f"Sharp features when at least {SHARP_SHARE:.0%} of the creased edges (> 20 deg) are sharp (> 45 deg) after "
            f"two `two_stage` iterations, unless more than {TOO_NOISY:.0%} of all edges are sharp (noise not removed). "
            f"{wrong} wrong verdict(s).", ""]
    write_table(a.out, head + rows)
    print(f"{wrong} wrong verdict(s)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())

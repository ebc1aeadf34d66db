"""How each filter's main parameter should grow with the noise, in mean edge lengths: the oracle's choice measured.

Usage::

    python benchmarks/parameter_scale.py [--methods sobolev ...] [--noise 0.1 0.3 1.0]
                                         [--out benchmarks/results/parameter-scale.md]

For meshes the project generates (``icosphere(4)``, ``torus(80, 40)``) and pymeshlab's bunny,
Gaussian noise along the normals of ``s`` mean edge lengths (``s`` from ``--noise``) is added
(seed 0); each filter's parameter is then chosen against the clean mesh
(``choose_parameters(..., criterion="oracle")``, the best in hindsight over the filter's own
search space) and printed beside ``s``. The filters' docstrings quote these numbers ("how to
choose ... for a scan").
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from tables import provenance, write_table  # noqa: E402

MAIN = {"sobolev": "mu", "sobolev_bilaplacian": "mu", "taubin": "iterations", "filtering": "iterations",
        "heat": "time", "two_stage": "iterations", "sobolev_normal": "mu", "sobolev_axes": "mu1", "sobolev_gls": "mu",
        "sinkhorn": "t"}
DEFAULT_METHODS = ("sobolev", "sobolev_bilaplacian", "taubin", "filtering", "heat", "two_stage")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--methods", nargs="+", default=list(DEFAULT_METHODS), choices=list(MAIN))
    ap.add_argument("--meshes", nargs="+", default=None, help="of: icosphere(4), 'torus(80, 40)', bunny (default: all)")
    ap.add_argument("--noise", nargs="+", type=float, default=[0.1, 0.3, 1.0])
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args(argv)
    import meshdenoise as md
    from meshdenoise.data import sample_mesh
    from meshdenoise.io import load_arrays
    from meshdenoise.operators import get_operators
    from meshdenoise.shapes import icosphere, torus
    from meshdenoise.tuning.noise_level import mean_edge_length

    meshes = {"icosphere(4)": icosphere(4), "torus(80, 40)": torus(80, 40), "bunny": load_arrays(sample_mesh("bunny.obj"))}
    meshes = {k: v for k, v in meshes.items() if a.meshes is None or k in a.meshes}
    rows = ["| filter | parameter | mesh | " + " | ".join(f"noise {s:g} h" for s in a.noise) + " |",
            "|---|---|---|" + "---|" * len(a.noise)]
    for method in a.methods:
        for name, (V, F) in meshes.items():
            h = mean_edge_length(V, get_operators(F, V.shape[0]))
            cells = []
            for s in a.noise:
                Vn = md.add_normal_noise((V, F), s * h, seed=0)[0]
                p = md.choose_parameters((Vn, F), method, criterion="oracle", reference=V)
                value = p[MAIN[method]]
                cells.append(f"{value:.3g}" if isinstance(value, float) else str(value))
            rows.append(f"| {method} | {MAIN[method]} | {name} | " + " | ".join(cells) + " |")
            print(rows[-1], flush=True)
    head = [provenance("parameter_scale.py", argv), "",
            "# Each filter's best main parameter (oracle) against the noise, in mean edge lengths h", "",
            "Gaussian noise along the normals, seed 0; the parameter minimising the true squared error over the "
            "filter's own search space.", ""]
    write_table(a.out, head + rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())

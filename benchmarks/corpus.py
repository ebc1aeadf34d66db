"""The validation corpus: clean meshes, their noisy versions, and a fixed split into tune and check cases.

Usage::

    python benchmarks/corpus.py [--cases NAME ...] [--out out/corpus] [--list] [--jobs 2]

Builds every case (or the named ones) into ``OUT/v<CORPUS_VERSION>/<case>.npz`` (``V0`` the clean
vertices, ``F`` the faces, ``Vn`` the noisy vertices, and the case's description), skipping those
already built; ``--list`` prints the cases, their kind, noise level, split and size, and builds
nothing. Deterministic: the same arrays on every run (every random draw is seeded by the case's
name). The meshes are never committed; the peers' oracle (``benchmarks/corpus_peers.py``) and the
report (``benchmarks/corpus_report.py``) build what they need through :func:`load_case`.

Cases (:data:`CASES`, 53 of them):

- every CAD part of :mod:`corpus_shapes` (15, sharp edges, fillets, chamfers, holes, thin walls),
  remeshed to about 5,000 vertices, with one of three noises (cycled in the order of the parts):
  Gaussian along the normals (``normal``), Gaussian in random directions (``random``), or
  impulsive (``impulsive``: a tenth of the vertices moved along their normals);
- every organic shape (10) at two resolutions (about 3,000 and 10,000 vertices), the same cycle;
- virtual range scans (``scan``, :func:`meshdenoise.simulate_scan`) of 8 CAD parts and the 10 organic
  shapes (10), one view each, about 6,000 vertices, with correlation 0 to 3 pixels, stripes on one in three;
- noise levels cycle through 0.1, 0.2, 0.3, 0.4, 0.5 and 0.7 mean edge lengths of the clean mesh (out of step
  with the kinds, so that every kind meets several levels).

Split: a case is ``tune`` when the first byte of the SHA-256 of its name is even, else ``check``
(:func:`split`). Rules and constants are chosen on tune cases only; every table reports the check
cases separately; the split is never changed.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import corpus_shapes  # noqa: E402

# The corpus's version: change it whenever a case's arrays change (a shape, a size, a noise), so that the
# peers' oracle (benchmarks/results/corpus-peers.json) is recomputed for the new meshes.
CORPUS_VERSION = "2"

LEVELS = (0.1, 0.2, 0.3, 0.4, 0.5, 0.7)  # noise levels cycled over the cases, in mean edge lengths
KINDS = ("normal", "random", "impulsive")  # the synthetic noises cycled over the meshes; scans are the fourth
IMPULSIVE_FRACTION = 0.1  # impulsive noise moves this fraction of the vertices (the Twelve0.5Impulsive benchmark's kind)
CAD_VERTICES = 5000
ORGANIC_VERTICES = (3000, 10000)
SCAN_VERTICES = 6000
SCANNED_VERTICES = 10000  # the mesh a scan of SCAN_VERTICES samples is this fine: it samples a smooth surface
SCAN_CAD_PARTS = ("bracket", "flange", "gear", "housing", "knob", "pipe_tee", "slotted_plate", "t_beam")
SCAN_VIEWS = ((30.0, 20.0), (120.0, 35.0), (-60.0, 10.0), (200.0, -25.0), (75.0, 60.0))
SCAN_CORRELATIONS = (0.0, 1.0, 2.0, 3.0)  # pixels


@dataclass(frozen=True)
class Case:
    """One corpus case: a clean mesh and how its noise is made."""

    name: str
    family: str  # "cad" or "organic"
    shape: str
    vertices: int | None  # the size the clean mesh is remeshed to (scans: the scan's target size)
    kind: str  # normal, random, impulsive or scan
    level: float  # mean edge lengths of the clean mesh (scans: of the clean scan)
    view: tuple[float, float] = (0.0, 0.0)
    correlation: float = 0.0
    stripes: float = 0.0

    @property
    def split(self) -> str:
        return split(self.name)

    @property
    def needs_data(self) -> bool:
        """Whether it reads a shared mesh (MESHDENOISE_DATA)."""
        return self.shape in corpus_shapes.NEEDS_DATA


def split(name: str) -> str:
    """``tune`` or ``check``, fixed by the SHA-256 of the case's name.

    >>> split("bracket-normal-0.1"), split("bunny-3k-random-0.2")
    ('check', 'tune')
    """
    return "tune" if hashlib.sha256(name.encode()).digest()[0] % 2 == 0 else "check"


def _cases() -> list[Case]:
    out: list[Case] = []
    i = 0

    def level() -> float:  # shifted by one every full cycle: out of step with the cycle of three kinds
        return LEVELS[(i + i // len(LEVELS)) % len(LEVELS)]

    for k, part in enumerate(corpus_shapes.CAD):
        kind = KINDS[k % len(KINDS)]
        out.append(Case(f"{part}-{kind}-{level():g}", "cad", part, CAD_VERTICES, kind, level()))
        i += 1
    k = 0
    for shape in corpus_shapes.ORGANIC:
        for size in ORGANIC_VERTICES:
            kind = KINDS[k % len(KINDS)]
            out.append(Case(f"{shape}-{size // 1000}k-{kind}-{level():g}", "organic", shape, size, kind, level()))
            i += 1
            k += 1
    scanned = [("cad", p) for p in SCAN_CAD_PARTS] + [("organic", s) for s in corpus_shapes.ORGANIC]
    for k, (family, shape) in enumerate(scanned):
        view = SCAN_VIEWS[k % len(SCAN_VIEWS)]
        corr = SCAN_CORRELATIONS[k % len(SCAN_CORRELATIONS)]
        stripes = 0.3 if k % 3 == 2 else 0.0
        out.append(Case(f"{shape}-scan-{level():g}-c{corr:g}" + ("-striped" if stripes else ""), family, shape,
                        SCAN_VERTICES, "scan", level(), view, corr, stripes))
        i += 1
    return out


CASES: dict[str, Case] = {c.name: c for c in _cases()}


def _seed(name: str) -> int:
    return int.from_bytes(hashlib.sha256(("noise:" + name).encode()).digest()[:8], "little")


def mean_edge(V: np.ndarray, F: np.ndarray) -> float:
    E = np.unique(np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1), axis=0)
    return float(np.linalg.norm(V[E[:, 0]] - V[E[:, 1]], axis=1).mean())


def _clean(case: Case, vertices: int) -> tuple[np.ndarray, np.ndarray]:
    if case.family == "cad":
        return corpus_shapes.cad_part(case.shape, vertices)
    return corpus_shapes.organic_shape(case.shape, vertices)


def _scan(case: Case, V: np.ndarray, F: np.ndarray, rng: np.random.Generator,
          vertices: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A range scan of about ``vertices`` vertices: a small probe scan sets the resolution."""
    from meshdenoise.scanner import simulate_scan

    probe = simulate_scan((V, F), view=case.view, resolution=(96, 72), noise=0.0)
    covered = len(probe.V) / (96 * 72)
    width = max(16, int(round(math.sqrt(vertices / covered / 0.75))))
    scan = simulate_scan((V, F), view=case.view, resolution=(width, int(round(0.75 * width))), noise=case.level,
                         correlation=case.correlation, stripes=case.stripes, seed=rng)
    return scan.V_clean, scan.F, scan.V


def _noisy(case: Case, V: np.ndarray, F: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    from meshdenoise.geometry import vertex_normals

    rho = case.level * mean_edge(V, F)
    n = len(V)
    if case.kind == "normal":
        return V + rho * rng.standard_normal(n)[:, None] * vertex_normals(V, F)
    if case.kind == "random":
        u = rng.standard_normal((n, 3))
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        return V + rho * rng.standard_normal(n)[:, None] * u
    if case.kind == "impulsive":
        picked = rng.choice(n, size=int(round(IMPULSIVE_FRACTION * n)), replace=False)
        out = V.copy()
        out[picked] += rho * rng.standard_normal(picked.size)[:, None] * vertex_normals(V, F)[picked]
        return out
    raise ValueError(f"unknown noise kind {case.kind!r}")


def describe(case: Case) -> str:
    """The noise in words (the tables' ``noise`` column)."""
    if case.kind == "scan":
        return (f"range scan from {case.view[0]:g},{case.view[1]:g}: {case.level:g} mean edge lengths along the rays, "
                f"correlation {case.correlation:g} px" + (f", stripes {case.stripes:g}" if case.stripes else ""))
    what = {"normal": "Gaussian along the normals", "random": "Gaussian in random directions",
            "impulsive": f"impulsive ({IMPULSIVE_FRACTION:.0%} of the vertices, along their normals)"}[case.kind]
    return f"{what}, {case.level:g} mean edge lengths"


def split_nonmanifold_vertices(V0: np.ndarray, F: np.ndarray, Vn: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A vertex where two fans of faces meet (a bowtie: a range grid's corner, a remeshed pinch) becomes one per fan.

    pymeshlab's ``meshing_repair_non_manifold_vertices`` splits them, appending the copies; each copy takes its
    original's noisy position. MeshLib and PyGEL split such vertices on loading, so without this they could not
    be compared vertex to vertex (``benchmarks/peers.py``: "topology changed").
    """
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=np.ascontiguousarray(V0), face_matrix=np.ascontiguousarray(F, dtype=np.int32)))
    ms.meshing_repair_non_manifold_vertices()
    m = ms.current_mesh()
    V1, F1 = np.asarray(m.vertex_matrix(), dtype=np.float64), np.asarray(m.face_matrix(), dtype=np.int64)
    n = len(V0)
    if len(V1) == n:
        return V0, F, Vn
    if len(F1) != len(F) or not np.array_equal(V1[:n], V0):
        raise RuntimeError("pymeshlab's non-manifold vertex split changed more than it appends")
    from scipy.spatial import cKDTree

    dist, origin = cKDTree(V0).query(V1[n:])
    if dist.max() > 0:
        raise RuntimeError("a split vertex is not at its original's position")
    return V1, F1, np.concatenate([Vn, Vn[origin]])


def build_case(case: Case, vertices: int | None = None) -> dict:
    """The case's arrays: ``{"V0", "F", "Vn", "noise"}`` (clean, faces, noisy, in words).

    ``vertices`` replaces the case's size (smaller meshes for the tests); the corpus is built at its own.
    """
    rng = np.random.default_rng(_seed(case.name))
    size = case.vertices if vertices is None else vertices
    V, F = _clean(case, round(size * SCANNED_VERTICES / SCAN_VERTICES) if case.kind == "scan" else size)
    if case.kind == "scan":
        V, F, Vn = _scan(case, V, F, rng, size)
    else:
        Vn = _noisy(case, V, F, rng)
    V, F, Vn = split_nonmanifold_vertices(V, F, Vn)
    return {"V0": V, "F": F, "Vn": Vn, "noise": describe(case)}


def case_path(name: str, out: Path = ROOT / "out" / "corpus") -> Path:
    return Path(out) / f"v{CORPUS_VERSION}" / f"{name}.npz"


def load_case(name: str, out: Path = ROOT / "out" / "corpus") -> dict:
    """The case's arrays from the cache, built (and cached) when missing."""
    if name not in CASES:
        raise KeyError(f"unknown corpus case {name!r}")
    path = case_path(name, out)
    if path.is_file():
        with np.load(path) as z:
            return {"V0": z["V0"], "F": z["F"], "Vn": z["Vn"], "noise": str(z["noise"])}
    m = build_case(CASES[name])
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp.npz")
    np.savez(tmp, V0=m["V0"], F=m["F"], Vn=m["Vn"], noise=np.array(m["noise"]))
    tmp.replace(path)
    return m


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", nargs="+", default=None, help="case names (default: all)")
    ap.add_argument("--out", type=Path, default=ROOT / "out" / "corpus")
    ap.add_argument("--list", action="store_true", help="print the cases; build nothing")
    ap.add_argument("--no-data", action="store_true", help="leave out the cases that read MESHDENOISE_DATA")
    a = ap.parse_args(argv)
    names = a.cases or list(CASES)
    bad = [n for n in names if n not in CASES]
    if bad:
        print(f"corpus.py: unknown case {bad[0]!r} (see --list)", file=sys.stderr)
        return 2
    if a.no_data:
        names = [n for n in names if not CASES[n].needs_data]
    if a.list:
        for n in names:
            c = CASES[n]
            print(f"{c.split:5s} {c.family:7s} {c.kind:9s} {c.level:4g}  {n}")
        counts = {s: sum(CASES[n].split == s for n in names) for s in ("tune", "check")}
        print(f"{len(names)} cases: {counts['tune']} tune, {counts['check']} check (corpus version {CORPUS_VERSION})")
        return 0
    for n in names:
        t0 = time.perf_counter()
        built = case_path(n, a.out).is_file()
        m = load_case(n, a.out)
        print(f"{CASES[n].split:5s} {n:40s} {len(m['V0']):6d} vertices {len(m['F']):6d} faces "
              f"{'cached' if built else f'built in {time.perf_counter() - t0:.1f} s'}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())

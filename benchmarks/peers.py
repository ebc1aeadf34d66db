"""Side-by-side peers benchmark: other libraries' smoothing filters, tuned on the clean mesh, beside ours.

Usage::

    python benchmarks/peers.py [--meshes NAME ...] [--peers NAME ...] [--ours NAME ...]
                               [--timeout 120] [--peer-timeout 600] [--jobs 2] [--quick] [--resume] [--out DIR]

Each *cell* (one mesh and one method) runs in a fresh Python process (``subprocess``), at most
``--jobs`` at a time; a cell that exceeds its timeout is killed and recorded as ``> T s``
(``--timeout``, default 120 s, for each of ours, one call; ``--peer-timeout``, default 600 s,
for a peer's whole grid search). A cell's result is stored in ``OUT/cells/`` as soon as it completes (``--resume``
measures only what is missing there, or was measured on another mesh: every cell names its mesh's content
fingerprint, :func:`mesh_fingerprint`, and older cells without one are reused only when their mesh's stored input
cell names the noise the mesh has now).

Peers (installed by the optional extra ``pip install -e '.[bench]'``; a peer whose library
is missing is reported as such): MeshLib (``meshDenoiseViaNormals``, ``relaxKeepVolume``),
PyGEL (``anisotropic_smooth``, ``taubin_smooth``), PyVista (``smooth_taubin``, ``smooth``),
pymeshlab (Laplacian, HC Laplacian, Taubin, two-step) and Open3D (simple, Taubin). Each is
tuned over the grid of :data:`PEERS` against the clean mesh (its best case): the best grid
point by mean face-normal error and, separately, the best by SNR are reported. Where the
library's filter is memoryless from one iteration to the next (checked in the tests for
the ones marked ``path``), the iteration count is read along one run, one call per
iteration, stopping ``PATIENCE`` iterations after the last improvement of either criterion
or at ``MAX_ITERS``. The time reported is one fresh call at the best setting (loading the
arrays into the library, the filter, reading the vertices back), measured in the cell's
process after the search.

Ours, with no clean mesh: the default ``meshdenoise.denoise(mesh)`` (whatever method and
parameters it picks when run) and every filter with an automatic rule
(``meshdenoise.denoise(mesh, method=M)``), each timed as one call.

Vertex order: every peer's mesh is loaded, its vertex positions and faces read back right
after loading and after the filter; the library's vertex ``j`` is mapped to our vertex by
position (exact up to the library's float32), the mapping must be a bijection, and the
library's faces, mapped back, must be ours (up to a cyclic rotation of each triangle) both
before and after the filter. A peer failing this is reported ("topology changed"), never
compared.

Meshes (:data:`MESHES`): the shared benchmark pairs (``MESHDENOISE_DATA/benchmark/*``, their
own noise), the paper's elephant and Nefertiti with Gaussian noise along the normals at
rho = 0.2 (the README quality table's rows), and pymeshlab's sample bunny and range map
``face000.ply`` with scanner-like noise: ``meshdenoise.add_scanner_noise`` when the package
has it, else the stand-in :func:`correlated_normal_noise` (labelled "stand-in" in the table).

Writes ``peers.md`` and ``peers.json`` to ``--out``.
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import shlex
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

MAX_ITERS = 200  # cap of an iteration-count search read along one run
# Stop a run this many iterations after the last improvement of the best over the whole grid so far: a grid
# search with early termination across a peer's settings, not meshdenoise.tuning.walk's per-run minimum (the
# oracle walk of our filters, quality.py and features.py); kept so the committed peers tables stay reproducible.
PATIENCE = 10
SCANNER_RHO_EDGES = 0.5  # scanner-like noise: rms displacement along normals, in mean edge lengths
SCANNER_CORRELATION_EDGES = 2.0  # its correlation length, in mean edge lengths
STANDIN_STEPS = 8  # lazy random-walk steps of the stand-in (about 2 edge lengths, see correlated_normal_noise)


class TopologyChanged(RuntimeError):
    """A peer's output does not correspond vertex by vertex to its input."""


# ----------------------------------------------------------------------------- meshes
def mean_edge_length(V: np.ndarray, F: np.ndarray) -> float:
    """Mean length of the mesh's undirected edges."""
    E = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    E = np.unique(E, axis=0)
    return float(np.linalg.norm(V[E[:, 0]] - V[E[:, 1]], axis=1).mean())


def correlated_normal_noise(V: np.ndarray, F: np.ndarray, rho: float, steps: int = STANDIN_STEPS,
                            seed: int = 0) -> np.ndarray:
    """Stand-in scanner noise: spatially correlated displacement along the vertex normals.

    White Gaussian noise per vertex, smoothed by ``steps`` lazy random-walk steps
    ``e <- (e + D^-1 W e) / 2`` on the edge graph (W the 0/1 adjacency, D its degrees), then
    rescaled to root-mean-square ``rho`` and applied along the unit vertex normals. A lazy
    step spreads a value by a variance of about half an edge length squared, so ``steps`` = 8
    gives a kernel of standard deviation about 2 edge lengths.

    Parameters
    ----------
    V : (n, 3) float array
    F : (m, 3) int array
    rho : float
        Root-mean-square displacement, mesh units.
    steps : int
        Random-walk steps (correlation length about ``sqrt(steps / 2)`` edge lengths).
    seed : int

    Returns
    -------
    (n, 3) float array
        The noisy vertices.
    """
    import scipy.sparse as sp

    from meshdenoise.geometry import vertex_normals

    n = V.shape[0]
    E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    W = sp.coo_matrix((np.ones(len(E)), (E[:, 0], E[:, 1])), shape=(n, n)).tocsr()
    W = ((W + W.T) > 0).astype(np.float64)
    deg = np.asarray(W.sum(1)).ravel()
    deg[deg == 0] = 1.0
    P = sp.diags(1.0 / deg) @ W
    e = np.random.default_rng(seed).standard_normal(n)
    for _ in range(steps):
        e = 0.5 * (e + P @ e)
    e *= rho / np.sqrt(np.mean(e**2))
    return V + e[:, None] * vertex_normals(V, F)


def _scanner_noise(V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, str]:
    import meshdenoise as md

    h = mean_edge_length(V, F)
    rho = SCANNER_RHO_EDGES * h
    fn = getattr(md, "add_scanner_noise", None)
    if fn is not None:
        try:
            out = fn((V, F), rho, correlation_length=SCANNER_CORRELATION_EDGES, seed=0)
            Vn = out[0] if isinstance(out, tuple) else out
            return np.asarray(Vn, dtype=np.float64), (
                f"meshdenoise.add_scanner_noise, rms {SCANNER_RHO_EDGES:g} edge lengths, "
                f"correlation {SCANNER_CORRELATION_EDGES:g} edge lengths")
        except TypeError:
            pass  # a different signature than expected: use the stand-in, and say so
    return correlated_normal_noise(V, F, rho), (
        f"stand-in correlated noise along normals (benchmarks/peers.py), rms {SCANNER_RHO_EDGES:g} edge lengths, "
        f"{STANDIN_STEPS} random-walk steps (~{SCANNER_CORRELATION_EDGES:g} edge lengths)")


def _benchmark_pair(name: str) -> Callable[[], dict]:
    def build() -> dict:
        from meshdenoise.data import data_file
        from meshdenoise.io import load_arrays

        V0, F = load_arrays(data_file(f"benchmark/{name}/Original.obj"))
        Vn, Fn = load_arrays(data_file(f"benchmark/{name}/Noisy.obj"))
        if not np.array_equal(F, Fn):
            raise ValueError(f"benchmark/{name}: Noisy.obj and Original.obj have different faces")
        return {"V0": V0, "F": F, "Vn": Vn, "noise": "the benchmark's own noise"}

    return build


def _paper(file: str, rho: float) -> Callable[[], dict]:
    def build() -> dict:
        from meshdenoise.data import data_file
        from meshdenoise.io import load_arrays
        from meshdenoise.noise import add_normal_noise

        V0, F = load_arrays(data_file(file))
        Vn = add_normal_noise((V0, F), rho, seed=0)[0]
        return {"V0": V0, "F": F, "Vn": Vn, "noise": f"Gaussian along normals, rho={rho:g} (seed 0)"}

    return build


def _sample(file: str) -> Callable[[], dict]:
    def build() -> dict:
        from meshdenoise.data import sample_mesh
        from meshdenoise.io import load_arrays

        V0, F = load_arrays(sample_mesh(file))
        used = np.unique(F)
        dropped = V0.shape[0] - used.size
        if dropped:  # a range map ships unreferenced vertices; libraries that drop them (PyGEL) could not be compared
            number = np.full(V0.shape[0], -1, dtype=np.int64)
            number[used] = np.arange(used.size)
            V0, F = V0[used], number[F]
        Vn, label = _scanner_noise(V0, F)
        return {"V0": V0, "F": F, "Vn": Vn,
                "noise": label + (f"; {dropped} unreferenced vertices of the file dropped" if dropped else "")}

    return build


def _tiny() -> dict:
    """A small generated mesh (icosphere, normal noise) for tests and --quick."""
    from meshdenoise.noise import add_normal_noise
    from meshdenoise.shapes import icosphere

    V0, F = icosphere(2)
    Vn = add_normal_noise((V0, F), 0.02, seed=0)[0]
    return {"V0": V0, "F": F, "Vn": Vn, "noise": "Gaussian along normals, rho=0.02 (seed 0)"}


MESHES: dict[str, Callable[[], dict]] = {
    "Fandisk0.3": _benchmark_pair("Fandisk0.3"),
    "Block0.4": _benchmark_pair("Block0.4"),
    "Twelve0.5Impulsive": _benchmark_pair("Twelve0.5Impulsive"),
    "nefertiti rho=0.2": _paper("nefertiti.off", 0.2),
    "Bunny0.2": _benchmark_pair("Bunny0.2"),
    "bunny scanner": _sample("bunny.obj"),
    "elephant rho=0.2": _paper("elephant-50kv.off", 0.2),
    "face000 scanner": _sample("rangemaps/face000.ply"),
    "tiny": _tiny,
}
DEFAULT_MESHES = [m for m in MESHES if m != "tiny"]
CORPUS_PREFIX = "corpus:"  # "corpus:NAME" is case NAME of the validation corpus (benchmarks/corpus.py)


def build_mesh(name: str) -> dict:
    """A benchmark mesh by name: a row of :data:`MESHES` or a corpus case ``corpus:NAME``."""
    if name.startswith(CORPUS_PREFIX):
        import corpus

        return corpus.load_case(name[len(CORPUS_PREFIX):])
    return MESHES[name]()


# ----------------------------------------------------------------------------- vertex order
def _canonical_triangles(F: np.ndarray) -> np.ndarray:
    """Each row rotated so that its smallest index comes first (orientation kept), rows sorted."""
    F = np.asarray(F, dtype=np.int64)
    r = np.argmin(F, axis=1)
    idx = (r[:, None] + np.arange(3)[None, :]) % 3
    G = np.take_along_axis(F, idx, axis=1)
    return G[np.lexsort(G.T[::-1])]


def vertex_map(V: np.ndarray, F: np.ndarray, V_lib: np.ndarray, F_lib: np.ndarray) -> np.ndarray:
    """Index ``idx`` with ``V_lib[idx]`` in our vertex order; raises :class:`TopologyChanged`.

    ``V_lib``, ``F_lib`` are the library's vertices and faces right after loading ``(V, F)``.
    Vertex ``i`` is matched to the library vertex at the same position (identity when the
    library kept the order; else nearest position, tolerance 1e-5 of the bounding-box
    diagonal, for float32 libraries); the match must be a bijection and the library's faces,
    mapped back, must equal ``F`` up to a cyclic rotation of each triangle and their order.

    Parameters
    ----------
    V : (n, 3) float array
    F : (m, 3) int array
    V_lib : (n', 3) float array
    F_lib : (m', 3) int array

    Returns
    -------
    (n,) int array
    """
    n = V.shape[0]
    if V_lib.shape != V.shape or np.asarray(F_lib).shape != F.shape:
        raise TopologyChanged(f"{V_lib.shape[0]} vertices and {len(F_lib)} faces, the input has {n} and {len(F)}")
    tol = 1e-5 * float(np.linalg.norm(V.max(0) - V.min(0)))
    if np.abs(V_lib - V).max() <= tol:
        idx = np.arange(n)
    else:
        from scipy.spatial import cKDTree

        dist, idx = cKDTree(V_lib).query(V)
        if dist.max() > tol:
            raise TopologyChanged(f"a vertex moved by {dist.max():.3g} on loading (tolerance {tol:.3g})")
        if np.unique(idx).size != n:
            idx = _resolve_coincident(V, F, V_lib, np.asarray(F_lib, dtype=np.int64), idx, tol)
    check_faces(F, F_lib, idx)
    return idx


def _resolve_coincident(V: np.ndarray, F: np.ndarray, V_lib: np.ndarray, F_lib: np.ndarray, idx: np.ndarray,
                        tol: float) -> np.ndarray:
    """Tell apart vertices at one position (a non-manifold vertex split into one per fan) by their faces.

    Each of our vertices that shares its nearest library vertex with another is matched to the library vertex
    at its position whose faces' other corners (mapped through ``idx``) are its own; :class:`TopologyChanged`
    when not exactly one does. A loop over those few vertices only.
    """
    from scipy.spatial import cKDTree

    idx = idx.copy()
    tree = cKDTree(V_lib)
    for i in np.flatnonzero(np.bincount(idx, minlength=len(V_lib))[idx] > 1):
        ours = {frozenset(int(idx[v]) for v in row if v != i) for row in F[(F == i).any(1)]}
        match = [j for j in tree.query_ball_point(V[i], tol)
                 if {frozenset(int(v) for v in row if v != j) for row in F_lib[(F_lib == j).any(1)]} == ours]
        if len(match) != 1:
            raise TopologyChanged(f"the vertex mapping is not a bijection (vertex {i} has {len(match)} matches)")
        idx[i] = match[0]
    if np.unique(idx).size != len(idx):
        raise TopologyChanged(f"the vertex mapping is not a bijection ({len(idx) - np.unique(idx).size} collisions)")
    return idx


def check_faces(F: np.ndarray, F_lib: np.ndarray, idx: np.ndarray) -> None:
    """Raise :class:`TopologyChanged` unless ``F_lib`` mapped back through ``idx`` is ``F``."""
    F_lib = np.asarray(F_lib, dtype=np.int64)
    if F_lib.shape != F.shape or (F_lib.size and (F_lib.min() < 0 or F_lib.max() >= len(idx))):
        raise TopologyChanged(f"faces changed: {len(F_lib)} faces, the input has {len(F)}")
    inv = np.empty(len(idx), dtype=np.int64)
    inv[idx] = np.arange(len(idx))
    if not np.array_equal(_canonical_triangles(inv[F_lib]), _canonical_triangles(F)):
        raise TopologyChanged("the library's faces, mapped back to our vertices, differ from the input's")


# ----------------------------------------------------------------------------- peers
class Session:
    """One mesh loaded into a library. Subclasses load in ``__init__`` and set nothing else.

    ``vertices()`` and ``faces()`` read the library's current state (its vertex order);
    ``apply(params, iterations)`` runs the filter in place ``iterations`` times (one call
    when the library takes an iteration count).
    """

    def __init__(self, V: np.ndarray, F: np.ndarray):
        raise NotImplementedError

    def vertices(self) -> np.ndarray:
        raise NotImplementedError

    def faces(self) -> np.ndarray:
        raise NotImplementedError

    def apply(self, params: dict, iterations: int = 1) -> None:
        raise NotImplementedError


class _MeshLibSession(Session):
    def __init__(self, V, F):
        from meshlib import mrmeshnumpy as mn

        self.mn = mn
        self.m = mn.meshFromFacesVerts(np.ascontiguousarray(F, dtype=np.int32), np.ascontiguousarray(V))

    def vertices(self):
        return np.asarray(self.mn.getNumpyVerts(self.m), dtype=np.float64)

    def faces(self):
        return np.asarray(self.mn.getNumpyFaces(self.m.topology), dtype=np.int64)


class MeshLibDenoise(_MeshLibSession):
    def apply(self, params, iterations=1):
        from meshlib import mrmeshpy as mr

        s = mr.DenoiseViaNormalsSettings()
        for k, v in params.items():
            setattr(s, k, v)
        for _ in range(iterations):
            mr.meshDenoiseViaNormals(self.m, s)


class MeshLibRelax(_MeshLibSession):
    def apply(self, params, iterations=1):
        from meshlib import mrmeshpy as mr

        p = mr.MeshRelaxParams()
        p.force = float(params["force"])
        p.iterations = int(iterations)
        mr.relaxKeepVolume(self.m, p)


class _PyGELSession(Session):
    def __init__(self, V, F):
        from pygel3d import hmesh

        self.hmesh = hmesh
        self.m = hmesh.Manifold.from_triangles(np.ascontiguousarray(V), np.ascontiguousarray(F, dtype=np.int64))

    def vertices(self):
        ids = np.asarray(list(self.m.vertices()), dtype=np.int64)
        return np.asarray(self.m.positions(), dtype=np.float64)[ids]

    def faces(self):
        ids = np.asarray(list(self.m.vertices()), dtype=np.int64)
        compact = np.full(self.m.no_allocated_vertices(), -1, dtype=np.int64)
        compact[ids] = np.arange(len(ids))
        return compact[np.array([list(self.m.circulate_face(f, "v")) for f in self.m.faces()], dtype=np.int64)]


class PyGELAnisotropic(_PyGELSession):
    def apply(self, params, iterations=1):
        self.hmesh.anisotropic_smooth(self.m, sharpness=float(params["sharpness"]), no_iters=int(iterations))


class PyGELTaubin(_PyGELSession):
    def apply(self, params, iterations=1):
        self.hmesh.taubin_smooth(self.m, no_iters=int(iterations))


class _PyVistaSession(Session):
    def __init__(self, V, F):
        import pyvista as pv

        self.pd = pv.PolyData.from_regular_faces(np.ascontiguousarray(V), np.ascontiguousarray(F, dtype=np.int64))

    def vertices(self):
        return np.asarray(self.pd.points, dtype=np.float64)

    def faces(self):
        return np.asarray(self.pd.regular_faces, dtype=np.int64)


class PyVistaTaubin(_PyVistaSession):
    def apply(self, params, iterations=1):
        for _ in range(iterations):
            self.pd = self.pd.smooth_taubin(**params)


class PyVistaSmooth(_PyVistaSession):
    def apply(self, params, iterations=1):
        for _ in range(iterations):
            self.pd = self.pd.smooth(**params)


class _MeshLabSession(Session):
    filter_name = ""
    steps_param: str | None = "stepsmoothnum"

    def __init__(self, V, F):
        import pymeshlab

        self.ms = pymeshlab.MeshSet()
        self.ms.add_mesh(pymeshlab.Mesh(vertex_matrix=np.ascontiguousarray(V), face_matrix=np.ascontiguousarray(F, dtype=np.int32)))

    def vertices(self):
        return np.array(self.ms.current_mesh().vertex_matrix(), dtype=np.float64)

    def faces(self):
        return np.array(self.ms.current_mesh().face_matrix(), dtype=np.int64)

    def apply(self, params, iterations=1):
        fn = getattr(self.ms, self.filter_name)
        if self.steps_param is None:
            for _ in range(iterations):
                fn(**params)
        else:
            fn(**params, **{self.steps_param: int(iterations)})


class MeshLabLaplacian(_MeshLabSession):
    filter_name = "apply_coord_laplacian_smoothing"


class MeshLabHC(_MeshLabSession):
    filter_name = "apply_coord_hc_laplacian_smoothing"
    steps_param = None


class MeshLabTaubin(_MeshLabSession):
    filter_name = "apply_coord_taubin_smoothing"


class MeshLabTwoStep(_MeshLabSession):
    filter_name = "apply_coord_two_steps_smoothing"


class _Open3DSession(Session):
    method = ""

    def __init__(self, V, F):
        import open3d as o3d

        self.m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(np.ascontiguousarray(V)),
                                           o3d.utility.Vector3iVector(np.ascontiguousarray(F, dtype=np.int32)))

    def vertices(self):
        return np.asarray(self.m.vertices, dtype=np.float64).copy()

    def faces(self):
        return np.asarray(self.m.triangles, dtype=np.int64).copy()

    def apply(self, params, iterations=1):
        self.m = getattr(self.m, self.method)(number_of_iterations=int(iterations), **params)


class Open3DSimple(_Open3DSession):
    method = "filter_smooth_simple"


class Open3DTaubin(_Open3DSession):
    method = "filter_smooth_taubin"


@dataclass
class Peer:
    """A peer filter and its tuning grid.

    ``grid`` and ``quick_grid`` list parameter dicts. With ``path`` the filter is memoryless
    from one iteration to the next: for each dict the iteration count is searched along one
    run (1 to ``MAX_ITERS``, patience ``PATIENCE``; 1 to ``quick_iters`` with ``--quick``);
    without it each dict is one fresh call (its iteration count, if any, is in the dict).
    """

    library: str  # the import name whose absence makes the peer "not installed"
    call: str  # what is called, for the table
    session: type
    grid: list[dict]
    quick_grid: list[dict]
    path: bool = False
    quick_iters: int = 3
    notes: str = ""


def _product(**axes: list) -> list[dict]:
    keys = list(axes)
    return [dict(zip(keys, vals)) for vals in itertools.product(*(axes[k] for k in keys))]


_PV_FEATURES = [{"feature_smoothing": False}] + [{"feature_smoothing": True, "feature_angle": a} for a in (30.0, 60.0)]

PEERS: dict[str, Peer] = {
    "MeshLib denoise": Peer(
        "meshlib", "mrmeshpy.meshDenoiseViaNormals", MeshLibDenoise,
        _product(beta=[0.001, 0.003, 0.01, 0.03, 0.1], gamma=[1.0, 3.0, 10.0, 30.0, 100.0]),
        _product(beta=[0.01], gamma=[1.0, 5.0]),
        notes="beta: crease sensitivity (0.001 sharp, 0.1 smooth); gamma: amount of smoothing; "
              "normalIters=10, pointIters=20 (defaults)"),
    "MeshLib relax": Peer(
        "meshlib", "mrmeshpy.relaxKeepVolume", MeshLibRelax,
        _product(force=[0.1, 0.25, 0.5]), _product(force=[0.5]), path=True,
        notes="force per iteration; iterations searched along the run"),
    "PyGEL anisotropic": Peer(
        "pygel3d", "hmesh.anisotropic_smooth", PyGELAnisotropic,
        _product(sharpness=[0.0, 3.0, 10.0, 30.0, 100.0]), _product(sharpness=[3.0]), path=True,
        notes="sharpness s: neighbour normal weight exp(-s * angle / pi); no_iters searched along the run"),
    "PyGEL Taubin": Peer("pygel3d", "hmesh.taubin_smooth", PyGELTaubin, [{}], [{}], path=True,
                         notes="fixed lambda 0.5, mu -0.52; no_iters searched along the run"),
    "PyVista Taubin": Peer(
        "pyvista", "PolyData.smooth_taubin", PyVistaTaubin,
        [{**a, **f} for a in _product(n_iter=[10, 20, 50, 100], pass_band=[0.001, 0.005, 0.02, 0.1]) for f in _PV_FEATURES],
        [{"n_iter": 10, "pass_band": 0.1, **f} for f in _PV_FEATURES[:2]],
        notes="windowed sinc (not memoryless: each n_iter a fresh call); feature_angle used when feature_smoothing"),
    "PyVista smooth": Peer(
        "pyvista", "PolyData.smooth", PyVistaSmooth,
        [{**a, **f} for a in _product(n_iter=[10, 30, 100, 300], relaxation_factor=[0.01, 0.03, 0.1, 0.3]) for f in _PV_FEATURES],
        [{"n_iter": 10, "relaxation_factor": 0.1, **f} for f in _PV_FEATURES[:2]],
        notes="Laplacian with relaxation factor; feature edges found on the input (a fresh call per setting)"),
    "MeshLab Laplacian": Peer(
        "pymeshlab", "apply_coord_laplacian_smoothing", MeshLabLaplacian,
        _product(cotangentweight=[False, True]), _product(cotangentweight=[False]), path=True),
    "MeshLab HC": Peer("pymeshlab", "apply_coord_hc_laplacian_smoothing", MeshLabHC, [{}], [{}], path=True,
                       notes="no parameter; repeated k times"),
    "MeshLab Taubin": Peer(
        "pymeshlab", "apply_coord_taubin_smoothing", MeshLabTaubin,
        [{"lambda_": 0.5, "mu": -0.53}, {"lambda_": 0.33, "mu": -0.34}, {"lambda_": 0.7, "mu": -0.75}],
        [{"lambda_": 0.5, "mu": -0.53}], path=True),
    "MeshLab two-step": Peer(
        "pymeshlab", "apply_coord_two_steps_smoothing", MeshLabTwoStep,
        _product(normalthr=[15.0, 30.0, 60.0, 90.0], stepnormalnum=[2, 5, 20]), _product(normalthr=[60.0], stepnormalnum=[5]),
        path=True, notes="normalthr: feature angle (deg); stepfitnum=20 (default); stepsmoothnum searched"),
    "Open3D simple": Peer("open3d", "filter_smooth_simple", Open3DSimple, [{}], [{}], path=True),
    "Open3D Taubin": Peer(
        "open3d", "filter_smooth_taubin", Open3DTaubin,
        [{"lambda_filter": 0.5, "mu": -0.53}, {"lambda_filter": 0.33, "mu": -0.34}],
        [{"lambda_filter": 0.5, "mu": -0.53}], path=True),
}


def installed(library: str) -> bool:
    import importlib.util

    return importlib.util.find_spec(library) is not None


# ----------------------------------------------------------------------------- measuring
def _quality(V0: np.ndarray, F: np.ndarray, X: np.ndarray, distance: bool = False) -> dict:
    from meshdenoise.metrics import snr
    from meshdenoise.metrics import mean_distance, normal_error_deg

    out = {"normal_error_deg": normal_error_deg((V0, F), X), "snr_db": snr(V0, X)}
    if distance:
        out["mean_distance"] = mean_distance((V0, F), X)
        out["flipped"] = flipped_faces(V0, F, X)
    return out


def flipped_faces(V0: np.ndarray, F: np.ndarray, X: np.ndarray) -> int:
    """Faces of ``(X, F)`` whose normal turned more than 90 degrees from the clean mesh's (degenerate ones left out)."""
    from meshdenoise.geometry import face_normals

    N0, N = face_normals(V0, F), face_normals(X, F)
    return int(np.count_nonzero(np.einsum("ij,ij->i", N0, N) < 0))


def _run_once(session_cls: type, V: np.ndarray, F: np.ndarray, params: dict, iterations: int) -> tuple[np.ndarray, float]:
    """One fresh call at a setting, timed (load, filter, read back); vertices in our order."""
    t0 = time.perf_counter()
    s = session_cls(V, F)
    idx = vertex_map(V, F, s.vertices(), s.faces())
    s.apply(params, iterations)
    X = s.vertices()
    elapsed = time.perf_counter() - t0
    if X.shape != V.shape:
        raise TopologyChanged(f"{X.shape[0]} vertices after the filter, {V.shape[0]} before")
    check_faces(F, s.faces(), idx)
    return X[idx], elapsed


def tune_peer(peer: Peer, V0: np.ndarray, F: np.ndarray, Vn: np.ndarray, quick: bool = False) -> dict:
    """Search the peer's grid against the clean mesh; best by normal error and best by SNR.

    Returns ``{"best_normal": {...}, "best_snr": {...}, "evaluated": int}``, each best with
    ``params``, ``iterations`` (path peers), the metrics of a fresh timed call and ``time_s``.
    """
    grid = peer.quick_grid if quick else peer.grid
    max_iters = peer.quick_iters if quick else MAX_ITERS
    best = {"normal": (np.inf, None), "snr": (-np.inf, None)}
    evaluated = 0

    def consider(X: np.ndarray, setting: tuple) -> tuple[bool, bool]:
        nonlocal evaluated
        evaluated += 1
        q = _quality(V0, F, X)
        better_n = q["normal_error_deg"] < best["normal"][0]
        better_s = q["snr_db"] > best["snr"][0]
        if better_n:
            best["normal"] = (q["normal_error_deg"], setting)
        if better_s:
            best["snr"] = (q["snr_db"], setting)
        return better_n, better_s

    for params in grid:
        if peer.path:
            s = peer.session(Vn, F)
            idx = vertex_map(Vn, F, s.vertices(), s.faces())
            last = 0
            for k in range(1, max_iters + 1):
                s.apply(params, 1)
                X = s.vertices()
                if X.shape != Vn.shape:
                    raise TopologyChanged(f"{X.shape[0]} vertices after {k} iterations, {Vn.shape[0]} before")
                if any(consider(X[idx], (params, k))):
                    last = k
                if k - last >= PATIENCE:
                    break
            check_faces(F, s.faces(), idx)
        else:
            X, _ = _run_once(peer.session, Vn, F, params, 1)
            consider(X, (params, 1))
    out = {"evaluated": evaluated}
    for key in ("normal", "snr"):
        params, k = best[key][1]
        X, elapsed = _run_once(peer.session, Vn, F, params, k)
        rec = {"params": dict(params), **_quality(V0, F, X, distance=True), "time_s": elapsed}
        if peer.path:
            rec["iterations"] = k
        out[f"best_{key}"] = rec
    return out


def run_ours(method: str | None, V0: np.ndarray, F: np.ndarray, Vn: np.ndarray) -> dict:
    """Our default (``method=None``) or one filter's automatic choice, timed as one call, no clean mesh."""
    import meshdenoise as md

    t0 = time.perf_counter()
    if method is None:  # the default returns its decision: the method it picked and that method's parameters
        (X, _), choice = md.denoise((Vn.copy(), F), return_params=True)
        used = {"method": choice.method, **choice.params}
    else:
        (X, _), used = md.denoise((Vn.copy(), F), method=method, return_params=True)
    elapsed = time.perf_counter() - t0
    used = {k: (v if isinstance(v, (int, float, str, bool)) or v is None else repr(v)) for k, v in dict(used).items()}
    return {"params": used, **_quality(V0, F, np.asarray(X, dtype=np.float64), distance=True), "time_s": elapsed}


def _has_rule(spec: Any) -> bool:
    """Whether a registered filter has an automatic rule (``FilterSpec.auto``, declared at registration)."""
    return spec.auto is not None


def our_methods() -> list[str]:
    """Every registered filter with an automatic rule."""
    from meshdenoise.registry import list_filters

    return [f.name for f in list_filters() if _has_rule(f)]


def filters_without_rule() -> list[str]:
    """Registered filters that ``denoise(mesh, method=M)`` cannot tune (so not in the table)."""
    from meshdenoise.registry import list_filters

    return [f.name for f in list_filters() if not _has_rule(f)]


def mesh_fingerprint(m: dict) -> str:
    """A content digest of a benchmark mesh (clean and noisy vertices, faces): stored in every cell, so that
    ``--resume`` never puts cells measured on two different meshes in one row (a changed noise, file or reader)."""
    from meshdenoise.tuning.memo import digest

    return digest(m["V0"], m["F"], m["Vn"])[:16]


def measure_cell(mesh: str, kind: str, name: str, quick: bool) -> dict:
    """One cell: ``kind`` is "peer", "ours" (``name`` a method or "default") or "input"; its result names the mesh's
    :func:`mesh_fingerprint`."""
    m = build_mesh(mesh)
    return {**_measure(m, kind, name, quick), "mesh_fingerprint": mesh_fingerprint(m)}


def _measure(m: dict, kind: str, name: str, quick: bool) -> dict:
    V0, F, Vn = m["V0"], m["F"], m["Vn"]
    if kind == "input":
        import meshdenoise as md

        return {"n_vertices": int(V0.shape[0]), "n_faces": int(F.shape[0]), "noise": m["noise"],
                "mean_edge": mean_edge_length(V0, F), "rho_estimated": float(md.estimate_noise((Vn, F))),
                **_quality(V0, F, Vn, distance=True)}
    if kind == "ours":
        return run_ours(None if name == "default" else name, V0, F, Vn)
    peer = PEERS[name]
    if not installed(peer.library):
        return {"status": f"{peer.library} not installed"}
    try:
        return tune_peer(peer, V0, F, Vn, quick=quick)
    except TopologyChanged as exc:
        return {"status": f"topology changed: {exc}"}


# ----------------------------------------------------------------------------- driving
def _slug(*parts: str) -> str:
    return "__".join("".join(c if c.isalnum() else "_" for c in p) for p in parts)


@dataclass
class Cell:
    mesh: str
    kind: str
    name: str
    result: dict = field(default_factory=dict)


def run_cells(cells: list[Cell], store: Path, timeout: float, jobs: int, quick: bool, resume: bool,
              log: Callable[[str], None] = print, peer_timeout: float | None = None) -> None:
    """Measure the cells, each in a fresh process, ``jobs`` at a time; results into ``cell.result``.

    ``timeout`` bounds each cell of ours (one call) and the input cell, ``peer_timeout``
    (default ``timeout``) each peer cell (a whole grid search).
    """
    store.mkdir(parents=True, exist_ok=True)
    todo = []
    current: dict[str, dict] = {}  # mesh -> its fingerprint and noise line now (built once, when cells are reused)
    for c in cells:
        f = store / (_slug(c.mesh, c.kind, c.name) + ".json")
        stored = json.loads(f.read_text()) if resume and f.is_file() else None
        if stored is not None:
            if c.mesh not in current:
                m = build_mesh(c.mesh)
                current[c.mesh] = {"fingerprint": mesh_fingerprint(m), "noise": m["noise"]}
            why = stale(stored, current[c.mesh], store / (_slug(c.mesh, "input", "input") + ".json"))
            if why:
                log(f"{c.mesh:20s} {c.kind:5s} {c.name:22s} stored cell {why}: measured again")
                stored = None
        if stored is not None:
            c.result = stored
        else:
            todo.append((c, f))
    running: list[tuple[Cell, Path, subprocess.Popen, float, Any]] = []
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    try:
        _drive(todo, running, env, timeout, peer_timeout or timeout, jobs, quick, log)
    finally:  # interrupted: no cell process outlives the driver
        for _, _, p, _, _ in running:
            if p.poll() is None:
                os.killpg(p.pid, 9)
                p.wait()


def stale(stored: dict, now: dict, input_cell: Path) -> str:
    """Why a stored cell may not be reused for the mesh as it is ``now`` (its fingerprint and noise line), "" if it may.

    A cell with a fingerprint is reused only on the same mesh. Older cells have none: they are
    reused when the stored input cell of their mesh names the noise the mesh has now (a run made
    when the noise was another, e.g. ``peers.py``'s stand-in, measured another mesh).
    """
    if "status" in stored and "mesh_fingerprint" not in stored:
        return ""  # a timeout or failure record: nothing measured on any mesh
    if "mesh_fingerprint" in stored:
        return "" if stored["mesh_fingerprint"] == now["fingerprint"] else "was measured on another mesh (fingerprint)"
    noise = json.loads(input_cell.read_text()).get("noise") if input_cell.is_file() else None
    if noise is not None and noise != now["noise"]:
        return f"predates fingerprints and its mesh had another noise ({noise!r})"
    return ""


def _drive(todo: list, running: list, env: dict, timeout: float, peer_timeout: float, jobs: int, quick: bool,
           log: Callable) -> None:
    while todo or running:
        while todo and len(running) < jobs:
            c, f = todo.pop(0)
            err = tempfile.TemporaryFile()
            cmd = [sys.executable, str(Path(__file__).resolve()), "--_cell", json.dumps([c.mesh, c.kind, c.name, quick]),
                   "--_result", str(f)]
            p = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=err, env=env, start_new_session=True)
            running.append((c, f, p, time.monotonic(), err))
        time.sleep(0.05)
        for item in list(running):
            c, f, p, t0, err = item
            wall = time.monotonic() - t0
            limit = peer_timeout if c.kind == "peer" else timeout
            if p.poll() is None and wall <= limit:
                continue
            if p.poll() is None:
                os.killpg(p.pid, 9)
                p.wait()
                c.result = {"status": f"> {limit:g} s", "timeout_s": limit}
            elif p.returncode == 0 and f.is_file():
                c.result = json.loads(f.read_text())
            else:
                err.seek(0)
                lines = [ln for ln in err.read().decode(errors="replace").strip().splitlines() if ln.strip()]
                c.result = {"status": "failed: " + (lines[-1] if lines else f"exit {p.returncode}")}
            c.result["wall_s"] = wall
            if "status" in c.result:
                f.write_text(json.dumps(c.result))
            err.close()
            running.remove(item)
            log(f"{c.mesh:20s} {c.kind:5s} {c.name:22s} {wall:7.1f} s  {c.result.get('status', 'ok')}")


def _cell_main(spec: str, result: str) -> None:
    mesh, kind, name, quick = json.loads(spec)
    out = measure_cell(mesh, kind, name, quick)
    out["cpu_s"] = time.process_time()  # the whole process, imports included, all threads
    tmp = Path(result).with_suffix(".tmp")
    tmp.write_text(json.dumps(out))
    tmp.replace(result)


# ----------------------------------------------------------------------------- table
def grid_edges(peer: Peer, rec: dict) -> list[str]:
    """The tuned parameters whose best value is the smallest or largest of its grid axis (numbers only)."""
    edges = []
    for k, v in rec.get("params", {}).items():
        axis = sorted({g[k] for g in peer.grid if k in g and isinstance(g[k], (int, float)) and not isinstance(g[k], bool)})
        if len(axis) > 1 and v in (axis[0], axis[-1]):
            edges.append(k)
    if peer.path and rec.get("iterations") == MAX_ITERS:
        edges.append("iterations")
    return edges


def _params(rec: dict, edges: list[str] = ()) -> str:
    p = dict(rec.get("params", {}))
    if "iterations" in rec:
        p["iterations"] = rec["iterations"]
    mark = {k: " (edge)" if k in edges else "" for k in p}
    return ", ".join((f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}") + mark[k] for k, v in p.items())


def _row(label: str, rec: dict, edges: list[str] = ()) -> str:
    if "status" in rec:
        return f"| {label} | {rec['status']} | | | | |"
    return (f"| {label} | {rec['normal_error_deg']:.2f} | {rec['snr_db']:.2f} | {rec['mean_distance']:.4g} | "
            f"{rec['time_s']:.2f} | {_params(rec, edges)} |")


def summarise(results: dict) -> list[dict]:
    """Per mesh: noisy, our default, our best automatic filter, best peer by normal error and by SNR."""
    rows = []
    for mesh, per in results.items():
        inp = per.get("input", {})
        ours = {k: v for k, v in per.get("ours", {}).items() if "status" not in v}
        peers = {k: v for k, v in per.get("peers", {}).items() if "status" not in v}
        row = {"mesh": mesh, "noisy_normal": inp.get("normal_error_deg"), "noisy_snr": inp.get("snr_db")}
        d = per.get("ours", {}).get("default")
        row["default"] = d
        auto = {k: v for k, v in ours.items() if k != "default"}
        if auto:
            k = min(auto, key=lambda m: auto[m]["normal_error_deg"])
            row["best_auto"] = (k, auto[k])
        if peers:
            k = min(peers, key=lambda m: peers[m]["best_normal"]["normal_error_deg"])
            row["best_peer_normal"] = (k, peers[k]["best_normal"])
            k = max(peers, key=lambda m: peers[m]["best_snr"]["snr_db"])
            row["best_peer_snr"] = (k, peers[k]["best_snr"])
        rows.append(row)
    return rows


def write_markdown(results: dict, meta: dict, path: Path) -> None:
    L = [f"# Peers benchmark ({meta['date']})", "",
         f"Command: `{meta['command']}`; commit {meta['commit']}; {meta['machine']}.", "",
         "Peers tuned on the clean mesh (their best case), ours with no clean mesh. Normal error: mean angle "
         "between corresponding face normals (deg, lower is better); SNR in dB (higher is better); "
         "distance: mean distance from the result's vertices to the clean surface (mesh units); time: one call "
         "(s, load + filter + read back for peers; the whole `denoise` call, choice included, for ours). "
         f"Registered filters with no automatic rule (not in the table): "
         f"{', '.join(meta.get('filters_without_automatic_rule', [])) or 'none'}.", "",
         "## Summary (mean face-normal error, deg; SNR, dB)", "",
         "| mesh | noisy | our default | our best automatic filter | best peer by normal error | best peer by SNR |",
         "|---|---|---|---|---|---|"]

    def cell(rec, name=None):
        if rec is None:
            return "not run"
        if "status" in rec:
            return (f"{name} " if name else "") + rec["status"]
        return (f"{name} " if name else "") + f"{rec['normal_error_deg']:.2f} ({rec['snr_db']:.2f} dB, {rec['time_s']:.2f} s)"

    for r in summarise(results):
        noisy = "not run" if r["noisy_normal"] is None else f"{r['noisy_normal']:.2f} ({r['noisy_snr']:.2f} dB)"
        L.append(f"| {r['mesh']} | {noisy} | {cell(r['default'])} | "
                 f"{cell(*r['best_auto'][::-1]) if 'best_auto' in r else 'none'} | "
                 f"{cell(*r['best_peer_normal'][::-1]) if 'best_peer_normal' in r else 'none'} | "
                 f"{cell(*r['best_peer_snr'][::-1]) if 'best_peer_snr' in r else 'none'} |")
    L += ["", "## Against the targets of issue 22 (our default, no clean mesh)", "",
          "Normal error at or below the best oracle-tuned peer's; SNR at least 3 dB above the input and within "
          "0.5 dB of the best peer's SNR (or above it). Peers that beat our default / our best automatic filter on "
          "normal error (at their best-normal setting) are listed.", "",
          "| mesh | default / best peer normal error | default SNR - input (dB) | default SNR - best peer SNR (dB) | "
          "peers beating our default | peers beating our best automatic filter |", "|---|---|---|---|---|---|"]
    for r in summarise(results):
        d, per = r["default"], results[r["mesh"]]
        if not d or "status" in d or "best_peer_normal" not in r or r["noisy_snr"] is None:
            L.append(f"| {r['mesh']} | not measured | | | | |")
            continue
        bp, bs = r["best_peer_normal"][1], r["best_peer_snr"][1]
        ok = {k: v["best_normal"]["normal_error_deg"] for k, v in per["peers"].items() if "status" not in v}
        beat_d = [k for k, e in sorted(ok.items(), key=lambda t: t[1]) if e < d["normal_error_deg"]]
        ba = r.get("best_auto", (None, None))[1]
        beat_a = [k for k, e in sorted(ok.items(), key=lambda t: t[1]) if ba and e < ba["normal_error_deg"]]
        L.append(f"| {r['mesh']} | {d['normal_error_deg'] / bp['normal_error_deg']:.2f} | "
                 f"{d['snr_db'] - r['noisy_snr']:+.2f} | {d['snr_db'] - bs['snr_db']:+.2f} | "
                 f"{', '.join(beat_d) or 'none'} | {', '.join(beat_a) or 'none'} |")
    for mesh, per in results.items():
        inp = per.get("input", {})
        L += ["", f"## {mesh}", ""]
        if "status" in inp or not inp:
            L.append(f"input: {inp.get('status', 'not run')}")
            continue
        L += [f"{inp['n_vertices']} vertices, {inp['n_faces']} faces, mean edge {inp['mean_edge']:.4g}; noise: {inp['noise']}; "
              f"our noise estimate {inp['rho_estimated']:.4g}.", "",
              "| method | normal err (deg) | SNR (dB) | mean dist | time (s) | parameters ('edge': best at the end of "
              "its grid axis) |", "|---|---|---|---|---|---|",
              f"| noisy input | {inp['normal_error_deg']:.2f} | {inp['snr_db']:.2f} | {inp['mean_distance']:.4g} | | |"]
        for name, rec in per.get("ours", {}).items():
            L.append(_row("ours: default `denoise(mesh)`" if name == "default" else f"ours: {name} auto", rec))
        for name, rec in per.get("peers", {}).items():
            if "status" in rec:
                L.append(_row(f"{name} ({PEERS[name].call})", rec))
                continue
            L.append(_row(f"{name}, best normal", rec["best_normal"], grid_edges(PEERS[name], rec["best_normal"])))
            L.append(_row(f"{name}, best SNR", rec["best_snr"], grid_edges(PEERS[name], rec["best_snr"])))
    L += ["", "## Grids", "", "| peer | call | grid | notes |", "|---|---|---|---|"]
    for name, p in PEERS.items():
        grid = "; ".join(", ".join(f"{k}={v}" for k, v in g.items()) or "(none)" for g in p.grid)
        if p.path:
            grid += f"; iterations 1..{MAX_ITERS} along the run (patience {PATIENCE})"
        L.append(f"| {name} | `{p.call}` | {grid} | {p.notes} |")
    path.write_text("\n".join(L) + "\n")


def _commit() -> str:
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True,
                              check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=ROOT, capture_output=True,
                               text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return head + ("+dirty" if dirty else "")


def _terminate(signum, frame):  # SIGTERM: unwind through run_cells' cleanup
    raise KeyboardInterrupt


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--meshes", nargs="+", default=None, help=f"of {', '.join(MESHES)} (default: all but tiny)")
    ap.add_argument("--peers", nargs="+", default=None, help=f"of {', '.join(PEERS)} (default: all)")
    ap.add_argument("--ours", nargs="+", default=None, help="'default' and filters with an automatic rule (default: all)")
    ap.add_argument("--timeout", type=float, default=120.0, help="seconds per cell of ours (one call; default 120)")
    ap.add_argument("--peer-timeout", type=float, default=600.0,
                    help="seconds per peer cell (its whole grid search; default 600)")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--quick", action="store_true", help="small grids and few iterations (for tests)")
    ap.add_argument("--resume", action="store_true", help="reuse the cells stored in OUT/cells")
    ap.add_argument("--table-only", action="store_true",
                    help="write the table from the cells stored in OUT/cells; measure nothing (missing: 'not run')")
    ap.add_argument("--out", type=Path, default=Path("out/peers"))
    ap.add_argument("--_cell", help=argparse.SUPPRESS)
    ap.add_argument("--_result", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a._cell:
        _cell_main(a._cell, a._result)
        return 0
    meshes = a.meshes or DEFAULT_MESHES
    peers = a.peers or list(PEERS)
    ours = a.ours or ["default", *our_methods()]
    for kind, names, known in (("mesh", meshes, MESHES), ("peer", peers, PEERS)):
        bad = [n for n in names if n not in known]
        if bad:
            print(f"peers.py: unknown {kind} {bad[0]!r}; known: {', '.join(known)}", file=sys.stderr)
            return 2
    bad = [n for n in ours if n != "default" and n not in our_methods()]
    if bad:
        print(f"peers.py: {bad[0]!r} is not a filter with an automatic rule; known: default, {', '.join(our_methods())}",
              file=sys.stderr)
        return 2
    if a.timeout <= 0 or a.peer_timeout <= 0 or a.jobs < 1:
        print("peers.py: --timeout and --peer-timeout must be > 0 and --jobs >= 1", file=sys.stderr)
        return 2
    cells = []
    for mesh in meshes:
        cells.append(Cell(mesh, "input", "input"))
        cells += [Cell(mesh, "peer", p) for p in peers]
        cells += [Cell(mesh, "ours", o) for o in ours]
    import signal

    signal.signal(signal.SIGTERM, _terminate)
    t0 = time.time()
    if a.table_only:
        for c in cells:
            f = a.out / "cells" / (_slug(c.mesh, c.kind, c.name) + ".json")
            c.result = json.loads(f.read_text()) if f.is_file() else {"status": "not run"}
    else:
        run_cells(cells, a.out / "cells", a.timeout, a.jobs, a.quick, a.resume, peer_timeout=a.peer_timeout)
    results: dict = {}
    for c in cells:
        per = results.setdefault(c.mesh, {"input": {}, "ours": {}, "peers": {}})
        if c.kind == "input":
            per["input"] = c.result
        else:
            per["ours" if c.kind == "ours" else "peers"][c.name] = c.result
    load = os.getloadavg()
    meta = {"date": time.strftime("%Y-%m-%d", time.gmtime()), "commit": _commit(),
            "command": "python benchmarks/peers.py " + shlex.join(argv if argv is not None else sys.argv[1:]),
            "machine": f"{os.cpu_count()} cores, load average {load[0]:.1f} at the end (shared machine: times are under load)",
            "wall_s": time.time() - t0, "timeout_s": a.timeout, "peer_timeout_s": a.peer_timeout, "quick": a.quick,
            "grids": {n: {"call": p.call, "grid": p.grid, "path": p.path, "notes": p.notes} for n, p in PEERS.items()},
            "filters_without_automatic_rule": filters_without_rule()}
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "peers.json").write_text(json.dumps({"meta": meta, "results": results}, indent=1, default=float))
    write_markdown(results, meta, a.out / "peers.md")
    print(f"wrote {a.out / 'peers.md'} and {a.out / 'peers.json'} ({meta['wall_s']:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

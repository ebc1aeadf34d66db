"""The clean shapes of the validation corpus (benchmarks/corpus.py): CAD parts, organic and scanned shapes.

CAD parts are built with manifold3d (constructive solid geometry: booleans, extrusions of
offset cross-sections for fillets, revolutions, hulls) and remeshed to near-uniform triangles by
pymeshlab's isotropic remeshing with feature edges kept. Organic shapes are pymeshlab's and
PyVista's sample meshes, the shared meshes' clean sides, and implicit surfaces through marching
cubes (VTK's, through PyVista). manifold3d and PyVista are in the ``bench`` extra, never needed at
run time. Every builder is deterministic: the same numbers on every machine and run.
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np

SEGMENTS = 64  # circle segments of the CAD primitives: facets of 5.6 degrees, below the remeshing's feature angle
FEATURE_DEG = 30.0  # the remeshing keeps edges sharper than this (pymeshlab's default)
REMESH_ITERATIONS = 8


# ----------------------------------------------------------------------------- remeshing
def _arrays(manifold) -> tuple[np.ndarray, np.ndarray]:
    mesh = manifold.to_mesh64() if hasattr(manifold, "to_mesh64") else manifold.to_mesh()
    return np.asarray(mesh.vert_properties, dtype=np.float64)[:, :3], np.asarray(mesh.tri_verts, dtype=np.int64)


def _area(V: np.ndarray, F: np.ndarray) -> float:
    return float(0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1).sum())


def remesh(V: np.ndarray, F: np.ndarray, vertices: int, feature_deg: float = FEATURE_DEG) -> tuple[np.ndarray, np.ndarray]:
    """Near-uniform triangles, about ``vertices`` of them, edges sharper than ``feature_deg`` kept.

    The target edge length L gives about ``area / (sqrt(3)/2 L^2)`` vertices (equilateral
    triangles, two faces per vertex).
    """
    import pymeshlab

    target = math.sqrt(_area(V, F) / (math.sqrt(3) / 2 * vertices))
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=np.ascontiguousarray(V), face_matrix=np.ascontiguousarray(F, dtype=np.int32)))
    ms.meshing_remove_duplicate_vertices()
    ms.meshing_isotropic_explicit_remeshing(iterations=REMESH_ITERATIONS, targetlen=pymeshlab.PureValue(target),
                                            featuredeg=feature_deg, maxsurfdist=pymeshlab.PureValue(target / 4))
    ms.meshing_remove_unreferenced_vertices()
    m = ms.current_mesh()
    return np.asarray(m.vertex_matrix(), dtype=np.float64), np.asarray(m.face_matrix(), dtype=np.int64)


def normalised(V: np.ndarray) -> np.ndarray:
    """Centred on its bounding box, diagonal 1 (the corpus's meshes share one scale)."""
    lo, hi = V.min(0), V.max(0)
    return (V - 0.5 * (lo + hi)) / float(np.linalg.norm(hi - lo))


# ----------------------------------------------------------------------------- CAD parts
def _m3():
    import manifold3d

    return manifold3d


def _cyl(h: float, r: float, r2: float = -1.0, center: bool = True):
    return _m3().Manifold.cylinder(h, r, r2, SEGMENTS, center)


def _box(x: float, y: float, z: float, center: bool = True):
    return _m3().Manifold.cube((x, y, z), center)


def _rounded_rect(w: float, h: float, r: float):
    cs = _m3().CrossSection
    return cs.square((w - 2 * r, h - 2 * r), True).offset(r, _m3().JoinType.Round, 2.0, SEGMENTS)


def bracket():
    """An L bracket: two plates, a filleted inner corner, two bolt holes and a chamfered outer edge."""
    base = _box(4, 2, 0.4).translate((0, 0, 0.2))
    wall = _box(0.4, 2, 2.4).translate((-1.8, 0, 1.2))
    fillet = _box(0.5, 2, 0.5).translate((-1.35, 0, 0.65)) - _cyl(2.2, 0.5).rotate((90, 0, 0)).translate((-1.1, 0, 0.9))
    part = base + wall + fillet
    for x in (0.3, 1.3):
        part -= _cyl(1.0, 0.25).translate((x, 0, 0.2))
    part -= _cyl(1.0, 0.3).rotate((0, 90, 0)).translate((-1.8, 0, 1.7))
    chamfer = _box(0.6, 2.2, 0.6).rotate((0, 45, 0)).translate((2.0, 0, 0.4))
    return part - chamfer


def flange():
    """A flange: a disc, a hub, a bore and six bolt holes."""
    part = _cyl(0.4, 2.0).translate((0, 0, 0.2)) + _cyl(1.2, 0.9).translate((0, 0, 0.6))
    part -= _cyl(3.0, 0.5)
    for k in range(6):
        a = 2 * math.pi * k / 6
        part -= _cyl(1.0, 0.18).translate((1.5 * math.cos(a), 1.5 * math.sin(a), 0.2))
    return part


def rounded_box():
    """A box with every edge filleted (the hull of eight spheres)."""
    M = _m3().Manifold
    s = M.sphere(0.4, SEGMENTS)
    return M.batch_hull([s.translate((x, y, z)) for x in (-1, 1) for y in (-0.6, 0.6) for z in (-0.4, 0.4)])


def chamfered_block():
    """A block with all twelve edges chamfered and a blind pocket."""
    part = _box(2.4, 1.6, 1.2)
    for axis in ((45, 0, 0), (0, 45, 0), (0, 0, 45)):
        part ^= _box(2.9, 2.9, 2.9).scale((1.0, 1.0, 1.0)).rotate(axis).scale((0.93, 0.78, 0.68))
    return part - _box(1.0, 0.6, 0.8).translate((0.3, 0, 0.5))


def hex_nut():
    """A hexagonal nut: a six-sided prism, a bore, both faces chamfered by a double cone."""
    prism = _m3().Manifold.cylinder(0.8, 1.0, -1.0, 6, True)
    cone = _cyl(0.8, 1.25, 0.85).translate((0, 0, 0)) ^ _cyl(0.8, 0.85, 1.25)
    return (prism ^ cone) - _cyl(1.0, 0.5)


def stepped_shaft():
    """A turned shaft: three diameters, a groove and a filleted shoulder (a revolved profile)."""
    cs = _m3().CrossSection
    profile = cs([[(0, 0), (0.6, 0), (0.6, 1.2), (0.45, 1.2), (0.45, 1.3), (0.6, 1.3), (0.6, 1.5), (0.9, 1.6),
                   (0.9, 2.4), (0.4, 2.4), (0.4, 3.6), (0, 3.6)]])
    return _m3().Manifold.revolve(profile, SEGMENTS)


def thin_tube():
    """A thin-walled tube (wall a tenth of its radius) with a side window."""
    tube = _cyl(3.0, 1.0) - _cyl(3.2, 0.9)
    return tube - _box(0.6, 3.0, 0.8).translate((0, 1.0, 0.3))


def housing():
    """An open box with thin walls, a floor, a window and a boss inside."""
    shell = _box(3.0, 2.0, 1.4) - _box(2.7, 1.7, 1.4).translate((0, 0, 0.15))
    shell -= _box(3.4, 0.6, 0.5).translate((0, 0, 0.1))
    return shell + _cyl(0.9, 0.25).translate((0.8, 0.4, -0.2)) - _cyl(1.0, 0.1).translate((0.8, 0.4, -0.2))


def gear():
    """A spur gear: twenty rectangular teeth on a disc, a bore with a keyway."""
    part = _cyl(0.5, 1.5)
    for k in range(20):
        part += _box(0.24, 0.35, 0.5).translate((0, 1.6, 0)).rotate((0, 0, 360.0 * k / 20))
    return part - _cyl(0.7, 0.4) - _box(0.16, 0.2, 0.7).translate((0, 0.45, 0))


def slotted_plate():
    """A plate with rounded corners, two slots and a countersunk hole."""
    plate = _m3().Manifold.extrude(_rounded_rect(4, 2.4, 0.4), 0.3)
    M = _m3().Manifold
    for y in (-0.6, 0.6):
        slot = M.batch_hull([_cyl(0.6, 0.15).translate((x, y, 0.15)) for x in (-1.2, 0.2)])
        plate -= slot
    return plate - _cyl(0.31, 0.15, 0.35, center=False).translate((1.3, 0, 0.0))


def knob():
    """A knob: a domed cylinder (a sphere cap) with a knurled rim of twelve flutes and a bore."""
    body = _cyl(1.0, 1.0) ^ _m3().Manifold.sphere(1.25, SEGMENTS).translate((0, 0, -0.4))
    for k in range(12):
        body -= _cyl(1.2, 0.12).translate((1.02, 0, 0)).rotate((0, 0, 30.0 * k))
    return body - _cyl(0.8, 0.2).translate((0, 0, -0.5))


def t_beam():
    """A T beam: an extruded profile with filleted inner corners, one end mitred."""
    cs = _m3().CrossSection
    profile = cs.square((2.0, 0.3), True).translate((0, 0.85)) + cs.square((0.3, 2.0), True)
    profile = profile.offset(0.12, _m3().JoinType.Round, 2.0, SEGMENTS).offset(-0.12, _m3().JoinType.Round, 2.0, SEGMENTS)
    beam = _m3().Manifold.extrude(profile, 4.0).translate((0, 0, -2.0))
    return beam - _box(3, 3, 2).rotate((30, 0, 0)).translate((0, 0, 2.4))


def pipe_tee():
    """Two thin pipes joined in a tee."""
    a = _cyl(4.0, 0.6).rotate((0, 90, 0))
    b = _cyl(2.0, 0.6).translate((0, 0, 1.0))
    inner = _cyl(4.2, 0.5).rotate((0, 90, 0)) + _cyl(2.2, 0.5).translate((0, 0, 1.1))
    return (a + b) - inner


def cross_block():
    """Three crossing bars with bores through them."""
    part = _box(3, 0.8, 0.8) + _box(0.8, 3, 0.8) + _box(0.8, 0.8, 2.0)
    part -= _cyl(4.0, 0.22).rotate((0, 90, 0)).translate((0, 0, 0))
    part -= _cyl(4.0, 0.22).rotate((90, 0, 0))
    return part - _cyl(3.0, 0.2)


def wedge_ramp():
    """A ramp: a prism with a sloped face, fillets along its sides and a through slot."""
    cs = _m3().CrossSection
    tri = cs([[(0, 0), (3.0, 0), (3.0, 0.4), (0.6, 1.4), (0, 1.4)]]).offset(-0.15, _m3().JoinType.Round, 2.0, SEGMENTS)
    tri = tri.offset(0.15, _m3().JoinType.Round, 2.0, SEGMENTS)
    part = _m3().Manifold.extrude(tri, 1.6).rotate((90, 0, 0))
    return part - _box(1.2, 0.4, 2.0).translate((1.6, -0.8, 0.3))


CAD: dict[str, Callable] = {
    "bracket": bracket, "flange": flange, "rounded_box": rounded_box, "chamfered_block": chamfered_block,
    "hex_nut": hex_nut, "stepped_shaft": stepped_shaft, "thin_tube": thin_tube, "housing": housing, "gear": gear,
    "slotted_plate": slotted_plate, "knob": knob, "t_beam": t_beam, "pipe_tee": pipe_tee, "cross_block": cross_block,
    "wedge_ramp": wedge_ramp,
}


def cad_part(name: str, vertices: int) -> tuple[np.ndarray, np.ndarray]:
    """CAD part ``name`` remeshed to about ``vertices`` vertices, normalised."""
    V, F = _arrays(CAD[name]())
    V, F = remesh(normalised(V), F, vertices)
    return normalised(V), F


# ----------------------------------------------------------------------------- organic and scanned shapes
def _file(path) -> tuple[np.ndarray, np.ndarray]:
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.load_new_mesh(str(path))
    ms.meshing_remove_duplicate_vertices()
    ms.meshing_remove_unreferenced_vertices()
    ms.meshing_remove_duplicate_faces()
    m = ms.current_mesh()
    return np.asarray(m.vertex_matrix(), dtype=np.float64), np.asarray(m.face_matrix(), dtype=np.int64)


def _pymeshlab_sample(name: str):
    def load():
        from meshdenoise.data import sample_mesh

        return _file(sample_mesh(name))

    return load


def _pyvista_sample(name: str):
    def load():
        import os

        from pyvista import examples

        return _file(os.path.join(os.path.dirname(examples.__file__), name))

    return load


def _shared(name: str):
    def load():
        from meshdenoise.data import data_file

        return _file(data_file(name))

    return load


def _contour(values: np.ndarray, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """The zero level set of a sampled field by VTK's flying edges (marching cubes), largest piece."""
    import pyvista as pv

    grid = pv.ImageData(dimensions=values.shape, spacing=(spacing,) * 3, origin=(0.0, 0.0, 0.0))
    grid.point_data["f"] = values.ravel(order="F")
    surf = grid.contour([0.0], scalars="f").triangulate().clean().connectivity("largest")
    F = np.asarray(surf.faces).reshape(-1, 4)[:, 1:].astype(np.int64)
    return np.asarray(surf.points, dtype=np.float64), F


def _lattice(n: int, half: float = 1.3):
    t = np.linspace(-half, half, n)
    return np.meshgrid(t, t, t, indexing="ij"), t[1] - t[0]


def metaballs(n: int = 96):
    """Five metaballs: a smooth blob with saddles between its lobes."""
    (x, y, z), h = _lattice(n)
    centres = [(0, 0, 0, 0.55), (0.6, 0.2, 0.1, 0.4), (-0.5, 0.35, -0.2, 0.4), (0.1, -0.6, 0.3, 0.35), (0.2, 0.3, -0.65, 0.3)]
    f = sum(r**2 / ((x - a) ** 2 + (y - b) ** 2 + (z - c) ** 2 + 1e-9) for a, b, c, r in centres)
    return _contour(1.0 - f, h)


def rock(n: int = 96):
    """A sphere with smooth random bumps (a sum of low-frequency sines, fixed phases)."""
    (x, y, z), h = _lattice(n)
    rng = np.random.default_rng(12345)
    r = np.sqrt(x**2 + y**2 + z**2)
    bumps = sum(0.06 * np.sin(k[0] * x + k[1] * y + k[2] * z + p)
                for k, p in zip(rng.normal(0, 3.0, (8, 3)), rng.uniform(0, 2 * np.pi, 8)))
    return _contour(r - 0.9 - bumps, h)


def gyroid_ball(n: int = 110):
    """A ball cut by a thickened gyroid: many saddles and thin bridges."""
    (x, y, z), h = _lattice(n)
    k = 2 * np.pi / 1.1
    g = np.sin(k * x) * np.cos(k * y) + np.sin(k * y) * np.cos(k * z) + np.sin(k * z) * np.cos(k * x)
    ball = np.sqrt(x**2 + y**2 + z**2) - 1.1
    return _contour(np.maximum(ball, np.abs(g) - 0.45), h)


def torus_knot(n: int = 100):
    """A (2, 3) torus knot as a tube: a long thin part that winds around itself."""
    from scipy.spatial import cKDTree

    (x, y, z), h = _lattice(n)
    t = np.linspace(0, 2 * np.pi, 3000, endpoint=False)
    r = 0.75 + 0.3 * np.cos(3 * t)
    curve = np.stack([r * np.cos(2 * t), r * np.sin(2 * t), 0.3 * np.sin(3 * t)], 1)
    dist, _ = cKDTree(curve).query(np.stack([x.ravel(), y.ravel(), z.ravel()], 1))
    return _contour(dist.reshape(x.shape) - 0.17, h)


ORGANIC: dict[str, Callable] = {
    "bunny": _pymeshlab_sample("bunny.obj"),
    "cow": _pymeshlab_sample("cow.obj"),
    "bone": _pymeshlab_sample("bone.ply"),
    "ant": _pyvista_sample("ant.ply"),
    "elephant": _shared("elephant-50kv.off"),
    "nefertiti": _shared("nefertiti.off"),
    "metaballs": metaballs,
    "rock": rock,
    "gyroid_ball": gyroid_ball,
    "torus_knot": torus_knot,
}
NEEDS_DATA = {"elephant", "nefertiti"}  # read from MESHDENOISE_DATA (the shared meshes)


def organic_shape(name: str, vertices: int | None) -> tuple[np.ndarray, np.ndarray]:
    """Organic shape ``name``: remeshed to about ``vertices`` vertices, or as it comes (``None``), normalised."""
    V, F = ORGANIC[name]()
    V = normalised(V)
    if vertices is not None:
        V, F = remesh(V, F, vertices, feature_deg=60.0)
        V = normalised(V)
    return V, F

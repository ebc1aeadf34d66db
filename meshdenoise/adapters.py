"""The one conversion layer between mesh objects and the array core.

Supported inputs and what a filter returns for each:

========================================  ==================================================
input                                     result
========================================  ==================================================
``(V, F)`` tuple of arrays                a new ``(V, F)`` tuple; ``V`` keeps a float dtype
``pymeshlab.MeshSet``                     the same MeshSet, its current mesh changed in place
                                          (as MeshLab filters do), faces, colours, textures,
                                          selection and custom attributes kept, normals
                                          recomputed
``pymeshlab.Mesh``                        a new ``pymeshlab.Mesh`` (with normals, quality,
                                          colours and texture coordinates)
``open3d.geometry.TriangleMesh``          a new TriangleMesh, input untouched (as Open3D's
                                          ``filter_smooth_*``); colours kept, normals
                                          recomputed when the input had them
========================================  ==================================================

pymeshlab offers no setter for vertex positions (``Mesh`` has getters only, and
``vertex_matrix()`` returns a copy). To change them in place, keeping the mesh's id, name,
textures, colours, selection and custom attributes, we use two MeshLab filters and no
attribute: ``compute_coord_by_function(x="0", y="0", z="0")`` sets every position to
exactly 0, then ``compute_coord_linear_morphing(targetmesh=t, percentmorph=100)`` moves each
vertex to the same-index vertex of a temporary mesh ``t`` holding the new coordinates
(MeshLab computes ``p + (q - p) * 1.0``, which is ``q`` exactly when ``p = 0``), and the
temporary mesh is deleted. The result is bit-exact (``tests/test_adapters.py``), and six
in-place calls leave the mesh as it was apart from its coordinates and normals.

Earlier versions passed the coordinates as three per-vertex custom attributes read by
``compute_coord_by_function``, which left three attributes per call: pymeshlab 2025.7
cannot delete a custom attribute, refuses to add one under an existing name, returns
attribute arrays as copies (writing into them changes nothing) and reads a per-vertex
*point* attribute wrongly in ``compute_coord_by_function``; ``tests/test_adapters.py`` keeps
these facts checked. Pipelines are not concerned either way: they carry arrays
(:class:`meshdenoise.pipeline.state.MeshState`) and build a throw-away MeshSet only around
pymeshlab steps.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from .arrays import MeshValidationError, check_mesh_arrays

__all__ = ["MeshData", "read_mesh", "mesh_kind", "to_arrays"]


def mesh_kind(mesh: Any) -> str:
    """``'arrays'``, ``'meshset'``, ``'pymeshlab_mesh'`` or ``'open3d'``; ``TypeError`` otherwise."""
    module = type(mesh).__module__ or ""
    name = type(mesh).__name__
    if module.startswith("pymeshlab"):
        if name == "MeshSet":
            return "meshset"
        if name == "Mesh":
            return "pymeshlab_mesh"
    if module.startswith("open3d") and name == "TriangleMesh":
        if ".t." in module + "." or module.startswith("open3d.cpu.pybind.t"):
            raise TypeError("open3d.t.geometry.TriangleMesh is not supported: convert it with .to_legacy()")
        return "open3d"
    if isinstance(mesh, (tuple, list)) and len(mesh) == 2:
        return "arrays"
    raise TypeError(
        "expected a mesh: a (V, F) tuple of arrays, a pymeshlab.MeshSet or Mesh, "
        f"or an open3d.geometry.TriangleMesh; got {type(mesh).__module__}.{name}"
    )


@dataclass
class MeshData:
    """A mesh read into the array core, with what is needed to give the result back.

    Attributes
    ----------
    V : ndarray, shape (n, 3), float64
    F : ndarray, shape (m, 3), int64
    kind : str
        See :func:`mesh_kind`.
    source : object
        The caller's mesh object.
    """

    V: np.ndarray
    F: np.ndarray
    kind: str
    source: Any
    _writer: Callable[[np.ndarray], Any]
    _selection: Callable[[], np.ndarray] | None = None

    def write(self, V_new: np.ndarray) -> Any:
        """Return the result in the caller's mesh type (in place for a MeshSet)."""
        return self._writer(V_new)

    def selection(self) -> np.ndarray:
        """The pymeshlab vertex selection as a boolean mask; ``ValueError`` for other mesh types."""
        if self._selection is None:
            raise ValueError(
                f"a vertex selection is read from a pymeshlab MeshSet or Mesh; this mesh is of kind '{self.kind}'"
            )
        return self._selection()


def to_arrays(mesh: Any, *, allow_no_faces: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """``(V, F)`` as ``float64`` / ``int64`` arrays for any supported mesh (copies, never views of it)."""
    data = read_mesh(mesh, allow_no_faces=allow_no_faces)
    return data.V.copy(), data.F.copy()


def read_mesh(mesh: Any, *, allow_no_faces: bool = False) -> MeshData:
    """Read any supported mesh into a :class:`MeshData` (validated arrays + a writer)."""
    kind = mesh_kind(mesh)
    return _READERS[kind](mesh, allow_no_faces)


# --- numpy arrays ---------------------------------------------------------------------------
def _read_arrays(mesh, allow_no_faces):
    V_in, F_in = mesh
    V, F = check_mesh_arrays(V_in, F_in, allow_no_faces=allow_no_faces)
    dtype = np.asarray(V_in).dtype
    out_dtype = dtype if np.issubdtype(dtype, np.floating) else np.float64
    if V is V_in:  # check_mesh_arrays may return the caller's own array
        V = V.copy()
    # the returned faces are a copy made when the result is written, after the filter's peak (48 B/vertex)
    return MeshData(V, F, "arrays", mesh, lambda V_new: (V_new.astype(out_dtype, copy=False), F.copy()))


# --- pymeshlab ------------------------------------------------------------------------------
def _set_coordinates_in_place(ms, V_new: np.ndarray) -> None:
    """Write new coordinates into the MeshSet's current mesh, exactly, keeping everything else (module docstring).

    ``V_new`` (n, 3) float64, ``n`` the current mesh's vertex count (compact). The MeshSet's
    current mesh, its id and its other meshes are as before; vertex and face normals are
    recomputed.
    """
    import pymeshlab

    current = ms.current_mesh_id()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=np.ascontiguousarray(V_new, dtype=np.float64)), set_as_current=True)
    target = ms.current_mesh_id()
    try:
        ms.set_current_mesh(current)
        ms.compute_coord_by_function(x="0", y="0", z="0", onselected=False)
        ms.compute_coord_linear_morphing(targetmesh=target, percentmorph=100.0)
    finally:
        ms.set_current_mesh(target)
        ms.delete_current_mesh()
        ms.set_current_mesh(current)
    ms.compute_normal_per_vertex()
    ms.compute_normal_per_face()


def _meshset_arrays(ms, allow_no_faces):
    if ms.mesh_number() == 0:
        raise MeshValidationError("the MeshSet has no mesh: load one first (ms.load_new_mesh(path))")
    m = ms.current_mesh()
    if not m.is_compact():
        m.compact()  # drop deleted elements so arrays and vertex order agree
    return check_mesh_arrays(m.vertex_matrix(), m.face_matrix(), allow_no_faces=allow_no_faces)


def _read_meshset(ms, allow_no_faces):
    V, F = _meshset_arrays(ms, allow_no_faces)

    def write(V_new):
        _set_coordinates_in_place(ms, V_new)
        return ms

    return MeshData(V, F, "meshset", ms, write, lambda: ms.current_mesh().vertex_selection_array().astype(bool))


def _standalone_mesh(m):
    """A new ``pymeshlab.Mesh`` owning its data (a MeshSet's mesh dies with its MeshSet).

    Carries coordinates, faces, normals, quality, colours and texture coordinates: all
    the constructor accepts. Custom attributes and texture images stay behind.
    """
    import pymeshlab

    kwargs = {
        "vertex_matrix": m.vertex_matrix(),
        "face_matrix": m.face_matrix(),
        "v_normals_matrix": m.vertex_normal_matrix(),
        "f_normals_matrix": m.face_normal_matrix(),
    }
    optional = [
        ("has_vertex_scalar", "v_scalar_array", "vertex_scalar_array"),
        ("has_face_scalar", "f_scalar_array", "face_scalar_array"),
        ("has_vertex_color", "v_color_matrix", "vertex_color_matrix"),
        ("has_face_color", "f_color_matrix", "face_color_matrix"),
        ("has_vertex_tex_coord", "v_tex_coords_matrix", "vertex_tex_coord_matrix"),
        ("has_wedge_tex_coord", "w_tex_coords_matrix", "wedge_tex_coord_matrix"),
    ]
    for has, key, getter in optional:
        if getattr(m, has)():
            kwargs[key] = getattr(m, getter)()
    return pymeshlab.Mesh(**kwargs)


def _read_pymeshlab_mesh(mesh, allow_no_faces):
    import pymeshlab

    V, F = check_mesh_arrays(mesh.vertex_matrix(), mesh.face_matrix(), allow_no_faces=allow_no_faces)

    def write(V_new):
        ms = pymeshlab.MeshSet()
        ms.add_mesh(mesh)  # a copy: the caller's Mesh is not changed
        _set_coordinates_in_place(ms, V_new)
        return _standalone_mesh(ms.current_mesh())

    return MeshData(V, F, "pymeshlab_mesh", mesh, write, lambda: mesh.vertex_selection_array().astype(bool))


# --- Open3D ---------------------------------------------------------------------------------
def _read_open3d(mesh, allow_no_faces):
    import open3d as o3d

    V, F = check_mesh_arrays(np.asarray(mesh.vertices), np.asarray(mesh.triangles), allow_no_faces=allow_no_faces)

    def write(V_new):
        out = o3d.geometry.TriangleMesh(mesh)  # copy constructor: colours, UVs, textures kept
        out.vertices = o3d.utility.Vector3dVector(V_new)
        if mesh.has_triangle_normals():
            out.compute_triangle_normals()
        if mesh.has_vertex_normals():
            out.compute_vertex_normals()
        return out

    return MeshData(V, F, "open3d", mesh, write)


_READERS = {
    "arrays": _read_arrays,
    "meshset": _read_meshset,
    "pymeshlab_mesh": _read_pymeshlab_mesh,
    "open3d": _read_open3d,
}

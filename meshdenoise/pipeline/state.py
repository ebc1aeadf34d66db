"""The working mesh of a pipeline: arrays plus per-element attributes.

A pipeline carries its mesh as a :class:`MeshState` (coordinates, faces and the attributes
a step may read or set: colours, quality, selection). Our filters, Open3D operations,
``add_noise``, ``metrics``, ``save`` and ``render`` work on the arrays; a
``pymeshlab.MeshSet`` is built only around pymeshlab steps (and kept while several
pymeshlab steps follow each other), then read back. No custom attribute is ever left on a
mesh: the MeshSet is ours and thrown away.

Vertex normals are held only once a pymeshlab vertex-normal filter computed them
(``compute_normal_per_vertex``, ``compute_normal_for_point_clouds``...); ``save`` writes what is held.
A later step that moves the vertices or changes the mesh recomputes them from its result (the
normalised sum of the faces' unit normals: ``compute_normal_per_vertex``'s default, "Simple
Average"), as MeshLab's own filters update the normals of what they move.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

__all__ = ["MeshState"]

_SELECTION_ATTRIBUTE = "__meshdenoise_selection"


@dataclass
class MeshState:
    """A triangle mesh and its attributes, as arrays.

    Attributes
    ----------
    V : ndarray, shape (n, 3), float64
    F : ndarray, shape (m, 3), int64
    vertex_colors, face_colors : ndarray, shape (n, 4) / (m, 4), float64 in [0, 1], or None
        RGBA.
    vertex_quality, face_quality : ndarray, shape (n,) / (m,), float64, or None
        MeshLab's per-element scalar ("quality"), set by some pymeshlab filters.
    vertex_selection, face_selection : ndarray, shape (n,) / (m,), bool, or None
        MeshLab's selection (``None``: nothing selected).
    vertex_normals : ndarray, shape (n, 3), float64, or None
        The per-vertex normals a step computed for these vertices (None: no step computed any);
        see the module's docstring for how later steps keep them.
    extras : meshdenoise.io.PlyExtras or None
        The input PLY's other data (a scanner's confidence, MeshLab flags, a camera), written
        again by ``save`` to a PLY while the vertices and faces are the same
        (:meth:`~meshdenoise.io.PlyExtras.for_mesh`).
    """

    V: np.ndarray
    F: np.ndarray
    vertex_colors: np.ndarray | None = None
    face_colors: np.ndarray | None = None
    vertex_quality: np.ndarray | None = None
    face_quality: np.ndarray | None = None
    vertex_selection: np.ndarray | None = None
    face_selection: np.ndarray | None = None
    extras: Any = None
    vertex_normals: np.ndarray | None = None
    _meshset: Any = field(default=None, repr=False, compare=False)  # in step with the arrays when not None

    @property
    def n_vertices(self) -> int:
        return int(self.V.shape[0])

    @property
    def n_faces(self) -> int:
        return int(self.F.shape[0])

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """``(V, F)``."""
        return self.V, self.F

    def with_vertices(self, V: np.ndarray) -> "MeshState":
        """The same mesh with new coordinates (same vertices, faces and attributes).

        Raises
        ------
        ValueError
            ``V`` is not ``(n, 3)`` with this mesh's ``n``.
        """
        V = np.asarray(V, dtype=np.float64)
        if V.shape != self.V.shape:
            raise ValueError(f"new coordinates have shape {V.shape}, the mesh {self.V.shape}")
        return replace(self, V=V, vertex_normals=self.normals_for(V, self.F), _meshset=None)

    def with_mesh(self, V: np.ndarray, F: np.ndarray, vertex_colors: np.ndarray | None = None) -> "MeshState":
        """A new mesh (new vertices and faces): the vertex colours given are kept, and the extras still valid."""
        V = np.asarray(V, dtype=np.float64)
        F = np.asarray(F, dtype=np.int64).reshape(-1, 3)
        extras = self.extras.for_mesh(V.shape[0], F.shape[0]) if self.extras is not None else None
        return MeshState(V, F, vertex_colors, extras=extras, vertex_normals=self.normals_for(V, F))

    def normals_for(self, V: np.ndarray, F: np.ndarray) -> np.ndarray | None:
        """The normals this state holds, carried to the mesh ``(V, F)``: kept when it is this one,
        recomputed from it when it moved or changed (``compute_normal_per_vertex``'s "Simple Average"),
        None when none are held."""
        if self.vertex_normals is None:
            return None
        if V.shape == self.V.shape and F.shape == self.F.shape and np.array_equal(V, self.V) and np.array_equal(F, self.F):
            return self.vertex_normals
        from ..geometry import vertex_normals

        return vertex_normals(V, F) if len(F) else np.zeros_like(V)

    def extras_to_write(self):
        """:attr:`extras` for a file of this mesh: what is still valid, the current selection and quality in it."""
        if self.extras is None:
            return None
        extras = self.extras.for_mesh(self.n_vertices, self.n_faces).with_selection(self.vertex_selection)
        return extras.with_quality(self.vertex_quality, self.face_quality)

    # --- pymeshlab --------------------------------------------------------------------------
    def meshset(self):
        """A ``pymeshlab.MeshSet`` holding this mesh and its attributes (built once, then reused).

        Returned wrapped (every method of the MeshSet is there): the wrapper remembers this state
        and the filter applied, so :meth:`from_meshset` knows which normals the result holds.
        """
        if self._meshset is None:
            self._meshset = _to_meshset(self)
        return _StepMeshSet(self._meshset, self)

    @classmethod
    def from_meshset(cls, ms, extras: Any = None) -> "MeshState":
        """The current mesh of ``ms`` (compacted first) as a state that keeps ``ms`` for the next pymeshlab step.

        ``extras`` (the state's before the step) are kept while still valid. Given the MeshSet
        :meth:`meshset` returned, the vertex normals are read after a vertex-normal filter and
        carried from the state before otherwise (:meth:`normals_for`).
        """
        before, applied = getattr(ms, "before", None), getattr(ms, "applied", None)
        ms = getattr(ms, "meshset", ms)
        m = ms.current_mesh()
        if not m.is_compact():
            m.compact()
        vsel = np.asarray(m.vertex_selection_array(), dtype=bool)
        fsel = np.asarray(m.face_selection_array(), dtype=bool)
        state = cls(
            np.array(m.vertex_matrix(), dtype=np.float64),
            np.array(m.face_matrix(), dtype=np.int64).reshape(-1, 3),
            np.array(m.vertex_color_matrix()) if m.has_vertex_color() else None,
            np.array(m.face_color_matrix()) if m.has_face_color() else None,
            np.array(m.vertex_scalar_array(), dtype=np.float64) if m.has_vertex_scalar() else None,
            np.array(m.face_scalar_array(), dtype=np.float64) if m.has_face_scalar() else None,
            vsel if vsel.any() else None,
            fsel if fsel.any() else None,
        )
        if extras is not None:
            state.extras = extras.for_mesh(state.n_vertices, state.n_faces)
        if applied is not None and _sets_vertex_normals(applied):
            state.vertex_normals = np.array(m.vertex_normal_matrix(), dtype=np.float64).reshape(-1, 3)
        elif before is not None:
            state.vertex_normals = before.normals_for(state.V, state.F)
        state._meshset = ms
        return state


class _StepMeshSet:
    """A ``pymeshlab.MeshSet`` (every attribute forwarded) with the state it was made for and the last filter applied."""

    def __init__(self, meshset, before: MeshState):
        self.meshset, self.before, self.applied = meshset, before, None

    def apply_filter(self, name: str, *args, **kwargs):
        self.applied = name
        return self.meshset.apply_filter(name, *args, **kwargs)

    def __getattr__(self, name: str):
        return getattr(self.meshset, name)


def _sets_vertex_normals(filter_name: str) -> bool:
    """pymeshlab's filters that compute or change per-vertex normals (``compute_normal_per_vertex``,
    ``compute_normal_for_point_clouds``, ``apply_normal_normalization_per_vertex``...)."""
    return filter_name.startswith(("compute_normal", "apply_normal")) and "per_face" not in filter_name


def _to_meshset(state: MeshState):
    import pymeshlab

    kwargs = {}
    for key, value in (
        ("v_color_matrix", state.vertex_colors),
        ("f_color_matrix", state.face_colors),
        ("v_scalar_array", state.vertex_quality),
        ("f_scalar_array", state.face_quality),
    ):
        if value is not None:
            kwargs[key] = np.asarray(value, dtype=np.float64)
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=state.V, face_matrix=np.asarray(state.F, dtype=np.int32).reshape(-1, 3), **kwargs))
    m = ms.current_mesh()
    # pymeshlab has no selection setter: a 0/1 attribute of this throw-away MeshSet, then MeshLab's selection by condition
    if state.vertex_selection is not None:
        m.add_vertex_custom_scalar_attribute(np.asarray(state.vertex_selection, dtype=np.float64), _SELECTION_ATTRIBUTE)
        ms.compute_selection_by_condition_per_vertex(condselect=f"{_SELECTION_ATTRIBUTE} > 0.5")
    if state.face_selection is not None:
        m.add_face_custom_scalar_attribute(np.asarray(state.face_selection, dtype=np.float64), _SELECTION_ATTRIBUTE)
        ms.compute_selection_by_condition_per_face(condselect=f"{_SELECTION_ATTRIBUTE} > 0.5")
    return ms

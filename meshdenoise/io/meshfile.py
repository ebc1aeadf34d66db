"""What a mesh file held: :class:`MeshFile` (arrays, colours, notes) and a PLY's other properties, :class:`PlyExtras`."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np


_COLOUR_NAMES = frozenset(f"{p}{c}" for p in ("", "diffuse_") for c in ("red", "green", "blue", "alpha"))
_RECOMPUTED = frozenset(("x", "y", "z", "nx", "ny", "nz")) | _COLOUR_NAMES


@dataclass
class PlyExtras:
    """What a PLY file holds beside coordinates, triangles and colours, kept to be written again.

    A scanner's PLY often carries per-vertex ``quality``/``confidence``/``intensity``, MeshLab's
    ``flags``, vertex normals and a ``camera`` element (the scan's view point). A filter that
    keeps the vertices and faces (every denoiser) keeps them valid, so :func:`save_mesh` writes
    them to a PLY: the properties as they were (same names and types), normals recomputed from
    the new coordinates, other elements verbatim. :meth:`for_mesh` drops what a change of the
    vertices or faces makes meaningless.

    Attributes
    ----------
    vertex, face : dict of str -> (str, ndarray (n,) or (m,))
        Scalar properties by name: (numpy type code such as ``"f4"``, values), in file order.
        Coordinates, normals and colours are not in ``vertex`` (written from the arrays).
        ``face`` is empty when the file's polygons were split into triangles.
    elements : list of (str, int, list, dict)
        Every element of the file in order, as ``(name, count, properties, values)``;
        ``vertex`` and ``face`` appear with ``properties`` and ``values`` empty (placeholders
        for their position).
    normals : bool
        The vertices had ``nx ny nz``.
    """

    vertex: dict = field(default_factory=dict)
    face: dict = field(default_factory=dict)
    elements: list = field(default_factory=list)
    normals: bool = False

    def other_elements(self) -> list:
        return [e for e in self.elements if e[0] not in ("vertex", "face")]

    def describe(self) -> list[str]:
        """Short names of what is carried, for messages: ``['vertex quality', 'camera', ...]``."""
        out = [f"vertex {k}" for k in self.vertex] + [f"face {k}" for k in self.face]
        out += ["vertex normals"] if self.normals else []
        return out + [name for name, *_ in self.other_elements()]

    def with_selection(self, selected: np.ndarray | None) -> "PlyExtras":
        """MeshLab's "selected" bit (0x20) of integer vertex ``flags`` set from ``selected`` (n,) bool (None: none)."""
        if "flags" not in self.vertex or self.vertex["flags"][0][0] not in "iu":
            return self
        t, flags = self.vertex["flags"]
        bit = np.asarray(0x20).astype(t)
        new = flags & ~bit if selected is None else np.where(np.asarray(selected, bool), flags | bit, flags & ~bit)
        return PlyExtras({**self.vertex, "flags": (t, new.astype(t))}, self.face, self.elements, self.normals)

    def with_quality(self, vertex: np.ndarray | None, face: np.ndarray | None) -> "PlyExtras":
        """Per-vertex and per-face ``quality`` (MeshLab's scalar) set to the arrays given (kept as read when None)."""
        out = {"vertex": dict(self.vertex), "face": dict(self.face)}
        for where, values in (("vertex", vertex), ("face", face)):
            if values is not None:
                t = out[where].get("quality", ("f4", None))[0]
                out[where]["quality"] = (t, np.asarray(values).astype(t))
        return PlyExtras(out["vertex"], out["face"], self.elements, self.normals)

    def for_mesh(self, n: int, m: int) -> "PlyExtras":
        """What stays valid for a mesh of ``n`` vertices and ``m`` faces (the same ones, if counts match).

        Vertex properties need ``n`` equal to theirs, face properties ``m``; with other
        vertices, other elements are kept only when they refer to no vertex (no list
        property, no property named ``vertex*``: a camera yes, a range grid or edges no).
        """
        nv = next((len(a) for _, a in self.vertex.values()), None)
        nf = next((len(a) for _, a in self.face.values()), None)
        same_vertices = nv is None or nv == n
        vertex = self.vertex if same_vertices else {}
        face = self.face if nf is None or nf == m else {}

        def refers_to_vertices(props) -> bool:
            return any(not isinstance(t, str) or name.startswith("vertex") for name, t in props)

        elements = [e for e in self.elements
                    if e[0] in ("vertex", "face") or same_vertices or not refers_to_vertices(e[2])]
        return PlyExtras(vertex, face, elements, self.normals)


@dataclass
class MeshFile:
    """A mesh read from a file.

    Attributes
    ----------
    V : ndarray, shape (n, 3), float64
    F : ndarray, shape (m, 3), int64
        Triangles; polygons of the file are split into fans ``(a, b, c), (a, c, d), ...``.
    vertex_colors : ndarray, shape (n, 4), float64 in [0, 1], or None
        RGBA, when the file has vertex colours.
    notes : list of str
        What was done to read an unusual but legal file (polygons triangulated, STL corners
        merged, CR line endings) and legal oddities worth knowing (unreferenced vertices,
        duplicate faces, non-manifold edges, no faces).
    path : Path
    selection : ndarray, shape (n,), bool, or None
        The MeshLab vertex selection, when the file stores it: a PLY whose vertices have the
        integer property ``flags`` (MeshLab's "Flags" save option; bit 0x20 is "selected").
        None for every other file.
    extras : PlyExtras or None
        A PLY file's other properties and elements (quality, flags, camera...), written again by
        :func:`save_mesh` to a PLY. None for every other format.
    """

    V: np.ndarray
    F: np.ndarray
    vertex_colors: np.ndarray | None = None
    notes: list[str] = field(default_factory=list)
    path: Path | None = None
    selection: np.ndarray | None = None
    extras: PlyExtras | None = None

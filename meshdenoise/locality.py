"""Relabelling a large mesh's vertices so that neighbours sit close in memory.

Every sparse product here gathers the rows of a coordinate (or probe) block at the
neighbours of each vertex. Meshes made by subdivision, or stitched and merged from
several scans, list a vertex far from its neighbours (the Loop-subdivided scale benchmark
mesh: 80 % of the face sides join vertices more than 16,384 rows apart), so at a million
vertices the products wait on cache misses. A real range scan, listed row by row, does not.

:func:`relabelling` decides from the faces alone whether a mesh needs it and returns a
:class:`Relabelling` (reverse Cuthill-McKee of the edge graph: bandwidth-reducing, so
neighbours are near each other in the new order). The choice of parameters and the filters
run on the relabelled arrays (:func:`meshdenoise.tuning.choose.choose_parameters`, the filter
adapter) and give the result back
in the caller's labels: the same computation on relabelled vertices. Deterministic filters
give the same coordinates up to rounding (row sums in another order); the automatic
choices draw their random probes and regions per vertex index, so they see other draws
of the same distributions.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np
from scipy.sparse.csgraph import reverse_cuthill_mckee

from .kernels.topology import relabel_faces
from .operators import (  # noqa: F401 - far_side_fraction and its limits live with Operators.in_locality_order
    FAR_ROWS,
    FAR_SIDES_MAX,
    LOCALITY_MIN_VERTICES,
    Operators,
    far_side_fraction,
    gather_rows,
    get_operators,
    on_clear_cache,
    topology_key,
)

__all__ = ["Relabelling", "relabelling", "relabelled_operators", "far_side_fraction", "clear", "LOCALITY_MIN_VERTICES", "FAR_ROWS",
           "FAR_SIDES_MAX"]


_lock = threading.Lock()
_last: tuple[tuple, "Relabelling | None"] | None = None  # one entry: the choice and the filter of one call share it


@dataclass(frozen=True, eq=False)
class Relabelling:
    """A vertex order with neighbours close in memory, and the faces in that order.

    Attributes
    ----------
    order : ndarray, shape (n,), int32 (int64 from 2^31 vertices)
        New label -> old label: new vertex ``k`` is old vertex ``order[k]``.
    inverse : ndarray, shape (n,), same type
        Old label -> new label.
    faces : ndarray, shape (m, 3), same type
        The faces in new labels, rows sorted by their smallest vertex (so loops over faces
        also walk memory in order).

    Examples
    --------
    >>> import numpy as np
    >>> r = Relabelling.from_order(np.array([2, 0, 1]), np.array([[0, 1, 2]]))
    >>> V = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0]])
    >>> r.vertices(V)[:, 0], r.faces.tolist()
    (array([2., 0., 1.]), [[1, 2, 0]])
    >>> bool((r.restore(r.vertices(V)) == V).all())
    True
    """

    order: np.ndarray
    inverse: np.ndarray
    faces: np.ndarray

    @classmethod
    def from_order(cls, order: np.ndarray, F: np.ndarray) -> "Relabelling":
        """The relabelling to ``order`` (new -> old, a permutation of ``range(n)``) of faces ``F``."""
        index = np.int32 if order.size < 2**31 - 1 else np.int64  # half the bytes of int64 at scan size
        order = np.asarray(order, dtype=index)
        inverse = np.empty_like(order)
        inverse[order] = np.arange(order.size, dtype=index)
        G = relabel_faces(F, inverse) if len(F) else np.zeros((0, 3), dtype=index)  # rows by their least corner, stably
        for a in (order, inverse, G):
            a.flags.writeable = False
        return cls(order, inverse, np.ascontiguousarray(G))

    @property
    def n(self) -> int:
        return int(self.order.size)

    def vertices(self, X: np.ndarray) -> np.ndarray:
        """Per-vertex rows ``X`` (n, ...) in the new labels: ``X[order]``, a new array."""
        X = np.asarray(X)
        if X.shape[0] != self.n:
            raise ValueError(f"Relabelling: {X.shape[0]} rows for a relabelling of {self.n} vertices")
        if X.dtype == np.float64 and X.ndim == 2:
            return gather_rows(X, self.order)
        return X[self.order]

    def mask(self, m: np.ndarray | None) -> np.ndarray | None:
        """A per-vertex mask (n,) in the new labels (``None`` stays ``None``)."""
        return None if m is None else np.asarray(m)[self.order]

    def restore(self, Y: np.ndarray) -> np.ndarray:
        """Per-vertex rows computed in the new labels, back in the old ones: ``Z[order] = Y``."""
        Y = np.asarray(Y)
        if Y.shape[0] != self.n:
            raise ValueError(f"Relabelling: {Y.shape[0]} rows for a relabelling of {self.n} vertices")
        if Y.dtype == np.float64 and Y.ndim == 2:
            return gather_rows(Y, self.inverse)
        return Y[self.inverse]

    @property
    def nbytes(self) -> int:
        return int(self.order.nbytes + self.inverse.nbytes + self.faces.nbytes)


def relabelling(F: np.ndarray, n: int, ops: Operators | None = None) -> Relabelling | None:
    """The :class:`Relabelling` a mesh needs, or ``None`` when it is small or already in a good order.

    ``None`` below :data:`LOCALITY_MIN_VERTICES` vertices and when at most :data:`FAR_SIDES_MAX`
    of the face sides join vertices more than :data:`FAR_ROWS` rows apart; otherwise reverse
    Cuthill-McKee of the edge graph (:attr:`meshdenoise.operators.Operators.locality_order`).
    The last answer is kept (one entry, :func:`clear` forgets it), so the choice of parameters
    and the filter that follows share it.

    Parameters
    ----------
    F : ndarray, shape (m, 3), int
    n : int
        Number of vertices.
    ops : Operators, optional
        The operators of ``(F, n)`` when the caller holds them: their adjacency is used (built if
        it is not yet) instead of a throwaway one (at 1.6M vertices its build took 0.9 s).

    Examples
    --------
    >>> import numpy as np
    >>> relabelling(np.array([[0, 1, 2]]), 3) is None  # small
    True
    """
    global _last
    if n < LOCALITY_MIN_VERTICES or far_side_fraction(F) <= FAR_SIDES_MAX:
        return None
    key = topology_key(F, n)
    with _lock:
        if _last is not None and _last[0] == key:
            return _last[1]
    if ops is not None and (ops.n != n or ops.F.shape != np.shape(F)):
        raise ValueError(f"relabelling: operators of {ops.n} vertices and {ops.F.shape[0]} faces for a mesh of {n} "
                         f"vertices and {np.shape(F)[0]} faces")
    own = ops if ops is not None else Operators(F, n)  # not the cached one: its W on the old labels is dropped at once
    # Operators.locality_order, not kept on the operators (n int64 they would hold for nothing): this mesh is not in
    # locality order (checked above), so it is reverse Cuthill-McKee of W
    result = Relabelling.from_order(np.asarray(reverse_cuthill_mckee(own.W, symmetric_mode=True), dtype=np.int64), own.F)
    del own
    with _lock:
        _last = (key, result)
    return result


def relabelled_operators(r: Relabelling, ops: Operators) -> Operators:
    """The cached operators of the relabelled faces ``r.faces``, told what ``ops`` (the caller's labels) knows of the
    vertices' border.

    Whether a vertex is on the border is a property of the vertex, moved with it by the relabelling:
    ``ops.boundary_vertices[r.order]``, when ``ops`` has it. A filter run on the relabelled mesh that reads the
    border (``boundary_motion="normal"``) then builds no edge list of its own (2 s and 36 bytes per vertex at 5M).
    """
    if ops.n != r.n:
        raise ValueError(f"relabelled_operators: operators of {ops.n} vertices for a relabelling of {r.n}")
    own = get_operators(r.faces, r.n)
    if "boundary_vertices" in ops.__dict__ and "boundary_vertices" not in own.__dict__:
        own.boundary_vertices = ops.boundary_vertices[r.order]  # the cached property's own slot
    return own


def clear() -> None:
    """Forget the kept relabelling."""
    global _last
    with _lock:
        _last = None


on_clear_cache(clear)  # operators.clear_cache forgets it too

"""A sampled region of a mesh: a few balls of vertices on which a statistic of the whole mesh is estimated.

Generic machinery: nothing here knows a filter. A rule or an estimate whose statistic is a
median or a mean over vertices of something local (a band-pass residual, a filter run's
normal error) can be computed on a region of a few thousand vertices instead of the whole
mesh, in time independent of the mesh size. The region is cut out of the mesh, so vertices
near a cut see a different neighbourhood than in the whole mesh: ``inner`` marks those far
enough from every cut to be counted. The mesh's own open borders are no cut (a region
vertex on a border sees what it sees in the whole mesh).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra

from ..operators import Operators

__all__ = ["SampledRegion", "ring_distance"]


def ring_distance(W: sp.spmatrix, sources: np.ndarray, limit: float = np.inf) -> np.ndarray:
    """Number of edges from the nearest of ``sources`` (indices) to every vertex over the graph ``W`` (n, n).

    ``inf`` beyond ``limit`` rings or where no source is reachable; (n,) float64.
    """
    n = W.shape[0]
    if len(sources) == 0:
        return np.full(n, np.inf)
    return dijkstra(sp.csr_matrix(W), directed=False, indices=np.asarray(sources), unweighted=True,
                    limit=limit, min_only=True)


class SampledRegion:
    """A part of a mesh made of ``patches`` vertex balls (rings of neighbours), about ``size`` vertices in all.

    Parameters
    ----------
    F : ndarray of int, shape (m, 3)
    ops : Operators
        The mesh's operators (its adjacency ``W``).
    size : int, >= 1
        Vertices wanted; a mesh of at most ``size`` vertices is its own region (nothing cut).
    patches : int, >= 1
        Seed vertices, drawn uniformly among the vertices on a face.
    margin : int, >= 0
        Rings of vertices next to a cut that ``inner`` leaves out.
    seed : int
        Seed of the draw (same seed, same region).

    Attributes
    ----------
    vertices : ndarray of int64, shape (k,)
        The region's vertices (indices into the mesh), increasing: the vertices within
        ``radius`` rings of a seed that are on a face whose three corners are.
    F : ndarray of int64, shape (l, 3)
        The faces with all three corners in the region, on the region's numbering.
    inner : ndarray of bool, shape (k,)
        Vertices more than ``margin`` rings from a cut (a region vertex with a neighbour
        outside the region).
    scored : ndarray of bool, shape (l,)
        Faces whose three corners are inner.
    whole : bool
        True when the region is the whole mesh.
    seeds : ndarray of int64
        The balls' centres (empty for the whole mesh).
    radius : int
        The balls' common radius in rings: the smallest that holds ``size`` vertices
        (-1 for the whole mesh, or when the reachable vertices are fewer).

    Examples
    --------
    >>> from meshdenoise.shapes import icosphere
    >>> from meshdenoise.operators import get_operators
    >>> V, F = icosphere(4)
    >>> r = SampledRegion(F, get_operators(F, len(V)), 600, 3, 2)
    >>> 600 <= r.vertices.size < len(V), bool(r.inner.any() and not r.inner.all())
    (True, True)
    """

    def __init__(self, F: np.ndarray, ops: Operators, size: int, patches: int, margin: int, seed: int = 0):
        for name, value, low in (("size", size, 1), ("patches", patches, 1), ("margin", margin, 0)):
            if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or value < low:
                raise ValueError(f"SampledRegion: parameter {name!r} must be an int >= {low}, got {value!r}")
        n = ops.n
        F = np.asarray(F, dtype=np.int64)
        if n <= size:
            self.vertices = np.arange(n, dtype=np.int64)
            self.F = F
            self.inner = np.ones(n, dtype=bool)
            self.scored = np.ones(F.shape[0], dtype=bool)
            self.whole = True
            self.seeds, self.radius = np.zeros(0, dtype=np.int64), -1
            self._sub, self._cut = None, np.zeros(0, dtype=np.int64)
            return
        self.whole = False
        W = ops.W
        rng = np.random.default_rng(seed)
        used = np.zeros(n, dtype=bool)
        used[F.ravel()] = True
        candidates = np.flatnonzero(used)
        seeds = rng.choice(candidates, size=min(patches, candidates.size), replace=False).astype(np.int64)
        radius = -1
        # balls of a common radius: the smallest with at least `size` vertices (a guess of the radius first,
        # doubled while too small; a new seed when every ball has filled its connected component)
        limit = max(4.0, 2.0 * np.sqrt(size / (3.0 * len(seeds))))
        while True:
            dist = ring_distance(W, seeds, limit)
            reached = np.isfinite(dist)
            if reached.sum() >= size:
                counts = np.bincount(dist[reached].astype(np.int64))
                radius = int(np.searchsorted(np.cumsum(counts), size))
                inside = dist <= radius
                break
            if np.all(dist[reached] < limit):  # every ball filled its component: one more seed elsewhere
                rest = np.flatnonzero(used & ~reached)
                if rest.size == 0:
                    inside, radius = reached, -1
                    break
                seeds = np.append(seeds, rng.choice(rest))
            else:
                limit *= 2.0
        self.seeds, self.radius = seeds, radius
        keep = inside[F].all(axis=1)
        inside = np.zeros(n, dtype=bool)  # the vertices of the kept faces (a ball's rim vertex on none is dropped)
        inside[F[keep].ravel()] = True
        self.vertices = np.flatnonzero(inside)
        number = np.full(n, -1, dtype=np.int64)
        number[self.vertices] = np.arange(self.vertices.size)
        self.F = number[F[keep]]
        cut = np.flatnonzero(inside & (W @ (~inside).astype(np.float64) > 0))
        sub = sp.csr_matrix(W)[self.vertices][:, self.vertices]
        self._sub, self._cut = sub, number[cut]
        if cut.size:
            self.inner = ~(ring_distance(sub, number[cut], float(margin)) <= margin)
        else:
            self.inner = np.ones(self.vertices.size, dtype=bool)
        self.scored = self.inner[self.F].all(axis=1)

    def cut_rings(self, limit: int) -> np.ndarray:
        """Rings from the nearest cut vertex (0 on one) of every region vertex, ``inf`` beyond ``limit`` rings.

        (k,) float64; all ``inf`` for a region that is the whole mesh or has no cut.
        """
        if self._sub is None or self._cut.size == 0:
            return np.full(self.vertices.size, np.inf)
        return ring_distance(self._sub, self._cut, float(limit))

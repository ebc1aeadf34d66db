"""Held-out vertices: the error of a filter's run read on vertices it was not shown (knows no filter).

A filter run on the noisy mesh cannot be scored against the noisy positions it was given: it
would be rewarded for keeping the noise. Hide some vertices first (Batson and Royer's
Noise2Self): each hidden *centre* and the vertices within ``radius`` rings of it (its *hole*)
take harmonic values interpolated from the vertices around the hole, the filter runs on that
copy, and its face normals around each centre are compared with the noisy mesh's there
(:func:`path_losses`):

.. math:: L = \\frac{1}{|T|} \\sum_{f \\in T} \\big(1 - \\hat n_f \\cdot n_f\\big)

where :math:`\\hat n_f` is the run's normal of face ``f`` on the copy with the holes filled and
:math:`n_f` the noisy one. When the noise in a hole is independent of the noise outside it (zero
mean), the run is blind to it and, up to a factor, the loss's expectation is the run's mean angle
error plus a constant (the proof in :func:`path_losses`): its least value over candidates picks the
least error, whatever the noise's distribution (Gaussian, along random directions, impulsive).
Scanner noise is correlated over a few samples; a hole of ``radius`` rings keeps the centre's noise
out of what the filter sees as long as the correlation is shorter than the hole. At little smoothing
the run on the copy keeps the harmonic fill, itself a smoother: the loss there reads the fill's error
rather than the filter's.

Centres are spread over the mesh: a vertex is a centre of a mask when its key is the least within
``2 radius + 1`` rings, so holes of one mask neither overlap nor touch. Keys are read from the
geometry (the fractional part of a large multiple of each vertex's distance to its neighbours'
mean, over the median), not from vertex indices: the same surface numbered or oriented otherwise,
rotated, moved or scaled gets the same centres.

References
----------
J. Batson, L. Royer, "Noise2Self: blind denoising by self-supervision", ICML 2019.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Iterator

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.sparse.linalg import splu

from ..geometry import vertex_face_incidence
from ..operators import Operators

__all__ = ["Holdout", "NoHoldout", "Region", "holdout", "path_losses", "region"]

_KEY_DIGITS = 1e6  # keys: fractional part of this multiple of a vertex's relative offset (roundoff stays far below 1)


class NoHoldout(ValueError):
    """The mesh has no vertex that can be held out (every piece is too small for a hole)."""


@dataclass(frozen=True)
class Holdout:
    """Masks of held-out vertices on one mesh (:func:`holdout`).

    Attributes
    ----------
    centres : list of ndarray of int64
        Per mask, the vertices scored.
    filled : list of ndarray, shape (n, 3)
        Per mask, the noisy positions with every hole replaced by its harmonic interpolation.
    radius : int
        Rings around a centre hidden with it.
    faces : list of ndarray of int64
        Per mask, the faces scored: those with a corner at a centre.
    """

    centres: list
    filled: list
    radius: int
    faces: list

    @property
    def count(self) -> int:
        """Centres over all masks."""
        return int(sum(len(c) for c in self.centres))


def _ring_min(W: sp.csr_matrix, key: np.ndarray, rings: int) -> np.ndarray:
    """The least key within ``rings`` rings of each vertex (itself included)."""
    out = key.copy()
    starts = W.indptr[:-1]
    has = np.diff(W.indptr) > 0
    for _ in range(rings):
        nb = np.full(key.shape, np.inf)
        if W.indices.size:
            nb[has] = np.minimum.reduceat(out[W.indices], starts[has])
        out = np.minimum(out, nb)
    return out


def _grow(W: sp.csr_matrix, mask: np.ndarray, rings: int) -> np.ndarray:
    for _ in range(rings):
        mask = mask | (W @ mask.astype(np.float64) > 0)
    return mask


def _keys(V: np.ndarray, ops: Operators) -> np.ndarray:
    """Pseudo-random keys in [0, 1) read from the geometry: invariant to numbering, orientation and similarity."""
    offset = np.linalg.norm(ops.P @ V - V, axis=1)
    scale = float(np.median(offset[offset > 0])) if np.any(offset > 0) else 1.0
    return np.mod(offset / scale * _KEY_DIGITS, 1.0)


def holdout(V: np.ndarray, ops: Operators, radius: int, masks: int, allowed: np.ndarray | None = None,
            centres: int = 0) -> Holdout:
    """Choose ``masks`` disjoint sets of centres (more on a small mesh, see ``centres``) and fill their holes.

    Parameters
    ----------
    V : ndarray, shape (n, 3)
        Noisy positions.
    ops : Operators
        The mesh's operators (adjacency ``W``, averaging ``P``, Laplacian ``L``).
    radius : int, >= 0
        Rings hidden around each centre.
    masks : int, >= 1
        Masks (each a filter run per candidate).
    allowed : ndarray of bool, shape (n,), optional
        Vertices that may be centres (default: all).
    centres : int, >= 0
        Masks are added past ``masks`` until at least this many centres are held out in all, up to
        ``4 * masks`` masks: a small mesh has few centres per mask, and the loss's spread grows as
        their count falls.

    Returns
    -------
    Holdout

    Examples
    --------
    >>> from meshdenoise.shapes import icosphere
    >>> from meshdenoise.operators import get_operators
    >>> V, F = icosphere(3)
    >>> h = holdout(V, get_operators(F, len(V)), radius=1, masks=2)
    >>> len(h.centres), h.count > 20
    (2, True)
    """
    if not isinstance(radius, (int, np.integer)) or radius < 0:
        raise ValueError(f"holdout: radius must be an int >= 0, got {radius!r}")
    if not isinstance(masks, (int, np.integer)) or masks < 1:
        raise ValueError(f"holdout: masks must be an int >= 1, got {masks!r}")
    if not isinstance(centres, (int, np.integer)) or centres < 0:
        raise ValueError(f"holdout: centres must be an int >= 0, got {centres!r}")
    W = ops.W.tocsr()
    n = W.shape[0]
    key = _keys(V, ops)
    # a centre's hole must leave most of its piece of the mesh outside (else nothing is left to fill it from)
    _, label = connected_components(W, directed=False)
    piece = np.bincount(label)[label]
    usable = (ops.degree > 0) & (piece >= 4 * (1 + 3 * radius * (radius + 1)))
    if allowed is not None:
        usable &= allowed
    key = np.where(usable, key, np.inf)
    L = ops.L.tocsr()
    centres_of, filled = [], []
    for c in range(4 * masks):
        if c >= masks and sum(len(x) for x in centres_of) >= centres:
            break
        # another digit of the same offsets for each mask, then the centres already used left out
        k = np.full(n, np.inf)
        k[usable] = np.mod(key[usable] * (c + 1) * 7.0, 1.0) if c else key[usable]
        for used in centres_of:
            k[used] = np.inf
        C = np.flatnonzero(np.isfinite(k) & (k <= _ring_min(W, k, 2 * radius + 1)))
        if C.size == 0:
            break
        start = np.zeros(n, dtype=bool)
        start[C] = True
        hole = _grow(W, start, radius)
        Y = np.array(V, dtype=np.float64)
        h = np.flatnonzero(hole)
        rest = np.flatnonzero(~hole)
        Lhh = L[h][:, h].tocsc()
        Y[h] = splu(Lhh).solve(-(L[h][:, rest] @ Y[rest]))
        centres_of.append(C)
        filled.append(Y)
    if not centres_of:
        raise NoHoldout(f"no vertex can be held out: every piece of the mesh has fewer than "
                        f"{4 * (1 + 3 * radius * (radius + 1))} vertices")
    incidence = vertex_face_incidence(ops.F, n).tocsr()
    faces = [np.unique(incidence[C].indices) for C in centres_of]
    return Holdout(centres=centres_of, filled=filled, radius=int(radius), faces=faces)


def _unit_face_normals(X: np.ndarray, F: np.ndarray) -> np.ndarray:
    a = X[F[:, 0]]
    n = np.cross(X[F[:, 1]] - a, X[F[:, 2]] - a)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, length, out=np.zeros_like(n), where=length > 0)


def path_losses(
    path: Callable[[np.ndarray], Iterator[np.ndarray]],
    V: np.ndarray,
    F: np.ndarray,
    held: Holdout,
    steps: int,
    patience: int,
) -> np.ndarray:
    """The held-out loss of the face normals after each step of a filter's run, over the masks.

    The faces scored are those around the centres (with ``radius >= 1`` their corners are all
    hidden): the loss is the mean of :math:`1 - \\hat n_f \\cdot n_f` with :math:`\\hat n_f` the run's
    face normal on the copy with the holes filled and :math:`n_f` the noisy mesh's own. With the
    run blind to face f's noise, :math:`E[\\hat n_f \\cdot n_f] = \\hat n_f \\cdot E[n_f]`, and when
    the noise is symmetric about the tangent plane (along the normals, along random directions,
    impulsive) :math:`E[n_f] = c\\,n^*_f` with :math:`0 < c \\le 1` and :math:`n^*_f` the clean normal:
    the loss is :math:`1 - c\\,E[\\cos\\theta_f]`, least where the mean angle error is least.

    Parameters
    ----------
    path : callable
        ``path(Y)`` yields the filter's positions after steps 1, 2, ... of one run from ``Y``.
    V : ndarray, shape (n, 3)
        The noisy positions.
    F : ndarray of int, shape (m, 3)
    held : Holdout
    steps : int
        Most steps read.
    patience : int
        A mask's run stops this many steps after its least loss.

    Returns
    -------
    ndarray, shape (steps,)
        Mean loss per scored face after each step; ``inf`` past the steps every mask reached.
    """
    total = np.zeros(steps)
    reached = steps
    count = sum(f.size for f in held.faces)
    for Y, f in zip(held.filled, held.faces):
        Ff = F[f]
        noisy = _unit_face_normals(V, Ff)
        best, at, k = np.inf, 0, 0
        for k, X in enumerate(path(Y)):
            if k >= steps:
                break
            loss = float(f.size - np.einsum("ij,ij->", _unit_face_normals(X, Ff), noisy)) / count
            total[k] += loss
            if loss < best:
                best, at = loss, k
            elif k - at >= patience:
                break
        reached = min(reached, k + 1)
    total[reached:] = np.inf
    return total


@dataclass(frozen=True)
class Region:
    """A part of a mesh scored instead of the whole (:func:`region`).

    Attributes
    ----------
    vertices : ndarray of int64, shape (k,)
        The part's vertices (indices into the mesh), increasing.
    F : ndarray of int64, shape (l, 3)
        Its faces (all three corners in the part), on the part's numbering.
    inner : ndarray of bool, shape (k,)
        Vertices farther than the margin from where the part was cut (centres are drawn there).
    """

    vertices: np.ndarray
    F: np.ndarray
    inner: np.ndarray


def _neighbours(W: sp.csr_matrix, vertices: np.ndarray) -> np.ndarray:
    """The neighbours of ``vertices`` in ``W`` (with repeats): the rows' column indices, read row by row."""
    start, stop = W.indptr[vertices], W.indptr[vertices + 1]
    length = stop - start
    offset = np.repeat(start - np.cumsum(length) + length, length)
    return W.indices[np.arange(offset.size) + offset]


def _rings(W: sp.csr_matrix, inside: np.ndarray, frontier: np.ndarray, rings: int, size: int = 0,
           within: np.ndarray | None = None) -> np.ndarray:
    """``inside`` (bool, n) grown ring by ring from ``frontier`` (its last ring) in place: ``rings`` rings, or until
    it holds ``size`` vertices; only vertices of ``within`` join when given. Work in the rows read, not the mesh."""
    count = int(np.count_nonzero(inside))
    for _ in range(rings):
        if size and count >= size:
            break
        near = _neighbours(W, frontier)
        near = near[~inside[near]]
        if within is not None:
            near = near[within[near]]
        if near.size == 0:
            break
        inside[near] = True
        frontier = np.unique(near)
        count += frontier.size
    return inside


def region(V: np.ndarray, F: np.ndarray, ops: Operators, size: int, patches: int, margin: int) -> Region:
    """Balls of rings around ``patches`` seeds, about ``size`` vertices in all; seeds drawn from the geometry.

    The seeds are the vertices of least key (:func:`holdout`'s keys), so the same surface numbered
    otherwise gets the same part. A mesh of at most ``size`` vertices is its own region. The balls
    grow ring by ring from their last ring only, and the margin from the cut inside the part, so
    the work past the keys is the part's, not the mesh's.
    """
    n = len(V)
    W = ops.W.tocsr()
    if n <= size:
        return Region(np.arange(n), np.asarray(F, dtype=np.int64), np.ones(n, dtype=bool))
    key = np.where(ops.degree > 0, _keys(V, ops), np.inf)
    k = min(patches, n)
    least = np.argpartition(key, k - 1)[:k]
    seeds = least[np.lexsort((least, key[least]))]  # the k least keys, ties to the lower index (argsort's order)
    inside = np.zeros(n, dtype=bool)
    inside[seeds] = True
    _rings(W, inside, np.unique(seeds), n, size)
    keep = inside[F].all(axis=1)
    used = np.zeros(n, dtype=bool)
    used[F[keep].ravel()] = True
    vertices = np.flatnonzero(used)
    local = np.full(n, -1, dtype=np.int64)
    local[vertices] = np.arange(vertices.size)
    # a vertex within `margin` rings of one outside the part is near the cut: the part's vertices next to one
    # outside, then `margin - 1` rings grown inside the part (a shortest path from outside enters the part once)
    near_cut = np.zeros(n, dtype=bool)
    if margin > 0:
        around = _neighbours(W, vertices)
        row = np.repeat(vertices, np.diff(W.indptr)[vertices])
        edge = row[~used[around]]
        near_cut[edge] = True
        _rings(W, near_cut, np.unique(edge), margin - 1, within=used)
    return Region(vertices, local[F[keep]], ~near_cut[vertices])

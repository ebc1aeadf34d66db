"""Faces a filter turned over, found and smoothed out: the default's fold guard (knows no filter).

A face is turned over when its normal is more than 90 degrees from its own normal in the input and from
its neighbours' in the result (:func:`turned_over`); :func:`unfold` averages the corners of such faces and
their neighbours until none is left. Both read the faces around the folds only, not the whole mesh.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.sparse as sp

from .geometry import face_normals
from .operators import Operators

__all__ = ["Folds", "turned_over", "flipped_faces", "unfold", "unfold_with"]


_CHUNK = 1 << 18  # faces per block of the first fold test: two (block, 3) normal arrays, not two (m, 3)


def _rows_of(ptr: np.ndarray, members: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The CSR rows ``rows`` (ptr, members) concatenated, and each one's length."""
    start, length = ptr[rows], ptr[rows + 1] - ptr[rows]
    offset = np.repeat(start - np.cumsum(length) + length, length)
    return members[np.arange(offset.size) + offset], length


class Folds:
    """The faces of ``(X, F)`` turned over (turned_over), kept up to date as vertices move.

    The test of a face needs the unit normals of the faces sharing a vertex with it: it is made
    on the faces turned from their input normal only, and after a move on the faces around the
    moved vertices only. The neighbours' sums are the
    incidence products of turned_over restricted to those rows (each vertex's faces in
    increasing order, each face's vertices in increasing order, from 0): the same bits, so the same
    mask as a test of the whole mesh; at 1.6M vertices the guard's five whole-mesh tests took 5.4 s.

    Attributes
    ----------
    turned : ndarray of bool, shape (m,)
        Faces more than 90 degrees from their own normal in ``(V, F)``.
    mask : ndarray of bool, shape (m,)
        Faces turned over: turned and more than 90 degrees from their neighbours' normal.
    """

    def __init__(self, V: np.ndarray, X: np.ndarray, F: np.ndarray):
        from .kernels.topology import _csr_of_groups

        self.V, self.F = V, np.asarray(F)
        m = self.F.shape[0]
        # each vertex's faces in increasing order, as CSR (a face twice at a degenerate corner: its normal is 0)
        self.ptr, corners = _csr_of_groups(self.F.ravel(), len(V), np.int32 if 3 * m < 2**31 - 1 else np.int64)
        corners //= 3
        self.faces_at = corners
        self.turned = np.zeros(m, dtype=bool)
        for s in range(0, m, _CHUNK):  # blocks: the same rows' arithmetic as one call on the whole mesh
            rows = self.F[s:s + _CHUNK]
            self.turned[s:s + _CHUNK] = np.einsum("ij,ij->i", face_normals(X, rows), face_normals(V, rows)) < 0
        self.mask = np.zeros(m, dtype=bool)
        self._test(X, np.flatnonzero(self.turned))

    def _unique(self, values: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray]:
        """``np.unique(values)`` for indices below ``size``, by a mask of them instead of a sort; and the mask."""
        seen = np.zeros(size, dtype=bool)
        seen[values] = True
        return np.flatnonzero(seen), seen

    def _test(self, X: np.ndarray, faces: np.ndarray) -> None:
        """Test ``faces`` (sorted, unique) again on the positions ``X``."""
        self.mask[faces] = False
        faces = faces[self.turned[faces]]
        if faces.size == 0:
            return
        F, n, m = self.F, self.ptr.size - 1, self.F.shape[0]
        corners = np.sort(F[faces], axis=1)
        vertices, seen = self._unique(corners, n)
        vrank = np.cumsum(seen) - 1
        del seen
        around, length = _rows_of(self.ptr, self.faces_at, vertices)  # the faces at those vertices, vertex by vertex
        near, seen = self._unique(around, m)
        frank = np.cumsum(seen) - 1
        del seen
        N = face_normals(X, F[near])
        # the sums of M @ N on those rows: scipy's CSR product adds each row's entries in order to a zero start
        indptr = np.zeros(vertices.size + 1, dtype=np.int64)
        np.cumsum(length, out=indptr[1:])
        rows = sp.csr_matrix((np.ones(around.size), frank[around], indptr), shape=(vertices.size, near.size))
        S = rows @ N
        at = vrank[corners]
        own = N[frank[faces]]
        # M.T @ S on a face: its corners' sums added in increasing vertex order (scipy's CSC product), less its own 3
        total = S[at[:, 0]] + S[at[:, 1]] + S[at[:, 2]] - 3.0 * own
        self.mask[faces] = np.einsum("ij,ij->i", own, total) < 0

    def faces_of(self, vertices: np.ndarray) -> np.ndarray:
        """The faces with a corner in ``vertices``, sorted and unique."""
        return self._unique(_rows_of(self.ptr, self.faces_at, vertices)[0], self.F.shape[0])[0]

    def corners_of(self, faces: np.ndarray) -> np.ndarray:
        """The corners of ``faces``, sorted and unique."""
        return self._unique(self.F[faces], self.ptr.size - 1)[0]

    def mean_of_neighbours(self, X: np.ndarray, vertices: np.ndarray, degree: np.ndarray) -> np.ndarray:
        """``P[vertices] @ X`` (``P = D^-1 W``) for vertices of ``degree`` > 0, from the faces around them.

        A vertex's neighbours in ``W`` are the other corners of its faces (a face's three sides are edges,
        a degenerate face's self-loop is none); each row sums ``X`` at them in increasing order times
        ``1 / degree`` from a zero start, as scipy's product with the rows of ``P``: the same bits.
        """
        n = self.ptr.size - 1
        faces, length = _rows_of(self.ptr, self.faces_at, vertices)
        row = np.repeat(np.arange(vertices.size), 3 * length)
        other = self.F[faces].ravel()
        keep = other != np.repeat(vertices, 3 * length)
        pairs = np.unique(row[keep] * np.int64(n) + other[keep])  # (row, neighbour), each once, sorted
        row, other = np.divmod(pairs, n)
        indptr = np.zeros(vertices.size + 1, dtype=np.int64)
        np.cumsum(np.bincount(row, minlength=vertices.size), out=indptr[1:])
        weights = (1.0 / degree[vertices])[row]
        return sp.csr_matrix((weights, other, indptr), shape=(vertices.size, n)) @ X

    def moved(self, X: np.ndarray, vertices: np.ndarray) -> None:
        """Update after the (sorted, unique) ``vertices`` moved to their rows of ``X``."""
        faces = self.faces_of(vertices)
        if faces.size == 0:
            return
        rows = self.F[faces]
        self.turned[faces] = np.einsum("ij,ij->i", face_normals(X, rows), face_normals(self.V, rows)) < 0
        # a face's test reads the normals of the faces sharing a vertex with it
        self._test(X, self.faces_of(self.corners_of(faces)))

    @property
    def count(self) -> int:
        return int(np.count_nonzero(self.mask))


def turned_over(V: np.ndarray, X: np.ndarray, F: np.ndarray, M: Any = None) -> np.ndarray:
    """Mask (m,) of the faces of ``(X, F)`` turned over: more than 90 degrees from their own normal in ``(V, F)``
    and from their neighbours' in ``(X, F)``.

    The neighbours' normal of a face: the sum of the unit normals of the faces of ``(X, F)`` sharing a
    vertex with it (itself left out). A noisy face that the filter turns back into line with its
    neighbours is not counted; a fold the filter makes is. ``M``: the (n, m) vertex-face incidence, when
    the caller has it.
    """
    if M is None:  # the test of the turned faces alone (Folds): no product over the whole mesh
        return Folds(V, X, F).mask
    N = face_normals(X, F)
    around = M.T @ (M @ N) - 3.0 * N  # faces sharing a vertex, each once per shared vertex; the face's own 3 left out
    turned = np.einsum("ij,ij->i", N, face_normals(V, F)) < 0
    return turned & (np.einsum("ij,ij->i", N, around) < 0)


def flipped_faces(V: np.ndarray, X: np.ndarray, F: np.ndarray) -> int:
    """How many faces of ``(X, F)`` are turned over (turned_over)."""
    return Folds(V, X, F).count if F.shape[0] else 0


def unfold(V: np.ndarray, X: np.ndarray, F: np.ndarray, ops: Operators, rounds: int) -> tuple[np.ndarray, int]:
    """``X`` with its folds smoothed out: up to ``rounds`` times, the corners of the turned-over faces and their
    neighbours take their neighbours' mean (the rest stays); returns the positions and the folds left.

    Only vertices the filter moved and not on an open border are moved (pinned vertices, those outside a
    region and borders keep what the filter gave them).
    """
    X = np.array(X, dtype=np.float64)
    return unfold_with(V, X, F, ops, rounds, Folds(V, X, F))


def unfold_with(V: np.ndarray, X: np.ndarray, F: np.ndarray, ops: Operators, rounds: int,
            folds: Folds) -> tuple[np.ndarray, int]:
    """:func:`unfold` on ``X`` (float64, written in place) whose folds are ``folds``.

    Each round reads the neighbours of the vertices at the folds only, from the faces around them:
    the same vertices and the same means as the products with ``W`` and ``P`` over the whole mesh,
    which the guard does not need (the default drops them before its run: 160 bytes per vertex).
    """
    movable = np.any(X != V, axis=1) & (ops.degree > 0)
    movable[ops.boundary_vertices] = False
    for _ in range(rounds):
        folded = np.flatnonzero(folds.mask)
        if folded.size == 0:
            return X, 0
        # the corners of the folds and their neighbours: the corners of the faces around them
        near = folds.corners_of(folds.faces_of(folds.corners_of(folded)))
        idx = near[movable[near]]
        if idx.size == 0:  # nothing may move: the rounds left would change nothing
            break
        X[idx] = folds.mean_of_neighbours(X, idx, ops.degree)
        folds.moved(X, idx)
    return X, folds.count

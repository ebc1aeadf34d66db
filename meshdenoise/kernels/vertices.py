"""Per-vertex passes: the two-stage vertex fit and tangential restore, Open3D-weight Taubin, sobolev_normal's divergence."""

from __future__ import annotations

import numpy as np
from numba import prange

from .elementary import face_cross, unit_into
from .threads import njit


# --------------------------------------------------------------------------- vertex update
@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def corner_face(corner):  # pragma: no cover - compiled
    """The face of a corner index ``3 f + k`` (>= 0): ``f``.

    Unsigned, the division by 3 is a multiplication and a shift; numba's signed ``//`` adds the
    correction of Python's floor division for negative numbers, which made a vertex pass of
    ``fit_vertices`` a quarter slower.
    """
    return np.uint64(corner) // np.uint64(3)


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def fit_vertices(X, F, N, corner_ptr, corners, scale, iterations, C):  # pragma: no cover - compiled
    """``iterations`` Jacobi steps ``x_i += scale_i sum_{corners c of i} n_f (n_f . (c_f - x_i))``, in place on ``X``.

    ``corners`` lists, per vertex (rows ``corner_ptr``), its corner indices ``3 f + k`` in
    increasing order; ``C`` (m, 3) is scratch, C-contiguous.

    Each step's face pass stores ``d_f = n_f . c_f`` (its first ``m`` numbers), and the vertex pass
    takes ``n_f . (c_f - x_i)`` as ``d_f - n_f . x_i``: 8 bytes a face written and gathered instead
    of the centroid's 24. A step's move rounds differently by about an ulp of ``|x|``, the size of
    the centroid's own rounding (tests/test_two_stage_kernel.py holds the result to 1e-12 of the
    numpy code's).
    """
    m = F.shape[0]
    n = X.shape[0]
    D = C.reshape(C.size)[:m]  # contiguous: the first m numbers of the scratch
    for _ in range(iterations):
        for f in prange(m):
            a, b, c = F[f, 0], F[f, 1], F[f, 2]
            D[f] = (N[f, 0] * ((X[a, 0] + X[b, 0] + X[c, 0]) / 3.0)
                    + N[f, 1] * ((X[a, 1] + X[b, 1] + X[c, 1]) / 3.0)
                    + N[f, 2] * ((X[a, 2] + X[b, 2] + X[c, 2]) / 3.0))
        for v in prange(n):  # each vertex reads only its own x and the faces' d: in place is Jacobi
            x0 = X[v, 0]
            x1 = X[v, 1]
            x2 = X[v, 2]
            a0 = 0.0
            a1 = 0.0
            a2 = 0.0
            for t in range(corner_ptr[v], corner_ptr[v + 1]):
                f = corner_face(corners[t])
                s = D[f] - (N[f, 0] * x0 + N[f, 1] * x1 + N[f, 2] * x2)
                a0 += N[f, 0] * s
                a1 += N[f, 1] * s
                a2 += N[f, 2] * s
            X[v, 0] = x0 + scale[v] * a0
            X[v, 1] = x1 + scale[v] * a1
            X[v, 2] = x2 + scale[v] * a2


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def face_corner_mean(X, F, corner_ptr, corners, out):  # pragma: no cover - compiled
    """``out[v]``: the mean of the other corners of vertex ``v``'s faces, each face's two counted once.

    Each neighbour of an interior vertex of a manifold mesh lies on two of its faces, so this is its
    neighbours' mean (``P X``, ``P = D^-1 W``) read from the faces, with no adjacency matrix. A vertex
    on no face gets its own position.
    """
    n = X.shape[0]
    for v in prange(n):
        count = corner_ptr[v + 1] - corner_ptr[v]
        if count == 0:
            out[v, 0] = X[v, 0]
            out[v, 1] = X[v, 1]
            out[v, 2] = X[v, 2]
            continue
        s0 = 0.0
        s1 = 0.0
        s2 = 0.0
        for t in range(corner_ptr[v], corner_ptr[v + 1]):
            f = corner_face(corners[t])
            for k in range(3):
                w = F[f, k]
                s0 += X[w, 0]
                s1 += X[w, 1]
                s2 += X[w, 2]
        d = 2.0 * count
        out[v, 0] = (s0 - count * X[v, 0]) / d
        out[v, 1] = (s1 - count * X[v, 1]) / d
        out[v, 2] = (s2 - count * X[v, 2]) / d


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def restore_tangential(X, Y, N, corner_ptr, corners):  # pragma: no cover - compiled
    """``x_i += (I - u_i u_i^T)(y_i - x_i)`` in place, ``u_i = unit(sum_{corners of i} n_f)``.

    Each vertex takes back the tangential part of its move from ``Y`` (n, 3), keeping the
    part along its normal ``u_i`` (the normalised sum of the unit face normals ``N`` (m, 3)
    around it, :func:`meshdenoise.geometry.vertex_normals`); a vertex whose normal is zero
    (on no face, or normals cancelling) does not move.
    """
    n = X.shape[0]
    for v in prange(n):
        s0 = 0.0
        s1 = 0.0
        s2 = 0.0
        for t in range(corner_ptr[v], corner_ptr[v + 1]):
            f = corner_face(corners[t])
            s0 += N[f, 0]
            s1 += N[f, 1]
            s2 += N[f, 2]
        norm = np.sqrt(s0 * s0 + s1 * s1 + s2 * s2)
        if norm > 0:
            u0 = s0 / norm
            u1 = s1 / norm
            u2 = s2 / norm
            r0 = Y[v, 0] - X[v, 0]
            r1 = Y[v, 1] - X[v, 1]
            r2 = Y[v, 2] - X[v, 2]
            along = r0 * u0 + r1 * u1 + r2 * u2
            X[v, 0] += r0 - along * u0
            X[v, 1] += r1 - along * u1
            X[v, 2] += r2 - along * u2




# --------------------------------------------------------------------------- Open3D Taubin
@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def inverse_distance_pass(X, indptr, indices, fixed, f, Y):  # pragma: no cover - compiled
    """``Y = X + f (A X - X)`` with Open3D's weights ``A_ij ∝ 1 / (|x_i - x_j| + 1e-12)`` (rows normalised).

    A fixed vertex (``fixed[i]``) or one without neighbours keeps its position exactly.
    """
    n = X.shape[0]
    for i in prange(n):
        lo, hi = indptr[i], indptr[i + 1]
        x0 = X[i, 0]
        x1 = X[i, 1]
        x2 = X[i, 2]
        s = 0.0
        if not fixed[i]:
            for k in range(lo, hi):
                j = indices[k]
                d0 = x0 - X[j, 0]
                d1 = x1 - X[j, 1]
                d2 = x2 - X[j, 2]
                s += 1.0 / (np.sqrt(d0 * d0 + d1 * d1 + d2 * d2) + 1e-12)
        if s == 0.0:
            Y[i, 0] = x0
            Y[i, 1] = x1
            Y[i, 2] = x2
            continue
        inv = 1.0 / s
        a0 = 0.0
        a1 = 0.0
        a2 = 0.0
        for k in range(lo, hi):
            j = indices[k]
            d0 = x0 - X[j, 0]
            d1 = x1 - X[j, 1]
            d2 = x2 - X[j, 2]
            c = inv * (1.0 / (np.sqrt(d0 * d0 + d1 * d1 + d2 * d2) + 1e-12))
            a0 += c * X[j, 0]
            a1 += c * X[j, 1]
            a2 += c * X[j, 2]
        Y[i, 0] = x0 + f * (a0 - x0)
        Y[i, 1] = x1 + f * (a1 - x1)
        Y[i, 2] = x2 + f * (a2 - x2)




# --------------------------------------------------------------------------- sobolev_normal's divergence
@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def projected_divergence_terms(V, F, Y, X, O, B, t, delta, k0, out):  # pragma: no cover - compiled
    """``out[j] = b * (proj(V + delta b, Y + delta o) - X)`` for probe ``k = k0 + j`` (``b``, ``o``: columns
    ``3k .. 3k + 2`` of ``B`` and ``O``), one probe per thread.

    ``proj(X0, Yb) = X0 + n n^T D + t (I - n n^T) D``, ``D = Yb - X0``, ``n`` the area-weighted unit vertex
    normals of ``Yb``: numpy's arithmetic in :func:`meshdenoise.geometry.area_normals` (cross products
    summed onto the corners in ``np.bincount``'s order: first corners, then second, then third) and
    :func:`meshdenoise.plugins.sobolev_normal.project_update`, so the same numbers bit for bit.
    """
    n = V.shape[0]
    m = F.shape[0]
    for j in prange(out.shape[0]):
        k = k0 + j
        Yb = np.empty((n, 3))
        for i in range(n):
            for d in range(3):
                Yb[i, d] = Y[i, d] + delta * O[i, 3 * k + d]
        C = np.empty((m, 3))
        for f in range(m):
            c0, c1, c2 = face_cross(Yb, F[f, 0], F[f, 1], F[f, 2])
            C[f, 0] = c0
            C[f, 1] = c1
            C[f, 2] = c2
        S = np.zeros((n, 3))
        for corner in range(3):
            for f in range(m):
                v = F[f, corner]
                S[v, 0] += C[f, 0]
                S[v, 1] += C[f, 1]
                S[v, 2] += C[f, 2]
        N = np.empty((n, 3))
        for i in range(n):
            unit_into(N, i, S[i, 0], S[i, 1], S[i, 2])
            x0 = V[i, 0] + delta * B[i, 3 * k]
            x1 = V[i, 1] + delta * B[i, 3 * k + 1]
            x2 = V[i, 2] + delta * B[i, 3 * k + 2]
            d0 = Yb[i, 0] - x0
            d1 = Yb[i, 1] - x1
            d2 = Yb[i, 2] - x2
            dot = (d0 * N[i, 0] + d2 * N[i, 2]) + d1 * N[i, 1]  # numpy's einsum('ij,ij->i') order here (two lanes)
            p0 = dot * N[i, 0]
            p1 = dot * N[i, 1]
            p2 = dot * N[i, 2]
            out[j, i, 0] = B[i, 3 * k] * ((x0 + p0) + t * (d0 - p0) - X[i, 0])
            out[j, i, 1] = B[i, 3 * k + 1] * ((x1 + p1) + t * (d1 - p1) - X[i, 1])
            out[j, i, 2] = B[i, 3 * k + 2] * ((x2 + p2) + t * (d2 - p2) - X[i, 2])

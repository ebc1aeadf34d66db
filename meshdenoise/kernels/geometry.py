"""Face geometry: unit normals, areas and centroids, and the turn of the normals under a vertex displacement."""

from __future__ import annotations

from numba import prange

from .elementary import face_cross, unit_into
from .threads import njit


# --------------------------------------------------------------------------- face geometry
@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def face_geometry(X, F, N, A, C):  # pragma: no cover - compiled
    """Unit normals ``N`` (m, 3), areas ``A`` (m,) and centroids ``C`` (m, 3) of the faces, in place.

    Same arithmetic as :func:`meshdenoise.geometry.face_normals` (numpy's ``cross``, then
    division by the norm; zero for a zero-area face), ``face_areas`` and ``X[F].mean(1)``.
    """
    m = F.shape[0]
    for f in prange(m):
        a, b, c = F[f, 0], F[f, 1], F[f, 2]
        n0, n1, n2 = face_cross(X, a, b, c)
        A[f] = 0.5 * unit_into(N, f, n0, n1, n2)
        for d in range(3):
            C[f, d] = (X[a, d] + X[b, d] + X[c, d]) / 3.0


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def normal_turns(D, F, e1, e2, n, inv, out):  # pragma: no cover - compiled
    """The turn of each unit face normal under the vertex displacement ``D`` (n, 3), into ``out`` (m, 3).

    :class:`meshdenoise.tuning.normal_risk.NormalJacobian`'s product :math:`J d` in one pass over the faces:
    :math:`((d_1 - d_0) \\times e_2 + e_1 \\times (d_2 - d_0))` without its part along the unit normal
    ``n``, times ``inv`` (1 / twice the area; 0 for a zero-area face). Same products and sums as
    the numpy code (:func:`meshdenoise.geometry.cross_rows`), so the same rounding.
    """
    m = F.shape[0]
    for f in prange(m):
        a, b, c = F[f, 0], F[f, 1], F[f, 2]
        u0, u1, u2 = D[b, 0] - D[a, 0], D[b, 1] - D[a, 1], D[b, 2] - D[a, 2]
        w0, w1, w2 = D[c, 0] - D[a, 0], D[c, 1] - D[a, 1], D[c, 2] - D[a, 2]
        p0, p1, p2 = e1[f, 0], e1[f, 1], e1[f, 2]
        q0, q1, q2 = e2[f, 0], e2[f, 1], e2[f, 2]
        c0 = (u1 * q2 - u2 * q1) + (p1 * w2 - p2 * w1)
        c1 = (u2 * q0 - u0 * q2) + (p2 * w0 - p0 * w2)
        c2 = (u0 * q1 - u1 * q0) + (p0 * w1 - p1 * w0)
        t = n[f, 0] * c0 + n[f, 1] * c1 + n[f, 2] * c2
        out[f, 0] = (c0 - n[f, 0] * t) * inv[f]
        out[f, 1] = (c1 - n[f, 1] * t) * inv[f]
        out[f, 2] = (c2 - n[f, 2] * t) * inv[f]


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def normal_turns_many(D, F, e1, e2, n, inv, out):  # pragma: no cover - compiled
    """:func:`normal_turns` of ``P`` displacements at once: ``D`` (n, P, 3) into ``out`` (m, P, 3), the same
    products and sums per displacement (one pass over the faces instead of ``P`` calls: the exact traces'
    probes on a small mesh are one per vertex)."""
    m, P = F.shape[0], D.shape[1]
    for f in prange(m):
        a, b, c = F[f, 0], F[f, 1], F[f, 2]
        p0, p1, p2 = e1[f, 0], e1[f, 1], e1[f, 2]
        q0, q1, q2 = e2[f, 0], e2[f, 1], e2[f, 2]
        for k in range(P):
            u0, u1, u2 = D[b, k, 0] - D[a, k, 0], D[b, k, 1] - D[a, k, 1], D[b, k, 2] - D[a, k, 2]
            w0, w1, w2 = D[c, k, 0] - D[a, k, 0], D[c, k, 1] - D[a, k, 1], D[c, k, 2] - D[a, k, 2]
            c0 = (u1 * q2 - u2 * q1) + (p1 * w2 - p2 * w1)
            c1 = (u2 * q0 - u0 * q2) + (p2 * w0 - p0 * w2)
            c2 = (u0 * q1 - u1 * q0) + (p0 * w1 - p1 * w0)
            t = n[f, 0] * c0 + n[f, 1] * c1 + n[f, 2] * c2
            out[f, k, 0] = (c0 - n[f, 0] * t) * inv[f]
            out[f, k, 1] = (c1 - n[f, 1] * t) * inv[f]
            out[f, k, 2] = (c2 - n[f, 2] * t) * inv[f]


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def normal_turns_adjoint_many(W, F, e1, e2, n, inv, out):  # pragma: no cover - compiled
    """The adjoint of :func:`normal_turns_many`: ``W`` (m, P, 3) turns into ``out`` (n, P, 3), zeroed by the caller.
    Per face :math:`\\hat w = (w - n (n \\cdot w)) / \\|c\\|`, :math:`g_1 = e_2 \\times \\hat w`,
    :math:`g_2 = \\hat w \\times e_1`, added to corners 1 and 2 and subtracted from corner 0. Threads over the
    displacements (each writes its own slice of ``out``: no two threads add to one number), faces in order."""
    m, P = F.shape[0], W.shape[1]
    for k in prange(P):
        for f in range(m):
            s = inv[f]
            t = n[f, 0] * W[f, k, 0] + n[f, 1] * W[f, k, 1] + n[f, 2] * W[f, k, 2]
            w0, w1, w2 = (W[f, k, 0] - n[f, 0] * t) * s, (W[f, k, 1] - n[f, 1] * t) * s, (W[f, k, 2] - n[f, 2] * t) * s
            p0, p1, p2 = e1[f, 0], e1[f, 1], e1[f, 2]
            q0, q1, q2 = e2[f, 0], e2[f, 1], e2[f, 2]
            g0, g1, g2 = q1 * w2 - q2 * w1, q2 * w0 - q0 * w2, q0 * w1 - q1 * w0  # e2 x w
            h0, h1, h2 = w1 * p2 - w2 * p1, w2 * p0 - w0 * p2, w0 * p1 - w1 * p0  # w x e1
            a, b, c = F[f, 0], F[f, 1], F[f, 2]
            out[a, k, 0] -= g0 + h0
            out[a, k, 1] -= g1 + h1
            out[a, k, 2] -= g2 + h2
            out[b, k, 0] += g0
            out[b, k, 1] += g1
            out[b, k, 2] += g2
            out[c, k, 0] += h0
            out[c, k, 1] += h1
            out[c, k, 2] += h2

"""The numpy two-stage filter as it was before the compiled kernels (commit 6ab705a), kept as the slow reference.

tests/test_two_stage_kernel.py checks the compiled ``two_stage`` and its helpers against these
functions. Vectorised over sparse face pairs with a sort per pass: fine for a few thousand faces.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from meshdenoise.geometry import face_areas, face_normals, vertex_face_incidence


def _unit(X: np.ndarray) -> np.ndarray:
    norms = np.linalg.norm(X, axis=1, keepdims=True)
    out = np.zeros_like(X)
    np.divide(X, norms, out=out, where=norms > 0)
    return out


class FaceNeighbourhood:
    """Faces sharing a vertex with each face (itself included), as sorted sparse pairs; cached per topology.

    Attributes
    ----------
    rows, cols : ndarray of int64
        Pairs ``(f, g)``, sorted by ``f`` then ``g``: ``g`` shares at least one vertex with ``f``.
    starts : ndarray of int64
        Index in ``rows`` where each face's pairs begin (every face has itself, so none is empty).
    edge_a, edge_b : ndarray of int64
        Pairs of faces sharing an edge (each such pair once).
    patch, patch_edge : ndarray of int64
        For the guided filter: ``(j, e)`` when both faces of edge-pair ``e`` lie in the
        neighbourhood (patch) of face ``j``, sorted by ``j``.
    """

    def __init__(self, F: np.ndarray, n: int):
        m = F.shape[0]
        self.m = m
        face_of_corner = np.repeat(np.arange(m), 3)
        M = vertex_face_incidence(F, n)
        A = sp.csr_matrix(M.T @ M)
        A.sort_indices()
        self.rows = np.repeat(np.arange(m), np.diff(A.indptr))
        self.cols = A.indices.astype(np.int64)
        self.starts = A.indptr[:-1].astype(np.int64)
        self.matrix_pattern = (A.indices, A.indptr)
        # faces sharing an edge: the two face sides of the same undirected edge
        a, b = F.ravel(), F[:, [1, 2, 0]].ravel()
        key = np.minimum(a, b) * np.int64(n) + np.maximum(a, b)
        order = np.argsort(key, kind="stable")
        same = key[order][1:] == key[order][:-1]
        self.edge_a = face_of_corner[order][:-1][same]
        self.edge_b = face_of_corner[order][1:][same]
        # patch-edge incidences: for each edge pair (a, b), the patches j that contain a and b
        counts = np.diff(A.indptr)[self.edge_a]
        e_rep = np.repeat(np.arange(self.edge_a.size), counts)
        offsets = np.arange(e_rep.size) - np.repeat(np.cumsum(counts) - counts, counts)
        j = A.indices[np.repeat(A.indptr[self.edge_a], counts) + offsets].astype(np.int64)
        pair_keys = self.rows * m + self.cols  # sorted, since rows and cols are
        query = j * m + self.edge_b[e_rep]
        pos = np.minimum(np.searchsorted(pair_keys, query), pair_keys.size - 1)
        inside = pair_keys[pos] == query
        order = np.argsort(j[inside], kind="stable")
        self.patch = j[inside][order]
        self.patch_edge = e_rep[inside][order]

    def matrix(self, weights: np.ndarray) -> sp.csr_matrix:
        """The (m, m) CSR matrix with ``weights`` on the pairs ``(rows, cols)``."""
        indices, indptr = self.matrix_pattern
        return sp.csr_matrix((weights, indices, indptr), shape=(self.m, self.m))


def _segment_max(values: np.ndarray, groups: np.ndarray, m: int) -> np.ndarray:
    """Maximum of ``values`` per group id (groups sorted), 0 for empty groups."""
    out = np.zeros(m)
    if values.size:
        starts = np.r_[0, np.flatnonzero(np.diff(groups)) + 1]
        out[groups[starts]] = np.maximum.reduceat(values, starts)
    return out


def guidance_normals(N: np.ndarray, areas: np.ndarray, nb: FaceNeighbourhood) -> np.ndarray:
    """Zhang et al. (2015) guidance: the mean normal of the most consistent patch containing each face.

    The patch of face j is its neighbourhood P_j. Its mean normal is
    :math:`g_j = \\mathrm{unit}(\\sum_{k \\in P_j} A_k n_k)` and its inconsistency
    :math:`H(P_j) = D(P_j) R(P_j)`, with :math:`D = \\max_{k \\in P_j} \\|n_k - g_j\\|`
    (the normal spread; the paper uses the largest pairwise difference) and
    :math:`R = \\max_e \\varphi_e / (\\epsilon + \\sum_e \\varphi_e)` over the
    edges inside the patch, :math:`\\varphi_e = \\|n_a - n_b\\|`. A patch on one side
    of a sharp edge has a small H. Face i takes :math:`g_j` of the patch
    :math:`P_j \\ni i` with the smallest H.
    """
    m = nb.m
    g = _unit(nb.matrix(areas[nb.cols]) @ N)
    spread = _segment_max(np.linalg.norm(N[nb.cols] - g[nb.rows], axis=1), nb.rows, m)
    phi = np.linalg.norm(N[nb.edge_a] - N[nb.edge_b], axis=1)[nb.patch_edge]
    largest = _segment_max(phi, nb.patch, m)
    total = np.bincount(nb.patch, weights=phi, minlength=m)
    H = spread * largest / (1e-9 + total)
    # Symmetric meshes (an icosahedron, a CAD part's flat sides) have exactly tied patches; rounding
    # noise (say from a translation) must not decide between them. Quantise H to 1e-9 of its range
    # so near-ties are ties, broken by patch index.
    scale = float(H.max()) if H.size else 0.0
    Hq = np.round(H * (1e9 / scale)) if scale > 0 else np.zeros_like(H)  # two_stage.QUANTUM
    # for each face i, the neighbour patch j with the least H (rows are sorted, so lexsort by (H, j, row))
    order = np.lexsort((nb.cols, Hq[nb.cols], nb.rows))
    return g[nb.cols[order[nb.starts]]]


def bilateral_normals(
    N: np.ndarray,
    centroids: np.ndarray,
    areas: np.ndarray,
    nb: FaceNeighbourhood,
    *,
    sigma_s: float,
    sigma_r: float,
    iterations: int,
    guided: bool,
) -> np.ndarray:
    """``iterations`` Jacobi passes of (guided) bilateral filtering of the unit face normals ``N`` (m, 3).

    .. math:: n_i \\leftarrow \\mathrm{unit}\\Big(\\sum_{j \\in \\mathcal N(i)} A_j\\,
              e^{-\\|c_i - c_j\\|^2 / 2\\sigma_s^2}\\, e^{-\\|g_i - g_j\\|^2 / 2\\sigma_r^2}\\, n_j\\Big)

    with :math:`g = n` (bilateral, Zheng et al. 2011) or the guidance normals of
    :func:`guidance_normals` recomputed every pass (guided, Zhang et al. 2015).
    """
    d2 = np.einsum("ij,ij->i", centroids[nb.rows] - centroids[nb.cols], centroids[nb.rows] - centroids[nb.cols])
    spatial = areas[nb.cols] * np.exp(-d2 / (2.0 * sigma_s**2))
    for _ in range(iterations):
        G = guidance_normals(N, areas, nb) if guided else N
        diff = G[nb.rows] - G[nb.cols]
        w = spatial * np.exp(-np.einsum("ij,ij->i", diff, diff) / (2.0 * sigma_r**2))
        N = _unit(nb.matrix(w) @ N)
    return N


def fit_vertices_to_normals(
    X: np.ndarray, F: np.ndarray, N: np.ndarray, iterations: int, fixed: np.ndarray | None = None
) -> np.ndarray:
    """Move vertices so that the faces become orthogonal to the target normals ``N`` (Sun et al. 2007).

    .. math:: x_i \\leftarrow x_i + \\frac{1}{|F_i|} \\sum_{f \\ni i} n_f\\, \\big(n_f \\cdot (c_f - x_i)\\big)

    ``iterations`` Jacobi steps; :math:`c_f` is the face centroid under the current
    positions; :math:`F_i` the faces around vertex i. Fixed and isolated vertices stay.
    """
    n = X.shape[0]
    corner_vertex = F.ravel()
    corner_face = np.repeat(np.arange(F.shape[0]), 3)
    count = np.bincount(corner_vertex, minlength=n).astype(np.float64)
    scale = np.zeros(n)
    np.divide(1.0, count, out=scale, where=count > 0)
    if fixed is not None:
        scale[fixed] = 0.0
    Nc = N[corner_face]
    # sums over corners as one sparse product: vertex <- corner
    S = sp.csr_matrix((np.ones(corner_vertex.size), (corner_vertex, np.arange(corner_vertex.size))), shape=(n, 3 * F.shape[0]))
    X = np.array(X, dtype=np.float64)
    for _ in range(iterations):
        C = X[F].mean(axis=1)
        s = np.einsum("ij,ij->i", Nc, C[corner_face] - X[corner_vertex])
        X = X + scale[:, None] * (S @ (Nc * s[:, None]))
    return X


def restore_tangential(X: np.ndarray, Y: np.ndarray, F: np.ndarray) -> np.ndarray:
    """``x_i + (I - u_i u_i^T)(y_i - x_i)``, ``u_i`` the unit sum of the unit face normals of ``X`` at vertex i.

    A vertex whose normal sum is zero (on no face) stays. Written with ``np.add.at``, one
    corner at a time, as a check of the compiled ``restore_tangential``.
    """
    N = face_normals(X, F)
    U = np.zeros_like(X)
    for k in range(3):
        np.add.at(U, F[:, k], N)
    norm = np.linalg.norm(U, axis=1)
    moved = norm > 0
    U[moved] /= norm[moved, None]
    R = Y - X
    along = np.einsum("ij,ij->i", R, U)
    out = X.copy()
    out[moved] += (R - along[:, None] * U)[moved]
    return out


def reference_two_stage(V, F, *, fixed=None, iterations=3, normal_iterations=10, vertex_iterations=10, sigma_r=0.35,
                        sigma_s=1.0, guidance="guided", keep_tangential=False):
    """The old ``two_stage`` core, unchanged but for building its own neighbourhood (and ``keep_tangential``)."""
    nb = FaceNeighbourhood(F, V.shape[0])
    X = np.array(V, dtype=np.float64)
    Y = X.copy()
    if F.shape[0] == 0:
        return X
    for _ in range(iterations):
        N = face_normals(X, F)
        areas = face_areas(X, F)
        C = X[F].mean(axis=1)
        off = nb.rows != nb.cols
        spacing = float(np.linalg.norm(C[nb.rows[off]] - C[nb.cols[off]], axis=1).mean()) if off.any() else 0.0
        if spacing == 0.0:
            break
        N = bilateral_normals(
            N, C, areas, nb, sigma_s=sigma_s * spacing, sigma_r=sigma_r, iterations=normal_iterations,
            guided=guidance == "guided",
        )
        X = fit_vertices_to_normals(X, F, N, vertex_iterations, fixed)
        if keep_tangential:
            X = restore_tangential(X, Y, F)
    return X

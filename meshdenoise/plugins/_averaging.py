"""The averaging matrices of the linear filters, ``filtering``'s and ``taubin``'s, which their filters and their rules share.

The paper's uniform :math:`D^{-1} W`, MeshLab's (vcglib) and Open3D's simple smoothing as row-stochastic matrices
(:func:`averaging_operator`), vcglib's Taubin averaging (:func:`meshlab_taubin_operator`), and the two rules that
depend on the coordinates and are recomputed every step (MeshLab's cotangent average, inverse distances)."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..operators import Operators

__all__ = ["WEIGHTS", "LINEAR_WEIGHTS", "MESHLAB_WEIGHTS", "averaging_operator", "meshlab_taubin_operator",
           "meshlab_cotangent_average", "inverse_distance_operator", "vcglib_sum_matrix", "has_repeated_index"]

WEIGHTS = ("uniform", "meshlab", "meshlab_cotangent", "open3d", "inverse_distance")
LINEAR_WEIGHTS = ("uniform", "meshlab", "open3d")  # the rest depend on the coordinates, recomputed every step
MESHLAB_WEIGHTS = ("meshlab", "meshlab_cotangent")  # the ones that take MeshLab's ``boundary`` option


def _meshlab_operator(ops: Operators, boundary: bool = True) -> sp.csr_matrix:
    """vcglib's ``VertexCoordLaplacian`` (uniform weights) as a row-stochastic matrix.

    vcglib accumulates neighbours per face side, so an edge counts once per incident face
    (twice inside a manifold mesh, once on the boundary) and the vertex itself once:
    ``x_i <- (x_i + sum_j c_ij x_j) / (1 + sum_j c_ij)``. With MeshLab's ``boundary=True``
    a vertex on a boundary edge forgets its interior neighbours and averages along the
    boundary with double weight on itself: ``x_i <- (2 x_i + sum_{j ~b i} x_j) / (2 + k_i)``.
    With ``boundary=False`` every vertex uses the first rule. A face with a repeated index
    ``(i, i, j)`` has a side i-i, which vcglib counts like any other (adding ``x_i`` to itself, and
    a border side when no other face has it) while :class:`Operators` skips it.
    """
    key = ("meshlab_operator", boundary)
    if key in ops.cache:
        return ops.cache[key]
    n = ops.n
    if has_repeated_index(ops.F):
        A = vcglib_sum_matrix(ops, boundary) + sp.identity(n)
    else:
        edges, counts = ops._undirected_edges
        rows = np.concatenate([edges[:, 0], edges[:, 1]])
        cols = np.concatenate([edges[:, 1], edges[:, 0]])
        vals = np.concatenate([counts, counts]).astype(np.float64)
        self_w = np.ones(n)
        if boundary:
            on_border = ops.boundary_vertices
            edge_is_border = np.concatenate([counts, counts]) == 1
            keep = ~on_border[rows] | edge_is_border  # border vertices keep only their border edges
            rows, cols, vals = rows[keep], cols[keep], vals[keep]
            self_w[on_border] = 2.0
        A = sp.csr_matrix((vals, (rows, cols)), shape=(n, n)) + sp.diags(self_w)
    A = sp.csr_matrix(sp.diags(1.0 / np.asarray(A.sum(axis=1)).ravel()) @ A)
    A.sort_indices()
    ops.cache[key] = A
    return A


def _open3d_operator(ops: Operators) -> sp.csr_matrix:
    """Open3D's ``filter_smooth_simple``: ``x_i <- (x_i + sum_j x_j) / (1 + d_i)``."""
    if "open3d_operator" not in ops.cache:
        A = ops.W + sp.identity(ops.n, format="csr")
        ops.cache["open3d_operator"] = sp.csr_matrix(sp.diags(1.0 / (ops.degree + 1.0)) @ A)
    return ops.cache["open3d_operator"]


def inverse_distance_operator(ops: Operators, X: np.ndarray) -> sp.csr_matrix:
    """Open3D's ``filter_smooth_laplacian`` weights ``1 / (|x_i - x_j| + 1e-12)``, normalised per row."""
    W = ops.W
    rows = np.repeat(np.arange(ops.n), np.diff(W.indptr))
    w = 1.0 / (np.linalg.norm(X[rows] - X[W.indices], axis=1) + 1e-12)
    A = sp.csr_matrix((w, W.indices, W.indptr), shape=W.shape)
    s = np.asarray(A.sum(axis=1)).ravel()
    inv = np.zeros_like(s)
    np.divide(1.0, s, out=inv, where=s > 0)
    return sp.csr_matrix(sp.diags(inv) @ A + sp.diags((s == 0).astype(np.float64)))


def _meshlab_cotangent_pattern(ops: Operators, boundary: bool) -> dict:
    """Who adds what to whom in :func:`meshlab_cotangent_average`, in vcglib's order (cached per ``boundary``).

    Face side ``j`` of face ``f`` (side ``s = 3 f + j``) runs from ``v0 = F[f, j]`` to
    ``v1 = F[f, j + 1]``, opposite the corner ``v2 = F[f, j + 2]`` (vcglib's ``V0(j)``, ``V1(j)``,
    ``V2(j)``). Every term is ``(row, col, side)``: ``S[row] += w * X[col]``, ``c[row] += w``
    with ``w`` the cotangent of ``side``, or ``w = 1`` where ``side`` is -1. The terms are grouped
    by their rank among their row's terms: slice ``k`` (``bounds[k]:bounds[k + 1]``) holds the
    ``k``-th term of every row that has one, each row at most once.
    """
    key = ("meshlab_cotangent", boundary)
    if key in ops.cache:
        return ops.cache[key]
    n, F = ops.n, np.asarray(ops.F)
    v0, v1, v2 = F.ravel(), F[:, [1, 2, 0]].ravel(), F[:, [2, 0, 1]].ravel()
    border_side = np.zeros(v0.size, dtype=bool)
    if boundary:  # vcglib's FaceBorderFromNone: a side whose undirected edge no other face side shares
        _, inverse, counts = np.unique(np.minimum(v0, v1).astype(np.int64) * n + np.maximum(v0, v1),
                                       return_inverse=True, return_counts=True)
        border_side = counts[inverse.ravel()] == 1
    on_border = np.zeros(n, dtype=bool)
    on_border[v0[border_side]] = True
    on_border[v1[border_side]] = True
    # vcglib's three loops over the faces: (1) every inner side s adds to v0 then to v1; (2) every
    # vertex of a border side is reset to sum = x_i, cnt = 1 (its cotangent terms are lost, so they
    # are left out here); (3) every border side adds its other end with weight 1 to v0 then to v1
    sides = np.arange(v0.size)
    rows, cols = np.column_stack([v0, v1]).ravel(), np.column_stack([v1, v0]).ravel()
    inner = ~np.repeat(border_side, 2) & ~on_border[rows]
    outer = np.repeat(border_side, 2)
    reset = np.flatnonzero(on_border)
    rows = np.concatenate([rows[inner], reset, rows[outer]])
    cols = np.concatenate([cols[inner], reset, cols[outer]])
    side = np.concatenate([np.repeat(sides, 2)[inner], np.full(reset.size + int(outer.sum()), -1)])
    # a row's terms in vcglib's order (a stable sort keeps it), then grouped by their rank in the row
    order = np.argsort(rows, kind="stable")
    rows, cols, side = rows[order], cols[order], side[order]
    first = np.searchsorted(rows, rows, side="left")
    rank = np.arange(rows.size) - first
    order = np.argsort(rank, kind="stable")
    pattern = {
        "v0": v0, "v1": v1, "v2": v2,
        "rows": rows[order], "cols": cols[order], "side": side[order],
        "bounds": np.concatenate([[0], np.cumsum(np.bincount(rank))]) if rank.size else np.zeros(1, dtype=np.int64),
    }
    ops.cache[key] = pattern
    return pattern


def has_repeated_index(F: np.ndarray) -> bool:
    """Whether a face of ``F`` (m, 3) names a vertex twice, as ``(i, i, j)``."""
    F = np.asarray(F)
    return bool(((F[:, 0] == F[:, 1]) | (F[:, 1] == F[:, 2]) | (F[:, 2] == F[:, 0])).any())


def vcglib_sum_matrix(ops: Operators, boundary: bool = True) -> sp.csr_matrix:
    """vcglib's ``AccumulateLaplacianInfo`` with uniform weights as a matrix ``T`` (n, n): ``S = T X``, ``c = T 1``.

    Built side by side from :func:`_meshlab_cotangent_pattern` with every weight 1, so a face with
    a repeated index ``(i, i, j)`` adds its side i-i (``x_i`` to ``S_i``, a border side when no other
    face has it) as vcglib does; :class:`Operators` skips those sides. MeshLab's Laplacian step is
    ``(x_i + S_i) / (1 + c_i)``, its Taubin step moves towards ``S_i / c_i``.
    """
    p = _meshlab_cotangent_pattern(ops, boundary)
    return sp.csr_matrix((np.ones(p["rows"].size), (p["rows"], p["cols"])), shape=(ops.n, ops.n))


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot products of (s, 3) arrays, summed as ``(a0 b0 + a1 b1) + a2 b2``, shape (s,)."""
    out = a[:, 0] * b[:, 0]
    out += a[:, 1] * b[:, 1]
    out += a[:, 2] * b[:, 2]
    return out


def _vcglib_cotangents(X: np.ndarray, v0: np.ndarray, v1: np.ndarray, v2: np.ndarray) -> np.ndarray:
    """vcglib's cotangent weight of each face side, with its float32 roundings, shape (s,) float64.

    ``AccumulateLaplacianInfo`` computes ``float angle = Angle(P1 - P2, P0 - P2)`` and
    ``float weight = tan(M_PI / 2 - angle)``: the angle and the weight are both stored in C++
    ``float`` (the coordinates and sums stay double). Without those two roundings, ten steps on a
    noisy 15 x 11 grid (``boundary=False``) land 3.7e-7 of its diagonal away from pymeshlab's;
    with them, on the same bits. ``Angle`` (``vcg/space/point3.h``) clamps the cosine
    to [-1, 1] and returns -1 when an edge has zero length, so a corner whose two other vertices
    coincide weighs :math:`\\tan(\\pi/2 + 1) = -0.642`; a flat corner (angle 0) weighs 1.6e16.

    Parameters
    ----------
    X : (n, 3) float64
    v0, v1, v2 : (s,) int
        The two ends of each side and the opposite corner.
    """
    e1, e0 = X[v1] - X[v2], X[v0] - X[v2]
    # sums in vcglib's order, x + y + z, so that the cosine is bit-identical near +-1, where acos amplifies
    norms = np.sqrt(_dot(e1, e1)) * np.sqrt(_dot(e0, e0))
    cosine = _dot(e1, e0)
    np.divide(cosine, norms, out=cosine, where=norms != 0)
    angle = np.arccos(np.clip(cosine, -1.0, 1.0))
    angle[norms == 0] = -1.0
    angle = angle.astype(np.float32).astype(np.float64)
    return np.tan(np.pi * 0.5 - angle).astype(np.float32).astype(np.float64)


def meshlab_cotangent_average(ops: Operators, X: np.ndarray, boundary: bool = True) -> np.ndarray:
    """One step of MeshLab's cotangent-weighted Laplacian smoothing: the new coordinates, (n, 3).

    vcglib's ``Smooth::VertexCoordLaplacian(m, step, SmoothSelected, cotangentWeight=true)``
    (``vcg/complex/algorithms/smooth.h``), which pymeshlab's
    ``apply_coord_laplacian_smoothing(cotangentweight=True)`` calls (MeshLab's "Laplacian Smooth",
    ``filter_unsharp``). ``AccumulateLaplacianInfo`` gives every vertex a sum :math:`S_i` and a
    weight :math:`c_i`, then

    .. math::
        x_i \\leftarrow \\frac{x_i + S_i}{1 + c_i} \\quad \\text{if } c_i > 0,
        \\qquad x_i \\text{ unchanged otherwise.}

    Inside, every face side ij adds :math:`w = \\cot\\gamma` (:math:`\\gamma` the angle of
    that face opposite the side) to :math:`c_i` and :math:`c_j` and :math:`w x_j`, :math:`w x_i`
    to :math:`S_i`, :math:`S_j`: an edge with two faces weighs :math:`\\cot\\alpha + \\cot\\beta`
    (no factor 1/2, no area). Nothing is clamped: an obtuse angle gives a negative weight, a
    flat one a huge weight, and a vertex whose weights sum to :math:`c_i \\le 0` does not move.
    With ``boundary`` (MeshLab's "1D Boundary Smoothing", its default) a vertex on a border side
    (an edge with one face side) drops its cotangent terms and takes :math:`S_i = x_i + \\sum x_b`,
    :math:`c_i = 1 + k_i` over its :math:`k_i` border neighbours, weight 1 each:
    :math:`(2 x_i + \\sum_b x_b)/(2 + k_i)`, as with uniform weights. Without it MeshLab clears
    the border flags (``FaceClearB``) and every side takes its cotangent. MeshLab's ``selected``
    moves only the selected vertices, the sums still running over every face: that is the
    caller's ``pinned`` rows kept as they are (:func:`smoothing_steps`).

    Parameters
    ----------
    ops : Operators
        The mesh's operators (its faces ``ops.F`` (m, 3)).
    X : (n, 3) float64
        Current coordinates: the weights are recomputed from them at every step.
    boundary : bool
        MeshLab's ``boundary`` option.

    Returns
    -------
    (n, 3) float64
        A new array; rows with :math:`c_i \\le 0` (and isolated vertices) equal ``X``.

    Notes
    -----
    Bit-identical to pymeshlab 2025.7 on the meshes of ``tests/test_meshlab_cotangent.py``,
    degenerate faces included, as long as the faces are in the caller's order. A mesh the
    registry relabels (:mod:`meshdenoise.locality`) sums in another face order, and so does
    MeshLab when given the same faces shuffled: on the range scan face000 (pymeshlab's sample)
    that alone changes MeshLab's result after 10 steps by 1.9e-10 of the diagonal (2.2e-8 with
    ``boundary=False``), since its sliver faces amplify rounding.
    """
    p = _meshlab_cotangent_pattern(ops, boundary)
    w = _vcglib_cotangents(X, p["v0"], p["v1"], p["v2"])
    vals = np.where(p["side"] >= 0, w[p["side"]], 1.0)
    S = np.zeros((ops.n, 3))
    c = np.zeros(ops.n)
    # vcglib adds each vertex's terms one after the other in face order; adding the k-th term of
    # every vertex at once (a loop over ranks, about twice the largest valence, not over vertices)
    # keeps that order, so the sums are bit-identical, which matters on near-degenerate faces whose
    # huge weights amplify any rounding difference (a sparse product sums in another order)
    bounds = p["bounds"]
    for lo, hi in zip(bounds[:-1], bounds[1:]):
        rows = p["rows"][lo:hi]
        S[rows] += X[p["cols"][lo:hi]] * vals[lo:hi, None]
        c[rows] += vals[lo:hi]
    Y = np.array(X, dtype=np.float64)
    moves = c > 0  # vcglib's ``TD[*vi].cnt > 0``; then 1 + c > 1, so no division blows up
    Y[moves] = (X[moves] + S[moves]) / (1.0 + c[moves])[:, None]
    return Y


def averaging_operator(
    ops: Operators, weights: str = "uniform", pinned: np.ndarray | None = None, boundary: bool = True
) -> sp.csr_matrix:
    """The row-stochastic averaging matrix of a linear ``weights`` rule, pinned rows as identity.

    ``"uniform"`` is the paper's ``D^-1 W``; ``"meshlab"`` and ``"open3d"`` reproduce
    MeshLab's and Open3D's simple smoothing. ``"meshlab_cotangent"`` and ``"inverse_distance"``
    depend on the coordinates and have no fixed matrix.
    """
    if weights == "uniform":
        A, name = ops.P, "P"
    elif weights == "meshlab":
        A, name = _meshlab_operator(ops, boundary), f"meshlab-{boundary}"
    elif weights == "open3d":
        A, name = _open3d_operator(ops), "open3d"
    else:
        raise ValueError(
            f"weights={weights!r} depends on the coordinates and has no fixed matrix; linear rules are "
            + ", ".join(map(repr, LINEAR_WEIGHTS))
        )
    return ops.with_pinned_rows(A, pinned, name)


def meshlab_taubin_operator(ops: Operators) -> sp.csr_matrix:
    """vcglib's ``VertexCoordTaubin`` averaging ``S_i / C_i`` as a row-stochastic matrix (cached).

    vcglib's ``AccumulateLaplacianInfo`` counts each edge once per incident face side and
    excludes the vertex itself, so an interior vertex of a manifold mesh takes the plain
    mean of its neighbours (:math:`D^{-1} W`). A vertex on a border edge (an edge with one
    face side) forgets its interior neighbours and averages itself with its border
    neighbours: :math:`(x_i + x_a + x_b) / 3`. An isolated vertex keeps its row identity. A face
    with a repeated index adds its side i-i as vcglib does (:func:`vcglib_sum_matrix`).
    """
    if "meshlab_taubin" in ops.cache:
        return ops.cache["meshlab_taubin"]
    n = ops.n
    if has_repeated_index(ops.F):  # vcglib counts a side i-i, which Operators skips: build it side by side
        A = vcglib_sum_matrix(ops, True)
    else:
        edges, counts = ops._undirected_edges
        rows = np.concatenate([edges[:, 0], edges[:, 1]])
        cols = np.concatenate([edges[:, 1], edges[:, 0]])
        vals = np.concatenate([counts, counts]).astype(np.float64)
        on_border = ops.boundary_vertices
        edge_is_border = vals == 1
        keep = ~on_border[rows] | edge_is_border  # border vertices see only their border edges
        A = sp.csr_matrix((vals[keep], (rows[keep], cols[keep])), shape=(n, n))
        A = A + sp.diags(on_border.astype(np.float64))  # ... and themselves, with weight 1
    s = np.asarray(A.sum(axis=1)).ravel()
    inv = np.zeros(n)
    np.divide(1.0, s, out=inv, where=s > 0)
    A = sp.csr_matrix(sp.diags(inv) @ A + sp.diags((s == 0).astype(np.float64)))
    A.sort_indices()
    ops.cache["meshlab_taubin"] = A
    return A

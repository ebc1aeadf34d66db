"""Linear filtering: repeated neighbour averaging, with MeshLab's and Open3D's variants."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from ..gpu import BACKENDS, Backend, get_backend
from ..locality import LOCALITY_MIN_VERTICES
from ..operators import Operators, gather_rows
from ..registry import MAX_ITERATIONS, AutoRule, Param, ParameterError, register
from ..tuning.config import check_fields, resolve
from ..tuning.context import TuningContext
from ..tuning.risk import Point
from ..tuning.search import averaging_step, best_on_curve, best_on_path, iterative_path, path_curve
from ..tuning.sweep import HeldOutRule, Sweep, geometric

__all__ = ["filtering", "averaging_operator", "smoothing_steps", "step_matrix", "run_linear_steps", "WEIGHTS",
           "LocalityConfig"]

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


def _inverse_distance_operator(ops: Operators, X: np.ndarray) -> sp.csr_matrix:
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
    """Who adds what to whom in :func:`_meshlab_cotangent_average`, in vcglib's order (cached per ``boundary``).

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


def _meshlab_cotangent_average(ops: Operators, X: np.ndarray, boundary: bool = True) -> np.ndarray:
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


@dataclass(frozen=True)
class LocalityConfig:
    """When ``filtering``'s and ``heat``'s steps run on relabelled vertices (their cores' ``config=``).

    Attributes
    ----------
    min_vertices : int
        From this many vertices (:data:`~meshdenoise.locality.LOCALITY_MIN_VERTICES`: below it the coordinates fit in
        cache and relabelling cannot pay) ...
    min_steps : int
        ... for a run of at least this many steps, or once the order is computed: the first relabelling costs about
        15 products at 1.6M vertices.
    """

    min_vertices: int = LOCALITY_MIN_VERTICES
    min_steps: int = 16

    def __post_init__(self) -> None:
        check_fields(self, nonnegative=("min_vertices", "min_steps"))


DEFAULT = LocalityConfig()


def use_locality_order(ops: Operators, steps: int, config: LocalityConfig | None = None) -> bool:
    """Whether to iterate on relabelled vertices (:attr:`Operators.locality_order`).

    Yes for large meshes when the order is already computed or the run is long enough
    to repay computing it (:class:`LocalityConfig`; ``None``: its default).
    """
    config = resolve(config, DEFAULT)
    if ops.n < config.min_vertices or ops.in_locality_order:
        return False
    return "locality_order" in ops.__dict__ or steps >= config.min_steps


def step_matrix(
    ops: Operators,
    weights: str = "uniform",
    lam: float = 1.0,
    pinned: np.ndarray | None = None,
    boundary: bool = True,
    permuted: bool = False,
) -> sp.csr_matrix:
    """The one matrix of a step :math:`X \\leftarrow X + \\lambda (A X - X) = ((1 - \\lambda) I + \\lambda A) X`.

    Fixed vertices get exact identity rows, so they stay bit-identical. Folding the
    step into one matrix makes each iteration a single sparse product with no
    temporaries. Built per call for ``lam < 1`` (one sparse addition, O(nnz)); the
    ``lam = 1`` matrices are the cached averaging operators. With ``permuted=True`` the
    matrix acts on vertices relabelled by :attr:`Operators.locality_order`.
    """
    if permuted:
        order = ops.locality_order
        A = ops.permuted(averaging_operator(ops, weights, None, boundary), f"{weights}-{boundary}")
        pinned = None if pinned is None else pinned[order]
        if lam == 1.0:
            return ops.with_pinned_rows(A, pinned, f"permuted-{weights}-{boundary}")
    elif lam == 1.0:
        return averaging_operator(ops, weights, pinned, boundary)
    else:
        A = averaging_operator(ops, weights, None, boundary)
    M = sp.csr_matrix(lam * A + sp.diags(np.full(ops.n, 1.0 - lam)))
    if pinned is not None and pinned.any():
        M = sp.csr_matrix(sp.diags((~pinned).astype(np.float64)) @ M + sp.diags(pinned.astype(np.float64)))
        M.eliminate_zeros()
    M.sort_indices()
    return M


def run_linear_steps(
    M: sp.csr_matrix, V: np.ndarray, steps: int, backend: str | Backend = "cpu", order: np.ndarray | None = None
) -> np.ndarray:
    """``M^steps V`` by repeated sparse products on ``backend``; ``V`` (n, 3) is not modified.

    Two buffers alternate, so memory stays at two copies of the coordinates plus ``M``.
    With ``order``, ``M`` acts on the vertices relabelled by it (``M = A[order][:, order]``)
    and the result comes back in the original labels.
    """
    be = get_backend(backend) if isinstance(backend, str) else backend
    if steps == 0:
        return np.array(V, dtype=np.float64)
    Md = be.matrix(M)
    X = be.asarray(V) if order is None else be.asarray_owned(gather_rows(V, order))
    Y = be.zeros_like(X)
    for _ in range(steps):
        be.spmm(Md, X, out=Y)
        X, Y = Y, X
    result = be.to_new_numpy(X)
    if order is not None:
        inverse = np.empty_like(order)
        inverse[order] = np.arange(order.size)
        return gather_rows(result, inverse)
    return result


def smoothing_steps(
    V: np.ndarray,
    ops: Operators,
    *,
    weights: str = "uniform",
    lam: float = 1.0,
    pinned: np.ndarray | None = None,
    boundary: bool = True,
) -> Iterator[np.ndarray]:
    """Yield the coordinates after each step of :math:`X \\leftarrow X + \\lambda (A X - X)`, forever.

    Used by :func:`filtering` and :func:`~meshdenoise.plugins.heat.heat`, and by
    parameter searches that read a quality measure along one run instead of restarting
    for every number of steps. Each yielded array is new (safe to keep).
    """
    X = np.array(V, dtype=np.float64, order="C")
    M = None if weights not in LINEAR_WEIGHTS else step_matrix(ops, weights, lam, pinned, boundary)
    while True:
        if M is None:  # weights from the current coordinates
            if weights == "meshlab_cotangent":
                AX = _meshlab_cotangent_average(ops, X, boundary)
            else:
                AX = _inverse_distance_operator(ops, X) @ X
            if pinned is not None:
                AX[pinned] = X[pinned]
            X = AX if lam == 1.0 else X + lam * (AX - X)
        else:
            X = Backend().spmm(M, X)  # one threaded product per step, a new array each time
        yield X


# ----------------------------------------------------------------------------- automatic rule
def _check_linear_weights(ctx: TuningContext, method: str) -> None:
    w = ctx.given.get("weights", "uniform")
    if w not in LINEAR_WEIGHTS:
        raise ValueError(
            f"choose_parameters: method '{method}' with weights={w!r} is not a linear smoother (its weights "
            "follow the coordinates); automatic parameters need weights 'uniform', 'meshlab' or 'open3d'"
        )


def choose_filtering(ctx: TuningContext) -> tuple[dict, Point]:
    """``iterations`` of ``X <- X + lam (A X - X)``: SURE along one run (``H_k = (I + lam(A - I))^k``)."""
    _check_linear_weights(ctx, "filtering")
    lam = float(ctx.given.get("lam", 1.0))
    weights = ctx.given.get("weights", "uniform")
    boundary = ctx.given.get("boundary", True)
    A = averaging_operator(ctx.ops, weights, None, boundary)
    if ctx.oracle:
        p = best_on_path(iterative_path(ctx.V, ctx.ops, averaging_step(A, lam), ctx.exact), ctx.ops.n, ctx.rho, ctx.criterion)
    else:  # the memoised curve: uniform weights share the run of estimate_noise and mu_guess
        name = ("P", lam) if weights == "uniform" else (weights, boundary, lam)
        curve = path_curve(ctx.V, ctx.ops, averaging_step(A, lam), name, ctx.exact)
        p = best_on_curve(curve, ctx.ops.n, ctx.rho, ctx.criterion, coordinates=False)
    return {"iterations": int(p.value)}, p


# criterion "normals": iterations from 1 to 400 in steps of 15 % (every count up to 7) along one run, the least
# held-out face-normal loss: on the corpus's tune half 1.10 times the sweep's best error (geometric mean) against 1.37
# for SURE's choice moved by the estimated normal risk (benchmarks/results/held-out-sweeps.md)
FILTERING_NORMALS = HeldOutRule((Sweep("iterations", geometric(1, 400, 1.15, integer=True), additive=True),))


@register(
    "filtering",
    auto=AutoRule(("iterations",), choose_filtering, normals="iterations", held_out=FILTERING_NORMALS),
    summary="Linear filtering: average each vertex with its neighbours, k times (X <- D^-1 W X)",
    params=[
        Param("iterations", int, 10, low=0, high=MAX_ITERATIONS, help="number of averaging steps k"),
        Param(
            "weights",
            str,
            "uniform",
            choices=WEIGHTS,
            help="uniform: the paper's D^-1 W; meshlab / open3d: their simple Laplacian smoothing; "
            "meshlab_cotangent: MeshLab's cotangent-weighted Laplacian smoothing (pymeshlab's default); "
            "inverse_distance: Open3D's filter_smooth_laplacian weights",
        ),
        Param("lam", float, 1.0, low=0.0, high=1.0, low_open=True, help="step size lambda: X <- X + lam (A X - X)"),
        Param(
            "boundary",
            bool,
            True,
            help="weights 'meshlab' and 'meshlab_cotangent' only, MeshLab's option: True smooths boundary "
            "vertices along the boundary, False over their whole ring",
        ),
        Param(
            "backend",
            str,
            "cpu",
            choices=BACKENDS,
            help="where the sparse products run: cpu (default), scipy (reference), cupy or torch (GPU when present)",
        ),
    ],
    linear=True,
)
def filtering(V, F, *, ops, pinned, iterations, weights, lam, boundary, backend, config=None):
    """Linear filtering by repeated neighbour averaging (the paper's first method).

    .. math:: X^{(t+1)} = X^{(t)} + \\lambda \\left(A X^{(t)} - X^{(t)}\\right), \\qquad t = 0, \\dots, k - 1

    With the defaults (``weights="uniform"``, ``lam=1``) :math:`A = D^{-1} W` and this is
    the paper's :math:`X \\leftarrow D^{-1} W X`. One *iteration* is one application of
    :math:`A`. Other weights reproduce MeshLab and Open3D filters exactly:

    - ``weights="meshlab"``: pymeshlab ``apply_coord_laplacian_smoothing(stepsmoothnum=k,
      boundary=b, cotangentweight=False)`` with ``boundary=b``; its ``selected=True`` is
      ``region="selection"`` here. Each edge counts once per incident face, so an interior
      vertex moves to :math:`(x_i + 2\\sum_j x_j)/(2 d_i + 1)`, not to the plain mean.
    - ``weights="meshlab_cotangent"``: pymeshlab ``apply_coord_laplacian_smoothing(stepsmoothnum=k,
      boundary=b, cotangentweight=True)`` (pymeshlab's default weights) with ``boundary=b``:
      :math:`x_i \\leftarrow (x_i + \\sum_j w_{ij} x_j)/(1 + \\sum_j w_{ij})` with
      :math:`w_{ij} = \\cot\\alpha_{ij} + \\cot\\beta_{ij}` in float32, recomputed every step, not
      clamped; a vertex whose weights sum to 0 or less stays; border vertices as with
      ``"meshlab"``. Not linear; see :func:`_meshlab_cotangent_average`.
    - ``weights="open3d"``: Open3D ``filter_smooth_simple(k)``.
    - ``weights="inverse_distance", lam=l``: Open3D ``filter_smooth_laplacian(k, l)``
      (weights :math:`1/\\|x_i - x_j\\|`, recomputed every step; not linear).

    Isolated vertices stay where they are. Pinned vertices are Dirichlet data: their rows
    of :math:`A` are identity rows.

    Choosing ``iterations`` for a scan: with noise of 0.1, 0.3 and 1 mean edge lengths along the normals the
    oracle chose 0-1, 2 and 3 iterations on a sphere, a torus and the bunny
    (``benchmarks/results/parameter-scale.md``). More steps shrink the surface: prefer
    ``taubin`` or the Sobolev filters for more smoothing.

    Parameters
    ----------
    mesh : (V, F) tuple, pymeshlab.MeshSet or Mesh, or open3d.geometry.TriangleMesh
        ``V`` (n, 3) float, ``F`` (m, 3) int.
    iterations : int, >= 0
        Number of steps k.
    weights : {"uniform", "meshlab", "meshlab_cotangent", "open3d", "inverse_distance"}
    lam : float in (0, 1]
        Step size; 1 replaces each vertex by the average.
    boundary : bool
        Only with ``weights`` "meshlab" or "meshlab_cotangent": MeshLab's ``boundary`` option.
    backend : {"cpu", "scipy", "cupy", "torch"}
        Where the sparse products run (linear weights only); see :mod:`meshdenoise.gpu`.
        The default ``"cpu"`` folds a step into one matrix and runs scipy's CSR kernel
        threaded over row blocks.
    pinned, region, preserve_volume, operators
        Options shared by every filter; see the README.
    config : LocalityConfig, optional
        The array core's (``get_filter("filtering").core``) relabelled path by size; ``None``: its default.

    Returns
    -------
    Same type as ``mesh``
        A new mesh, or the same MeshSet changed in place.

    References
    ----------
    G. Taubin, "A signal processing approach to fair surface design", SIGGRAPH 1995.
    A. Vaillant-Tenzer, "Mesh Denoising", 2022.

    Examples
    --------
    >>> import numpy as np
    >>> V = np.array([[0., 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    >>> F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    >>> V1, F1 = filtering((V, F), iterations=1)
    >>> V1[0]  # the mean of vertices 1, 2 and 3
    array([0.33333333, 0.33333333, 0.33333333])
    """
    if not boundary and weights not in MESHLAB_WEIGHTS:
        raise ParameterError(
            f"parameter 'boundary' = False applies only to weights='meshlab' or 'meshlab_cotangent', "
            f"not weights={weights!r}"
        )
    if weights not in LINEAR_WEIGHTS:
        if backend != "cpu":
            raise ParameterError(
                f"parameter 'backend' = {backend!r} is not available with weights={weights!r} "
                "(its weights change every step); use backend='cpu' or a linear weights rule"
            )
        steps = smoothing_steps(V, ops, weights=weights, lam=lam, pinned=pinned, boundary=boundary)
        X = np.array(V, dtype=np.float64)
        for _ in range(iterations):
            X = next(steps)
        return X
    if iterations == 0:
        return np.array(V, dtype=np.float64)
    permuted = use_locality_order(ops, iterations, config)
    M = step_matrix(ops, weights, lam, pinned, boundary, permuted=permuted)
    return run_linear_steps(M, V, iterations, backend, ops.locality_order if permuted else None)

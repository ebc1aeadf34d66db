"""Linear filtering: repeated neighbour averaging, with MeshLab's and Open3D's variants."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import scipy.sparse as sp

from ..gpu import BACKENDS, Backend, get_backend
from ..locality import LOCALITY_MIN_VERTICES
from ..operators import Operators, gather_rows
from ..registry import MAX_ITERATIONS, AutoRule, Param, register
from ..tuning.context import TuningContext
from ..tuning.risk import Point
from ..tuning.search import averaging_step, best_on_curve, best_on_path, iterative_path, path_curve

__all__ = ["filtering", "averaging_operator", "smoothing_steps", "step_matrix", "run_linear_steps", "WEIGHTS"]

WEIGHTS = ("uniform", "meshlab", "open3d", "inverse_distance")


def _meshlab_operator(ops: Operators, boundary: bool = True) -> sp.csr_matrix:
    """vcglib's ``VertexCoordLaplacian`` (uniform weights) as a row-stochastic matrix.

    vcglib accumulates neighbours per face side, so an edge counts once per incident face
    (twice inside a manifold mesh, once on the boundary) and the vertex itself once:
    ``x_i <- (x_i + sum_j c_ij x_j) / (1 + sum_j c_ij)``. With MeshLab's ``boundary=True``
    a vertex on a boundary edge forgets its interior neighbours and averages along the
    boundary with double weight on itself: ``x_i <- (2 x_i + sum_{j ~b i} x_j) / (2 + k_i)``.
    With ``boundary=False`` every vertex uses the first rule.
    """
    key = ("meshlab_operator", boundary)
    if key in ops.cache:
        return ops.cache[key]
    n = ops.n
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


def averaging_operator(
    ops: Operators, weights: str = "uniform", pinned: np.ndarray | None = None, boundary: bool = True
) -> sp.csr_matrix:
    """The row-stochastic averaging matrix of a linear ``weights`` rule, pinned rows as identity.

    ``"uniform"`` is the paper's ``D^-1 W``; ``"meshlab"`` and ``"open3d"`` reproduce
    MeshLab's and Open3D's simple smoothing. ``"inverse_distance"`` depends on the
    coordinates and has no pinned matrix.
    """
    if weights == "uniform":
        A, name = ops.P, "P"
    elif weights == "meshlab":
        A, name = _meshlab_operator(ops, boundary), f"meshlab-{boundary}"
    elif weights == "open3d":
        A, name = _open3d_operator(ops), "open3d"
    else:
        raise ValueError(f"weights={weights!r} has no pinned matrix; linear rules are 'uniform', 'meshlab', 'open3d'")
    return ops.with_pinned_rows(A, pinned, name)


LOCALITY_MIN_STEPS = 16  # the first relabelling costs about 15 products at 1.6M vertices


def use_locality_order(ops: Operators, steps: int) -> bool:
    """Whether to iterate on relabelled vertices (:attr:`Operators.locality_order`).

    Yes for large meshes when the order is already computed or the run is long enough
    to repay computing it.
    """
    if ops.n < LOCALITY_MIN_VERTICES or ops.in_locality_order:
        return False
    return "locality_order" in ops.__dict__ or steps >= LOCALITY_MIN_STEPS


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
    M = None if weights == "inverse_distance" else step_matrix(ops, weights, lam, pinned, boundary)
    while True:
        if M is None:
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
    if w == "inverse_distance":
        raise ValueError(
            f"choose_parameters: method '{method}' with weights='inverse_distance' is not a linear smoother; "
            "automatic parameters need weights 'uniform', 'meshlab' or 'open3d'"
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


@register(
    "filtering",
    auto=AutoRule(("iterations",), choose_filtering, normals="iterations", additive=True, integer=True),
    summary="Linear filtering: average each vertex with its neighbours, k times (X <- D^-1 W X)",
    params=[
        Param("iterations", int, 10, low=0, high=MAX_ITERATIONS, help="number of averaging steps k"),
        Param(
            "weights",
            str,
            "uniform",
            choices=WEIGHTS,
            help="uniform: the paper's D^-1 W; meshlab / open3d: their simple Laplacian smoothing; "
            "inverse_distance: Open3D's filter_smooth_laplacian weights",
        ),
        Param("lam", float, 1.0, low=0.0, high=1.0, low_open=True, help="step size lambda: X <- X + lam (A X - X)"),
        Param(
            "boundary",
            bool,
            True,
            help="weights='meshlab' only, MeshLab's option: True smooths boundary vertices along the boundary, "
            "False over their whole ring",
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
def filtering(V, F, *, ops, pinned, iterations, weights, lam, boundary, backend):
    """Linear filtering by repeated neighbour averaging (the paper's first method).

    .. math:: X^{(t+1)} = X^{(t)} + \\lambda \\left(A X^{(t)} - X^{(t)}\\right), \\qquad t = 0, \\dots, k - 1

    With the defaults (``weights="uniform"``, ``lam=1``) :math:`A = D^{-1} W` and this is
    the paper's :math:`X \\leftarrow D^{-1} W X`. One *iteration* is one application of
    :math:`A`. Other weights reproduce MeshLab and Open3D filters exactly:

    - ``weights="meshlab"``: pymeshlab ``apply_coord_laplacian_smoothing(stepsmoothnum=k,
      boundary=b, cotangentweight=False)`` with ``boundary=b``; its ``selected=True`` is
      ``region="selection"`` here. Each edge counts once per incident face, so an interior
      vertex moves to :math:`(x_i + 2\\sum_j x_j)/(2 d_i + 1)`, not to the plain mean.
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
    weights : {"uniform", "meshlab", "open3d", "inverse_distance"}
    lam : float in (0, 1]
        Step size; 1 replaces each vertex by the average.
    boundary : bool
        Only with ``weights="meshlab"``: MeshLab's ``boundary`` option.
    backend : {"cpu", "scipy", "cupy", "torch"}
        Where the sparse products run (linear weights only); see :mod:`meshdenoise.gpu`.
        The default ``"cpu"`` folds a step into one matrix and runs scipy's CSR kernel
        threaded over row blocks.
    pinned, region, preserve_volume, operators
        Options shared by every filter; see the README.

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
    if not boundary and weights != "meshlab":
        raise ValueError(f"parameter 'boundary' = False applies only to weights='meshlab', not weights={weights!r}")
    if weights == "inverse_distance":
        if backend != "cpu":
            raise ValueError(
                f"parameter 'backend' = {backend!r} is not available with weights='inverse_distance' "
                "(its weights change every step); use backend='cpu' or a linear weights rule"
            )
        steps = smoothing_steps(V, ops, weights=weights, lam=lam, pinned=pinned, boundary=boundary)
        X = np.array(V, dtype=np.float64)
        for _ in range(iterations):
            X = next(steps)
        return X
    if iterations == 0:
        return np.array(V, dtype=np.float64)
    permuted = use_locality_order(ops, iterations)
    M = step_matrix(ops, weights, lam, pinned, boundary, permuted=permuted)
    return run_linear_steps(M, V, iterations, backend, ops.locality_order if permuted else None)

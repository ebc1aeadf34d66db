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
from ._averaging import (LINEAR_WEIGHTS, MESHLAB_WEIGHTS, WEIGHTS, averaging_operator, inverse_distance_operator,
                         meshlab_cotangent_average)
from .filtering_rule import FILTERING_NORMALS, choose_filtering

__all__ = ["filtering", "averaging_operator", "smoothing_steps", "step_matrix", "run_linear_steps", "WEIGHTS",
           "LocalityConfig"]


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
                AX = meshlab_cotangent_average(ops, X, boundary)
            else:
                AX = inverse_distance_operator(ops, X) @ X
            if pinned is not None:
                AX[pinned] = X[pinned]
            X = AX if lam == 1.0 else X + lam * (AX - X)
        else:
            X = Backend().spmm(M, X)  # one threaded product per step, a new array each time
        yield X


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
      ``"meshlab"``. Not linear; see :func:`meshlab_cotangent_average`.
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

"""Taubin lambda/mu smoothing: a shrinking pass then an inflating pass, without shrinkage."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from ..operators import Operators, spmm
from ..registry import MAX_ITERATIONS, AutoRule, Param, get_filter, register
from ..tuning.config import check_fields
from ..tuning.context import TuningContext
from ..tuning.risk import Point
from ..tuning.search import averaging_step, best_on_curve, best_on_path, iterative_path, path_curve
from ..tuning.sweep import HeldOutRule, Sweep, geometric
from .filtering import has_repeated_index, vcglib_sum_matrix

__all__ = ["taubin", "meshlab_taubin_operator", "pass_matrix", "TAUBIN_WEIGHTS", "TaubinConfig"]

TAUBIN_WEIGHTS = ("uniform", "meshlab", "open3d")


def meshlab_taubin_operator(ops: Operators) -> sp.csr_matrix:
    """vcglib's ``VertexCoordTaubin`` averaging ``S_i / C_i`` as a row-stochastic matrix (cached).

    vcglib's ``AccumulateLaplacianInfo`` counts each edge once per incident face side and
    excludes the vertex itself, so an interior vertex of a manifold mesh takes the plain
    mean of its neighbours (:math:`D^{-1} W`). A vertex on a border edge (an edge with one
    face side) forgets its interior neighbours and averages itself with its border
    neighbours: :math:`(x_i + x_a + x_b) / 3`. An isolated vertex keeps its row identity. A face
    with a repeated index adds its side i-i as vcglib does (:func:`~meshdenoise.plugins.filtering.vcglib_sum_matrix`).
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


# ----------------------------------------------------------------------------- automatic rule
TAUBIN_LAMBDAS = (0.5, 0.25, 0.125)  # candidate shrinking steps of the automatic taubin rule


@dataclass(frozen=True)
class TaubinConfig:
    """The taubin rule's pruning (``choose_parameters(..., config=TaubinConfig(...))``).

    Attributes
    ----------
    fine_min_vertices : int
        From this size a finer lambda is tried only while ...
    fine_max_iterations : int
        ... the coarser one's best count is below this (a count past it is already a fine step's).
    """

    fine_min_vertices: int = 10_000
    fine_max_iterations: int = 8

    def __post_init__(self) -> None:
        check_fields(self, nonnegative=("fine_min_vertices", "fine_max_iterations"))


DEFAULT = TaubinConfig()


def taubin_mu_for(lam: float, pass_band: float) -> float:
    """The inflating step ``mu`` that gives Taubin's filter the pass-band frequency ``pass_band``.

    .. math:: k_{PB} = \\frac1\\lambda + \\frac1\\mu \\quad\\Rightarrow\\quad \\mu = \\frac{1}{k_{PB} - 1/\\lambda}

    Parameters
    ----------
    lam : float in (0, 1]
        Shrinking step.
    pass_band : float
        :math:`k_{PB}`, with :math:`0 < k_{PB} < 1/\\lambda - 1` so that :math:`-1 \\le \\mu < 0`.

    Examples
    --------
    >>> round(taubin_mu_for(0.5, 1 / 0.5 + 1 / -0.53), 6)  # the defaults' own pass band
    -0.53
    """
    if not (0 < lam <= 1):
        raise ValueError(f"taubin_mu_for: parameter 'lam' = {lam!r} is out of range: 0 < lam <= 1")
    if not (0 < pass_band < 1 / lam - 1):
        raise ValueError(f"taubin_mu_for: parameter 'pass_band' = {pass_band!r} is out of range: 0 < pass_band < 1/lam - 1")
    return 1.0 / (pass_band - 1.0 / lam)


def choose_taubin(ctx: TuningContext) -> tuple[dict, Point]:
    """``iterations`` (and ``lam``, ``mu`` unless given) of Taubin lambda/mu smoothing.

    With ``weights`` "uniform" or "meshlab" one iteration is the linear map
    :math:`H_1 = (I + \\mu(A - I))(I + \\lambda(A - I))`, so SURE is read along one run
    exactly as for ``filtering``. Unless ``lam`` or ``mu`` is given, the run is repeated for
    :math:`\\lambda \\in` ``TAUBIN_LAMBDAS`` (0.5, 0.25, 0.125) with :math:`\\mu` from
    :func:`taubin_mu_for` keeping the pass band :math:`k_{PB} = 1/\\lambda + 1/\\mu` of the
    defaults (0.5, -0.53): the same low-pass shape, finer steps (one default iteration
    can already be too much on weak noise: Nefertiti at rho = 0.015), and the smallest
    SURE wins, as ``tau`` for ``heat``. From ``TaubinConfig.fine_min_vertices`` (10,000) vertices a
    finer lambda is tried only while the best count so far is below ``TaubinConfig.fine_max_iterations``
    (8): the finer steps are there for weak noise, where one default iteration is already too
    much; with more iterations the count itself resolves the time, and each halving of lambda
    doubles a walk that is already long (the 400k scale mesh: 80 iterations at lambda 0.5,
    docs/scale.md). Open3D's weights depend on the coordinates: not
    linear, not supported here.
    """
    weights = ctx.given.get("weights", "uniform")
    if weights == "open3d":
        raise ValueError(
            "choose_parameters: taubin with weights='open3d' (inverse-distance, recomputed each pass) is not a "
            "linear smoother; automatic parameters need weights 'uniform' or 'meshlab'"
        )
    spec = get_filter("taubin")
    lam0, mu0 = float(spec.param("lam").default), float(spec.param("mu").default)
    if "lam" in ctx.given or "mu" in ctx.given:
        pairs = [(float(ctx.given.get("lam", lam0)), float(ctx.given.get("mu", mu0)))]
    else:
        pass_band = 1.0 / lam0 + 1.0 / mu0
        pairs = [(lam, taubin_mu_for(lam, pass_band)) for lam in TAUBIN_LAMBDAS]
    A = ctx.ops.P if weights == "uniform" else meshlab_taubin_operator(ctx.ops)
    config = ctx.config_for(DEFAULT)
    best, best_pair = None, None
    for lam, mu in pairs:
        if best is not None and ctx.n >= config.fine_min_vertices and best.value >= config.fine_max_iterations:
            break  # the run's own count already resolves the time; a finer step costs twice the walk
        shrink, inflate = averaging_step(A, lam), averaging_step(A, mu)
        step = lambda Y, s=shrink, f=inflate: f(s(Y))  # noqa: E731
        if ctx.oracle:
            p = best_on_path(iterative_path(ctx.V, ctx.ops, step, ctx.exact), ctx.ops.n, ctx.rho, ctx.criterion)
        else:
            curve = path_curve(ctx.V, ctx.ops, step, ("taubin", weights, lam, mu), ctx.exact)
            p = best_on_curve(curve, ctx.ops.n, ctx.rho, ctx.criterion, coordinates=False)
        if best is None or p.score < best.score:
            best, best_pair = p, (lam, mu)
    out = {"iterations": int(best.value)}
    if len(pairs) > 1:
        out.update(lam=best_pair[0], mu=best_pair[1])
    return out, best


# criterion "normals": iterations from 1 to 2,000 in steps of 15 % along one run, lam and mu the defaults, the least
# held-out face-normal loss: on the corpus's tune half 1.19 times the sweep's best error (geometric mean) against 1.39
# for SURE over three lambdas moved by the estimated normal risk (benchmarks/results/held-out-sweeps.md)
TAUBIN_NORMALS = HeldOutRule((Sweep("iterations", geometric(1, 2000, 1.15, integer=True), (("lam", 0.5), ("mu", -0.53)),
                                    additive=True),))


@register(
    "taubin",
    auto=AutoRule(("iterations", "lam", "mu"), choose_taubin, normals="iterations", held_out=TAUBIN_NORMALS),
    summary="Taubin lambda/mu smoothing: per iteration X += lam (AX - X), then X += mu (AX - X), mu < 0",
    params=[
        Param("iterations", int, 10, low=0, high=MAX_ITERATIONS, help="number of (lambda pass + mu pass) pairs"),
        Param("lam", float, 0.5, low=0.0, high=1.0, low_open=True, help="shrinking step lambda, 0 < lam <= 1"),
        Param("mu", float, -0.53, low=-1.0, high=0.0, high_open=True, help="inflating step mu < 0 (added)"),
        Param(
            "weights",
            str,
            "uniform",
            choices=TAUBIN_WEIGHTS,
            help="uniform: D^-1 W; meshlab: apply_coord_taubin_smoothing exactly; open3d: filter_smooth_taubin",
        ),
    ],
    linear=False,
)
def taubin(V, F, *, ops, pinned, iterations, lam, mu, weights):
    """Taubin's lambda/mu smoothing, a low-pass filter that does not shrink the mesh.

    One *iteration* is a shrinking pass with :math:`\\lambda > 0` followed by an
    inflating pass with :math:`\\mu < 0` (the MeshLab and Open3D convention):

    .. math::
        X \\leftarrow X + \\lambda (A X - X), \\qquad X \\leftarrow X + \\mu (A X - X)

    so that the transfer function on a Laplacian eigenvalue :math:`k` of
    :math:`I - A` is :math:`((1 - \\lambda k)(1 - \\mu k))^N`: it is close to 1 for
    :math:`k < k_{PB} = 1/\\lambda + 1/\\mu` (low frequencies pass, no shrinkage) and
    small for high frequencies. Taubin recommends :math:`k_{PB} \\approx 0.1` and
    :math:`-\\mu > \\lambda`.

    ``weights`` selects :math:`A`:

    - ``"uniform"``: the paper's :math:`D^{-1} W` (linear).
    - ``"meshlab"``: pymeshlab ``apply_coord_taubin_smoothing(lambda_=lam, mu=mu,
      stepsmoothnum=iterations)`` to rounding: :math:`D^{-1} W` inside, the border rule
      :math:`(x_i + x_a + x_b)/3` at a vertex on a border edge, and ``lam``, ``mu``
      rounded to float32 as vcglib does. MeshLab's Taubin has no cotangent form (unlike its
      Laplacian smoothing, ``filtering(weights="meshlab_cotangent")``): vcglib's
      ``Smooth::VertexCoordTaubin`` calls ``AccumulateLaplacianInfo`` without the cotangent
      flag, and pymeshlab's filter has no ``cotangentweight`` parameter.
    - ``"open3d"``: Open3D ``filter_smooth_taubin(iterations, lambda_filter=lam, mu=mu)``:
      inverse-distance weights :math:`1/(\\|x_i - x_j\\| + 10^{-12})`, recomputed
      before every pass (not linear); each pass is one compiled loop over the edges,
      faster than Open3D's own.

    trimesh's ``smoothing.filter_taubin(lamb, nu, iterations=k)`` counts every *pass* as
    an iteration and subtracts a positive ``nu``: it corresponds to ``iterations=k/2``,
    ``lam=lamb``, ``mu=-nu`` here (for even ``k``).

    Choosing ``iterations`` for a scan: the count depends on ``lam`` as much as on the noise (with
    noise of 0.1, 0.3 and 1 mean edge lengths along the normals the oracle took 13 to 330 steps over
    its three ``lam`` values on a sphere, a torus and the bunny, ``benchmarks/results/parameter-scale.md``): let the
    automatic rule choose both (``denoise(method="taubin")``), or fix ``lam=0.5`` and compare
    renders at 20, 50 and 100 iterations.

    Parameters
    ----------
    mesh : (V, F) tuple, pymeshlab.MeshSet or Mesh, or open3d.geometry.TriangleMesh
    iterations : int, >= 0
        Number of lambda/mu pass pairs.
    lam : float in (0, 1]
    mu : float in [-1, 0)
        Added, so negative: inflation.
    weights : {"uniform", "meshlab", "open3d"}
    pinned, region, preserve_volume, operators
        Options shared by every filter; see the README.

    Returns
    -------
    Same type as ``mesh``

    References
    ----------
    G. Taubin, "A signal processing approach to fair surface design", SIGGRAPH 1995.
    G. Taubin, "Curve and surface smoothing without shrinkage", ICCV 1995.

    Examples
    --------
    >>> import numpy as np
    >>> V = np.array([[0., 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    >>> F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    >>> V1, _ = taubin((V, F), iterations=1, lam=0.5, mu=-0.5)
    >>> V1[0]  # on K4 a pass scales x - centroid by 1 - 4f/3: 1/3 then 5/3, so 0.25 - 0.25 * 5/9
    array([0.11111111, 0.11111111, 0.11111111])
    """
    X = np.array(V, dtype=np.float64)
    if iterations == 0:
        return X
    if weights == "meshlab":
        # vcglib passes lambda and mu as C++ float
        lam, mu = float(np.float32(lam)), float(np.float32(mu))
    if weights == "open3d":
        return _open3d_taubin(X, ops, pinned, iterations, lam, mu)
    A = ops.P if weights == "uniform" else meshlab_taubin_operator(ops)
    # each pass X + f (AX - X) = ((1 - f) I + f A) X folded into one matrix: one threaded product, no temporaries
    passes = [pass_matrix(A, f, pinned) for f in (lam, mu)]
    Y = np.empty_like(X)
    for _ in range(iterations):
        for M in passes:
            spmm(M, X, out=Y)
            X, Y = Y, X
    return X


def pass_matrix(A: sp.csr_matrix, f: float, pinned: np.ndarray | None = None) -> sp.csr_matrix:
    """``(1 - f) I + f A`` (n, n) CSR, with identity rows at ``pinned`` vertices (they stay bit-identical)."""
    n = A.shape[0]
    keep = np.ones(n) if pinned is None else (~pinned).astype(np.float64)
    M = sp.csr_matrix(sp.diags(f * keep) @ A + sp.diags(1.0 - f * keep))
    M.eliminate_zeros()
    M.sort_indices()
    return M


def _open3d_taubin(
    X: np.ndarray, ops: Operators, pinned: np.ndarray | None, iterations: int, lam: float, mu: float
) -> np.ndarray:
    """Open3D-weight passes ``X <- X + f (A(X) X - X)``, ``A(X)_ij ∝ 1 / (|x_i - x_j| + 1e-12)``, compiled.

    Each pass is one threaded loop over the rows of ``W`` (:func:`meshdenoise.kernels.inverse_distance_pass`)
    from one preallocated (n, 3) buffer into the other: the weights are never stored.
    ``X`` (n, 3) float64 is used as one of the buffers; returns the result (n, 3).
    """
    from .. import kernels

    kernels.set_threads()
    W = ops.W
    mask = np.zeros(ops.n, dtype=bool) if pinned is None else np.ascontiguousarray(pinned, dtype=bool)
    X = np.ascontiguousarray(X)
    Y = np.empty_like(X)
    for _ in range(iterations):
        for f in (lam, mu):
            kernels.inverse_distance_pass(X, W.indptr, W.indices, mask, float(f), Y)
            X, Y = Y, X
    return X

"""Taubin lambda/mu smoothing: a shrinking pass then an inflating pass, without shrinkage."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..operators import Operators, spmm
from ..registry import MAX_ITERATIONS, AutoRule, Param, register
from ._averaging import meshlab_taubin_operator
from .taubin_rule import TAUBIN_NORMALS, choose_taubin

__all__ = ["taubin", "meshlab_taubin_operator", "pass_matrix", "TAUBIN_WEIGHTS"]

TAUBIN_WEIGHTS = ("uniform", "meshlab", "open3d")


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

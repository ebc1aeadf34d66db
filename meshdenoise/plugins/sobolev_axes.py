"""Polyharmonic Sobolev smoothing with one weight per principal axis of the surface normals."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..geometry import vertex_normals
from ..operators import Operators
from ..registry import Param, register
from ..solvers import SPDSolver, cached_solver

__all__ = ["sobolev_axes", "normal_frame", "laplacian_power"]


def laplacian_power(ops: Operators, order: int) -> sp.csr_matrix:
    """:math:`L^p` for the graph Laplacian ``L = D - W`` of this topology (cached), ``order`` = p >= 1."""
    powers = ops.cache.setdefault("laplacian_powers", {})
    if order not in powers:
        M = sp.csr_matrix(ops.L)
        for _ in range(order - 1):
            M = sp.csr_matrix(M @ ops.L)
        M.sort_indices()
        powers[order] = M
    return powers[order]


def normal_frame(X: np.ndarray, F: np.ndarray, ops: Operators, steps: int) -> tuple[np.ndarray, np.ndarray]:
    """Principal axes of the vertex normals of the mesh smoothed by ``steps`` averaging steps.

    .. math:: T = \\sum_i \\tilde n_i \\tilde n_i^T = E \\,\\mathrm{diag}(w)\\, E^T, \\qquad
              \\tilde X = (D^{-1}W)^{s} X

    Returns ``(E, w)``: the orthonormal eigenvectors (3, 3) as columns, by increasing
    eigenvalue ``w`` (3,). Under the paper's noise model (displacements along the normals)
    the noise energy along axis ``e_d`` is :math:`\\rho^2 \\sum_i (n_i \\cdot e_d)^2`: the
    axes separate directions with little and much noise. ``T`` is quadratic in the
    normals, so the frame does not depend on their orientation, and it rotates with
    the mesh.

    Examples
    --------
    >>> from meshdenoise.shapes import grid
    >>> from meshdenoise.operators import get_operators
    >>> V, F = grid(5, 5)  # flat in z = 0: every normal is +-e_z, the last axis
    >>> E, w = normal_frame(V, F, get_operators(F, len(V)), steps=0)
    >>> [round(abs(float(c)), 6) for c in E[:, 2]], round(float(w[2]), 6)
    ([0.0, 0.0, 1.0], 25.0)
    """
    Y = np.array(X, dtype=np.float64)
    for _ in range(steps):
        Y = ops.P @ Y
    N = vertex_normals(Y, F)
    w, E = np.linalg.eigh(N.T @ N)
    return E, w


def _solver(ops: Operators, order: int, mu: float, fixed: np.ndarray | None) -> SPDSolver:
    """The cached Cholesky factor of ``I + mu L^order`` (pinned rows as Dirichlet data) on this topology."""
    return cached_solver(
        ops, f"sobolev_axes-p{order}", mu, fixed,
        lambda: SPDSolver(sp.identity(ops.n, format="csr") + mu * laplacian_power(ops, order), fixed),
    )


@register(
    "sobolev_axes",
    summary="Polyharmonic Sobolev (I + mu_d L^p) y_d = x_d, one mu per principal axis of the normals",
    params=[
        Param("mu1", float, 1.0, low=0.0, help="weight on the axis the normals point along least (0 keeps it)"),
        Param("mu2", float, 1.0, low=0.0, help="weight on the middle axis"),
        Param("mu3", float, 1.0, low=0.0, help="weight on the axis the normals point along most"),
        Param("order", int, 3, low=1, high=4, help="power p of the Laplacian in the penalty ||L^{p/2} y||^2"),
        Param("frame_steps", int, 10, low=0, help="averaging steps before the normals that define the axes"),
    ],
    linear=False,
)
def sobolev_axes(V, F, *, ops, fixed, mu1, mu2, mu3, order, frame_steps):
    """Polyharmonic Sobolev smoothing, with its own strength on each principal axis of the normals.

    With :math:`E = (e_1, e_2, e_3)` the principal axes of the normals of the mesh
    smoothed by ``frame_steps`` averaging steps (:func:`normal_frame`, increasing
    eigenvalues of :math:`\\sum_i n_i n_i^T`), each coordinate in that frame is
    smoothed separately:

    .. math:: (I + \\mu_d L^p)\\, y_d = X e_d, \\quad d = 1, 2, 3, \\qquad
              Y = \\sum_d y_d\\, e_d^T, \\qquad L = D - W

    i.e. :math:`y_d = \\arg\\min_y \\|y - X e_d\\|^2 + \\mu_d\\, y^T L^p y`. Why one
    weight per axis: the paper's noise moves vertex ``i`` along its normal, so the
    noise energy along :math:`e_d` is :math:`\\rho^2 \\sum_i (n_i \\cdot e_d)^2`, small
    on :math:`e_1` and large on :math:`e_3` (a flat region has all of its noise on one
    axis), while the shape's own energy is spread differently: the best strength
    differs per axis. ``meshdenoise.auto.choose_parameters`` picks the three weights by
    SURE, one axis at a time (the risk is a sum over axes). ``p = 3`` (a transfer
    function :math:`1/(1 + \\mu k^3)` on the Laplacian eigenvalue ``k``) is flatter on
    the shape and steeper on the noise than the bi-Laplacian's; ``p = 1, 2`` are the
    ``sobolev`` / ``sobolev_bilaplacian`` penalties. The result is translation and
    rotation equivariant (the frame rotates with the mesh; :math:`L 1 = 0`); for a
    fixed frame it is linear. Each :math:`I + \\mu_d L^p` is factorised once per
    (topology, p, mu, pinned mask) with cholespy and cached; pinned vertices are
    solved as in ``sobolev_bilaplacian``.

    Parameters
    ----------
    mesh : (V, F) tuple, pymeshlab.MeshSet or Mesh, or open3d.geometry.TriangleMesh
    mu1, mu2, mu3 : float, >= 0
        Weights on the axes :math:`e_1, e_2, e_3` (0 leaves that coordinate as is).
    order : int, 1 <= order <= 4
        Power ``p`` of the Laplacian.
    frame_steps : int, >= 0
        Averaging steps applied before taking the normals that define the axes.
    pinned, region, preserve_volume, operators
        Options shared by every filter; see the README.

    Returns
    -------
    Same type as ``mesh``

    References
    ----------
    M. Desbrun, M. Meyer, P. Schröder, A. Barr, "Implicit fairing of irregular meshes
    using diffusion and curvature flow", SIGGRAPH 1999 (higher-order implicit fairing).
    C. Stein, "Estimation of the mean of a multivariate normal distribution", 1981.
    A. Vaillant-Tenzer, "Mesh Denoising", 2022 (Sobolev regularisation, noise model).

    Examples
    --------
    >>> import numpy as np
    >>> from meshdenoise.shapes import grid
    >>> V, F = grid(6, 6)
    >>> Vn = V + [0, 0, 0.01] * np.random.default_rng(0).standard_normal((len(V), 1))
    >>> V1, _ = sobolev_axes((Vn, F), mu1=0.0, mu2=0.0, mu3=5.0)
    >>> bool(V1[:, 2].std() < 0.5 * Vn[:, 2].std()), bool(np.allclose(V1[:, :2], Vn[:, :2], atol=1e-3))
    (True, True)
    """
    X = np.array(V, dtype=np.float64)
    if F.shape[0] == 0:
        return X
    E, _ = normal_frame(X, F, ops, frame_steps)
    C = X @ E
    out = np.empty_like(C)
    for d, mu in enumerate((mu1, mu2, mu3)):
        out[:, d] = C[:, d] if mu == 0 else _solver(ops, order, mu, fixed).solve(C[:, d])
    return out @ E.T

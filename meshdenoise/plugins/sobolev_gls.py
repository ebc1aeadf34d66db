"""Polyharmonic Sobolev smoothing with a data term weighted along the estimated normals."""

from __future__ import annotations

import warnings

import numpy as np

from ..geometry import coherent_normals  # re-exported: the filter's normals
from ..operators import Operators
from ..registry import Param, register
from .sobolev_axes import _solver, laplacian_power

__all__ = ["sobolev_gls", "normal_weighted_solve", "coherent_normals"]

CG_TOL = 1e-9  # relative residual of the preconditioned conjugate gradient
CG_MAXITER = 300


def _apply_weight(N: np.ndarray, beta: float, Y: np.ndarray) -> np.ndarray:
    """:math:`W Y`, :math:`W_i = \\beta I - (\\beta - 1) N_i N_i^T`, for ``Y`` (n, 3) or (n, 3, k)."""
    if Y.ndim == 2:
        return beta * Y - (beta - 1.0) * N * np.sum(N * Y, axis=1, keepdims=True)
    return beta * Y - (beta - 1.0) * N[:, :, None] * np.sum(N[:, :, None] * Y, axis=1, keepdims=True)


def normal_weighted_solve(
    ops: Operators, N: np.ndarray, beta: float, mu: float, order: int, B: np.ndarray,
    fixed: np.ndarray | None = None, x0: np.ndarray | None = None,
) -> np.ndarray:
    """Solve :math:`(W + \\mu\\, L^p \\otimes I_3)\\, Y = B` by conjugate gradients, for one or several right-hand sides.

    :math:`W` is block diagonal, :math:`W_i = \\beta I - (\\beta - 1) N_i N_i^T`
    (``N`` (n, 3) unit rows, ``beta >= 1``); ``B`` is (n, 3) or (n, 3, k) (k independent
    systems, each an (n, 3) array). The preconditioner is :math:`(I + \\mu L^p)^{-1}` on each
    coordinate (the cached Cholesky factor of ``sobolev_axes``): :math:`I \\preceq W \\preceq \\beta I`,
    so the preconditioned matrix has its spectrum in :math:`[1, \\beta]` and CG converges in
    :math:`O(\\sqrt\\beta)` iterations whatever the mesh. With ``fixed`` vertices their rows
    of ``x0`` are kept and the free rows solve the reduced system.
    """
    many = B.ndim == 3
    Bk = B if many else B[:, :, None]
    n, _, k = Bk.shape
    S = _solver(ops, order, mu, fixed)
    M = laplacian_power(ops, order)

    def A(Y):  # (n, 3, k)
        return _apply_weight(N, beta, Y) + mu * (M @ Y.reshape(n, 3 * k)).reshape(n, 3, k)

    def prec(R):
        return S.solve(R.reshape(n, 3 * k)).reshape(n, 3, k)

    Y = np.zeros_like(Bk) if x0 is None else np.array(x0 if many else x0[:, :, None], dtype=np.float64)
    free = None if fixed is None or not fixed.any() else ~fixed
    R = Bk - A(Y)
    if free is not None:
        R[~free] = 0.0
    Z = prec(R)
    if free is not None:
        Z[~free] = 0.0
    P = Z.copy()
    rz = np.einsum("ijk,ijk->k", R, Z)
    norm0 = np.sqrt(np.einsum("ijk,ijk->k", Bk, Bk)) + 1e-300
    for _ in range(CG_MAXITER):
        if np.all(np.sqrt(np.einsum("ijk,ijk->k", R, R)) <= CG_TOL * norm0):
            break
        AP = A(P)
        if free is not None:
            AP[~free] = 0.0
        pap = np.einsum("ijk,ijk->k", P, AP)
        alpha = np.where(pap > 0, rz / np.where(pap > 0, pap, 1.0), 0.0)
        Y += alpha * P
        R -= alpha * AP
        Z = prec(R)
        if free is not None:
            Z[~free] = 0.0
        rz_new = np.einsum("ijk,ijk->k", R, Z)
        P = Z + np.where(rz > 0, rz_new / np.where(rz > 0, rz, 1.0), 0.0) * P
        rz = rz_new
    else:
        warnings.warn(
            f"sobolev_gls: conjugate gradients did not reach a relative residual of {CG_TOL:g} in {CG_MAXITER} "
            f"iterations (beta = {beta:g}); a smaller beta converges faster",
            UserWarning,
            stacklevel=3,
        )
    return Y if many else Y[:, :, 0]


@register(
    "sobolev_gls",
    summary="Polyharmonic Sobolev with the data term weighted beta times more across the estimated normals",
    params=[
        Param("mu", float, 1000.0, low=0.0, help="weight of the penalty ||L^{p/2} Y||^2 (0 returns the input)"),
        Param("beta", float, 3.0, low=1.0, help="weight of the tangential data term relative to the normal one (1: sobolev)"),
        Param("order", int, 3, low=1, high=4, help="power p of the Laplacian in the penalty"),
    ],
    linear=False,
)
def sobolev_gls(V, F, *, ops, fixed, mu, beta, order):
    """Polyharmonic Sobolev smoothing whose data term trusts the tangential directions more.

    The paper's noise moves each vertex along its normal only, so a denoiser should
    change positions across the surface much more than along it. With :math:`\\hat N_i`
    the vertex normals (:func:`coherent_normals`) of the isotropic estimate :math:`\\hat X = (I + \\mu L^p)^{-1} X`
    (the same penalty, :math:`\\beta = 1`), the result minimises

    .. math:: \\sum_i (Y_i - X_i)^T W_i\\, (Y_i - X_i) + \\mu \\sum_{d=1}^3 y_d^T L^p y_d,
              \\qquad W_i = \\hat N_i \\hat N_i^T + \\beta\\, (I - \\hat N_i \\hat N_i^T),

    i.e. :math:`(W + \\mu L^p \\otimes I_3)\\, Y = W X`: a weighted (generalised) least
    squares fit whose weight is the inverse of a noise covariance
    :math:`\\propto \\hat N_i \\hat N_i^T + \\beta^{-1}(I - \\hat N_i \\hat N_i^T)`, flattened along the
    normal (Aitken's generalised least squares; a Tikhonov / Sobolev prior as in the paper).
    :math:`\\beta = 1` is the isotropic polyharmonic Sobolev filter; large :math:`\\beta`
    keeps the tangential coordinates (the uniform Laplacian's tangential drift, which
    costs SNR, is held back). ``beta`` is finite because the estimated normals of a
    heavily smoothed surface are off the true noise directions by several degrees.
    The system couples the three coordinates; it is solved by conjugate gradients
    preconditioned with the cached Cholesky factor of :math:`I + \\mu L^p`
    (:func:`normal_weighted_solve`, spectrum in :math:`[1, \\beta]`), for the correction
    :math:`Y - \\hat X`. For fixed normals
    the map is linear; the filter is translation and rotation equivariant.
    ``meshdenoise.auto.choose_parameters`` picks ``mu`` and ``beta`` by SURE.

    Parameters
    ----------
    mesh : (V, F) tuple, pymeshlab.MeshSet or Mesh, or open3d.geometry.TriangleMesh
    mu : float, >= 0
        Weight of the polyharmonic penalty (0 returns the input).
    beta : float, >= 1
        Tangential weight of the data term.
    order : int, 1 <= order <= 4
        Power ``p`` of the Laplacian.
    pinned, region, preserve_volume, operators
        Options shared by every filter; see the README.

    Returns
    -------
    Same type as ``mesh``

    References
    ----------
    A. C. Aitken, "On least squares and linear combination of observations", Proc. R. Soc. Edinb. 55, 1935.
    M. Desbrun, M. Meyer, P. Schröder, A. Barr, "Implicit fairing of irregular meshes
    using diffusion and curvature flow", SIGGRAPH 1999.
    A. Vaillant-Tenzer, "Mesh Denoising", 2022 (Sobolev regularisation, noise model).

    Examples
    --------
    >>> import numpy as np
    >>> from meshdenoise.shapes import grid
    >>> V, F = grid(6, 6)
    >>> Vn = V + [0, 0, 0.01] * np.random.default_rng(0).standard_normal((len(V), 1))
    >>> V1, _ = sobolev_gls((Vn, F), mu=5.0, beta=10.0)
    >>> Vi, _ = sobolev_gls((Vn, F), mu=5.0, beta=1.0)  # isotropic: drifts along the plane
    >>> drift = lambda Y: np.abs(Y[:, :2] - Vn[:, :2]).max()
    >>> bool(V1[:, 2].std() < 0.5 * Vn[:, 2].std()), bool(drift(V1) < 0.5 * drift(Vi))
    (True, True)
    """
    X = np.array(V, dtype=np.float64)
    if F.shape[0] == 0 or mu == 0:
        return X
    X0 = _solver(ops, order, mu, fixed).solve(X)
    if beta == 1.0:
        return X0
    N = coherent_normals(X0, F)
    return X0 + normal_weighted_solve(ops, N, beta, mu, order, _correction_rhs(N, beta, X, X0), fixed)


def _correction_rhs(N: np.ndarray, beta: float, X: np.ndarray, X0: np.ndarray) -> np.ndarray:
    """Right-hand side of the system for :math:`D = Y - X_0`: :math:`(\\beta - 1)(I - N N^T)(X - X_0)`.

    From :math:`(I + \\mu K) X_0 = X`: :math:`(W + \\mu K) D = W X - (W + \\mu K) X_0 = (W - I)(X - X_0)`.
    It does not see a translation of the mesh (unlike :math:`W X`), so the iterative
    solve's tolerance is relative to the correction, not to the coordinates' magnitude.
    """
    R = X - X0
    return (beta - 1.0) * (R - N * np.sum(N * R, axis=1, keepdims=True))

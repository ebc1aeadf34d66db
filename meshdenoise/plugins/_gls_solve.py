"""``sobolev_gls``' settings and its solves of the normal-weighted system, which its filter and its rule share.

:class:`GlsConfig` holds the sizes and bounds that choose the filter's and its rule's solve paths
(``plugins/sobolev_gls.py`` and ``plugins/sobolev_gls_rule.py`` read them; ``get_filter("sobolev_gls").core(...,
config=)`` and ``choose_parameters(..., config=)`` take another); :func:`normal_weighted_cg` solves
:math:`(W + \\mu L^p \\otimes I_3)\\, Y = B` without a factor, :func:`normal_weighted_solve` by CG preconditioned by
the isotropic system (or densely on a small mesh).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.linalg as sla

from ..operators import Operators, spmm
from ..solvers import laplacian_power, shifted_solver
from ..tuning.config import check_fields, resolve

__all__ = ["GlsConfig", "DEFAULT", "CG_TOL", "CG_MAXITER", "normal_weighted_cg", "normal_weighted_solve", "apply_weight",
           "correction_rhs"]

CG_TOL = 1e-9  # relative residual of the preconditioned conjugate gradient (the rule's whole-mesh solves)


@dataclass(frozen=True)
class GlsConfig:
    """``sobolev_gls``' solve paths: the values, and where they were measured.

    Attributes
    ----------
    filter_tol : float
        The filter's CG relative residual, every path: A >= I, so the correction's error is at most tol ||b|| <=
        tol (beta - 1) ||X - X0||, 1.1e-3 of the isotropic pass's change at beta = 12. Measured against 1e-10: the
        result within 1.8e-5 of the change (bunny scanner, Block0.4, the elephant), the same SNR to 1e-4 dB; at 400k
        (mu 3.6, beta 12) 2.5e-5 rho RMS from the converged result, about 205 block-Jacobi iterations (500 for 1e-9).
    dense_max_vertices : int
        Up to this many vertices the 3n x 3n system is factorised densely: the exact traces' 3n right-hand sides made
        ~10 CG iterations of 3n columns each (a 162-vertex sphere's choice: 11 s -> under 1 s).
    iterative_min_vertices : int
        Without held rows the filter factorises nothing from this size: at 400k (mu 4.7, CG's bound 820) CG
        preconditioned by the one-ring factor took 13.2 s and 1,181 MB at its peak, block-Jacobi CG 7.9 s and 635 MB
        (benchmarks/scale.py) ...
    factor_free_min_vertices : int
        ... and below it from this size, held rows or not, while ...
    factor_free_cg_bound : float
        ... CG's bound for I + mu L^p at ``filter_tol`` is at most this (past it, CG preconditioned by a one-ring
        factor, ShiftedPCG): measured, factor-free (Lanczos or Jacobi CG, then block-Jacobi CG) against a factor and
        CG preconditioned by it, beta 12, cold: Bunny0.2 0.21 against 0.86 s at mu 0.1, the two equal near a bound of
        1,000 (mu 4), the elephant near 760 (mu 3 to 10), face000 near 710 (mu 10 to 12); against ShiftedPCG, free
        rows: face000 at mu 34 (bound 1,200) 3.1 against 2.1 s.
    jacobi_max_iterations : int
        Block-Jacobi CG's cap before the Lanczos-preconditioned solve takes over.
    family_min_betas : int
        The rule's sweep over at least this many betas at one mu solves them by one CG run (shifted_family_cg:
        Block0.4's sweep 71 -> 21 preconditioner solves, its choice 3.0-3.4 -> 2.4 s; bunny scanner 6.5 -> 5.4 s,
        the same betas).

    Examples
    --------
    >>> GlsConfig(dense_max_vertices=0).filter_tol
    0.0001
    """

    filter_tol: float = 1e-4
    dense_max_vertices: int = 400
    iterative_min_vertices: int = 200_000
    factor_free_min_vertices: int = 20_000
    factor_free_cg_bound: float = 700
    jacobi_max_iterations: int = 3000
    family_min_betas: int = 2

    def __post_init__(self) -> None:
        check_fields(self, positive=("filter_tol",),
                     nonnegative=("dense_max_vertices", "iterative_min_vertices", "factor_free_min_vertices",
                                  "factor_free_cg_bound", "jacobi_max_iterations", "family_min_betas"))


DEFAULT = GlsConfig()


def _laplacian_power_diagonal(ops: Operators, order: int) -> np.ndarray:
    """:math:`\\mathrm{diag}(L^p)` (n,), as :math:`\\sum_j (L^a)_{ij} (L^b)_{ij}`, :math:`a = \\lceil p/2 \\rceil`,
    :math:`b = \\lfloor p/2 \\rfloor` (``L`` symmetric), without forming :math:`L^p` beyond :math:`L^a`."""
    a, b = (order + 1) // 2, order // 2
    La = laplacian_power(ops, a)
    if b == 0:
        return np.asarray(La.diagonal(), dtype=np.float64)
    Lb = laplacian_power(ops, b)
    return np.asarray(La.multiply(Lb).sum(axis=1), dtype=np.float64).ravel()


def normal_weighted_cg(
    ops: Operators, N: np.ndarray, beta: float, mu: float, order: int, B: np.ndarray,
    tol: float = CG_TOL, maxiter: int = DEFAULT.jacobi_max_iterations, x0: np.ndarray | None = None,
    pinned: np.ndarray | None = None,
) -> tuple[np.ndarray, bool]:
    """:math:`(W + \\mu L^p \\otimes I_3)\\, Y = B` (``B`` (n, 3)) by block-Jacobi CG, nothing factorised.

    The operator is applied matrix-free (``p`` products with ``L`` on the three columns, not
    :math:`L^p`); the preconditioner is the inverse of its 3 x 3 diagonal blocks
    :math:`M_i = W_i + c_i I`, :math:`c_i = \\mu (L^p)_{ii}`, in closed form:

    .. math:: M_i^{-1} = \\frac{1}{\\beta + c_i}\\Big(I + \\frac{\\beta - 1}{1 + c_i} N_i N_i^T\\Big)

    (:math:`W_i = \\beta I - (\\beta - 1) N_i N_i^T`). Its iterations grow like
    :math:`\\sqrt{\\mu}\\,\\lambda_{max}^{p/2}` (no longer bounded by :math:`\\sqrt\\beta` as
    :func:`normal_weighted_solve`'s), but each costs ``p`` products on three columns where the
    factor-preconditioned iteration costs a solve with the factor of :math:`I + \\mu L^p` (at 100k
    vertices and ``p = 3``: a 20 s factorisation). ``x0`` (n, 3): a starting guess. ``pinned`` (bool (n,),
    optional): rows held at ``x0``'s values (zero without it), the free rows solving the reduced system (as
    :func:`normal_weighted_solve`). Returns ``(Y, converged)`` (relative residual ``tol`` of the free rows, relative
    to ``B``'s, within ``maxiter`` iterations). The vector work of an iteration is done in place (no (n, 3)
    temporaries beyond the products').
    """
    n = N.shape[0]
    L = ops.L
    N = np.ascontiguousarray(N, dtype=np.float64)
    c = mu * _laplacian_power_diagonal(ops, order)
    inv_a = (1.0 / (beta + c))[:, None]
    g = (beta - 1.0) / (1.0 + c)
    bm1 = beta - 1.0

    def A(Y):  # (W + mu L^p) Y = mu L^p Y + beta Y - (beta - 1) N (N . Y)
        Z = Y
        for _ in range(order):
            Z = spmm(L, Z)
        Z *= mu
        Z += beta * Y
        Z -= (bm1 * np.einsum("ij,ij->i", N, Y))[:, None] * N
        return Z

    held = None if pinned is None or not np.any(pinned) else np.asarray(pinned, dtype=bool)
    if held is not None:  # the reduced system: no scaling on the held rows keeps every search direction zero there
        inv_a = np.where(held[:, None], 0.0, inv_a)

    def prec(R):
        Z = (g * np.einsum("ij,ij->i", N, R))[:, None] * N
        Z += R
        Z *= inv_a
        return Z

    def dot(a, b):  # einsum, not BLAS: OpenBLAS's threaded dot was 13x slower on a loaded machine
        return float(np.einsum("ij,ij->", a, b))

    B = np.ascontiguousarray(B, dtype=np.float64)
    if held is not None:
        B = np.where(held[:, None], 0.0, B)
    norm0 = math.sqrt(dot(B, B)) + 1e-300
    if x0 is None:
        Y = np.zeros((n, 3))
        R = B.copy()
    else:
        Y = np.array(x0, dtype=np.float64)
        R = B - A(Y)
        if held is not None:
            R[held] = 0.0
    Z = prec(R)
    P = Z.copy()
    rz = dot(R, Z)
    for _ in range(int(maxiter)):
        if math.sqrt(dot(R, R)) <= tol * norm0:
            return Y, True
        AP = A(P)
        if held is not None:
            AP[held] = 0.0
        pap = dot(P, AP)
        if pap <= 0:
            break
        alpha = rz / pap
        Y += alpha * P
        AP *= alpha
        R -= AP
        Z = prec(R)
        rz_new = dot(R, Z)
        if rz > 0:
            P *= rz_new / rz
            P += Z
        else:
            P = Z
        rz = rz_new
    return Y, bool(math.sqrt(dot(R, R)) <= tol * norm0)


CG_MAXITER = 300  # normal_weighted_solve's cap on CG steps before it warns


def apply_weight(N: np.ndarray, beta: float, Y: np.ndarray) -> np.ndarray:
    """:math:`W Y`, :math:`W_i = \\beta I - (\\beta - 1) N_i N_i^T`, for ``Y`` (n, 3) or (n, 3, k)."""
    if Y.ndim == 2:
        return beta * Y - (beta - 1.0) * N * np.sum(N * Y, axis=1, keepdims=True)
    return beta * Y - (beta - 1.0) * N[:, :, None] * np.sum(N[:, :, None] * Y, axis=1, keepdims=True)


def normal_weighted_solve(
    ops: Operators, N: np.ndarray, beta: float, mu: float, order: int, B: np.ndarray,
    pinned: np.ndarray | None = None, x0: np.ndarray | None = None, prec: Any = None, tol: float = CG_TOL,
    config: GlsConfig | None = None,
) -> np.ndarray:
    """Solve :math:`(W + \\mu\\, L^p \\otimes I_3)\\, Y = B` by conjugate gradients, for one or several right-hand sides.

    :math:`W` is block diagonal, :math:`W_i = \\beta I - (\\beta - 1) N_i N_i^T`
    (``N`` (n, 3) unit rows, ``beta >= 1``); ``B`` is (n, 3) or (n, 3, k) (k independent
    systems, each an (n, 3) array). The preconditioner is :math:`(I + \\mu L^p)^{-1}` on each
    coordinate (the cached Cholesky factor of ``sobolev_axes``): :math:`I \\preceq W \\preceq \\beta I`,
    so the preconditioned matrix has its spectrum in :math:`[1, \\beta]` and CG converges in
    :math:`O(\\sqrt\\beta)` iterations whatever the mesh. With ``pinned`` vertices their rows
    of ``x0`` are kept and the free rows solve the reduced system. ``prec`` (optional) applies
    :math:`(I + \\mu L^p)^{-1}`, or an SPD approximation of it (zero on pinned rows), to an (n, c) array instead of the
    factor. ``tol``: the
    relative residual every system reaches. Up to ``config.dense_max_vertices`` vertices (:class:`GlsConfig`,
    ``None``: its default) the system is solved directly instead (:func:`_dense_normal_weighted_solve`; ``tol`` and
    ``prec`` unused).
    """
    many = B.ndim == 3
    Bk = B if many else B[:, :, None]
    n, _, k = Bk.shape
    if n <= resolve(config, DEFAULT).dense_max_vertices:
        start = x0 if x0 is None or many else x0[:, :, None]
        Y = _dense_normal_weighted_solve(ops, N, beta, mu, order, Bk, pinned, start)
        return Y if many else Y[:, :, 0]
    M = laplacian_power(ops, order)
    if prec is None:
        S = shifted_solver(ops, mu, order, pinned)
        # held rows with the product form (HeldByProduct): its free factors are the preconditioner (R is zero on the
        # held rows and Z is zeroed there, so it is (A^-1)_ff: two more iterations on Bunny0.2, no inner CG)
        S = getattr(S, "product", S)

        def prec(R):
            return S.solve(R.reshape(n, 3 * k)).reshape(n, 3, k)
    else:
        apply_inverse = prec

        def prec(R):
            return apply_inverse(R.reshape(n, 3 * k)).reshape(n, 3, k)

    def A(Y):  # (n, 3, k)
        return apply_weight(N, beta, Y) + mu * (M @ Y.reshape(n, 3 * k)).reshape(n, 3, k)

    Y = np.zeros_like(Bk) if x0 is None else np.array(x0 if many else x0[:, :, None], dtype=np.float64)
    free = None if pinned is None or not pinned.any() else ~pinned
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
        if np.all(np.sqrt(np.einsum("ijk,ijk->k", R, R)) <= tol * norm0):
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
            f"sobolev_gls: conjugate gradients did not reach a relative residual of {tol:g} in {CG_MAXITER} "
            f"iterations (beta = {beta:g}); a smaller beta converges faster",
            UserWarning,
            stacklevel=3,
        )
    return Y if many else Y[:, :, 0]


def _dense_normal_weighted_solve(
    ops: Operators, N: np.ndarray, beta: float, mu: float, order: int, Bk: np.ndarray,
    pinned: np.ndarray | None, x0: np.ndarray | None,
) -> np.ndarray:
    """:func:`normal_weighted_solve` on a small mesh: :math:`A = W + \\mu L^p \\otimes I_3` (index ``3i + d``)
    formed densely and factorised by Cholesky, exact where CG stops at its tolerance. ``Bk`` (n, 3, k); pinned
    rows keep ``x0``'s values (zero without it) and the free rows solve the reduced system, as CG does."""
    n, _, k = Bk.shape
    A = mu * np.kron(laplacian_power(ops, order).toarray(), np.eye(3))
    blocks = A.reshape(n, 3, n, 3)
    i = np.arange(n)
    blocks[i, :, i, :] += beta * np.eye(3) - (beta - 1.0) * N[:, :, None] * N[:, None, :]
    B2 = np.ascontiguousarray(Bk, dtype=np.float64).reshape(3 * n, k)
    if pinned is None or not np.any(pinned):
        return sla.cho_solve(sla.cho_factor(A, check_finite=False), B2, check_finite=False).reshape(n, 3, k)
    Y = np.zeros((3 * n, k)) if x0 is None else np.array(x0, dtype=np.float64).reshape(3 * n, k)
    free = np.repeat(~np.asarray(pinned, dtype=bool), 3)
    rhs = B2[free] - A[np.ix_(free, ~free)] @ Y[~free]
    Y[free] = sla.cho_solve(sla.cho_factor(A[np.ix_(free, free)], check_finite=False), rhs, check_finite=False)
    return Y.reshape(n, 3, k)


def correction_rhs(N: np.ndarray, beta: float, X: np.ndarray, X0: np.ndarray) -> np.ndarray:
    """Right-hand side of the system for :math:`D = Y - X_0`: :math:`(\\beta - 1)(I - N N^T)(X - X_0)`.

    From :math:`(I + \\mu K) X_0 = X`: :math:`(W + \\mu K) D = W X - (W + \\mu K) X_0 = (W - I)(X - X_0)`.
    It does not see a translation of the mesh (unlike :math:`W X`), so the iterative
    solve's tolerance is relative to the correction, not to the coordinates' magnitude. ``X``, ``X0``: (n, 3), or
    (n, 3, k) for k systems.
    """
    R = X - X0
    Nb = N if R.ndim == 2 else N[:, :, None]
    return (beta - 1.0) * (R - Nb * np.sum(Nb * R, axis=1, keepdims=True))

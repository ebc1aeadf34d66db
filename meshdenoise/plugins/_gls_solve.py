"""``sobolev_gls``' settings and its factor-free solve: block-Jacobi CG on the normal-weighted system.

:class:`GlsConfig` holds the sizes and bounds that choose the filter's and its rule's solve paths
(``plugins/sobolev_gls.py`` reads them; ``get_filter("sobolev_gls").core(..., config=)`` and
``choose_parameters(..., config=)`` take another); :func:`normal_weighted_cg` solves
:math:`(W + \\mu L^p \\otimes I_3)\\, Y = B` without a factor.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..operators import Operators, spmm
from ..solvers import laplacian_power
from ..tuning.config import check_fields

__all__ = ["GlsConfig", "DEFAULT", "CG_TOL", "normal_weighted_cg"]

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

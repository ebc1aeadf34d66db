"""One preconditioned conjugate-gradient run for a family of systems :math:`(K + s_j P)\\, X_j = B`.

A parameter sweep that solves the same right-hand sides for several weights of one term (``sobolev_gls``'s
tangential weights ``beta``: :math:`W + \\mu L^p = (I + \\mu L^p) + (\\beta - 1) P_T`) pays one CG run per weight.
Preconditioned by :math:`K^{-1}`, every system is :math:`I + s_j M` with :math:`M = K^{-1} P`, self-adjoint in the
:math:`K` inner product: their Krylov spaces are one, and the residuals stay collinear. So the hardest system's CG
(the largest :math:`s`) carries all the others for a few vector updates each (Jegerlehner's CG-M, 1996; Frommer,
"BiCGStab(l) for families of shifted linear systems", 2003), one application of :math:`K^{-1}` per step in all.

References
----------
B. Jegerlehner, "Krylov space solvers for shifted linear systems", arXiv:hep-lat/9612014 (1996).
"""

from __future__ import annotations

import warnings
from typing import Callable, Sequence

import numpy as np

__all__ = ["shifted_family_cg"]


def _dots(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Column dot products (the last axis holds the columns): shape ``(A.shape[-1],)``."""
    return np.einsum("ij,ij->j", A.reshape(-1, A.shape[-1]), B.reshape(-1, B.shape[-1]))


def shifted_family_cg(solve_K: Callable[[np.ndarray], np.ndarray], apply_P: Callable[[np.ndarray], np.ndarray],
                      B: np.ndarray, shifts: Sequence[float], *, tol: float = 1e-9,
                      maxiter: int = 300) -> list[np.ndarray]:
    r"""Solve :math:`(K + s_j P)\, X_j = B` for every shift :math:`s_j > 0` by one CG run preconditioned by :math:`K^{-1}`.

    With :math:`M = K^{-1} P` and :math:`c = K^{-1} B`, :math:`X_j = s_j^{-1} (M + \sigma_j I)^{-1} c`,
    :math:`\sigma_j = 1 / s_j`: CG on the seed :math:`M + \sigma_0 I` (the smallest :math:`\sigma`, the slowest to
    converge) in the :math:`K` inner product, and for the others the CG-M recurrences (Jegerlehner 1996)

    .. math:: \zeta^j_{k+1} = \frac{\zeta^j_k \zeta^j_{k-1} \alpha_{k-1}}
              {\alpha_k \beta_{k-1} (\zeta^j_{k-1} - \zeta^j_k) + \zeta^j_{k-1} \alpha_{k-1} (1 + (\sigma_j - \sigma_0) \alpha_k)},
              \qquad \alpha^j_k = \alpha_k \frac{\zeta^j_{k+1}}{\zeta^j_k}, \qquad
              \beta^j_k = \beta_k \Big(\frac{\zeta^j_{k+1}}{\zeta^j_k}\Big)^2,

    system ``j``'s residual being :math:`\zeta^j` times the seed's. ``K`` is applied only through ``solve_K``, once
    per step (the seed's :math:`K p` is kept by its own recurrence, :math:`K p_{k+1} = R_{k+1} + \beta_k K p_k`).

    Parameters
    ----------
    solve_K : callable
        :math:`K^{-1} Y` for an array shaped like ``B`` or with fewer columns (the last axis: a column done for every
        shift leaves the run); ``K`` symmetric positive definite.
    apply_P : callable
        :math:`P Y` for such an array; ``P`` symmetric positive semi-definite.
    B : ndarray, shape (..., c)
        ``c`` independent right-hand sides along the last axis (each system is over the other axes).
    shifts : sequence of float, each > 0
    tol : float
        Every system's relative residual :math:`\|B - (K + s_j P) X_j\| / \|B\|`, per column.
    maxiter : int

    Returns
    -------
    list of ndarray, each shaped like ``B``: :math:`X_j` in the order of ``shifts``.

    Warns
    -----
    UserWarning
        When a system has not reached ``tol`` in ``maxiter`` steps (its last iterate is returned).

    Examples
    --------
    >>> import numpy as np
    >>> K, P = np.diag([1.0, 2.0, 3.0]), np.diag([1.0, 0.0, 0.5])
    >>> B = np.ones((3, 1))
    >>> X = shifted_family_cg(lambda Y: np.linalg.solve(K, Y), lambda Y: P @ Y, B, [1.0, 4.0])
    >>> [np.round(x.ravel(), 10).tolist() for x in X]
    [[0.5, 0.5, 0.2857142857], [0.2, 0.5, 0.2]]
    """
    shifts = [float(s) for s in shifts]
    if not shifts or not all(s > 0 and np.isfinite(s) for s in shifts):
        raise ValueError(f"shifted_family_cg: shifts must be finite numbers > 0, got {shifts!r}")
    if not (tol > 0 and int(maxiter) >= 1):
        raise ValueError(f"shifted_family_cg: tol must be > 0 and maxiter >= 1, got {tol!r}, {maxiter!r}")
    B = np.asarray(B, dtype=np.float64)
    sigma = np.array([1.0 / s for s in shifts])
    s0 = float(sigma.min())  # the seed: the strongest shift of P, the slowest system
    delta = sigma - s0  # (shifts,)
    ncol = B.shape[-1]
    norm_b = np.sqrt(_dots(B, B))
    limit = tol * np.where(norm_b > 0, norm_b, 1.0)
    R = B.copy()  # the seed's residual in B's space: R = K r
    r = solve_K(R)
    p, Kp = r.copy(), R.copy()
    X = [np.zeros_like(B) for _ in shifts]  # the solutions of (M + sigma_j) y = c, scaled by 1 / s_j at the end
    Pj = [r.copy() for _ in shifts]
    zeta, zeta_prev = np.ones((len(shifts), ncol)), np.ones((len(shifts), ncol))
    alpha_prev, beta_prev = np.ones(ncol), np.zeros(ncol)
    rr = _dots(r, R)
    done = np.zeros((len(shifts), ncol), dtype=bool)
    cols = np.arange(ncol)  # the columns still running: a column done for every shift leaves the solves (each
    # column's recurrences are its own; the elephant's sweep: its probes done 3 steps before the correction)
    converged = False
    for _ in range(int(maxiter)):
        res = np.sqrt(np.maximum(_dots(R, R), 0.0))
        # B - (K + s_j P) x_j = K (c - (M + sigma_j) y_j) = zeta_j R: each system's residual from the seed's
        done |= np.abs(zeta) * res[None, :] <= limit[cols][None, :]
        if done.all():
            converged = True
            break
        running = ~done.all(axis=0)
        if not running.all():
            cols = cols[running]
            R, r, p, Kp = R[..., running], r[..., running], p[..., running], Kp[..., running]
            Pj = [P[..., running] for P in Pj]
            zeta, zeta_prev, done = zeta[:, running], zeta_prev[:, running], done[:, running]
            alpha_prev, beta_prev, rr = alpha_prev[running], beta_prev[running], rr[running]
        whole = cols.size == ncol
        PP = apply_P(p)
        pw = _dots(p, PP) + s0 * _dots(p, Kp)  # <p, (M + s0) p>_K
        alpha = np.divide(rr, pw, out=np.zeros(cols.size), where=pw > 0)
        denom = alpha[None, :] * beta_prev[None, :] * (zeta_prev - zeta) \
            + zeta_prev * alpha_prev[None, :] * (1.0 + delta[:, None] * alpha[None, :])
        zeta_next = np.divide(zeta * zeta_prev * alpha_prev[None, :], denom, out=np.zeros_like(zeta), where=denom != 0)
        ratio = np.divide(zeta_next, zeta, out=np.zeros_like(zeta), where=zeta != 0)
        for j in range(len(shifts)):
            a_j = np.where(done[j], 0.0, alpha * ratio[j])  # a converged system keeps its iterate
            if whole:
                X[j] += a_j * Pj[j]
            else:
                X[j][..., cols] += a_j * Pj[j]
        w = solve_K(PP) + s0 * p  # (M + s0) p
        r -= alpha * w
        R -= alpha * (PP + s0 * Kp)
        rr_next = _dots(r, R)
        beta = np.divide(rr_next, rr, out=np.zeros(cols.size), where=rr > 0)
        for j in range(len(shifts)):
            Pj[j] = zeta_next[j] * r + beta * ratio[j] ** 2 * Pj[j]
        p = r + beta * p
        Kp = R + beta * Kp
        zeta_prev, zeta = zeta, zeta_next
        alpha_prev, beta_prev, rr = alpha, beta, rr_next
    if not converged:
        res = np.sqrt(np.maximum(_dots(R, R), 0.0))
        done |= np.abs(zeta) * res[None, :] <= limit[cols][None, :]
        if not done.all():
            warnings.warn(
                f"shifted_family_cg: {int((~done).sum())} of {len(shifts) * ncol} systems did not reach a relative "
                f"residual of {tol:g} in {maxiter} iterations; a larger maxiter or a closer preconditioner converges",
                UserWarning, stacklevel=2)
    return [x * sj for x, sj in zip(X, sigma)]  # x_j = y_j / s_j

"""SNR of many explicit-Euler heat runs at once, through one Chebyshev basis of the random-walk Laplacian.

``k`` heat steps of length ``tau`` map ``X`` to ``(I - tau Delta)^k X`` with ``Delta = I - D^-1 W``,
whose eigenvalues are real, in ``[0, lambda_max]``. A small step needs ``T / tau`` sparse products
(12,600 for ``T = 40`` at the paper's smallest ``tau``), but the polynomial ``(1 - tau lambda)^k``
is close to ``exp(-T lambda)`` and is matched to 1e-12 by a Chebyshev series of low degree ``m``.
So ``m`` products build the basis ``B_j = T_j(2 Delta / b - I) X`` once, and every ``(tau, k)``
then costs an ``m x m`` quadratic form: with ``c`` the series coefficients,

.. math:: \\|Y - V\\|_F^2 = c^T G c - 2 c^T g + \\|V\\|_F^2, \\qquad G_{ij} = \\langle B_i, B_j \\rangle,
          \\quad g_j = \\langle B_j, V \\rangle.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.fft import dct

from .batch import NoisyBatch, snr_from_squared_error

__all__ = ["chebyshev_coefficients", "heat_snr_chebyshev"]


def chebyshev_coefficients(taus: np.ndarray, ks: np.ndarray, b: float, degree: int) -> np.ndarray:
    """Coefficients (len(taus), degree + 1) of ``(1 - tau lambda)^k`` on ``[0, b]`` in Chebyshev polynomials.

    Interpolation at the ``degree + 1`` Chebyshev points of the first kind (a DCT-II),
    exact when ``k <= degree``.

    Examples
    --------
    On ``[0, 2]``, :math:`(1 - \\lambda / 2)^2 = ((1 - x) / 2)^2 = \\tfrac38 T_0 - \\tfrac12 T_1 + \\tfrac18 T_2`
    with :math:`x = \\lambda - 1`:

    >>> np.round(chebyshev_coefficients(np.array([0.5]), np.array([2]), b=2.0, degree=3), 12) + 0.0
    array([[ 0.375, -0.5  ,  0.125,  0.   ]])
    """
    N = degree + 1
    x = np.cos(np.pi * (np.arange(N) + 0.5) / N)
    lam = 0.5 * b * (x + 1.0)
    values = (1.0 - np.outer(taus, lam)) ** np.asarray(ks, dtype=np.float64)[:, None]
    c = dct(values, type=2, axis=1) / N
    c[:, 0] /= 2.0
    return c


def _degree(taus: np.ndarray, ks: np.ndarray, b: float, tol: float, max_degree: int) -> tuple[int, np.ndarray]:
    """The smallest power-of-two degree whose dropped coefficients are all below ``tol``.

    The coefficients of these entire functions decay faster than geometrically past the
    degree where they start to fall, so the largest dropped one bounds the truncation
    error up to a small factor; a sum would instead add up the DCT's rounding (~1e-16 each).
    """
    m = 32
    while True:
        c = chebyshev_coefficients(taus, ks, b, 2 * m + 1)  # twice the degree, to see the tail
        tail = np.abs(c[:, m + 1 :]).max()
        if tail <= tol:
            return m, c[:, : m + 1]
        if m >= max_degree:
            raise RuntimeError(
                f"heat search: a Chebyshev series of degree {m} still misses (1 - tau lambda)^k by {tail:.2g} "
                f"(tolerance {tol:g}); use more direct steps (direct_steps=) for these step sizes"
            )
        m *= 2


def heat_snr_chebyshev(
    batch: NoisyBatch, taus: np.ndarray, ks: np.ndarray, tol: float = 1e-13, max_degree: int = 4096
) -> tuple[np.ndarray, int]:
    """SNR per seed of ``ks[i]`` heat steps of length ``taus[i]``, shape (len(taus), S), and the degree used.

    ``taus`` and ``ks`` are paired (one entry per run). Every step size must be stable
    (``tau lambda_max <= 2``), so that ``|1 - tau lambda| <= 1`` on the spectrum.

    Examples
    --------
    >>> from meshdenoise import heat, snr
    >>> from meshdenoise.reproduce.batch import make_batch
    >>> from meshdenoise.shapes import icosphere
    >>> b = make_batch("sphere", *icosphere(1), rho=0.05, seeds=(0,))
    >>> values, degree = heat_snr_chebyshev(b, np.array([0.01]), np.array([300]))
    >>> Y, _ = heat((b.noisy(0), b.F), tau=0.01, time=3.0)  # the same 300 steps, run one by one
    >>> bool(abs(values[0, 0] - snr(b.V, Y)) < 1e-8), degree < 300
    (True, True)
    """
    ops = batch.ops
    taus = np.asarray(taus, dtype=np.float64)
    ks = np.asarray(ks, dtype=np.int64)
    lam_max = ops.lambda_max()
    if np.any(taus * lam_max > 2.0 + 1e-9):
        raise ValueError(f"heat_snr_chebyshev: unstable tau {taus.max():g} for lambda_max = {lam_max:.6g}")
    b = lam_max * (1.0 + 1e-9) + 1e-12  # Lanczos gives lambda_max to ~1e-10: keep the spectrum inside [0, b]
    m, coef = _degree(taus, ks, b, tol, max_degree)
    # Basis B_j = T_j(A) X with A = 2 Delta / b - I = (2 / b - 1) I - (2 / b) P, by the three-term recurrence.
    A = sp.csr_matrix((2.0 / b - 1.0) * sp.identity(ops.n) - (2.0 / b) * ops.P)
    n, S = batch.V.shape[0], batch.n_seeds
    per_seed = np.empty((S, m + 1, 3 * n))  # contiguous rows for the Gram products
    prev, cur = None, batch.X
    for j in range(m + 1):
        if j == 1:
            prev, cur = cur, A @ cur
        elif j >= 2:
            prev, cur = cur, 2.0 * (A @ cur) - prev
        for s in range(S):
            per_seed[s, j] = cur[:, 3 * s : 3 * s + 3].ravel()
    clean = batch.V.ravel()
    out = np.empty((taus.size, S))
    for s in range(S):
        B = per_seed[s]
        G = B @ B.T
        g = B @ clean
        err2 = np.einsum("ij,ij->i", coef @ G, coef) - 2.0 * coef @ g + batch.clean_norm2
        out[:, s] = snr_from_squared_error(np.maximum(err2, 0.0), batch.clean_norm2)
    return out, m

"""Lanczos recurrences of the spectral filters, their second pass, and the shifted tridiagonal solves."""

from __future__ import annotations

import numpy as np
from numba import prange

from .sparse import CG_BLOCK, add_row_product
from .threads import njit


# --------------------------------------------------------------------------- guided filter
@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def lanczos_product(indptr, indices, data, Q, W, U, partial_a, partial_d):  # pragma: no cover - compiled
    """``W = M Q`` (rows summed as :func:`csr_matmat` sums them); per block of :data:`CG_BLOCK` rows ``partial_a[b, c]``,
    the sum of ``Q[i, c] W[i, c]``, and ``partial_d[f, b, c]``, of ``U[f, i, c] Q[i, c]`` (the duals' projections)."""
    n = Q.shape[0]
    k = Q.shape[1]
    duals = U.shape[0]
    for b in prange(partial_a.shape[0]):
        for c in range(k):
            partial_a[b, c] = 0.0
        for f in range(duals):
            for c in range(k):
                partial_d[f, b, c] = 0.0
        for i in range(b * CG_BLOCK, min(n, (b + 1) * CG_BLOCK)):
            for c in range(k):
                W[i, c] = 0.0
            add_row_product(indptr, indices, data, Q, W, i)
            for c in range(k):
                partial_a[b, c] += Q[i, c] * W[i, c]
            for f in range(duals):
                for c in range(k):
                    partial_d[f, b, c] += U[f, i, c] * Q[i, c]


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def lanczos_update(Q, Qp, W, alpha, beta_prev, partial_b):  # pragma: no cover - compiled
    """``W = W - Q alpha - Qp beta_prev`` (per column) and per block of :data:`CG_BLOCK` rows the sum of ``W^2``."""
    n = Q.shape[0]
    k = Q.shape[1]
    for b in prange(partial_b.shape[0]):
        for c in range(k):
            partial_b[b, c] = 0.0
        for i in range(b * CG_BLOCK, min(n, (b + 1) * CG_BLOCK)):
            for c in range(k):
                w = W[i, c] - Q[i, c] * alpha[c] - Qp[i, c] * beta_prev[c]
                W[i, c] = w
                partial_b[b, c] += w * w


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def lanczos_accumulate(Q, Y, out):  # pragma: no cover - compiled
    """``out[m] += Q Y[m]`` (per column) for every set ``m`` of coefficients: several functions' second pass at once."""
    n = Q.shape[0]
    k = Q.shape[1]
    sets = Y.shape[0]
    for i in prange(n):
        for m in range(sets):
            for c in range(k):
                out[m, i, c] += Q[i, c] * Y[m, c]


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def lanczos_next_row(indptr, indices, data, Q, Qp, alpha, beta_prev, inv, Qn, i, w):  # pragma: no cover - compiled
    """Row ``i`` of the next basis vectors, ``((M Q - Q alpha) - Qp beta_prev) inv``, into ``Qn`` (``Qp`` itself
    allowed: its row is read before written); ``w`` (k,) scratch."""
    k = Q.shape[1]
    for c in range(k):
        w[c] = 0.0
    for t in range(indptr[i], indptr[i + 1]):
        a = data[t]
        j = indices[t]
        for c in range(k):
            w[c] += a * Q[j, c]
    for c in range(k):
        Qn[i, c] = ((w[c] - Q[i, c] * alpha[c]) - Qp[i, c] * beta_prev[c]) * inv[c]


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def lanczos_regenerate(indptr, indices, data, Q, Qp, alpha, beta_prev, inv, Y, out):  # pragma: no cover - compiled
    """One step of a second pass, in one sweep of the rows: ``out[m] += Q Y[m]`` (per column, as
    :func:`lanczos_accumulate`), then the next basis vectors into ``Qp``, in place: ``((M Q - Q alpha) - Qp beta_prev)
    inv`` with the first pass's ``alpha`` and ``inv = 1 / beta`` (the arithmetic of :func:`lanczos_product`,
    :func:`lanczos_update` and :func:`lanczos_scale`, so the same basis to the bit, with no sums and a third of the
    memory traffic). Row ``i`` reads ``Qp[i]`` before writing it and ``Q`` only: safe on any number of threads."""
    n = Q.shape[0]
    k = Q.shape[1]
    sets = Y.shape[0]
    for b in prange((n + CG_BLOCK - 1) // CG_BLOCK):
        w = np.empty(k)
        for i in range(b * CG_BLOCK, min(n, (b + 1) * CG_BLOCK)):
            for m in range(sets):
                for c in range(k):
                    out[m, i, c] += Q[i, c] * Y[m, c]
            lanczos_next_row(indptr, indices, data, Q, Qp, alpha, beta_prev, inv, Qp, i, w)


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def lanczos_next(indptr, indices, data, Q, Qp, alpha, beta_prev, inv, Qn):  # pragma: no cover - compiled
    """:func:`lanczos_regenerate`'s recurrence alone, the next basis vectors into ``Qn`` (another buffer:
    ``((M Q - Q alpha) - Qp beta_prev) inv``, the same arithmetic, the same bits)."""
    n = Q.shape[0]
    k = Q.shape[1]
    for b in prange((n + CG_BLOCK - 1) // CG_BLOCK):
        w = np.empty(k)
        for i in range(b * CG_BLOCK, min(n, (b + 1) * CG_BLOCK)):
            lanczos_next_row(indptr, indices, data, Q, Qp, alpha, beta_prev, inv, Qn, i, w)


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def lanczos_accumulate_steps(ring, slots, Y, out):  # pragma: no cover - compiled
    """``out[m] += sum_s ring[slots[s]] Y[s, m]`` (per column), the steps ``s`` added in order: the numbers of one
    :func:`lanczos_regenerate` accumulation per step, with ``out`` read and written once for all of them."""
    n = out.shape[1]
    k = out.shape[2]
    sets = out.shape[0]
    steps = slots.shape[0]
    for b in prange((n + CG_BLOCK - 1) // CG_BLOCK):
        acc = np.empty((sets, k))
        for i in range(b * CG_BLOCK, min(n, (b + 1) * CG_BLOCK)):
            for m in range(sets):
                for c in range(k):
                    acc[m, c] = out[m, i, c]
            for s in range(steps):  # each step's row once (contiguous), its additions in step order
                r = slots[s]
                for m in range(sets):
                    for c in range(k):
                        acc[m, c] += ring[r, i, c] * Y[s, m, c]
            for m in range(sets):
                for c in range(k):
                    out[m, i, c] = acc[m, c]


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def lanczos_scale(W, inv, out):  # pragma: no cover - compiled
    """``out = W inv`` (per column): the next basis vectors."""
    n = W.shape[0]
    k = W.shape[1]
    for i in prange(n):
        for c in range(k):
            out[i, c] = W[i, c] * inv[c]


@njit(cache=True, nogil=True, error_model="numpy")
def shifted_tridiagonal_solves(alpha, beta, sizes, mu, order, out):  # pragma: no cover - compiled
    """``out[:k_j, j] = (I + mu T_j^p)^{-1} e_1``, ``T_j`` the symmetric tridiagonal of column ``j``'s first ``k_j =
    sizes[j]`` steps (diagonal ``alpha[:k_j, j]``, off-diagonal ``beta[:k_j - 1, j]``), zero below ``k_j``.

    ``1 + mu x^p = mu prod_m (x - z_m)`` over its roots ``z_m = a exp(i pi (2m + 1) / p)``, ``a = mu^(-1/p)``: one
    Thomas recurrence per root, in turn (a product of inverses, no sum: partial fractions cancel to 1e-9 where the
    result is small), each without pivoting (``T - z I`` has a definite imaginary part, or is SPD for the real root
    ``-a``); the result is real up to rounding, its real part kept. ``out`` (kmax, c), written."""
    kmax = out.shape[0]
    c = out.shape[1]
    a = mu ** (-1.0 / order)
    w = np.empty(kmax, dtype=np.complex128)
    cp = np.empty(kmax, dtype=np.complex128)
    for j in range(c):
        k = sizes[j]
        for i in range(kmax):
            out[i, j] = 0.0
        if k == 0:
            continue
        for i in range(k):
            w[i] = 0.0
        w[0] = 1.0
        for m in range(order):
            angle = np.pi * (2 * m + 1) / order
            z = complex(a * np.cos(angle), a * np.sin(angle))
            if 2 * m + 1 == order:
                z = complex(-a, 0.0)  # exactly real
            d = alpha[0, j] - z
            cp[0] = beta[0, j] / d if k > 1 else 0.0
            w[0] = w[0] / d
            for i in range(1, k):
                d = (alpha[i, j] - z) - beta[i - 1, j] * cp[i - 1]
                cp[i] = beta[i, j] / d if i < k - 1 else 0.0
                w[i] = (w[i] - beta[i - 1, j] * w[i - 1]) / d
            for i in range(k - 2, -1, -1):
                w[i] = w[i] - cp[i] * w[i + 1]
        for i in range(k):
            out[i, j] = w[i].real / mu

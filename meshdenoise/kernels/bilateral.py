"""Normal filtering over face pairs: centroid spacing, spatial weights, the (guided) bilateral pass, the guidance."""

from __future__ import annotations

import numpy as np
from numba import prange

from .elementary import EXP_BLOCK, exp_nonpositive, unit_into
from .threads import njit


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def centroid_spacing_sums(C, indptr, indices, out):  # pragma: no cover - compiled
    """Per face ``i``: twice the sum of ``|c_i - c_j|`` over its neighbours ``j > i`` into ``out`` (m,); returns the
    count of ordered pairs ``(i, j)``, ``j != i``.

    The pattern must be symmetric with each row sorted (the faces sharing a vertex with a face are:
    :class:`meshdenoise.normal_filter.FaceNeighbourhood`). Then every unordered pair is one entry ``j > i``
    of row ``i`` and one ``i < j`` of row ``j``: ``out.sum()`` is the sum over the ordered pairs
    (``sum / count`` their mean spacing) with half the square roots, which bound this pass. Times 2 is
    exact; the sum is in another order than over the ordered pairs, so it agrees to a few units in the
    last place, not bit for bit.
    """
    m = C.shape[0]
    count = 0
    for i in prange(m):
        lo, hi = indptr[i], indptr[i + 1]
        start = lo
        while start < hi and indices[start] <= i:  # a sorted row: the entries past i, after a few steps
            start += 1
        s = 0.0
        c0 = C[i, 0]
        c1 = C[i, 1]
        c2 = C[i, 2]
        for k in range(start, hi):
            j = indices[k]
            d0 = c0 - C[j, 0]
            d1 = c1 - C[j, 1]
            d2 = c2 - C[j, 2]
            s += np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        out[i] = 2.0 * s
        count += 2 * (hi - start)
    return count


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def gaussian_block(X, indptr, indices, factor, lo, hi, out):  # pragma: no cover - compiled
    """``out[k - indptr[lo]] = exp(factor |x_i - x_j|^2)`` for the pairs ``k = (i, j)`` of rows ``lo`` to ``hi - 1``
    of the CSR pattern, ``X`` (m, 3), ``factor = -1 / denom`` (< 0). The exponents first, then their
    exponentials at once (:func:`exp_nonpositive`; exp(-0) is 1 exactly).

    A product by the reciprocal instead of a division per pair: the exponent differs by at most an
    ulp of it, the weight by ``|exponent|`` ulps (a weight above 1e-300 by under 1e-13 of itself).
    """
    base = indptr[lo]
    for i in range(lo, hi):
        x0 = X[i, 0]
        x1 = X[i, 1]
        x2 = X[i, 2]
        for k in range(indptr[i], indptr[i + 1]):
            j = indices[k]
            d0 = x0 - X[j, 0]
            d1 = x1 - X[j, 1]
            d2 = x2 - X[j, 2]
            out[k - base] = (d0 * d0 + d1 * d1 + d2 * d2) * factor
    exp_nonpositive(out, indptr[hi] - base)


@njit(cache=True, nogil=True, error_model="numpy")
def _block_pairs(indptr, blocks):  # pragma: no cover - compiled
    """The most face pairs in any :data:`EXP_BLOCK` rows: the size of a block's scratch."""
    m = indptr.shape[0] - 1
    most = 0
    for b in range(blocks):
        lo = b * EXP_BLOCK
        most = max(most, indptr[min(m, lo + EXP_BLOCK)] - indptr[lo])
    return most


# The pair kernels' exponentials: FMA contraction (fastmath "contract" only: no reassociation, no
# assumptions on NaN or infinities) halves the operations of the exponential's polynomial, whose
# dependent chain bounds them, and rounds once where a product and a sum rounded twice; the
# exponential stays within 1 ulp of numpy's (tests/test_two_stage_kernel.py).
PAIR_MATH = {"contract"}


@njit(parallel=True, cache=True, nogil=True, error_model="numpy", fastmath=PAIR_MATH)
def spatial_weights(C, A, indptr, indices, denom, S):  # pragma: no cover - compiled
    """``S[k] = A_j exp(-|c_i - c_j|^2 / denom)`` for every pair ``k = (i, j)`` of the CSR pattern.

    The exponentials by blocks of :data:`EXP_BLOCK` rows, in ``S`` itself (:func:`gaussian_block`), each
    then times ``A_j`` while the block is in cache.
    """
    m = C.shape[0]
    factor = -1.0 / denom
    for b in prange((m + EXP_BLOCK - 1) // EXP_BLOCK):
        lo = b * EXP_BLOCK
        hi = min(m, lo + EXP_BLOCK)
        start, stop = indptr[lo], indptr[hi]
        gaussian_block(C, indptr, indices, factor, lo, hi, S[start:stop])
        for k in range(start, stop):
            S[k] *= A[indices[k]]


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def patch_scores(N, A, indptr, indices, edge_a, edge_b, patch_ptr, patch_edge, g, H, phi):  # pragma: no cover
    """Mean normal ``g`` (m, 3) and inconsistency ``H`` (m,) of every patch (Zhang et al. 2015).

    ``g_j = unit(sum_k A_k n_k)`` over the faces ``k`` of patch ``j`` (its CSR row),
    ``H_j = max_k |n_k - g_j| * max_e phi_e / (1e-9 + sum_e phi_e)`` over the face pairs
    ``e`` sharing an edge inside the patch (``patch_edge``, rows ``patch_ptr``), with
    ``phi_e = |n_a - n_b|`` written to ``phi`` (E,).
    """
    m = N.shape[0]
    for e in prange(edge_a.shape[0]):
        a, b = edge_a[e], edge_b[e]
        d0 = N[a, 0] - N[b, 0]
        d1 = N[a, 1] - N[b, 1]
        d2 = N[a, 2] - N[b, 2]
        phi[e] = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
    for j in prange(m):
        s0 = 0.0
        s1 = 0.0
        s2 = 0.0
        for k in range(indptr[j], indptr[j + 1]):
            q = indices[k]
            w = A[q]
            s0 += w * N[q, 0]
            s1 += w * N[q, 1]
            s2 += w * N[q, 2]
        unit_into(g, j, s0, s1, s2)
        s0 = g[j, 0]
        s1 = g[j, 1]
        s2 = g[j, 2]
        spread2 = 0.0  # sqrt is monotone and correctly rounded: sqrt(max r^2) == max sqrt(r^2)
        for k in range(indptr[j], indptr[j + 1]):
            q = indices[k]
            d0 = N[q, 0] - s0
            d1 = N[q, 1] - s1
            d2 = N[q, 2] - s2
            r2 = d0 * d0 + d1 * d1 + d2 * d2
            if r2 > spread2:
                spread2 = r2
        spread = np.sqrt(spread2)
        largest = 0.0
        total = 0.0
        for t in range(patch_ptr[j], patch_ptr[j + 1]):
            p = phi[patch_edge[t]]
            if p > largest:
                largest = p
            total += p
        H[j] = spread * largest / (1e-9 + total)


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def pick_guidance(H, factor, g, indptr, indices, label, shift, key, G):  # pragma: no cover - compiled
    """``G_i = g_j`` for the patch ``j`` around face ``i`` with the least ``rint(H_j * factor)``, ties to the least ``label[j]``.

    ``label`` (m,) is the faces' index in the caller's order (the identity when the faces are
    not relabelled). Each patch's quantised score and label are packed into one integer,
    ``key[j] = rint(H_j * factor) << shift | label[j]`` (``key`` (m,) int64 scratch; ``shift``
    bits hold every label, and the scores are at most 2^30): comparing keys is comparing
    scores, then labels, and a loop of integer minima runs without branches (twice as fast
    as comparing the two in turn).
    """
    m = g.shape[0]
    for j in prange(m):
        key[j] = (np.int64(np.rint(H[j] * factor)) << shift) | label[j]
    for i in prange(m):
        best = indices[indptr[i]]
        best_key = key[best]
        for k in range(indptr[i] + 1, indptr[i + 1]):
            j = indices[k]
            candidate = key[j]
            better = candidate < best_key
            best = j if better else best
            best_key = candidate if better else best_key
        G[i, 0] = g[best, 0]
        G[i, 1] = g[best, 1]
        G[i, 2] = g[best, 2]


EXP_CHUNK = 8  # blocks of EXP_BLOCK rows per thread's task: one scratch allocation serves them all


@njit(parallel=True, cache=True, nogil=True, error_model="numpy", fastmath=PAIR_MATH)
def bilateral_pass(N, G, S, indptr, indices, denom, out):  # pragma: no cover - compiled
    """One Jacobi pass ``out_i = unit(sum_j S_ij exp(-|G_i - G_j|^2 / denom) n_j)``.

    By blocks of :data:`EXP_BLOCK` rows: the block's exponents, then their exponentials at once
    (:func:`exp_nonpositive`), then the sums (each row's in the pattern's order, as before).
    """
    m = N.shape[0]
    blocks = (m + EXP_BLOCK - 1) // EXP_BLOCK
    size = _block_pairs(indptr, blocks)
    factor = -1.0 / denom
    for chunk in prange((blocks + EXP_CHUNK - 1) // EXP_CHUNK):
        w = np.empty(size)
        for b in range(chunk * EXP_CHUNK, min(blocks, (chunk + 1) * EXP_CHUNK)):
            lo = b * EXP_BLOCK
            hi = min(m, lo + EXP_BLOCK)
            base = indptr[lo]
            gaussian_block(G, indptr, indices, factor, lo, hi, w)
            for i in range(lo, hi):
                s0 = 0.0
                s1 = 0.0
                s2 = 0.0
                for k in range(indptr[i], indptr[i + 1]):
                    j = indices[k]
                    wk = S[k] * w[k - base]
                    s0 += wk * N[j, 0]
                    s1 += wk * N[j, 1]
                    s2 += wk * N[j, 2]
                unit_into(out, i, s0, s1, s2)


@njit(parallel=True, cache=True, nogil=True, error_model="numpy", fastmath=PAIR_MATH)
def bilateral_spatial_pass(N, G, C, A, indptr, indices, denom_s, denom_r, out):  # pragma: no cover - compiled
    """:func:`spatial_weights` and :func:`bilateral_pass` in one sweep of the face pairs, the weights never stored.

    ``out_i = unit(sum_j A_j exp(-|c_i - c_j|^2 / denom_s - |G_i - G_j|^2 / denom_r) n_j)``: the product of
    the two kernels' weights as one exponential of the sum of their exponents, half the exponentials
    (which bound the pass), and without writing and reading back ``S`` (8 bytes a pair) or reading the
    pattern twice. For a run of one normal-filtering pass per outer iteration (the default's), where
    ``S`` is used once. The sum of the exponents rounds once more: a weight differs from the product of
    the two exponentials by about ``|exponent|`` ulps (under 1e-13 of itself above 1e-300), and the two
    exponents add into one non-positive number, so a pair far in either tail gets a weight of 0 or
    tiny, as before.
    """
    m = N.shape[0]
    blocks = (m + EXP_BLOCK - 1) // EXP_BLOCK
    size = _block_pairs(indptr, blocks)
    factor_s = -1.0 / denom_s
    factor_r = -1.0 / denom_r
    for chunk in prange((blocks + EXP_CHUNK - 1) // EXP_CHUNK):
        w = np.empty(size)
        for b in range(chunk * EXP_CHUNK, min(blocks, (chunk + 1) * EXP_CHUNK)):
            lo = b * EXP_BLOCK
            hi = min(m, lo + EXP_BLOCK)
            base = indptr[lo]
            for i in range(lo, hi):  # both exponents of the block's pairs, in one sweep of their indices
                c0 = C[i, 0]
                c1 = C[i, 1]
                c2 = C[i, 2]
                g0 = G[i, 0]
                g1 = G[i, 1]
                g2 = G[i, 2]
                for k in range(indptr[i], indptr[i + 1]):
                    j = indices[k]
                    d0 = c0 - C[j, 0]
                    d1 = c1 - C[j, 1]
                    d2 = c2 - C[j, 2]
                    e0 = g0 - G[j, 0]
                    e1 = g1 - G[j, 1]
                    e2 = g2 - G[j, 2]
                    w[k - base] = (d0 * d0 + d1 * d1 + d2 * d2) * factor_s + (e0 * e0 + e1 * e1 + e2 * e2) * factor_r
            exp_nonpositive(w, indptr[hi] - base)
            for i in range(lo, hi):
                s0 = 0.0
                s1 = 0.0
                s2 = 0.0
                for k in range(indptr[i], indptr[i + 1]):
                    j = indices[k]
                    wk = w[k - base] * A[j]
                    s0 += wk * N[j, 0]
                    s1 += wk * N[j, 1]
                    s2 += wk * N[j, 2]
                unit_into(out, i, s0, s1, s2)

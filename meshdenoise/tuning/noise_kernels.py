"""Compiled (numba) kernels of the noise estimate: the same numbers as the numpy/scipy code they replace, faster.

Each kernel repeats the arithmetic of the code it stands for in the same order, so that the
noise estimate (:func:`~meshdenoise.tuning.noise_level.estimate_noise`,
:func:`~meshdenoise.tuning.covariance.estimate_noise_model`) is the same bit for bit
(tests/test_noise_kernels.py compares every one of them with the numpy/scipy computation):

- :func:`fourth_difference_csr`: :math:`(I - P)^2` as scipy's ``(I - P) @ (I - P)`` builds it, by
  scipy's own ``csr_matmat`` on blocks of rows in threads (1.5 s on one thread at 1.6M vertices),
  ``I - P`` by ``csr_minus_csr``'s merge written out; the same entries in the same order, so that
  the sums over a row (``B.sum(axis=1)``'s pairwise ``reduceat``) and the products ``B X``
  (``csr_matvecs``) come out identical;
- :func:`vertex_normals`: :func:`meshdenoise.geometry.vertex_normals` (numpy's cross product,
  row norms :math:`\\sqrt{(x^2 + y^2) + z^2}`, ``bincount``'s sums over the faces in the order
  of ``F.T.ravel()``) without its nine ``(m,)`` temporaries: 0.7 s at 1.6M vertices, here
  about 0.1 s;
- :func:`edge_lengths`: ``np.linalg.norm(X[e[:, 0]] - X[e[:, 1]], axis=1)`` without the gathers.

Floating point: numba contracts no multiply-add into a fused one unless asked (``fastmath``),
so ``a * b - c * d`` rounds as numpy rounds it.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .. import geometry
from .. import kernels as _kernels  # the threading layer and OpenMP settings of the project's kernels
from ..kernels import njit, numba, prange
from .config import NOISE_KERNELS, NoiseKernelConfig, resolve

__all__ = ["fourth_difference_csr", "vertex_normals", "edge_lengths", "NoiseKernelConfig"]


# --------------------------------------------------------------------------- (I - P)^2
@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def _i_minus_counts(indptr, indices, data, counts):  # pragma: no cover - compiled
    """Per row, the entries of ``I - P`` that are not zero (``csr_binop_csr_canonical`` with minus)."""
    n = counts.size
    for i in prange(n):
        c = 0
        diag = False
        for jj in range(indptr[i], indptr[i + 1]):
            j = indices[jj]
            if j == i:
                diag = True
                if 1.0 - data[jj] != 0:
                    c += 1
            elif 0.0 - data[jj] != 0:
                c += 1
        if not diag:
            c += 1  # the identity's 1.0 - 0
        counts[i] = c


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def _i_minus_fill(indptr, indices, data, Ap, Aj, Ax):  # pragma: no cover - compiled
    """``I - P`` into ``Ap``, ``Aj``, ``Ax``: row ``i`` the sorted merge of ``(i, 1.0)`` and ``P``'s sorted row."""
    n = Ap.size - 1
    for i in prange(n):
        w = Ap[i]
        placed = False
        for jj in range(indptr[i], indptr[i + 1]):
            j = indices[jj]
            if not placed and j >= i:
                placed = True
                if j == i:
                    v = 1.0 - data[jj]
                    if v != 0:
                        Aj[w] = i
                        Ax[w] = v
                        w += 1
                    continue
                Aj[w] = i
                Ax[w] = 1.0 - 0.0
                w += 1
            v = 0.0 - data[jj]
            if v != 0:
                Aj[w] = j
                Ax[w] = v
                w += 1
        if not placed:
            Aj[w] = i
            Ax[w] = 1.0 - 0.0
            w += 1


def _index_dtype(size: int) -> type:
    return np.int32 if size < 2**31 - 1 else np.int64


def _i_minus(P: sp.csr_matrix, index_dtype: type) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``I - P`` as scipy's ``csr_minus_csr`` makes it (sorted rows, zeros dropped), on every thread: (indptr, indices, data)."""
    n = P.shape[0]
    indptr = P.indptr.astype(index_dtype, copy=False)  # P's own index arrays (int32 below 2^31 entries): no copy
    indices = P.indices.astype(index_dtype, copy=False)
    data = np.ascontiguousarray(P.data, dtype=np.float64)
    counts = np.zeros(n, dtype=index_dtype)
    _i_minus_counts(indptr, indices, data, counts)
    Ap = np.zeros(n + 1, dtype=index_dtype)
    np.cumsum(counts, out=Ap[1:])
    Aj = np.empty(int(Ap[-1]), dtype=index_dtype)
    Ax = np.empty(int(Ap[-1]))
    _i_minus_fill(indptr, indices, data, Ap, Aj, Ax)
    return Ap, Aj, Ax


_matmat_ok: bool | None = None  # scipy's private csr_matmat and csr_matmat_maxnnz: checked once against A @ A


def _check_matmat() -> bool:
    global _matmat_ok
    if _matmat_ok is None:
        _matmat_ok = False
        try:
            from scipy.sparse import _sparsetools as st

            A = sp.csr_matrix(np.array([[1.0, -0.5, 0.0], [-0.25, 1.0, -0.75], [0.0, -1.0, 1.0]]))
            nnz = int(st.csr_matmat_maxnnz(3, 3, A.indptr, A.indices, A.indptr, A.indices))
            Cp, Cj, Cx = np.empty(4, dtype=A.indptr.dtype), np.empty(nnz, dtype=A.indices.dtype), np.empty(nnz)
            st.csr_matmat(3, 3, A.indptr, A.indices, A.data, A.indptr, A.indices, A.data, Cp, Cj, Cx)
            _matmat_ok = bool(np.array_equal(sp.csr_matrix((Cx, Cj, Cp), shape=(3, 3)).toarray(), (A @ A).toarray()))
        except Exception:  # a changed private signature: scipy's public product
            _matmat_ok = False
    return _matmat_ok


def fourth_difference_csr(P: sp.csr_matrix, threads: int | None = None,
                          config: NoiseKernelConfig | None = None) -> sp.csr_matrix:
    """:math:`(I - P)^2` for a CSR ``P`` (n, n) with sorted, unique column indices: scipy's result, bit for bit.

    Below ``config.min_vertices`` rows (:class:`~meshdenoise.tuning.config.NoiseKernelConfig`, ``None``: its
    default) scipy's own one-threaded product (the same numbers).

    The same as ``sp.csr_matrix((sp.identity(n, format="csr") - P) @ (sp.identity(n, format="csr") - P))``:
    scipy's own kernel (``csr_matmat``, which releases the GIL) on ``threads`` blocks of rows
    (default :func:`meshdenoise.kernels.spmm_threads`; a row of the product depends on that row of
    the left factor only, so the split changes no entry and no order), ``I - P`` by
    :func:`_i_minus_counts` / :func:`_i_minus_fill` (``csr_minus_csr``'s merge). A ``P`` whose
    indices are not sorted and unique, or a scipy without the private kernels, takes scipy's route.
    """
    n = P.shape[0]
    if P.shape != (n, n) or n < max(resolve(config, NOISE_KERNELS).min_vertices, 1) or not P.has_canonical_format or not _check_matmat():
        A = sp.identity(n, format="csr") - sp.csr_matrix(P)
        return sp.csr_matrix(A @ A)
    from concurrent.futures import ThreadPoolExecutor

    from scipy.sparse import _sparsetools as st

    idx = _index_dtype(max(n + 1, P.nnz + n))
    Ap, Aj, Ax = _i_minus(P, idx)
    threads = max(1, min(_kernels.spmm_threads() if threads is None else int(threads), n))
    # row blocks of about equal numbers of entries of I - P (a mesh's rows cost about alike)
    bounds = np.searchsorted(Ap, np.linspace(0, int(Ap[-1]), threads + 1)).astype(np.int64)
    bounds[0], bounds[-1] = 0, n
    bounds = np.unique(bounds)

    def maxnnz(b: int) -> int:
        lo, hi = bounds[b], bounds[b + 1]
        return int(st.csr_matmat_maxnnz(int(hi - lo), n, Ap[lo:hi + 1], Aj, Ap, Aj))

    blocks = range(bounds.size - 1)
    with ThreadPoolExecutor(max_workers=len(blocks)) as pool:
        sizes = list(pool.map(maxnnz, blocks))
        if max(n, sum(sizes)) >= 2**31 - 1 and idx is np.int32:  # a product too large for 32-bit indices
            A = sp.csr_matrix((Ax, Aj.astype(np.int64), Ap.astype(np.int64)), shape=(n, n))
            return sp.csr_matrix(A @ A)
        offsets = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
        Cj = np.empty(int(offsets[-1]), dtype=idx)
        Cx = np.empty(int(offsets[-1]))
        Cps = [np.empty(int(bounds[b + 1] - bounds[b]) + 1, dtype=idx) for b in blocks]

        def product(b: int) -> None:
            lo, hi = bounds[b], bounds[b + 1]
            st.csr_matmat(int(hi - lo), n, Ap[lo:hi + 1], Aj, Ax, Ap, Aj, Ax, Cps[b],
                          Cj[offsets[b]:offsets[b + 1]], Cx[offsets[b]:offsets[b + 1]])

        list(pool.map(product, blocks))
    del Ap, Aj, Ax
    # the blocks' entries end to end (a block whose product dropped zeros fills less than its bound)
    indptr = np.empty(n + 1, dtype=idx)
    indptr[0] = 0
    at = 0
    for b in blocks:
        used = int(Cps[b][-1])
        if offsets[b] != at:
            Cj[at:at + used] = Cj[offsets[b]:offsets[b] + used]
            Cx[at:at + used] = Cx[offsets[b]:offsets[b] + used]
        indptr[bounds[b] + 1:bounds[b + 1] + 1] = Cps[b][1:] + at
        at += used
    return sp.csr_matrix((Cx[:at], Cj[:at], indptr), shape=(n, n))


# --------------------------------------------------------------------------- vertex normals
@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def _unit_face_normals(V, F, out):  # pragma: no cover - compiled
    """:func:`meshdenoise.geometry.face_normals`: ``cross_rows(V[b] - V[a], V[c] - V[a])`` divided by its norm."""
    for f in prange(F.shape[0]):
        n0, n1, n2 = _kernels.face_cross(V, F[f, 0], F[f, 1], F[f, 2])
        _kernels.unit_into(out, f, n0, n1, n2)


@njit(cache=True, nogil=True, error_model="numpy")
def _scatter_corners(F, values, out):  # pragma: no cover - compiled
    """``bincount(F.T.ravel(), weights=tile(values[:, d], 3))`` per column ``d``: corners 0, then 1, then 2."""
    for c in range(3):
        for f in range(F.shape[0]):
            v = F[f, c]
            out[v, 0] += values[f, 0]
            out[v, 1] += values[f, 1]
            out[v, 2] += values[f, 2]


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def _normalise_rows(X):  # pragma: no cover - compiled
    """Rows divided by :math:`\\sqrt{(x^2 + y^2) + z^2}` in place; zero rows (and NaN norms) set to zero."""
    for i in prange(X.shape[0]):
        norm = np.sqrt((X[i, 0] * X[i, 0] + X[i, 1] * X[i, 1]) + X[i, 2] * X[i, 2])
        if norm > 0:
            X[i, 0] = X[i, 0] / norm
            X[i, 1] = X[i, 1] / norm
            X[i, 2] = X[i, 2] / norm
        else:
            X[i, 0] = 0.0
            X[i, 1] = 0.0
            X[i, 2] = 0.0


def vertex_normals(V: np.ndarray, F: np.ndarray, config: NoiseKernelConfig | None = None) -> np.ndarray:
    """:func:`meshdenoise.geometry.vertex_normals` bit for bit: ``V`` (n, 3) float, ``F`` (m, 3) int in 0 .. n-1 -> (n, 3).

    Below ``config.min_vertices`` vertices (``None``: :class:`~meshdenoise.tuning.config.NoiseKernelConfig`'s
    default) that function itself."""
    V = np.ascontiguousarray(V, dtype=np.float64)
    F = np.ascontiguousarray(F, dtype=np.int64)
    if V.ndim != 2 or V.shape[1] != 3 or F.ndim != 2 or F.shape[1] != 3:
        raise ValueError(f"vertex_normals: V must be (n, 3) and F (m, 3), got {V.shape} and {F.shape}")
    if F.size and (F.min() < 0 or F.max() >= V.shape[0]):
        raise ValueError(f"vertex_normals: face indices must lie in 0 .. {V.shape[0] - 1}, got {F.min()} .. {F.max()}")
    if V.shape[0] < resolve(config, NOISE_KERNELS).min_vertices:
        return geometry.numpy_vertex_normals(V, F)
    _kernels.set_threads()
    normals = np.empty((F.shape[0], 3))
    _unit_face_normals(V, F, normals)
    out = np.zeros((V.shape[0], 3))
    _scatter_corners(F, normals, out)
    del normals
    _normalise_rows(out)
    return out


def _large_vertex_normals(V: np.ndarray, F: np.ndarray, config: NoiseKernelConfig | None = None) -> np.ndarray | None:
    """:func:`vertex_normals` from ``config.min_vertices`` vertices on, else None: what
    :func:`meshdenoise.geometry.vertex_normals` asks first (with the default)."""
    config = resolve(config, NOISE_KERNELS)
    return vertex_normals(V, F, config) if np.shape(V)[0] >= config.min_vertices else None


geometry.LARGE_VERTEX_NORMALS.append(_large_vertex_normals)


# --------------------------------------------------------------------------- edge lengths
@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def _edge_lengths(X, e, out):  # pragma: no cover - compiled
    for k in prange(e.shape[0]):
        a, b = e[k, 0], e[k, 1]
        d0 = X[a, 0] - X[b, 0]
        d1 = X[a, 1] - X[b, 1]
        d2 = X[a, 2] - X[b, 2]
        out[k] = np.sqrt((d0 * d0 + d1 * d1) + d2 * d2)


def edge_lengths(X: np.ndarray, e: np.ndarray, config: NoiseKernelConfig | None = None) -> np.ndarray:
    """``np.linalg.norm(X[e[:, 0]] - X[e[:, 1]], axis=1)`` bit for bit: ``X`` (n, 3), ``e`` (k, 2) int -> (k,).

    Below ``config.min_vertices`` vertices that expression itself."""
    X = np.ascontiguousarray(X, dtype=np.float64)
    e = np.ascontiguousarray(e, dtype=np.int64)
    if e.size and (e.min() < 0 or e.max() >= X.shape[0]):
        raise ValueError(f"edge_lengths: edge indices must lie in 0 .. {X.shape[0] - 1}, got {e.min()} .. {e.max()}")
    if X.shape[0] < resolve(config, NOISE_KERNELS).min_vertices:
        return np.linalg.norm(X[e[:, 0]] - X[e[:, 1]], axis=1)
    _kernels.set_threads()
    out = np.empty(e.shape[0])
    _edge_lengths(X, e, out)
    return out

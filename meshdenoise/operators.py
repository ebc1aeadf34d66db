"""The paper's graph operators, built once per topology and cached.

For a triangle mesh with ``n`` vertices, ``W`` is the symmetric 0/1 adjacency of the
faces' edges (duplicate faces and repeated edges count once, self-loops of degenerate
faces are dropped), ``D = diag(W 1)`` the degrees, ``P = D^-1 W`` the averaging
operator and ``L = D - W`` the combinatorial Laplacian. An isolated or unreferenced
vertex has degree 0; we define its row of ``P`` as the identity so that every filter
leaves it where it is.

Everything is built vectorised with scipy.sparse and cached by a hash of the faces, so
two calls on the same topology (a MeshSet denoised twice, the same faces with other
coordinates) share the operators and the factorisations stored in
:attr:`Operators.cache`.
"""

from __future__ import annotations

import hashlib
from functools import cached_property
from typing import Callable

import numba
import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import reverse_cuthill_mckee
from scipy.sparse.linalg import eigsh

from . import kernels
from .cache import ByteLRU, nbytes, on_clear
from .meshinfo import undirected_edges
from .kernels import _limits, spmm_threads, thread_limit  # noqa: F401 - the thread limits live in kernels; named here too

__all__ = ["Operators", "get_operators", "topology_key", "clear_cache", "trim_cache", "CACHE_BYTES", "spmm", "spmm_threads", "gather_rows"]

try:  # scipy's C kernel y += A x for CSR A and dense (n, k) x: writes into y, releases the GIL
    from scipy.sparse._sparsetools import csr_matvecs as _csr_matvecs
except ImportError:  # a scipy without it: spmm falls back to the public A @ X
    _csr_matvecs = None
_kernel_ok: bool | None = None  # checked once against A @ X before first use
_THREADED_NNZ = 1 << 20  # gather_rows: below this fancy indexing (one core) is as fast
# spmm: threads from this much work (non-zeros x columns; the bunny's P: 200k non-zeros, 3 columns: 0.10 ms on 2
# threads, 0.22 on 1) ...
_THREADED_WORK = 1 << 16
# ... and, on one thread, the compiled kernel for 3 columns and from this many (scipy's csr_matvecs is faster between:
# 9 columns 0.51 against 0.63 ms; 24 columns 0.98 against 0.74)
_COMPILED_FROM_COLUMNS = 16

CACHE_BYTES = 1 << 30  # operators of recent topologies, with their stored factorisations, up to 1 GiB
_cache = ByteLRU(CACHE_BYTES)  # topology key -> Operators


LOCALITY_MIN_VERTICES = 1 << 16  # below this the coordinates fit in cache and relabelling cannot pay
FAR_ROWS = 1 << 14  # a face side joining rows further apart than this misses the cache (16k rows = 384 KB of x, y, z)
FAR_SIDES_MAX = 0.05  # locality relabels when more face sides than this are far: a row-by-row range scan has about none


def far_side_fraction(F: np.ndarray, far: int = FAR_ROWS) -> float:
    """The fraction of face sides (three per face) whose two vertices are more than ``far`` rows apart.

    Examples
    --------
    >>> import numpy as np
    >>> far_side_fraction(np.array([[0, 1, 2], [0, 1, 100000]]), far=10)
    0.3333333333333333
    """
    F = np.asarray(F)
    if len(F) == 0:
        return 0.0
    far_sides = 0
    for a, b in ((0, 1), (1, 2), (2, 0)):
        far_sides += int(np.count_nonzero(np.abs(F[:, a].astype(np.int64) - F[:, b]) > far))
    return far_sides / (3 * len(F))


@kernels.njit(cache=True, nogil=True)
def _csr_from_sorted_edges(e, indptr, indices):  # pragma: no cover - compiled
    """The column indices of the symmetric adjacency of the edges ``e`` (sorted by low then high vertex): first
    every ``(high, low)`` entry in edge order, then every ``(low, high)``, each row filled from its start."""
    cursor = indptr[:-1].copy()
    for k in range(e.shape[0]):
        hi = e[k, 1]
        indices[cursor[hi]] = e[k, 0]
        cursor[hi] += 1
    for k in range(e.shape[0]):
        lo = e[k, 0]
        indices[cursor[lo]] = e[k, 1]
        cursor[lo] += 1


def topology_key(F: np.ndarray, n: int) -> tuple:
    """A hashable key identifying the topology ``(n, F)`` by content."""
    F = np.ascontiguousarray(F, dtype=np.int64)
    return (int(n), F.shape, hashlib.blake2b(F.data, digest_size=16).hexdigest())


def mask_key(mask: np.ndarray | None) -> str | None:
    """A short content hash of a boolean vertex mask (``None`` stays ``None``)."""
    if mask is None:
        return None
    return hashlib.blake2b(np.packbits(mask).data, digest_size=12).hexdigest()


class Operators:
    """Sparse operators of one mesh topology, computed lazily and kept.

    Parameters
    ----------
    F : ndarray of int64, shape (m, 3)
        Triangles.
    n : int
        Number of vertices (unreferenced ones included).

    Attributes
    ----------
    cache : dict
        Free space for work that depends only on the topology (factorisations keyed by
        their parameters). Filters store their solver objects here.

    Examples
    --------
    >>> import numpy as np
    >>> ops = Operators(np.array([[0, 1, 2], [0, 2, 3]]), 4)
    >>> ops.W.toarray().astype(int)
    array([[0, 1, 1, 1],
           [1, 0, 1, 0],
           [1, 1, 0, 1],
           [1, 0, 1, 0]])
    >>> ops.degree
    array([3., 2., 3., 2.])
    """

    def __init__(self, F: np.ndarray, n: int):
        self.F = np.array(F, dtype=np.int64, order="C")  # our own copy: the caller's array stays writable
        self.F.setflags(write=False)
        self.n = int(n)
        self.cache: dict = {}

    @property
    def nbytes(self) -> int:
        """Approximate memory held: the matrices built so far and the work stored in :attr:`cache`
        (factorisations estimated from their matrices' nonzeros)."""
        return nbytes(self.__dict__)

    def clear(self) -> None:
        """Drop everything built or stored on this object (it is rebuilt lazily on next use)."""
        F, n = self.F, self.n
        self.__dict__.clear()
        self.F, self.n, self.cache = F, n, {}

    def drop_matrices(self) -> int:
        """Drop the vertex matrices ``W``, ``P``, ``L``, their permuted copies and the edge list; return the bytes freed.

        They are rebuilt lazily, the same, on next use. For a caller whose remaining work needs
        none of them (the default before its ``two_stage`` runs): about 260 bytes per vertex. Kept:
        what is small (degrees, masks), :attr:`locality_order` and the :attr:`cache`'s other entries.
        """
        names = ("W", "P", "L", "_undirected_edges", "boundary_edges", "nonmanifold_edges")
        dropped = [self.__dict__.pop(name) for name in names if name in self.__dict__]
        keys = [key for key in self.cache if isinstance(key, tuple) and key[:1] == ("permuted",)]
        dropped += [self.cache.pop(key) for key in keys]
        return nbytes(dropped)

    # --- edges -----------------------------------------------------------------------
    @cached_property
    def _undirected_edges(self) -> tuple[np.ndarray, np.ndarray]:
        """Unique undirected edges (i < j) and how many face sides each one has
        (:func:`meshdenoise.meshinfo.undirected_edges`: sorted, int32 below 2^31 vertices, counts int32;
        12 bytes per edge held, built in O(m) without sorting every side's key)."""
        return undirected_edges(self.F, self.n)

    @property
    def edges(self) -> np.ndarray:
        """Unique undirected edges, shape (e, 2), with ``edges[:, 0] < edges[:, 1]``; int32 below 2^31 vertices."""
        return self._undirected_edges[0]

    @cached_property
    def boundary_edges(self) -> np.ndarray:
        """Edges with exactly one incident face side, shape (b, 2)."""
        edges, counts = self._undirected_edges
        return edges[counts == 1]

    @cached_property
    def boundary_vertices(self) -> np.ndarray:
        """Boolean mask (n,) of vertices on a boundary edge."""
        mask = np.zeros(self.n, dtype=bool)
        mask[self.boundary_edges.ravel()] = True
        return mask

    @cached_property
    def nonmanifold_edges(self) -> np.ndarray:
        """Edges shared by more than two face sides, shape (k, 2)."""
        edges, counts = self._undirected_edges
        return edges[counts > 2]

    # --- the paper's operators ----------------------------------------------------------
    @cached_property
    def W(self) -> sp.csr_matrix:
        """Symmetric 0/1 adjacency, CSR (n, n), float64, sorted int32 indices when n allows."""
        e = self.edges
        n = self.n
        # CSR by one counting pass over the edges, sorted by (low, high): row i gets its lower neighbours
        # (the edges (j, i), j ascending) and then its higher ones (the edges (i, j), j ascending), so each row
        # comes out sorted with no sort of the 2e directed keys (3 s at 5M vertices)
        index_dtype = np.int32 if max(n, 2 * e.shape[0]) < 2**31 - 1 else np.int64
        indptr = np.zeros(n + 1, dtype=index_dtype)
        np.cumsum(np.bincount(e.ravel(), minlength=n), out=indptr[1:])
        indices = np.empty(2 * e.shape[0], dtype=index_dtype)
        _csr_from_sorted_edges(e, indptr, indices)
        W = sp.csr_matrix((np.ones(indices.size), indices, indptr), shape=(n, n))
        W.has_sorted_indices = True
        W.has_canonical_format = True
        return W

    @cached_property
    def degree(self) -> np.ndarray:
        """Vertex degrees ``W 1``, shape (n,), float64."""
        return np.diff(self.W.indptr).astype(np.float64)

    @cached_property
    def isolated(self) -> np.ndarray:
        """Boolean mask (n,) of vertices on no edge (unreferenced or only in degenerate faces)."""
        return self.degree == 0

    @cached_property
    def P(self) -> sp.csr_matrix:
        """``D^-1 W``, with the identity on the rows of isolated vertices. CSR (n, n)."""
        W = self.W
        inv = np.zeros(self.n)
        np.divide(1.0, self.degree, out=inv, where=~self.isolated)
        # same sparsity as W: row i's entries all equal 1 / d_i
        P = sp.csr_matrix((np.repeat(inv, np.diff(W.indptr)), W.indices, W.indptr), shape=W.shape)
        P.has_sorted_indices = True
        P.has_canonical_format = True
        if self.isolated.any():  # rare: an identity row where W has an empty one
            P = sp.csr_matrix(P + sp.diags(self.isolated.astype(np.float64)))
            P.sort_indices()
        return P

    @cached_property
    def L(self) -> sp.csr_matrix:
        """Combinatorial Laplacian ``D - W``, CSR (n, n), symmetric positive semi-definite."""
        return sp.csr_matrix(sp.diags(self.degree) - self.W)

    def lambda_max(self) -> float:
        """Largest eigenvalue of ``I - D^-1 W`` (at most 2; 2 exactly for a bipartite graph).

        Computed once with Lanczos on the similar symmetric matrix
        ``I - D^-1/2 W D^-1/2`` restricted to non-isolated vertices, then cached.
        """
        if "lambda_max" not in self.cache:
            keep = ~self.isolated
            if not keep.any():
                self.cache["lambda_max"] = 0.0
            else:
                s = 1.0 / np.sqrt(self.degree[keep])
                Wk = self.W[keep][:, keep]
                Lsym = sp.identity(int(keep.sum()), format="csr") - sp.diags(s) @ Wk @ sp.diags(s)
                if Lsym.shape[0] <= 3:
                    lam = float(np.linalg.eigvalsh(Lsym.toarray()).max())
                else:
                    lam = float(eigsh(Lsym, k=1, which="LA", tol=1e-10, return_eigenvectors=False)[0])
                self.cache["lambda_max"] = min(lam, 2.0)
        return self.cache["lambda_max"]

    @cached_property
    def lambda_max_bound(self) -> float:
        r"""A guaranteed upper bound on :math:`\lambda_{max}(I - D^{-1} W)` from the faces alone, O(m).

        For every non-degenerate face :math:`t` and every ``x``,
        :math:`\sum_{ab \in t} (x_a + x_b)^2 = \sum_{v \in t} x_v^2 + (\sum_{v \in t} x_v)^2
        \ge \sum_{v \in t} x_v^2`. Summing over faces, with ``c`` the largest number of face
        sides on one edge and :math:`f_v` the faces at ``v``,

        .. math:: x^T (D + W) x = \sum_{ij \in E} (x_i + x_j)^2 \ge \frac{1}{c} \sum_v f_v x_v^2
                  \ge \beta\, x^T D x, \qquad \beta = \min_{d_v > 0} \frac{f_v}{c\, d_v},

        so the eigenvalues of :math:`I + D^{-1}W` are at least :math:`\beta` and those of
        :math:`I - D^{-1}W` at most :math:`2 - \beta`: 1.5 on a closed manifold mesh (where
        :math:`f_v = d_v`, ``c = 2``; the elephant's exact value is 1.484), at most 2 always.
        Identity rows (isolated or pinned vertices) only add eigenvalue 0 and, by interlacing,
        keep the rest inside the same interval. Chebyshev heat uses it to shrink its interval.

        Examples
        --------
        >>> import numpy as np
        >>> F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])  # tetrahedron: exact value 4/3
        >>> Operators(F, 4).lambda_max_bound
        1.5
        """
        d = self.degree
        has_edges = d > 0
        if not has_edges.any():
            return 0.0  # I - P is the zero matrix
        F = self.F
        proper = (F[:, 0] != F[:, 1]) & (F[:, 1] != F[:, 2]) & (F[:, 0] != F[:, 2])
        faces_at = np.bincount(F[proper].ravel(), minlength=self.n)
        c = int(self._undirected_edges[1].max())  # face sides per edge, degenerate faces included: >= needed
        beta = float(np.min(faces_at[has_edges] / (c * d[has_edges])))
        return 2.0 - beta

    def reorder_rows(self, X: np.ndarray) -> np.ndarray:
        """``X[locality_order]`` as a new C-contiguous float64 array (a threaded sparse gather)."""
        return gather_rows(X, self.locality_order)

    def restore_rows(self, Y: np.ndarray) -> np.ndarray:
        """The inverse of :meth:`reorder_rows`: ``Z`` with ``Z[locality_order] = Y``."""
        if "inverse_order" not in self.cache:
            inverse = np.empty_like(self.locality_order)
            inverse[self.locality_order] = np.arange(self.n)
            self.cache["inverse_order"] = inverse
        return gather_rows(Y, self.cache["inverse_order"])

    @cached_property
    def locality_order(self) -> np.ndarray:
        """A vertex order (n,) with neighbours close in memory: reverse Cuthill-McKee of ``W``.

        Meshes made by subdivision or stitched from scans list vertices far from their
        neighbours, so ``P @ X`` spends its time on cache misses gathering rows of ``X``.
        Iterating ``P[order][:, order]`` on ``X[order]`` is the same computation on
        relabelled vertices and ran 2.4 times faster on the 1.6M-vertex benchmark mesh.
        """
        if self.n == 0:
            return np.zeros(0, dtype=np.int64)
        if self.in_locality_order:
            return np.arange(self.n, dtype=np.int64)
        return np.asarray(reverse_cuthill_mckee(self.W, symmetric_mode=True), dtype=np.int64)

    @cached_property
    def in_locality_order(self) -> bool:
        """Whether the vertices are already in a cache-friendly order (then :attr:`locality_order` is the identity).

        True for a large mesh whose face sides rarely join far rows
        (:func:`far_side_fraction`): a range scan listed row by row, or a
        mesh :mod:`meshdenoise.locality` relabelled. Small meshes (below
        :data:`LOCALITY_MIN_VERTICES`) keep reverse Cuthill-McKee.
        """
        return self.n >= LOCALITY_MIN_VERTICES and far_side_fraction(self.F) <= FAR_SIDES_MAX

    def permuted(self, A: sp.csr_matrix, name: str) -> sp.csr_matrix:
        """``A[order][:, order]`` for :attr:`locality_order`, sorted CSR, cached under ``name``."""
        key = ("permuted", name)
        if key not in self.cache:
            order = self.locality_order
            inverse = np.empty_like(order)
            inverse[order] = np.arange(order.size)
            A = sp.csr_matrix(A)
            rows = A[order]  # row gather keeps each row's entries, then relabel the columns
            B = sp.csr_matrix((rows.data, inverse[rows.indices].astype(rows.indices.dtype), rows.indptr), shape=A.shape)
            B.sort_indices()
            self.cache[key] = B
        return self.cache[key]

    def with_pinned_rows(self, A: sp.csr_matrix, pinned: np.ndarray | None, name: str) -> sp.csr_matrix:
        """``A`` with the rows of ``pinned`` vertices replaced by identity rows (cached by mask).

        Multiplying by the result leaves pinned vertices bit-identical, which is how the
        iterative filters impose pinned vertices as Dirichlet boundary conditions.
        """
        if pinned is None or not pinned.any():
            return A
        key = ("pinned_rows", name, mask_key(pinned))
        if key not in self.cache:
            free = (~pinned).astype(np.float64)
            B = sp.diags(free) @ A + sp.diags(pinned.astype(np.float64))
            B = sp.csr_matrix(B)
            B.eliminate_zeros()
            self.cache[key] = B
        return self.cache[key]


def _check_kernel() -> bool:
    """Whether scipy's private ``csr_matvecs`` exists and agrees with ``A @ X`` (checked once)."""
    global _kernel_ok
    if _kernel_ok is None:
        _kernel_ok = False
        if _csr_matvecs is not None:
            A = sp.csr_matrix(np.array([[0.0, 2.0, 0.0], [1.0, 0.0, 3.0], [0.0, 0.0, 0.0]]))
            X = np.arange(6.0).reshape(3, 2)
            Y = np.full((3, 2), 1.0)
            try:
                _csr_matvecs(3, 3, 2, A.indptr, A.indices, A.data, X.ravel(), Y.ravel())
                _kernel_ok = bool(np.array_equal(Y, A @ X + 1.0))
            except Exception:  # a changed private signature: use the public product
                _kernel_ok = False
    return _kernel_ok


def spmm(
    A: sp.csr_matrix, X: np.ndarray, out: np.ndarray | None = None, *, accumulate: bool = False, threads: int | None = None
) -> np.ndarray:
    r"""``A @ X`` for CSR ``A`` (n, p) and dense ``X`` (p, k), on ``threads`` threads, into ``out``.

    .. math:: Y \leftarrow A X \quad\text{or, with accumulate=True,}\quad Y \leftarrow Y + A X

    Compiled kernels (:func:`~meshdenoise.kernels.csr_matmat`, its 3-column form) share the rows
    among numba's threads, each row writing its own row of ``out``: no temporary, no duplicate
    of ``X``; on one thread, scipy's CSR kernel for 1-2 and 4-15 columns, where it is faster.
    A matrix other than float64 CSR uses ``A @ X``. Float64 throughout; each row is summed over
    its non-zeros in storage order, as scipy's ``A @ X`` does, so the result is the same bits.

    Parameters
    ----------
    A : scipy.sparse CSR matrix, float64, shape (n, p), sorted or not
    X : ndarray, shape (p, k) or (p,)
    out : ndarray, shape (n, k), float64, C-contiguous, optional
        Written in place (and returned). Required when ``accumulate`` is True.
    accumulate : bool
        Add ``A X`` to ``out`` instead of overwriting it.
    threads : int, optional
        Default :func:`spmm_threads` for products of at least 2^16 non-zeros x columns, else 1;
        at most the calling thread's :func:`thread_limit` (1 in runs going side by side).

    Returns
    -------
    ndarray, shape (n, k)

    Examples
    --------
    >>> import numpy as np, scipy.sparse as sp
    >>> A = sp.csr_matrix(np.array([[0.0, 1.0], [2.0, 0.0]]))
    >>> spmm(A, np.array([[1.0, 2.0], [3.0, 4.0]]))
    array([[3., 4.],
           [2., 4.]])
    """
    if accumulate and out is None:
        raise ValueError("spmm: accumulate=True needs out= (the array to add A @ X to)")
    squeeze = X.ndim == 1
    X2 = np.ascontiguousarray(X.reshape(X.shape[0], -1), dtype=np.float64)
    n, k = A.shape[0], X2.shape[1]
    if X2.shape[0] != A.shape[1]:
        raise ValueError(f"spmm: A is {A.shape[0]} x {A.shape[1]} but X has {X2.shape[0]} rows")
    fresh = out is None
    if fresh:
        out = np.zeros((n, k))  # zero pages already: no second pass to clear them
    elif out.shape[0] != n or out.size != n * k or out.dtype != np.float64 or not out.flags.c_contiguous:
        raise ValueError(f"spmm: out must be a C-contiguous float64 array of shape ({n}, {k}), got {out.shape}")
    Y = out.reshape(n, k)
    if A.format != "csr" or A.dtype != np.float64:
        if accumulate:
            Y += A @ X2
        else:
            Y[...] = A @ X2
        return out.ravel() if squeeze else out
    if threads is None:  # work, not only non-zeros
        threads = min(spmm_threads(), thread_limit() or 1 << 30) if A.nnz * k >= _THREADED_WORK else 1
    threads = max(1, min(int(threads), n))
    if threads == 1 and k != 3 and k < _COMPILED_FROM_COLUMNS and A.indptr.dtype == A.indices.dtype and _check_kernel():
        # scipy's kernel: faster on one thread there
        if not accumulate and not fresh:  # the kernel adds into its output
            Y.fill(0.0)
        _csr_matvecs(n, A.shape[1], k, A.indptr, A.indices, A.data, X2.ravel(), Y.ravel())
        return out.ravel() if squeeze else out
    previous = numba.get_num_threads()
    numba.set_num_threads(max(1, min(threads, numba.config.NUMBA_NUM_THREADS)))
    try:
        (kernels.csr_matmat3 if k == 3 else kernels.csr_matmat)(A.indptr, A.indices, A.data, X2, Y, bool(accumulate))
    finally:
        numba.set_num_threads(previous)
    return out.ravel() if squeeze else out


def gather_rows(X: np.ndarray, index: np.ndarray) -> np.ndarray:
    """``X[index]`` as a new C-contiguous float64 array, through :func:`spmm` with a 0/1 matrix.

    A row gather of a few million coordinates is memory-bound; numpy's fancy indexing runs it
    on one core (61 ms for 1.6M x 3 here), the threaded product in 15 ms. Small inputs use
    fancy indexing.

    Examples
    --------
    >>> import numpy as np
    >>> gather_rows(np.array([[1.0, 2.0], [3.0, 4.0], [5.0, 6.0]]), np.array([2, 0]))
    array([[5., 6.],
           [1., 2.]])
    """
    n = len(index)
    X2 = np.ascontiguousarray(X, dtype=np.float64).reshape(X.shape[0], -1)
    if n and (index.min() < -X2.shape[0] or index.max() >= X2.shape[0]):
        raise IndexError(f"gather_rows: index out of range for {X2.shape[0]} rows")
    if n < _THREADED_NNZ:
        return np.ascontiguousarray(X2[index].reshape((n,) + X.shape[1:]))
    dtype = np.int32 if max(n, X2.shape[0]) < 2**31 - 1 else np.int64
    index = np.where(index < 0, index + X2.shape[0], index)  # numpy's negative indices, as fancy indexing
    G = sp.csr_matrix((np.ones(n), index.astype(dtype), np.arange(n + 1, dtype=dtype)), shape=(n, X2.shape[0]))
    return spmm(G, X2).reshape((n,) + X.shape[1:])


def get_operators(F: np.ndarray, n: int) -> Operators:
    """The cached :class:`Operators` for faces ``F`` on ``n`` vertices.

    The cache holds the most recent topologies up to :data:`CACHE_BYTES` (matrices and
    stored factorisations counted; :func:`clear_cache` empties it); the same faces (by
    content) return the same object, with its lazily built matrices and stored
    factorisations. Hold the returned object to keep its work past eviction.

    Examples
    --------
    >>> import numpy as np
    >>> F = np.array([[0, 1, 2]])
    >>> get_operators(F, 3) is get_operators(F.copy(), 3)
    True
    """
    key = topology_key(F, n)
    ops = _cache.lookup(key)
    if ops is None:
        _cache.max_bytes = CACHE_BYTES
        ops = _cache.put(key, Operators(F, n))
    return ops


def trim_cache() -> None:
    """Evict the least recently used topologies while the cache is over :data:`CACHE_BYTES`
    (called after work was stored on an :class:`Operators`, which grows it)."""
    _cache.max_bytes = CACHE_BYTES
    _cache.trim()


def clear_cache() -> None:
    """Forget every cached topology (operators and factorisations), the solvers' symbolic analyses and the kept
    vertex relabelling (the modules above that hold them register their own clear: :func:`on_clear_cache`)."""
    _cache.clear()
    for clear in list(_ON_CLEAR):
        clear()


_ON_CLEAR: list[Callable[[], None]] = []


def on_clear_cache(clear: Callable[[], None]) -> Callable[[], None]:
    """Have :func:`clear_cache` call ``clear`` too: a module above this one keeping something per topology
    (:func:`meshdenoise.solvers.clear_symbolic`, :func:`meshdenoise.locality.clear`) registers it at import."""
    _ON_CLEAR.append(clear)
    return clear


on_clear(clear_cache)

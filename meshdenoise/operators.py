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
import threading
from collections import OrderedDict
from functools import cached_property

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import eigsh

__all__ = ["Operators", "get_operators", "topology_key", "clear_cache"]

_CACHE_SIZE = 8
_cache: OrderedDict[tuple, "Operators"] = OrderedDict()
_lock = threading.Lock()


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

    # --- edges -----------------------------------------------------------------------
    @cached_property
    def _undirected_edges(self) -> tuple[np.ndarray, np.ndarray]:
        """Unique undirected edges (i < j) and how many face sides each one has."""
        F = self.F
        a = np.concatenate([F[:, 0], F[:, 1], F[:, 2]])
        b = np.concatenate([F[:, 1], F[:, 2], F[:, 0]])
        keep = a != b  # a degenerate face (i, i, j) has no edge i-i
        lo = np.minimum(a[keep], b[keep])
        hi = np.maximum(a[keep], b[keep])
        keys, counts = np.unique(lo * self.n + hi, return_counts=True)
        edges = np.stack([keys // self.n, keys % self.n], axis=1)
        return edges, counts

    @property
    def edges(self) -> np.ndarray:
        """Unique undirected edges, shape (e, 2), with ``edges[:, 0] < edges[:, 1]``."""
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
        """Symmetric 0/1 adjacency, CSR (n, n), float64."""
        e = self.edges
        rows = np.concatenate([e[:, 0], e[:, 1]])
        cols = np.concatenate([e[:, 1], e[:, 0]])
        data = np.ones(rows.size)
        W = sp.csr_matrix((data, (rows, cols)), shape=(self.n, self.n))
        W.sort_indices()
        return W

    @cached_property
    def degree(self) -> np.ndarray:
        """Vertex degrees ``W 1``, shape (n,), float64."""
        return np.asarray(self.W.sum(axis=1)).ravel()

    @cached_property
    def isolated(self) -> np.ndarray:
        """Boolean mask (n,) of vertices on no edge (unreferenced or only in degenerate faces)."""
        return self.degree == 0

    @cached_property
    def P(self) -> sp.csr_matrix:
        """``D^-1 W``, with the identity on the rows of isolated vertices. CSR (n, n)."""
        inv = np.zeros(self.n)
        np.divide(1.0, self.degree, out=inv, where=~self.isolated)
        P = sp.diags(inv) @ self.W + sp.diags(self.isolated.astype(np.float64))
        return sp.csr_matrix(P)

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

    def with_fixed_rows(self, A: sp.csr_matrix, fixed: np.ndarray | None, name: str) -> sp.csr_matrix:
        """``A`` with the rows of ``fixed`` vertices replaced by identity rows (cached by mask).

        Multiplying by the result leaves fixed vertices bit-identical, which is how the
        iterative filters impose pinned vertices as Dirichlet boundary conditions.
        """
        if fixed is None or not fixed.any():
            return A
        key = ("fixed_rows", name, mask_key(fixed))
        if key not in self.cache:
            free = (~fixed).astype(np.float64)
            B = sp.diags(free) @ A + sp.diags(fixed.astype(np.float64))
            B = sp.csr_matrix(B)
            B.eliminate_zeros()
            self.cache[key] = B
        return self.cache[key]


def get_operators(F: np.ndarray, n: int) -> Operators:
    """The cached :class:`Operators` for faces ``F`` on ``n`` vertices.

    The cache holds the last few topologies; the same faces (by content) return the
    same object, with its lazily built matrices and stored factorisations.

    Examples
    --------
    >>> import numpy as np
    >>> F = np.array([[0, 1, 2]])
    >>> get_operators(F, 3) is get_operators(F.copy(), 3)
    True
    """
    key = topology_key(F, n)
    with _lock:
        ops = _cache.get(key)
        if ops is not None:
            _cache.move_to_end(key)
            return ops
    ops = Operators(F, n)
    with _lock:
        _cache[key] = ops
        while len(_cache) > _CACHE_SIZE:
            _cache.popitem(last=False)
    return ops


def clear_cache() -> None:
    """Forget every cached topology (operators and factorisations)."""
    with _lock:
        _cache.clear()

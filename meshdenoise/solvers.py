"""Symmetric positive definite systems with Dirichlet (pinned) rows: factorised or iterative.

The implicit filters (Sobolev, higher-order Sobolev) all solve ``A Y = X`` with
``A = I + (positive semi-definite)``; with pinned vertices, on the free rows only.
:class:`SPDSolver` factorises once (sparse Cholesky) and caches; :class:`CGSolver`
runs a Jacobi-preconditioned block conjugate gradient with no factorisation, which
wins on very large, well-conditioned systems such as ``I + mu L`` with moderate ``mu``.
"""

from __future__ import annotations

import contextlib
import hashlib
import math
import threading
from collections import OrderedDict
from typing import Any, Callable, Iterator, Sequence

import warnings

import numpy as np
import scipy.sparse as sp
from cholespy import CholeskySolverD, MatrixType

from . import kernels
from .cache import FACTOR_BYTES_PER_NNZ, nbytes
from .operators import Operators, mask_key, on_clear_cache, spmm, trim_cache

__all__ = [
    "DirichletSystem", "SPDSolver", "CHOLMOD", "CHOLMOD_MAX_ROWS", "CHOLMOD_METIS_MAX_ROWS", "clear_symbolic", "CGSolver", "block_cg", "cached_solver", "retain_factors", "laplacian_power", "shifted_solver",
    "shifted_factor", "shifted_factor_matrices", "ShiftedProduct", "ShiftedInverse", "ShiftedPCG", "ShiftedPCGFamily", "one_ring_factor", "one_ring_solve", "HeldByProduct", "SHIFTED_METHODS", "LanczosQuadrature", "lanczos_shifted", "LanczosRows", "CompiledLanczos", "LanczosDots", "column_function", "FILTER_LANCZOS_TOL", "DRAFT_LANCZOS_TOL",
]

FACTORS_PER_FAMILY = 4  # a parameter sweep keeps only the last few factorisations of each filter


class DirichletSystem:
    """``A Y = X`` on the free rows of a symmetric positive definite ``A``, with ``Y = X`` on pinned rows.

    Holds the reduced matrix :math:`A_{ff}` (sorted CSR, attribute ``A``) and the coupling
    :math:`A_{fp}` that moves the pinned values to the right-hand side,
    :math:`A_{ff} Y_f = X_f - A_{fp} X_p`; every :math:`A_{ff}` of an SPD ``A`` is SPD.
    Subclasses solve the reduced system (a factorisation, or conjugate gradients).
    """

    def __init__(self, A: sp.spmatrix, pinned: np.ndarray | None = None):
        A = sp.csr_matrix(A, dtype=np.float64)
        self.n = A.shape[0]
        self.pinned = None if pinned is None or not pinned.any() else pinned.copy()
        if self.pinned is None:
            self.free = None
        else:
            self.free = np.flatnonzero(~self.pinned)
            self._pinned_rows = np.flatnonzero(self.pinned)
            A_free = A[self.free]
            self._coupling = A_free[:, self._pinned_rows]  # moves the pinned values to the right-hand side
            A = sp.csr_matrix(A_free[:, self.free])
        A.sort_indices()
        self.A = A
        self.size = A.shape[0]

    @property
    def nbytes(self) -> int:
        """Approximate memory held (matrices; a factorisation is estimated from its matrix)."""
        return nbytes(self.A) + nbytes(getattr(self, "_coupling", None))

    def _columns(self, X: np.ndarray) -> np.ndarray:
        """``X`` as float64 ``(n, k)``, checked against the system's size."""
        X = np.asarray(X, dtype=np.float64)
        if X.shape[0] != self.n:
            raise ValueError(f"{type(self).__name__}.solve: X has {X.shape[0]} rows, the system {self.n}")
        return X.reshape(self.n, -1)

    def _reduce(self, X2: np.ndarray, order: str = "C") -> np.ndarray:
        """The right-hand side of the reduced system: a new array in ``order`` (solvers may write into it)."""
        if self.free is None:
            return np.array(X2, dtype=np.float64, order=order)
        return np.asarray(X2[self.free] - self._coupling @ X2[self._pinned_rows], order=order)

    def _expand(self, X2: np.ndarray, out: np.ndarray) -> np.ndarray:
        """The full solution: ``out`` on the free rows, the pinned rows of ``X2`` bit for bit."""
        if self.free is None:
            return out
        Y = X2.copy()
        Y[self.free] = out
        return Y


_quiet_lock = threading.Lock()
_quiet: dict = {"depth": 0, "saved": {}, "tmps": {}}  # the one redirection of descriptors 1 and 2, shared by threads


def _without_cholmod_warnings(build: Callable[[], Any]) -> Any:
    """``build()`` with CHOLMOD's own C-level warning lines kept off the terminal.

    A failed factorisation (``ValueError: Matrix is not positive definite!``) is reported
    by our error message, which names the filter and its parameters; CHOLMOD also prints
    ``CHOLMOD warning: not positive definite ...`` through C's buffered ``stdout``. File
    descriptors 1 and 2 are sent to temporary files while the factor is built (C's buffers
    flushed before they are restored), then everything else written there meanwhile (other
    threads' output) is written back. Descriptors belong to the process: threads building at
    once share one redirection, made by the first to enter and undone by the last to leave
    (each saving and restoring its own would leave them on a deleted temporary file).
    """
    import ctypes
    import os
    import sys
    import tempfile

    with _quiet_lock:
        if _quiet["depth"] == 0:
            try:
                sys.stdout.flush()
                sys.stderr.flush()
                saved = {fd: os.dup(fd) for fd in (1, 2)}
            except (OSError, ValueError, AttributeError):  # no usable descriptors (embedded interpreters): build as is
                saved = None
            if saved is not None:
                tmps = {fd: tempfile.TemporaryFile() for fd in (1, 2)}
                for fd, tmp in tmps.items():
                    os.dup2(tmp.fileno(), fd)
                _quiet.update(saved=saved, tmps=tmps)
        _quiet["depth"] += 1
    try:
        return build()
    finally:
        with _quiet_lock:
            _quiet["depth"] -= 1
            if _quiet["depth"] == 0 and _quiet["saved"]:  # the last one out undoes the redirection, if one was made
                try:
                    ctypes.CDLL(None).fflush(None)  # C's buffered output into the temporary files first
                except (OSError, AttributeError):
                    pass
                saved, tmps = _quiet["saved"], _quiet["tmps"]
                _quiet.update(saved={}, tmps={})
                for fd, tmp in tmps.items():
                    os.dup2(saved[fd], fd)
                    os.close(saved[fd])
                    tmp.seek(0)
                    kept = [line for line in tmp.read().splitlines(keepends=True) if not line.startswith(b"CHOLMOD warning")]
                    tmp.close()
                    if kept:
                        os.write(fd, b"".join(kept))


def _cholmod_installed() -> bool:
    try:
        import sksparse.cholmod  # noqa: F401
    except ImportError:
        return False
    return True


CHOLMOD = _cholmod_installed()  # scikit-sparse (the "cholmod" extra): factorisations reuse a symbolic analysis ...
CHOLMOD_MAX_ROWS = 200_000  # ... for systems up to this many rows (larger ones by cholespy, see _cholmod_factor)
CHOLMOD_METIS_MAX_ROWS = 50_000  # METIS orders these; larger ones CHOLMOD's default (AMD, METIS if AMD fills much)
SYMBOLIC_MAX = 16  # symbolic analyses kept (sparsity patterns), least recently used out; clear_symbolic() drops them
_symbolic: OrderedDict = OrderedDict()
_symbolic_lock = threading.Lock()


def clear_symbolic() -> None:
    """Forget the stored symbolic analyses of :class:`SPDSolver` (CHOLMOD's orderings of each sparsity pattern)."""
    with _symbolic_lock:
        _symbolic.clear()


on_clear_cache(clear_symbolic)  # operators.clear_cache forgets them too


def _cholmod_factor(A: sp.csr_matrix) -> Any:
    """A numeric CHOLMOD factor of the symmetric positive definite ``A`` (sorted CSR), its symbolic analysis
    (simplicial ``L D L^T``) computed once per sparsity pattern and reused.

    The automatic rules factorise ``I + mu L^p`` for many ``mu`` on one pattern: only the numeric step is
    repeated (bunny scanner, 28,088 vertices, idle: ``I + c L`` 131 -> 37 ms, the two-ring factor of
    ``I + mu L^3`` 410 -> 243 ms against cholespy, which orders every matrix again; the solves cost the same;
    a factor used once costs about the same either way: the analysis is 88 and 164 ms). Up to
    :data:`CHOLMOD_METIS_MAX_ROWS` rows METIS orders the pattern; above, METIS's analysis costs more than it saves
    (face000's 85,182 vertices: 0.27 s for a one-ring matrix whose numeric factor takes 0.12 s) and CHOLMOD's default
    orders it (AMD, with METIS tried when AMD's fill is large): a one-ring factor 0.41 -> 0.18 s at 85k rows,
    0.62 -> 0.36 at 100k, 0.97 -> 0.77 at 139k against cholespy, two-ring factors 0.97 to 1.21 times cholespy's,
    solves 5 to 28 % slower (``benchmarks/factor_backend.py``). Up to :data:`CHOLMOD_MAX_ROWS` rows only, the same
    back end for a matrix whatever was factorised before: at 400k rows cholespy's factor is the faster (3.4 against
    4.4 s) and at 1.6M too (docs/benchmarks.md). A simplicial ``L D L^T`` does not fail on an indefinite matrix: a
    pivot ``D <= 0`` is reported as cholespy reports it.
    """
    from sksparse.cholmod import analyze

    pattern = hashlib.blake2b(f"{A.shape[0]} {A.indptr.dtype} {A.indices.dtype}".encode(), digest_size=20)
    pattern.update(np.ascontiguousarray(A.indptr))  # the buffers themselves: no converted copy
    pattern.update(np.ascontiguousarray(A.indices))
    key = pattern.digest()  # the pattern's content, not its arrays: nothing of size n kept but the analysis
    C = sp.csc_matrix((A.data, A.indices, A.indptr), shape=A.shape)  # a symmetric matrix's CSR is its CSC
    with _symbolic_lock:
        symbolic = _symbolic.get(key)
        if symbolic is not None:
            _symbolic.move_to_end(key)
    if symbolic is None:
        order = "metis" if A.shape[0] <= CHOLMOD_METIS_MAX_ROWS else "default"
        symbolic = analyze(C, mode="simplicial", ordering_method=order)
        with _symbolic_lock:
            _symbolic[key] = symbolic
            while len(_symbolic) > SYMBOLIC_MAX:
                _symbolic.popitem(last=False)
    factor = symbolic.cholesky(C)
    if not np.all(factor.D() > 0):
        raise ValueError("Matrix is not positive definite!")  # as cholespy says it
    return factor


class SPDSolver(DirichletSystem):
    """A sparse Cholesky factorisation of SPD ``A``, reduced to free rows when some are pinned.

    Solves ``A Y = X`` on the free rows with ``Y = X`` on the pinned ones, i.e. the reduced
    system :math:`A_{ff} Y_f = X_f - A_{fp} X_p`. With scikit-sparse installed (the ``cholmod``
    extra; ``make`` installs it) and up to :data:`CHOLMOD_MAX_ROWS` rows by CHOLMOD with one symbolic
    analysis per sparsity pattern (:func:`_cholmod_factor`: a parameter search's many weights), else
    by cholespy.

    Examples
    --------
    >>> import numpy as np, scipy.sparse as sp
    >>> A = sp.csr_matrix(np.array([[2.0, -1, 0], [-1, 2, -1], [0, -1, 2]]))
    >>> SPDSolver(A, np.array([False, True, False])).solve(np.array([[1.0], [5.0], [1.0]])).ravel()
    array([3., 5., 3.])
    """

    def __init__(self, A: sp.spmatrix, pinned: np.ndarray | None = None):
        super().__init__(A, pinned)
        A = self.A
        self._solver = self._factor = None
        if not self.size:
            return
        if CHOLMOD and self.size <= CHOLMOD_MAX_ROWS:
            self._factor = _cholmod_factor(A)
        else:
            self._solver = _without_cholmod_warnings(lambda: CholeskySolverD(
                self.size, A.indptr.astype(np.int32), A.indices.astype(np.int32), A.data.astype(np.float64),
                MatrixType.CSR,
            ))

    @property
    def nbytes(self) -> int:
        """Approximate memory held: the reduced matrix plus an estimate of its Cholesky factor
        (not reported by the solvers: :data:`~meshdenoise.cache.FACTOR_BYTES_PER_NNZ` per nonzero)."""
        return super().nbytes + FACTOR_BYTES_PER_NNZ * int(self.A.nnz)

    def solve(self, X: np.ndarray) -> np.ndarray:
        """``Y`` of the shape of ``X`` (n,) or (n, k), with ``(A Y)_f = X_f`` and ``Y_p = X_p``."""
        X2 = self._columns(X)
        # CHOLMOD solves column-major right-hand sides (scikit-sparse converts any other): one copy fewer, the same
        # bits (51 columns at 28k rows: 37 -> 32 ms)
        rhs = self._reduce(X2, order="F" if self._factor is not None else "C")
        if self._factor is not None:
            out = np.ascontiguousarray(self._factor(rhs), dtype=np.float64)
        else:
            out = np.empty_like(rhs)
            if self._solver is not None:
                self._solver.solve(rhs, out)
        return self._expand(X2, out).reshape(np.shape(X))


def block_cg(
    A: sp.csr_matrix,
    B: np.ndarray,
    *,
    tol: float = 1e-10,
    maxiter: int | None = None,
    x0: np.ndarray | None = None,
    inv_diag: np.ndarray | None = None,
) -> tuple[np.ndarray, int, np.ndarray]:
    r"""Solve ``A X = B`` for SPD ``A`` and several right-hand sides by Jacobi-preconditioned CG.

    Every column runs its own conjugate-gradient recurrence (its own step lengths
    :math:`\alpha_j`, :math:`\beta_j`), vectorised over the columns so that each
    iteration costs one sparse product ``A P`` with all columns at once
    (:func:`meshdenoise.operators.spmm`) and a few passes over ``(n, k)`` arrays.
    With :math:`M = \mathrm{diag}(A)`, per column:

    .. math::
        q = A p,\quad \alpha = \frac{r^T z}{p^T q},\quad x \leftarrow x + \alpha p,\quad
        r \leftarrow r - \alpha q,\quad z = M^{-1} r,\quad
        \beta = \frac{r^T z}{r_{old}^T z_{old}},\quad p \leftarrow z + \beta p

    A column stops (its step lengths set to 0) once :math:`\|r_j\|_2 \le
    \mathrm{tol}\, \|b_j\|_2`; the loop ends when all have. In exact arithmetic the
    error in the :math:`A`-norm falls at least like :math:`2\,((\sqrt\kappa - 1) /
    (\sqrt\kappa + 1))^i` with :math:`\kappa` the condition number of
    :math:`M^{-1/2} A M^{-1/2}`.

    Parameters
    ----------
    A : scipy.sparse matrix, shape (n, n), symmetric positive definite
    B : ndarray, shape (n, k) or (n,)
    tol : float, > 0
        Relative residual at which a column stops.
    maxiter : int, optional
        Iteration cap; default ``max(100, 2 n)`` capped at 100000. Reaching it with a column
        not converged emits a :class:`UserWarning` (the best iterate is returned).
    x0 : ndarray, shape of ``B``, optional
        Starting guess (warm start); default zeros.
    inv_diag : ndarray, shape (n,), optional
        ``1 / diag(A)`` when the caller already has it.

    Returns
    -------
    X : ndarray, shape of ``B``
    iterations : int
        Iterations run (sparse products, not counting the initial residual).
    relres : ndarray, shape (k,)
        Final relative residuals :math:`\|b_j - A x_j\| / \|b_j\|` of the recurrence
        (0 for a zero column of ``B``, whose solution is 0).

    Examples
    --------
    >>> import numpy as np, scipy.sparse as sp
    >>> A = sp.csr_matrix(np.array([[4.0, 1, 0], [1, 3, 1], [0, 1, 2]]))
    >>> X, its, res = block_cg(A, np.eye(3), tol=1e-12)
    >>> bool(np.allclose(X, np.linalg.inv(A.toarray()), atol=1e-12)), its <= 3
    (True, True)
    """
    if not (isinstance(tol, (float, int)) and 0 < tol < 1):
        raise ValueError(f"block_cg: tol must be a number in (0, 1), got {tol!r}")
    A = sp.csr_matrix(A, dtype=np.float64)
    n = A.shape[0]
    if A.shape != (n, n):
        raise ValueError(f"block_cg: A must be square, got shape {A.shape}")
    B = np.asarray(B, dtype=np.float64)
    if B.shape[0] != n:
        raise ValueError(f"block_cg: B has {B.shape[0]} rows, A has {n}")
    B2 = B.reshape(n, -1)
    k = B2.shape[1]
    if maxiter is None:
        maxiter = min(max(100, 2 * n), 100_000)
    if int(maxiter) < 1:
        raise ValueError(f"block_cg: maxiter must be at least 1, got {maxiter!r}")
    if inv_diag is None:
        diag = A.diagonal()
        if not np.all(diag > 0):
            bad = int(np.flatnonzero(~(diag > 0))[0])
            raise ValueError(f"block_cg: A is not positive definite: diagonal entry {bad} is {float(diag[bad])!r}")
        inv_diag = 1.0 / diag
    dinv = np.asarray(inv_diag, dtype=np.float64).reshape(n, 1)

    bnorm = np.sqrt(np.einsum("ij,ij->j", B2, B2))
    if x0 is None:
        X = np.zeros((n, k))
        R = np.array(B2, order="C")
    else:
        x0 = np.asarray(x0, dtype=np.float64)
        if x0.shape != B.shape:
            raise ValueError(f"block_cg: x0 has shape {x0.shape}, B {B.shape}")
        X = np.array(x0.reshape(n, k), order="C")
        X[:, bnorm == 0] = 0.0  # A x = 0 has the solution 0: no iteration for that column
        R = spmm(A, X)
        np.subtract(B2, R, out=R)
    target = tol * bnorm
    rnorm = np.sqrt(np.einsum("ij,ij->j", R, R))
    active = rnorm > target
    d = np.ascontiguousarray(dinv.ravel())
    P = R * dinv
    rz = np.einsum("ij,ij->j", R, P)
    Q = np.empty_like(P)
    # each iteration is three compiled passes (product and p.q, update and norms, direction) where numpy made
    # about ten over the (n, k) arrays; the dot products are summed by fixed blocks of rows (kernels.CG_BLOCK)
    kernels.set_threads()
    blocks = (n + kernels.CG_BLOCK - 1) // kernels.CG_BLOCK
    pq_parts, rr_parts, rz_parts = (np.empty((blocks, k)) for _ in range(3))
    it = 0
    while active.any() and it < maxiter:
        kernels.cg_product(A.indptr, A.indices, A.data, P, Q, pq_parts)
        alpha = np.divide(rz, pq_parts.sum(axis=0), out=np.zeros(k), where=active)
        kernels.cg_step(X, R, P, Q, alpha, d, rr_parts, rz_parts)
        it += 1
        rnorm = np.sqrt(rr_parts.sum(axis=0))
        active &= rnorm > target
        if not active.any():
            break
        rz_new = rz_parts.sum(axis=0)
        beta = np.divide(rz_new, rz, out=np.zeros(k), where=active)
        rz = np.where(active, rz_new, rz)
        kernels.cg_direction(P, R, d, beta)
    relres = np.divide(rnorm, bnorm, out=np.zeros(k), where=bnorm > 0)
    if active.any():
        warnings.warn(
            f"block_cg: {int(active.sum())} of {k} columns did not reach the relative residual tol = {tol:g} "
            f"in maxiter = {maxiter} iterations (worst {relres.max():.3g}); hint: raise maxiter, loosen tol, "
            "or use a direct factorisation (solver='cholesky') for this ill-conditioned system",
            UserWarning,
            stacklevel=2,
        )
    return X.reshape(B.shape), it, relres


class CGSolver(DirichletSystem):
    """Iterative counterpart of :class:`SPDSolver`: no factorisation, Jacobi-preconditioned block CG.

    Builds the reduced system once (``A_ff``, the coupling ``A_fp`` and ``1 / diag(A_ff)``);
    each :meth:`solve` runs :func:`block_cg` on
    :math:`A_{ff} Y_f = X_f - A_{fp} X_p` and copies the pinned rows ``Y_p = X_p``
    unchanged (bit-identical).

    Parameters
    ----------
    A : scipy.sparse matrix, shape (n, n), symmetric positive definite
    pinned : ndarray of bool, shape (n,), optional
    maxiter : int, optional
        Default iteration cap of :meth:`solve` (see :func:`block_cg`).

    Attributes
    ----------
    iterations : int
        Iterations of the last :meth:`solve`.
    relres : ndarray
        Per-column relative residuals of the last :meth:`solve`.

    Examples
    --------
    >>> import numpy as np, scipy.sparse as sp
    >>> A = sp.csr_matrix(np.array([[2.0, -1, 0], [-1, 2, -1], [0, -1, 2]]))
    >>> CGSolver(A, np.array([False, True, False])).solve(np.array([[1.0], [5.0], [1.0]])).ravel()
    array([3., 5., 3.])
    """

    def __init__(self, A: sp.spmatrix, pinned: np.ndarray | None = None, *, maxiter: int | None = None):
        super().__init__(A, pinned)
        self.maxiter = maxiter
        A = self.A
        diag = A.diagonal()
        if not np.all(diag > 0):
            bad = int(np.flatnonzero(~(diag > 0))[0])
            raise ValueError(f"CGSolver: A is not positive definite: diagonal entry {bad} (free rows) is {float(diag[bad])!r}")
        self._inv_diag = 1.0 / diag
        self.iterations = 0
        self.relres = np.zeros(0)

    def solve(self, X: np.ndarray, *, tol: float = 1e-10, x0: np.ndarray | None = None, maxiter: int | None = None) -> np.ndarray:
        """``Y`` of the shape of ``X`` (n,) or (n, k), with ``(A Y)_f = X_f`` to relative residual ``tol``, ``Y_p = X_p``.

        ``x0`` (shape of ``X``, optional) is the starting guess; only its free rows are used.
        """
        X2 = self._columns(X)
        x02 = None if x0 is None else np.asarray(x0, dtype=np.float64)
        if x02 is not None and x02.shape != np.shape(X):
            raise ValueError(f"{type(self).__name__}.solve: x0 has shape {x02.shape}, X {np.shape(X)}")
        rhs = self._reduce(X2)
        start = None if x02 is None else x02.reshape(self.n, -1)
        if start is not None and self.free is not None:
            start = start[self.free]
        if rhs.shape[0]:
            out, self.iterations, self.relres = block_cg(
                self.A, rhs, tol=tol, maxiter=maxiter if maxiter is not None else self.maxiter,
                x0=start, inv_diag=self._inv_diag,
            )
        else:
            out, self.iterations, self.relres = rhs.copy(), 0, np.zeros(rhs.shape[1])
        return self._expand(X2, out).reshape(np.shape(X))


_retained: list[dict] = []  # the open retain_factors scopes: {"count": int, "touched": [(ops, family), ...]}


def _family_limit() -> int:
    """Factorisations kept per family: :data:`FACTORS_PER_FAMILY`, more inside :func:`retain_factors`."""
    return max([FACTORS_PER_FAMILY] + [scope["count"] for scope in _retained])


@contextlib.contextmanager
def retain_factors(count: int) -> Iterator[None]:
    """Within the block, keep the last ``count`` factorisations of each family (at least :data:`FACTORS_PER_FAMILY`).

    A search whose candidates each factorise several weights (``sobolev_axes``: one per axis) and
    that comes back to earlier candidates (the normals search's second pass) would otherwise
    factorise them again (the bunny scanner: 15 of 36 factorisations were repeats). On leaving,
    the families the block stored into are trimmed back to the usual count: nothing more is kept
    after the search returns.

    Examples
    --------
    >>> with retain_factors(9):
    ...     _family_limit()
    9
    >>> _family_limit() == FACTORS_PER_FAMILY
    True
    """
    if not (isinstance(count, (int, np.integer)) and count >= 1):
        raise ValueError(f"retain_factors: count must be an integer >= 1, got {count!r}")
    scope: dict = {"count": int(count), "touched": []}
    _retained.append(scope)
    try:
        yield
    finally:
        _retained.remove(scope)
        limit = _family_limit()
        for ops, family in scope["touched"]:
            factors = ops.cache.get(family)
            while factors is not None and len(factors) > limit:
                factors.popitem(last=False)


def cached_solver(
    ops: Operators, family: str, param: float, pinned: np.ndarray | None, build: Callable[[], SPDSolver]
) -> SPDSolver:
    """The solver of ``family`` for ``(param, pinned mask)`` stored on this topology, built on first use.

    Keeps the last :data:`FACTORS_PER_FAMILY` of each family (least recently used first out), more
    inside :func:`retain_factors`.
    """
    factors = ops.cache.setdefault(family, OrderedDict())
    key = (float(param), mask_key(pinned if pinned is not None and pinned.any() else None))
    if key in factors:
        factors.move_to_end(key)
        return factors[key]
    solver = build()
    factors[key] = solver
    for scope in _retained:
        if not any(o is ops and f == family for o, f in scope["touched"]):
            scope["touched"].append((ops, family))
    limit = _family_limit()
    while len(factors) > limit:
        factors.popitem(last=False)
    trim_cache()  # the topology grew: keep the module's operators cache under its byte limit
    return solver


def laplacian_power(ops: Operators, order: int) -> sp.csr_matrix:
    """:math:`L^p` for the graph Laplacian ``L = D - W`` of this topology, ``order`` = p >= 1 (sorted CSR, stored on ``ops``).

    Examples
    --------
    >>> import numpy as np
    >>> from meshdenoise.operators import Operators
    >>> ops = Operators(np.array([[0, 1, 2]]), 3)
    >>> bool(np.allclose(laplacian_power(ops, 2).toarray(), ops.L.toarray() @ ops.L.toarray()))
    True
    """
    if isinstance(order, (bool, np.bool_)) or not isinstance(order, (int, np.integer)) or order < 1:
        raise ValueError(f"laplacian_power: order must be an int >= 1, got {order!r}")
    powers = ops.cache.setdefault("laplacian_powers", {})
    if order not in powers:
        M = sp.csr_matrix(ops.L)
        for _ in range(order - 1):
            M = sp.csr_matrix(M @ ops.L)
        M.sort_indices()
        powers[order] = M
    return powers[order]


SHIFTED_METHODS = ("cholesky", "cg", "pcg")


def shifted_matrix(ops: Operators, mu: float, order: int = 1) -> sp.csr_matrix:
    """:math:`I + \\mu L^p` (CSR): the one place the package writes this matrix (:func:`shifted_solver`,
    :class:`meshdenoise.plugins.sobolev.SobolevSolver`).

    Examples
    --------
    >>> import numpy as np
    >>> from meshdenoise.operators import Operators
    >>> ops = Operators(np.array([[0, 1, 2]]), 3)
    >>> bool(np.allclose(shifted_matrix(ops, 2.0).toarray(), np.eye(3) + 2.0 * ops.L.toarray()))
    True
    """
    return sp.csr_matrix(sp.identity(ops.n, format="csr") + float(mu) * laplacian_power(ops, order))


def shifted_factor_matrices(ops: Operators, mu: float, order: int) -> list[sp.csr_matrix]:
    """SPD polynomials in ``L`` of degree 1 or 2 whose product is :math:`(I + \\mu L^p) / \\mu`.

    The roots of :math:`1 + \\mu x^p` are :math:`x_k = a\\, e^{i \\pi (2k + 1) / p}`,
    :math:`a = \\mu^{-1/p}`; a conjugate pair gives the real quadratic
    :math:`x^2 - 2 a \\cos\\theta_k\\, x + a^2`, positive for every real ``x`` (its roots are not real), and an
    odd ``p`` has the real root :math:`-a`, the factor :math:`x + a`. So

    .. math:: I + \\mu L^3 = \\mu\\, (L + a I)(L^2 - a L + a^2 I), \\qquad
              I + \\mu L^4 = \\mu\\, (L^2 + \\sqrt2\\, a L + a^2 I)(L^2 - \\sqrt2\\, a L + a^2 I),

    every factor SPD for :math:`L \\succeq 0`, with at most ``L^2``'s pattern: Cholesky factors of those cost
    a third to a quarter of one of ``L^3`` (37 nonzeros a row) or ``L^4`` (61) on a mesh (measured at 28k
    vertices: 1.2-1.5 s against 3.2-4.3 s for ``p = 3``, 2.2 s against 7.4-9.3 s for ``p = 4``).

    Examples
    --------
    >>> import numpy as np
    >>> from meshdenoise.operators import Operators
    >>> ops = Operators(np.array([[0, 1, 2], [0, 2, 3]]), 4)
    >>> L = ops.L.toarray()
    >>> P = np.linalg.multi_dot([M.toarray() for M in shifted_factor_matrices(ops, 8.0, 3)])
    >>> bool(np.allclose(8.0 * P, np.eye(4) + 8.0 * np.linalg.matrix_power(L, 3)))
    True
    """
    if isinstance(order, (bool, np.bool_)) or not isinstance(order, (int, np.integer)) or order < 1:
        raise ValueError(f"shifted_factor_matrices: order must be an int >= 1, got {order!r}")
    a = float(mu) ** (-1.0 / order)
    eye = sp.identity(ops.n, format="csr")
    L, L2 = laplacian_power(ops, 1), laplacian_power(ops, 2) if order > 1 else None
    out = [sp.csr_matrix(L + a * eye)] if order % 2 else []
    for k in range(order // 2):
        c = 2.0 * a * math.cos(math.pi * (2 * k + 1) / order)
        out.append(sp.csr_matrix(L2 - c * L + (a * a) * eye))
    return out


class ShiftedProduct:
    """:math:`(I + \\mu L^p) Y = X` by one Cholesky factor per real factor of :math:`1 + \\mu x^p`
    (:func:`shifted_factor_matrices`), solved in turn: for ``p >= 3``, with no pinned rows (the free rows of a
    product are not the product of the factors' free rows).

    Examples
    --------
    >>> import numpy as np
    >>> from meshdenoise.operators import Operators
    >>> ops = Operators(np.array([[0, 1, 2], [0, 2, 3]]), 4)
    >>> X = np.arange(12.0).reshape(4, 3)
    >>> Y = ShiftedProduct(ops, 5.0, 3).solve(X)
    >>> bool(np.allclose(Y + 5.0 * np.linalg.matrix_power(ops.L.toarray(), 3) @ Y, X))
    True
    """

    def __init__(self, ops: Operators, mu: float, order: int):
        self.n, self.mu, self.order = ops.n, float(mu), int(order)
        self.factors = [SPDSolver(M) for M in shifted_factor_matrices(ops, self.mu, self.order)]

    @property
    def nbytes(self) -> int:
        """Approximate memory held: the factors' matrices and Cholesky factors."""
        return sum(f.nbytes for f in self.factors)

    def solve(self, X: np.ndarray) -> np.ndarray:
        """``Y`` of the shape of ``X`` (n,) or (n, k)."""
        X = np.asarray(X, dtype=np.float64)
        if X.shape[0] != self.n:
            raise ValueError(f"ShiftedProduct.solve: X has {X.shape[0]} rows, the system {self.n}")
        Y = X.reshape(self.n, -1)
        for factor in self.factors:
            Y = factor.solve(Y)
        Y /= self.mu
        return Y.reshape(X.shape)

def shifted_factor(ops: Operators, mu: float, order: int = 1,
                   pinned: np.ndarray | None = None) -> SPDSolver | ShiftedProduct:
    """A factorised solver of :math:`(I + \\mu L^p) Y = X`, not stored: :class:`ShiftedProduct` from ``p = 3``
    with no pinned rows, else one Cholesky factor of the matrix (:class:`SPDSolver`)."""
    if order >= 3 and (pinned is None or not np.any(pinned)):
        return ShiftedProduct(ops, mu, order)
    return SPDSolver(shifted_matrix(ops, mu, order), pinned)

HELD_BY_PRODUCT_MIN_VERTICES = 20_000  # shifted_solver: from this size held rows with p >= 3 by HeldByProduct (CG
# preconditioned by the free product's factors) instead of a factor of the whole I + mu L^p with them (Bunny0.2's 223
# border vertices, mu 0.107, p 3: 22 iterations, sobolev_gls' border run 2.1 -> 1.1 s)
HELD_BY_PRODUCT_MAX_HELD = 1_000  # ... while at most this many rows are held: the steps grow with their count (face000's
# 4,111 border vertices: 308 steps at mu 24.5, over 400 at 103, 9-11 s against a 3 s factor)
HELD_CG_TOL = 1e-10  # HeldByProduct's relative residual (as the filters' factor-free solves, FILTER_LANCZOS_TOL)
HELD_CG_MAXITER = 200  # HeldByProduct.solve: past this many steps the held system is factorised after all


def _preconditioned_cg(A: sp.csr_matrix | Callable[[np.ndarray], np.ndarray], b: np.ndarray,
                       precondition: Callable[[np.ndarray], np.ndarray], tol: float,
                       maxiter: int, x0: np.ndarray | None = None) -> tuple[np.ndarray, int] | None:
    """``A x = b`` (SPD ``A``, ``b`` (m, c)) by CG preconditioned by ``precondition``, started from ``x0`` (m, c) or else
    from the preconditioner's answer, every column to a relative residual ``tol``: ``(x, steps)``, or ``None`` past
    ``maxiter`` steps (the held solvers then factorise). ``A`` a matrix or its product on (m, c) blocks, column ``j``
    of the result being column ``j``'s own system's (:class:`ShiftedPCGFamily`: one weight per column).
    """
    if not callable(A):
        A = (lambda M: lambda P: spmm(M, P))(A)
    x = precondition(b) if x0 is None else np.array(x0, dtype=np.float64)
    r = b - A(x)
    z = precondition(r)
    p, rz = z.copy(), np.einsum("ij,ij->j", r, z)
    norm_b = np.sqrt(np.einsum("ij,ij->j", b, b))
    steps = 0
    while not np.all(np.sqrt(np.einsum("ij,ij->j", r, r)) <= tol * norm_b):
        if steps >= maxiter:
            return None
        q = A(p)
        pq = np.einsum("ij,ij->j", p, q)
        alpha = np.divide(rz, pq, out=np.zeros_like(rz), where=pq > 0)
        x += alpha * p
        r -= alpha * q
        z = precondition(r)
        rz_next = np.einsum("ij,ij->j", r, z)
        p = z + np.divide(rz_next, rz, out=np.zeros_like(rz), where=rz > 0) * p
        rz = rz_next
        steps += 1
    return x, steps


class HeldByProduct(DirichletSystem):
    r""":math:`(I + \mu L^p) Y = X` with held (pinned) rows, ``p >= 3``, by conjugate gradients on the free rows
    preconditioned by the free system's factors restricted to them, :math:`z = (A^{-1} [r; 0])_f`.

    The product form (:class:`ShiftedProduct`, a third to a quarter of the cost of factorising :math:`A = I + \mu L^p`)
    has no held rows; a factor of :math:`A_{ff}` with them is of the whole ``p``-ring pattern. But
    :math:`(A^{-1})_{ff} = (A_{ff} - A_{fp} A_{pp}^{-1} A_{pf})^{-1}` differs from :math:`A_{ff}^{-1}` by a term of rank
    at most the held count, so CG preconditioned by it converges in about that many steps at most, and in far fewer
    when a border is held (Bunny0.2, 223 border vertices: 22). ``product`` is the free solver (stored on ``ops`` by
    :func:`shifted_solver`); :attr:`product` also serves callers wanting an approximate inverse (a preconditioner).

    Examples
    --------
    >>> import numpy as np
    >>> from meshdenoise.shapes import icosphere
    >>> from meshdenoise.operators import get_operators
    >>> V, F = icosphere(2)
    >>> ops = get_operators(F, len(V))
    >>> held = np.zeros(len(V), dtype=bool); held[:5] = True
    >>> Y = HeldByProduct(ops, 0.5, 3, held).solve(V)
    >>> A = np.eye(len(V)) + 0.5 * np.linalg.matrix_power(ops.L.toarray(), 3)
    >>> bool(np.array_equal(Y[:5], V[:5])), bool(np.allclose((A @ Y)[5:], V[5:], atol=1e-8))
    (True, True)
    """

    def __init__(self, ops: Operators, mu: float, order: int, pinned: np.ndarray):
        if int(order) < 3:
            raise ValueError(f"HeldByProduct: order must be >= 3 (the product form), got {order!r}")
        self._matrix = shifted_matrix(ops, mu, order)
        super().__init__(self._matrix, pinned)
        self.product = shifted_solver(ops, mu, order)
        self._factor: SPDSolver | None = None

    @property
    def nbytes(self) -> int:
        """Approximate memory held: the matrices, the free factors (counted here too: this solver keeps them alive when
        the cache has let them go) and a fallback factor."""
        return (super().nbytes + nbytes(self._matrix) + self.product.nbytes
                + (self._factor.nbytes if self._factor is not None else 0))

    def solve(self, X: np.ndarray, *, tol: float = HELD_CG_TOL, maxiter: int | None = None) -> np.ndarray:
        """``Y`` of the shape of ``X`` (n,) or (n, k): ``Y_p = X_p`` bit for bit, the free rows to a relative residual
        ``tol`` per column; past ``maxiter`` steps (default :data:`HELD_CG_MAXITER`) by a factor of the held system
        (:class:`SPDSolver`, kept for the next solves)."""
        if self._factor is not None:
            return self._factor.solve(X)
        X2 = self._columns(X)
        b = self._reduce(X2)
        if self.free is None:
            return self.product.solve(X2).reshape(np.shape(X))
        n, free = self.n, self.free

        def precondition(R: np.ndarray) -> np.ndarray:
            Z = np.zeros((n, R.shape[1]))
            Z[free] = R
            return self.product.solve(Z)[free]

        # started from the free system's answer: the held rows' influence is the correction
        found = _preconditioned_cg(self.A, b, precondition, tol, HELD_CG_MAXITER if maxiter is None else int(maxiter))
        if found is None:  # far from the free system: factorise
            self._factor = SPDSolver(self._matrix, self.pinned)
            return self._factor.solve(X)
        return self._expand(X2, found[0]).reshape(np.shape(X))


def held_row_share(order: int) -> float:
    """:class:`ShiftedPCG`'s diagonal share ``(p - 1) / p`` of each free row's coupling to held rows (0 for ``p = 1``,
    where :math:`(L^p)_{ff} = L_{ff}`). Measured, steps to 1e-10 with shares 0 / 0.5 / 0.65 / 0.8: face000's 4,111 held
    border vertices, p = 3: 50 / 31 / 29 / 32 (mu 24.5), 68 / 42 / 39 / 41 (mu 103), 77 / 47 / 44 / 46 (mu 184); p = 4,
    mu 50: 170 / 89 / 80 / 78; p = 2: 16 / 13 / 15 / 17 (mu 5), 23 / 17 / 19 / 20 (mu 50); a 150 x 150 grid's border, p = 3:
    22 / 19 / 19 / 20 (mu 1) to 62 / 32 / 30 / 33 (mu 300); Bunny0.2's 223, p = 3: 19 / 22 / 23 / 25 at mu 0.1, 69 / 46 /
    44 / 43 at mu 100."""
    return (int(order) - 1) / int(order)


def one_ring_factor(ops: Operators, shift: float, order: int, pinned: np.ndarray | None = None) -> SPDSolver:
    r"""The factor of :class:`ShiftedPCG`'s one-ring matrix on the free rows, :math:`L_{ff} + a I + s\, H`:
    ``shift`` ``a`` (:math:`\mu^{-1/p}` for :math:`I + \mu L^p`), :math:`H` the diagonal of each free row's coupling
    to the held rows and :math:`s` = :func:`held_row_share` ``(p)`` (held rows make :math:`(L^p)_{ff}` exceed
    :math:`(L_{ff})^p` next to them; a diagonal share of their coupling stands for it). :math:`\mu^{-1}` times ``p``
    solves with it approximate :math:`(I + \mu L^p)_{ff}^{-1}`.

    Examples
    --------
    >>> import numpy as np
    >>> from meshdenoise.operators import Operators
    >>> ops = Operators(np.array([[0, 1, 2], [0, 2, 3]]), 4)
    >>> held = np.array([True, False, False, False])
    >>> A = one_ring_factor(ops, 0.5, 3, held).A.toarray()  # rows 1..3: L_ff + 0.5 I + (2/3) (held neighbours)
    >>> bool(np.allclose(A, ops.L.toarray()[1:, 1:] + np.diag(0.5 + 2 / 3 * np.array([1.0, 1.0, 1.0]))))
    True
    """
    diagonal = np.full(ops.n if pinned is None else int(np.count_nonzero(~pinned)), float(shift))
    if pinned is None or not np.any(pinned):
        L = ops.L
    else:
        free, held = np.flatnonzero(~pinned), np.flatnonzero(pinned)
        rows = ops.L[free]
        L = rows[:, free]
        diagonal += held_row_share(order) * np.asarray(abs(rows[:, held]).sum(axis=1)).ravel()
    return SPDSolver(sp.csr_matrix(L + sp.diags(diagonal, format="csr")))


def one_ring_solve(factor: SPDSolver, R: np.ndarray, order: int, mu: float | np.ndarray) -> np.ndarray:
    r""":math:`\mu^{-1} (L_{ff} + a I + s H)^{-p} R`: ``order`` solves of ``R`` (free rows, c) with ``factor`` (a
    :func:`one_ring_factor`), divided by ``mu`` (a number, or one per column, shape (c,)): the one-ring approximation
    of :math:`(I + \mu L^p)_{ff}^{-1}` that :class:`ShiftedPCG`, :class:`ShiftedPCGFamily` and ``sobolev_gls``' held
    correction precondition by."""
    Z = R
    for _ in range(int(order)):
        Z = factor.solve(Z)
    return Z / (np.asarray(mu, dtype=np.float64)[None, :] if np.ndim(mu) else float(mu))


SHIFTED_PCG_MAXITER = 300  # ShiftedPCG.solve: past this many steps the system is factorised after all (measured: 19 to
# 23 steps without held rows at 1e-10, 20 with Bunny0.2's 223 held border vertices, 55 to 78 with face000's 4,111)


class ShiftedPCG(DirichletSystem):
    r""":math:`(I + \mu L^p) Y = X` (held rows as Dirichlet data) by conjugate gradients preconditioned by
    :math:`\mu^{-1} (L_{ff} + a I)^{-p}`, :math:`a = \mu^{-1/p}`: one Cholesky factor of a one-ring matrix (``L``'s
    pattern, its ordering shared by every ``mu``), no factor of :math:`I + \mu L^p` (``p``-ring pattern).

    Without held rows :math:`\mu (L + a I)^p` and :math:`I + \mu L^p` share their eigenvectors, and their
    eigenvalues' ratio :math:`(1 + x^p) / (1 + x)^p`, :math:`x = \lambda / a`, lies in :math:`[2^{1 - p}, 1]`: the
    preconditioned matrix's condition number is at most :math:`2^{p - 1}` (4 for ``p = 3``) whatever ``mu`` and the
    mesh: 5 to 32 steps to a relative residual of 1e-10 measured (``p`` 2 to 4). Held rows make :math:`(L^p)_{ff}` differ from
    :math:`L_{ff}^p` by a term of rank at most their count, larger next to them: the one-ring matrix gets
    :func:`held_row_share` ``(p - 1) / p`` of each free row's coupling to held rows on its diagonal, which cut face000's
    steps (4,111 border vertices) from 50-77 to 29-44 for ``p = 3`` (55 to 78 steps took 1.8 to 2.6 s, against 2.8 to
    3.0 s for a factor of the held system); Bunny0.2's 223: 20 steps. Past
    :data:`SHIFTED_PCG_MAXITER` steps the held system is factorised after all (kept for the next solves).
    :meth:`precondition` is the preconditioner itself, for callers solving a system close to this one
    (``sobolev_gls``' weighted correction: its condition number at most :math:`2^{p-1} \beta`).

    Examples
    --------
    >>> import numpy as np
    >>> from meshdenoise.shapes import icosphere
    >>> from meshdenoise.operators import get_operators
    >>> V, F = icosphere(2)
    >>> ops = get_operators(F, len(V))
    >>> held = np.zeros(len(V), dtype=bool); held[:5] = True
    >>> Y = ShiftedPCG(ops, 30.0, 3, held).solve(V)
    >>> A = np.eye(len(V)) + 30.0 * np.linalg.matrix_power(ops.L.toarray(), 3)
    >>> b = V[5:] - A[5:, :5] @ V[:5]  # the free rows' right-hand side: relative residual 1e-10 (HELD_CG_TOL)
    >>> bool(np.array_equal(Y[:5], V[:5])), bool(np.linalg.norm(A[5:, 5:] @ Y[5:] - b) <= 1e-9 * np.linalg.norm(b))
    (True, True)
    """

    def __init__(self, ops: Operators, mu: float, order: int, pinned: np.ndarray | None = None):
        if isinstance(order, (bool, np.bool_)) or not isinstance(order, (int, np.integer)) or order < 1:
            raise ValueError(f"ShiftedPCG: order must be an int >= 1, got {order!r}")
        if not (isinstance(mu, (int, float, np.integer, np.floating)) and mu > 0 and np.isfinite(mu)):
            raise ValueError(f"ShiftedPCG: mu must be a finite number > 0, got {mu!r}")
        self._matrix = shifted_matrix(ops, mu, order)
        super().__init__(self._matrix, pinned)
        self.mu, self.order = float(mu), int(order)
        self.factor = one_ring_factor(ops, self.mu ** (-1.0 / self.order), self.order, self.pinned)
        self._fallback: SPDSolver | None = None
        self.iterations = 0

    @property
    def nbytes(self) -> int:
        """Approximate memory held: the matrices, the one-ring factor and a fallback factor."""
        return (super().nbytes + nbytes(self._matrix) + self.factor.nbytes
                + (self._fallback.nbytes if self._fallback is not None else 0))

    def precondition(self, R: np.ndarray) -> np.ndarray:
        r""":math:`\mu^{-1} (L_{ff} + a I)^{-p} R` for ``R`` (free rows, c): ``p`` solves with the one-ring factor."""
        return one_ring_solve(self.factor, R, self.order, self.mu)

    def solve(self, X: np.ndarray, *, tol: float = HELD_CG_TOL, maxiter: int | None = None,
              x0: np.ndarray | None = None) -> np.ndarray:
        """``Y`` of the shape of ``X`` (n,) or (n, k): ``Y_p = X_p`` bit for bit, the free rows to a relative residual
        ``tol`` per column, started from ``x0``'s free rows (shaped like ``X``: a guess, such as the same system's
        answer with other held values) or else from the preconditioner's answer; past ``maxiter`` steps (default
        :data:`SHIFTED_PCG_MAXITER`) by a factor of the held system."""
        if self._fallback is not None:
            return self._fallback.solve(X)
        X2 = self._columns(X)
        b = self._reduce(X2)
        if not self.size:
            return self._expand(X2, b).reshape(np.shape(X))
        start = None
        if x0 is not None:
            start = self._columns(x0)
            if start.shape != X2.shape:
                raise ValueError(f"ShiftedPCG.solve: x0 has shape {np.shape(x0)}, X {np.shape(X)}")
            start = start if self.free is None else start[self.free]
        found = _preconditioned_cg(self.A, b, self.precondition, tol,
                                   SHIFTED_PCG_MAXITER if maxiter is None else int(maxiter), start)
        if found is None:  # far from the bound: factorise
            self._fallback = SPDSolver(self._matrix, self.pinned)
            return self._fallback.solve(X)
        x, self.iterations = found
        return self._expand(X2, x).reshape(np.shape(X))


class ShiftedPCGFamily(DirichletSystem):
    r""":math:`(I + \mu_j L^p)\, y_j = x_j`, one weight :math:`\mu_j` per column, with held (pinned) rows: one run of
    conjugate gradients for the columns together, preconditioned by one factor of a one-ring matrix for them all.

    :class:`ShiftedPCG` with a weight per column: the preconditioner of column ``j`` is
    :math:`\mu_j^{-1} (L_{ff} + a I + \mathrm{share})^{-p}` with one shift for every column, ``a`` the geometric mean
    of the :math:`\mu_j^{-1/p}`, so each of its ``p`` solves per step is one triangular solve of all the columns (a
    solve of one column reads the whole factor: three columns cost little more than one), and the products share one
    :math:`L^p P` (``p`` products with ``L``, no :math:`L^p` formed). Measured on face000's three ``sobolev_axes``
    axes (4,111 held border vertices, ``mu`` 24.5, 103 and 184, p = 3, from the free run's result): 36 steps for the
    three together against 21, 29 and 35 each with its own factor; 1.45 against 2.48 s, one factor instead of three.
    The held rows of every column are its input's, bit for bit; past :data:`SHIFTED_PCG_MAXITER` steps each column's
    held system is factorised.

    Examples
    --------
    >>> import numpy as np
    >>> from meshdenoise.shapes import icosphere
    >>> from meshdenoise.operators import get_operators
    >>> V, F = icosphere(2)
    >>> ops = get_operators(F, len(V))
    >>> held = np.zeros(len(V), dtype=bool); held[:5] = True
    >>> Y = ShiftedPCGFamily(ops, [3.0, 30.0, 300.0], 3, held).solve(V)
    >>> L3 = np.linalg.matrix_power(ops.L.toarray(), 3)
    >>> A = [np.eye(len(V)) + mu * L3 for mu in (3.0, 30.0, 300.0)]  # each column's free rows' relative residual:
    >>> [bool(np.linalg.norm(A[j][5:] @ Y[:, j] - V[5:, j])  # at most 1e-10 (HELD_CG_TOL)
    ...       <= 1e-10 * np.linalg.norm(V[5:, j] - A[j][5:, :5] @ V[:5, j])) for j in range(3)]
    [True, True, True]
    >>> bool(np.array_equal(Y[:5], V[:5]))
    True
    """

    def __init__(self, ops: Operators, mus: Sequence[float], order: int, pinned: np.ndarray | None = None):
        if isinstance(order, (bool, np.bool_)) or not isinstance(order, (int, np.integer)) or order < 1:
            raise ValueError(f"ShiftedPCGFamily: order must be an int >= 1, got {order!r}")
        weights = np.asarray(mus, dtype=np.float64) if not isinstance(mus, (str, bytes)) else np.array([np.nan])
        if weights.ndim != 1 or not weights.size or not np.all(np.isfinite(weights) & (weights > 0)):
            raise ValueError(f"ShiftedPCGFamily: mus must be a non-empty sequence of finite numbers > 0, got {mus!r}")
        # the free rows' bookkeeping on L itself: the products take L^p by p products with L (no L^p formed and sliced,
        # 0.23 s on face000, for 1.3 ms more per step)
        super().__init__(ops.L, pinned)
        self._L = ops.L
        self.mus, self.order = weights, int(order)
        self.factor = one_ring_factor(ops, float(np.exp(np.mean(np.log(weights ** (-1.0 / self.order))))), self.order,
                                      self.pinned)
        self._ops = ops
        self.iterations = 0

    @property
    def nbytes(self) -> int:
        """Approximate memory held: the free rows' slices of ``L`` and the one-ring factor."""
        return super().nbytes + self.factor.nbytes

    def _power_free(self, Y: np.ndarray) -> np.ndarray:
        """:math:`L^p Y` on the free rows, ``Y`` (n, k) on every row."""
        for _ in range(self.order):
            Y = spmm(self._L, Y)
        return Y if self.free is None else Y[self.free]

    def _product(self, P: np.ndarray) -> np.ndarray:
        if self.free is None:
            return P + self.mus[None, :] * self._power_free(P)
        Y = np.zeros((self.n, P.shape[1]))
        Y[self.free] = P
        return P + self.mus[None, :] * self._power_free(Y)

    def precondition(self, R: np.ndarray) -> np.ndarray:
        r""":math:`\mu_j^{-1} (L_{ff} + a I)^{-p} r_j` for each column of ``R`` (free rows, k)."""
        return one_ring_solve(self.factor, R, self.order, self.mus)

    def solve(self, X: np.ndarray, *, tol: float = HELD_CG_TOL, maxiter: int | None = None,
              x0: np.ndarray | None = None) -> np.ndarray:
        """``Y`` (n, k), ``k`` the number of weights: ``Y_p = X_p`` bit for bit, the free rows of column ``j`` solving
        weight ``j``'s system to a relative residual ``tol``, started from ``x0``'s free rows (a guess shaped like
        ``X``) or else from the preconditioner's answer; past ``maxiter`` steps (default :data:`SHIFTED_PCG_MAXITER`)
        by a factor of each column's held system."""
        X2 = self._columns(X)
        if X2.shape[1] != self.mus.size:
            raise ValueError(f"ShiftedPCGFamily.solve: X has {X2.shape[1]} columns, the family {self.mus.size} weights")
        if self.free is None:
            b = np.array(X2)
        else:  # (L^p)_fp X_p: the held rows' values alone through L^p
            held = np.zeros_like(X2)
            held[self._pinned_rows] = X2[self._pinned_rows]
            b = X2[self.free] - self.mus[None, :] * self._power_free(held)
        if not self.size:
            return self._expand(X2, b)
        start = None
        if x0 is not None:
            start = self._columns(x0)
            if start.shape != X2.shape:
                raise ValueError(f"ShiftedPCGFamily.solve: x0 has shape {np.shape(x0)}, X {np.shape(X)}")
            start = start if self.free is None else start[self.free]
        found = _preconditioned_cg(self._product, b, self.precondition, tol,
                                   SHIFTED_PCG_MAXITER if maxiter is None else int(maxiter), start)
        if found is None:  # far from the bound: factorise each column's system
            return np.column_stack([SPDSolver(shifted_matrix(self._ops, mu, self.order), self.pinned).solve(X2[:, j])
                                    for j, mu in enumerate(self.mus)])
        x, self.iterations = found
        return self._expand(X2, x)


def shifted_solver(
    ops: Operators, mu: float, order: int = 1, pinned: np.ndarray | None = None, method: str = "cholesky"
) -> SPDSolver | ShiftedProduct | HeldByProduct | CGSolver:
    """The solver of :math:`(I + \\mu L^p) Y = X` on this topology (pinned rows as Dirichlet data), stored on ``ops``.

    The one place the package builds this family of systems: the Sobolev filters of every
    order and the automatic-parameter searches share its factorisations (the last
    :data:`FACTORS_PER_FAMILY` per (order, method), least recently used first out). From ``p = 3``
    with no pinned rows a ``"cholesky"`` solver factorises the real factors of :math:`1 + \\mu x^p`
    (:func:`shifted_factor`), a third to a quarter of the cost of factorising :math:`I + \\mu L^p`.

    Parameters
    ----------
    ops : Operators
    mu : float, > 0
    order : int, >= 1
        The power ``p`` of ``L = D - W``.
    pinned : ndarray of bool, shape (n,), optional
        Vertices held at their input value.
    method : {"cholesky", "cg", "pcg"}
        A sparse Cholesky factorisation (:class:`SPDSolver`), Jacobi-preconditioned
        block conjugate gradients with no factorisation (:class:`CGSolver`), or conjugate gradients
        preconditioned by one factor of a one-ring matrix (:class:`ShiftedPCG`).

    Examples
    --------
    >>> import numpy as np
    >>> from meshdenoise.operators import Operators
    >>> ops = Operators(np.array([[0, 1, 2], [0, 2, 3]]), 4)
    >>> X = np.eye(4)[:, :3]
    >>> A = np.eye(4) + 0.5 * ops.L.toarray() @ ops.L.toarray()
    >>> bool(np.allclose(A @ shifted_solver(ops, 0.5, order=2).solve(X), X))
    True
    """
    if not (isinstance(mu, (int, float, np.integer, np.floating)) and mu > 0 and np.isfinite(mu)):
        raise ValueError(f"shifted_solver: mu must be a finite number > 0, got {mu!r}")
    if method not in SHIFTED_METHODS:
        raise ValueError(f"shifted_solver: method must be one of {SHIFTED_METHODS}, got {method!r}")
    mu = float(mu)
    if method == "cholesky":
        held = (pinned is not None and 0 < np.count_nonzero(pinned) <= HELD_BY_PRODUCT_MAX_HELD and order >= 3
                and ops.n >= HELD_BY_PRODUCT_MIN_VERTICES)
        return cached_solver(ops, f"shifted-p{order}-{method}", mu, pinned,
                             (lambda: HeldByProduct(ops, mu, order, pinned)) if held
                             else (lambda: shifted_factor(ops, mu, order, pinned)))
    if method == "pcg":
        return cached_solver(ops, f"shifted-p{order}-{method}", mu, pinned, lambda: ShiftedPCG(ops, mu, order, pinned))
    return cached_solver(ops, f"shifted-p{order}-{method}", mu, pinned,
                         lambda: CGSolver(shifted_matrix(ops, mu, order), pinned))

class ShiftedInverse:
    r""":math:`g(x) = x_+^{\mathrm{lift}}\, (1 + \mu x_+^p)^{-\mathrm{power}}` (``power`` 1 or 2, ``lift`` >= 0,
    :math:`x_+ = \max(x, 0)`), the functions of ``L`` the shifted systems and their residuals apply, as a callable that
    :class:`LanczosQuadrature` recognises: its Gauss rules (:meth:`LanczosQuadrature.quadrature`, hence
    :meth:`~LanczosQuadrature.evaluate`) by :meth:`~LanczosQuadrature.shifted_forms`, and at ``power`` 1 its
    coefficients in :meth:`LanczosQuadrature.apply`, by ``p`` tridiagonal solves
    (:func:`~meshdenoise.kernels.shifted_tridiagonal_solves`) and ``lift`` tridiagonal products instead of an
    eigenproblem per column and size. ``lift``: a run on columns :math:`c = L^q X` serves the order ``p > q`` as well,
    :math:`(L^{p-q} c)^T g(L)\, L^{p-q} c = c^T L^{2(p-q)} g(L)\, c`
    (:func:`~meshdenoise.tuning.search.shifted_quadrature`: one run for the weights of orders 2 and 3).

    >>> import numpy as np
    >>> float(ShiftedInverse(2.0, 3)(np.array([1.0]))[0]), float(ShiftedInverse(2.0, 3, 2)(np.array([1.0]))[0])
    (0.3333333333333333, 0.1111111111111111)
    >>> float(ShiftedInverse(2.0, 3, 2, lift=2)(np.array([2.0]))[0])  # 2^2 / (1 + 2 * 8)^2
    0.01384083044982699
    """

    __slots__ = ("mu", "order", "power", "lift")

    def __init__(self, mu: float, order: int, power: int = 1, lift: int = 0):
        if power not in (1, 2):
            raise ValueError(f"ShiftedInverse: power must be 1 or 2, got {power!r}")
        if isinstance(lift, (bool, np.bool_)) or not isinstance(lift, (int, np.integer)) or lift < 0:
            raise ValueError(f"ShiftedInverse: lift must be an int >= 0, got {lift!r}")
        self.mu, self.order, self.power, self.lift = float(mu), int(order), int(power), int(lift)

    def __call__(self, x: np.ndarray) -> np.ndarray:
        x = np.maximum(x, 0.0)
        g = (1.0 / (1.0 + self.mu * x ** self.order)) ** self.power
        return g * x ** self.lift if self.lift else g


def _tridiagonal_times(alpha: np.ndarray, beta: np.ndarray, sizes: np.ndarray, Y: np.ndarray, times: int) -> np.ndarray:
    """``T_j^times Y[:, j]`` for every column ``j``, ``T_j`` the symmetric tridiagonal of its first ``sizes[j]`` steps
    (diagonal ``alpha[:, j]``, off-diagonal ``beta[:, j]``), zero below ``sizes[j]`` (as ``Y`` is); (kmax, c)."""
    if not times:
        return Y
    kmax = Y.shape[0]
    inside = np.arange(kmax)[:, None] < sizes[None, :]
    a, b = np.where(inside, alpha[:kmax], 0.0), np.where(inside[1:], beta[:kmax - 1], 0.0)
    for _ in range(int(times)):
        Z = a * Y
        Z[1:] += b * Y[:-1]
        Z[:-1] += b * Y[1:]
        Y = Z
    return Y


class LanczosQuadrature:
    r"""Gauss quadrature of :math:`b_j^T g(M)\, b_j` for a symmetric ``M``, every column ``b_j`` of ``B``, any ``g``.

    One Lanczos recurrence per column (vectorised over the columns: one threaded sparse
    product :func:`~meshdenoise.operators.spmm` with all columns per step) builds the
    tridiagonal :math:`T_k = Q_k^T M Q_k` of the Krylov space
    :math:`\mathcal K_k(M, b_j)`; with :math:`T_k = U \Theta U^T`,

    .. math:: b^T g(M)\, b \approx \|b\|^2 e_1^T g(T_k) e_1 = \|b\|^2 \sum_{i=1}^k U_{1i}^2\, g(\theta_i),

    the ``k``-point Gauss rule of the spectral measure of ``b`` (Golub and Meurant 1994): exact
    for polynomials of degree ``2k - 1``, so for ``g`` analytic on the spectrum the error falls
    geometrically in ``k``. The nodes and weights do not depend on ``g``: one run serves every
    ``g`` (every candidate weight of a search), and is extended when a new ``g`` needs more
    steps. Without re-orthogonalisation the finite-precision recurrence still gives a Gauss
    rule of a nearby measure (Greenbaum 1989; Golub and Strakos 1994): convergence is delayed,
    not lost. A column whose Krylov space is exhausted (its :math:`\beta` negligible) stops,
    and its rule is then exact.

    Parameters
    ----------
    M : scipy.sparse matrix, shape (n, n), symmetric
    B : ndarray, shape (n, k)
    max_steps : int
        Steps after which :meth:`evaluate` gives up (returns ``None``).

    References
    ----------
    G. H. Golub, G. Meurant, "Matrices, moments and quadrature", 1994.
    G. H. Golub, Z. Strakos, "Estimates in quadratic formulas", Numer. Algorithms 1994.
    A. Greenbaum, "Behavior of slightly perturbed Lanczos and conjugate-gradient recurrences", LAA 1989.

    Examples
    --------
    >>> import numpy as np, scipy.sparse as sp
    >>> M = sp.csr_matrix(np.diag([0.0, 1.0, 2.0, 4.0]))
    >>> q = LanczosQuadrature(M, np.ones((4, 1)))
    >>> round(float(q.evaluate(lambda t: 1.0 / (1.0 + t))[0]), 12)  # 1 + 1/2 + 1/3 + 1/5
    2.033333333333
    """

    def __init__(self, M: sp.spmatrix, B: np.ndarray, *, max_steps: int = 1000):
        M = sp.csr_matrix(M, dtype=np.float64)
        B = np.asarray(B, dtype=np.float64)
        if B.ndim != 2 or B.shape[0] != M.shape[0] or M.shape[0] != M.shape[1]:
            raise ValueError(f"LanczosQuadrature: M {M.shape} and B {B.shape} do not match (M square, B (n, k))")
        if int(max_steps) < 1:
            raise ValueError(f"LanczosQuadrature: max_steps must be at least 1, got {max_steps!r}")
        self.M, self.max_steps = M, int(max_steps)
        self._B = B
        k = B.shape[1]
        self.norms2 = np.einsum("ij,ij->j", B, B)
        self._scale = float(abs(M).sum(axis=1).max()) if M.nnz else 1.0  # ||M||_inf >= |eigenvalues|
        inv = np.divide(1.0, np.sqrt(self.norms2), out=np.zeros(k), where=self.norms2 > 0)
        self._q = B * inv
        self._q_prev = np.zeros_like(self._q)
        self._beta_prev = np.zeros(k)
        self._active = self.norms2 > 0
        self.lengths = np.zeros(k, dtype=np.int64)  # Lanczos steps per column (size of its T)
        self._alpha = np.zeros((0, k))
        self._beta = np.zeros((0, k))
        self._nodes: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}

    @property
    def steps(self) -> int:
        """Steps run so far (sparse products with all columns)."""
        return self._alpha.shape[0]

    @property
    def nbytes(self) -> int:
        """Bytes of the run's own arrays: its columns, its two last basis vectors and the recurrence so far (a kept
        basis too, :class:`CompiledLanczos`; the matrix is the caller's)."""
        arrays = (self._B, self._q, self._q_prev, self._alpha, self._beta, getattr(self, "_basis", None))
        return int(sum(a.nbytes for a in arrays if a is not None))

    def extend(self, steps: int) -> None:
        """Run ``steps`` more Lanczos steps on the columns still active."""
        k = self._q.shape[1]
        alphas, betas = np.zeros((steps, k)), np.zeros((steps, k))
        W = np.empty_like(self._q)
        tmp = np.empty_like(self._q)  # the products below written in place: the same operations, no new arrays
        for i in range(steps):
            if not self._active.any():
                alphas, betas = alphas[:i], betas[:i]
                break
            spmm(self.M, self._q, out=W)
            a = np.einsum("ij,ij->j", self._q, W)
            W -= np.multiply(self._q, a, out=tmp)
            W -= np.multiply(self._q_prev, self._beta_prev, out=tmp)
            b = np.sqrt(np.einsum("ij,ij->j", W, W))
            a[~self._active] = 0.0
            alphas[i] = a
            self.lengths[self._active] += 1
            self._active &= b > 1e-13 * self._scale  # an exhausted Krylov space: the rule is exact
            b[~self._active] = 0.0
            betas[i] = b
            inv = np.divide(1.0, b, out=np.zeros(k), where=self._active)
            q_next = np.multiply(W, inv, out=self._q_prev)  # q_prev is not needed any more: its buffer takes q_next
            self._q_prev, self._q = self._q, q_next
            self._beta_prev = b
        self._alpha = np.vstack([self._alpha, alphas])
        self._beta = np.vstack([self._beta, betas])

    def nodes(self, j: int, k: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Nodes :math:`\\theta_i` and weights :math:`\\|b_j\\|^2 U_{1i}^2` of column ``j``'s ``k``-step rule (default: all)."""
        k = int(self.lengths[j]) if k is None else max(0, min(int(k), int(self.lengths[j])))
        if (j, k) not in self._nodes:
            if k == 0:
                self._nodes[(j, k)] = (np.zeros(0), np.zeros(0))
            else:
                from scipy.linalg import eigh_tridiagonal

                theta, U = eigh_tridiagonal(self._alpha[:k, j], self._beta[: k - 1, j])
                self._nodes[(j, k)] = (theta, self.norms2[j] * U[0] ** 2)
        return self._nodes[(j, k)]

    def quadrature(self, g: Callable[[np.ndarray], np.ndarray], columns=None, k: int | None = None) -> np.ndarray:
        """The ``k``-step rule (default: all steps run) of ``g`` on ``columns`` (default all), shape (len(columns),)."""
        if isinstance(g, ShiftedInverse):  # no eigenproblem: tridiagonal solves
            return self.shifted_forms(g.mu, g.order, g.power, columns, k, g.lift)
        cols = range(self._q.shape[1]) if columns is None else columns
        out = []
        for j in cols:
            theta, w = self.nodes(j, k)
            out.append(float(np.dot(w, g(theta))) if w.size else 0.0)
        return np.array(out)

    def evaluate(self, g: Callable[[np.ndarray], np.ndarray], columns=None, *, rtol: float = 1e-10,
                 check: int = 10, growth: float = 0.0,
                 scale: Callable[[int], np.ndarray] | None = None) -> np.ndarray | None:
        """:math:`b_j^T g(M) b_j` on ``columns``, extending the recurrence until converged.

        Converged when the rule changes by at most ``rtol`` (relative, per column) over the
        last ``check`` steps (the error falls geometrically, so the last rule is several times
        closer); ``None`` if :attr:`max_steps` is reached first. ``growth`` > 0: after a failed test the run is
        extended by ``max(check, growth x steps)`` steps (as for :meth:`_converged_coefficients`: each test solves
        every column's tridiagonal eigenproblem at a new size). ``scale(k)`` (optional): per column, what the change
        is relative to after ``k`` steps instead of the rule itself (a dual's Cauchy-Schwarz scale,
        :class:`~meshdenoise.tuning.spectral.StartDual`).
        """
        cols = list(range(self._q.shape[1])) if columns is None else list(columns)
        if self.steps < check:
            self.extend(check - self.steps)
        while True:
            k = self.steps
            now = self.quadrature(g, cols, k)
            before = self.quadrature(g, cols, k - check)
            done = ~self._active[cols]
            if np.all(done | (np.abs(now - before) <= rtol * (np.abs(now) if scale is None else scale(k)))):
                return now
            if k >= self.max_steps:
                return None
            self.extend(min(max(check, int(growth * k)), self.max_steps - k))

    def shifted_forms(self, mu: float, order: int, power: int, columns=None, k: int | None = None,
                      lift: int = 0) -> np.ndarray:
        """The ``k``-step rules (default: all steps run) of :math:`g(x) = x^l (1 + \\mu x^p)^{-\\mathrm{power}}` on
        ``columns`` (default all), ``power`` 1 or 2, ``l = lift`` >= 0 (:class:`ShiftedInverse`), without an
        eigenproblem: with :math:`y = (I + \\mu T^p)^{-1} e_1`
        (:func:`~meshdenoise.kernels.shifted_tridiagonal_solves`, ``p`` tridiagonal solves: time linear in ``k``,
        where :meth:`nodes` solves an eigenproblem, time about ``k^2``) and :math:`u = T^{\\lfloor l/2 \\rfloor} y`,
        :math:`\\|b_j\\|^2 e_1^T g(T) e_1` is :math:`\\|b_j\\|^2 (T^l y)_1` (power 1) or :math:`\\|b_j\\|^2 u^T T^{l \\bmod 2} u`
        (power 2): :meth:`quadrature` of a :class:`ShiftedInverse`.
        The same numbers as the eigenvalue route for that ``g`` up to rounding, shape (len(columns),)."""
        if power not in (1, 2):
            raise ValueError(f"shifted_forms: power must be 1 or 2, got {power!r}")
        if isinstance(lift, (bool, np.bool_)) or not isinstance(lift, (int, np.integer)) or lift < 0:
            raise ValueError(f"shifted_forms: lift must be an int >= 0, got {lift!r}")
        cols = np.arange(self._q.shape[1]) if columns is None else np.asarray(list(columns), dtype=np.int64)
        steps = self.steps if k is None else max(0, min(int(k), self.steps))
        sizes = np.minimum(self.lengths[cols], steps).astype(np.int64)
        kmax = int(sizes.max()) if sizes.size else 0
        if not kmax:
            return np.zeros(cols.size)
        out = np.zeros((kmax, cols.size))
        alpha, beta = np.ascontiguousarray(self._alpha[:kmax, cols]), np.ascontiguousarray(self._beta[:kmax, cols])
        if mu == 0.0:  # g = x^lift: y = e_1 (the recurrences' roots would be at infinity)
            out[0, sizes > 0] = 1.0
        else:
            kernels.shifted_tridiagonal_solves(alpha, beta, sizes, float(mu), int(order), out)
        if power == 1:
            return self.norms2[cols] * _tridiagonal_times(alpha, beta, sizes, out, lift)[0]
        u = _tridiagonal_times(alpha, beta, sizes, out, lift // 2)
        return self.norms2[cols] * np.einsum("ij,ij->j", u, _tridiagonal_times(alpha, beta, sizes, u, lift % 2))

    def _coefficients(self, g: Callable[[np.ndarray], np.ndarray], j: int, k: int) -> np.ndarray:
        """:math:`\\|b_j\\| U g(\\Theta) U^T e_1` of column ``j``'s ``k``-step rule (length ``k``)."""
        from scipy.linalg import eigh_tridiagonal

        k = max(0, min(int(k), int(self.lengths[j])))
        if k == 0:
            return np.zeros(0)
        if isinstance(g, ShiftedInverse) and g.power == 1:
            return self._shifted_coefficients(g, j, k)
        theta, U = eigh_tridiagonal(self._alpha[:k, j], self._beta[: k - 1, j])
        return math.sqrt(self.norms2[j]) * (U @ (g(theta) * U[0]))

    def _shifted_coefficients(self, g: ShiftedInverse, j: int, k: int) -> np.ndarray:
        """:meth:`_coefficients` of a :class:`ShiftedInverse` (power 1): :math:`\\|b_j\\| T_k^l (I + \\mu T_k^p)^{-1} e_1`,
        ``k >= 1``, ``l = g.lift``."""
        out = np.zeros((k, 1))
        alpha, beta = np.ascontiguousarray(self._alpha[:k, j:j + 1]), np.ascontiguousarray(self._beta[:k, j:j + 1])
        sizes = np.array([k], dtype=np.int64)
        if g.mu == 0.0:  # g = x^lift: (I + 0)^-1 e_1 = e_1
            out[0, 0] = 1.0
        else:
            kernels.shifted_tridiagonal_solves(alpha, beta, sizes, g.mu, g.order, out)
        return math.sqrt(self.norms2[j]) * _tridiagonal_times(alpha, beta, sizes, out, g.lift)[:, 0]

    def _converged_coefficients(self, g: Callable[[np.ndarray], np.ndarray], rtol: float, check: int,
                                columns=None, growth: float = 0.0) -> list[np.ndarray] | None:
        """Every column's coefficients :meth:`_coefficients`, the run extended until none of the active
        columns' changes by more than ``rtol`` (relative, in norm) over the last ``check`` steps; ``None``
        if :attr:`max_steps` is reached first. ``columns`` (default all): those columns only, in that
        order. ``growth`` > 0: after a
        failed test the run is extended by ``max(check, growth x steps)`` steps instead of ``check`` (the
        test itself is the same): each test solves tridiagonal eigenproblems of the run's size (time
        about ``k^2``), so tests every ``check`` steps cost about ``k^3 / (3 check)`` in all (0.8 s per
        test at 1,200 steps: minutes), tests at geometrically growing sizes a few ``k^2``, for at most
        a share ``growth`` more steps than the old schedule would run."""
        cols = list(range(self._q.shape[1])) if columns is None else [int(j) for j in columns]
        if self.steps < check:
            self.extend(check - self.steps)
        while True:
            k = self.steps
            ok = True
            coef = []
            for j in cols:
                now = self._coefficients(g, j, k)
                before = self._coefficients(g, j, k - check)
                diff = now.copy()
                diff[: before.size] -= before
                if self._active[j] and np.linalg.norm(diff) > rtol * np.linalg.norm(now):
                    ok = False
                coef.append(now)
            if ok:
                return coef
            if k >= self.max_steps:
                return None
            self.extend(min(max(check, int(growth * k)), self.max_steps - k))

    def apply(self, g: Callable[[np.ndarray], np.ndarray], *, rtol: float = 1e-10, check: int = 10, columns=None,
              growth: float = 0.0) -> np.ndarray | None:
        """:math:`g(M)\\, B` (n, k) by the Lanczos approximation :math:`\\|b\\| Q_k\\, g(T_k)\\, e_1`, per column.

        The coefficients in the Lanczos basis are extended until they change by at most
        ``rtol`` (relative, in norm) over the last ``check`` steps (``None`` if
        :attr:`max_steps` is reached first); then a second pass regenerates the basis
        vectors from the stored recurrence (nothing of size ``n x steps`` is kept) and sums
        them. Two passes of sparse products, no factorisation.

        ``columns`` (sequence of int, optional): only those columns of ``B``, in that order (the
        result is ``(n, len(columns))``; the second pass runs on them alone), e.g. the
        coordinates' columns of a run that also holds trace probes.
        ``growth``: the spacing of the convergence tests (:meth:`_converged_coefficients`).
        """
        cols = list(range(self._q.shape[1])) if columns is None else [int(j) for j in columns]
        kcols = len(cols)
        coef = self._converged_coefficients(g, rtol, check, None if columns is None else cols, growth)
        if coef is None:
            return None
        B = self._B if columns is None else np.ascontiguousarray(self._B[:, cols])
        norms2 = self.norms2[cols]
        alpha, beta = (self._alpha, self._beta) if columns is None else (self._alpha[:, cols], self._beta[:, cols])
        inv = np.divide(1.0, np.sqrt(norms2), out=np.zeros(kcols), where=norms2 > 0)
        q_prev, q = np.zeros_like(B), B * inv
        beta_prev = np.zeros(kcols)
        out = np.zeros_like(B)
        W = np.empty_like(q)
        tmp = np.empty_like(q)  # in place, the same operations as q * y etc.: no new array per step
        for i in range(max(c.size for c in coef) if coef else 0):
            y = np.array([c[i] if i < c.size else 0.0 for c in coef])
            out += np.multiply(q, y, out=tmp)
            spmm(self.M, q, out=W)
            W -= np.multiply(q, alpha[i], out=tmp)
            W -= np.multiply(q_prev, beta_prev, out=tmp)
            b = beta[i]
            inv = np.divide(1.0, b, out=np.zeros(kcols), where=b > 0)
            q_prev, q = q, np.multiply(W, inv, out=q_prev)
            beta_prev = b
        return out


def shifted_cg_bound(ops: Operators, mu: float, order: int, tol: float) -> float:
    r"""Iterations CG needs at most for :math:`I + \mu L^p` (up to rounding): :math:`\tfrac12\sqrt\kappa\,\ln(2/\mathrm{tol})`,
    :math:`\kappa \le 1 + \mu (2 d_{max})^p` (the eigenvalues of ``L`` are at most :math:`2 d_{max}`, Gershgorin).

    >>> from meshdenoise.operators import Operators
    >>> import numpy as np
    >>> round(shifted_cg_bound(Operators(np.array([[0, 1, 2]]), 3), 1.0, 2, 1e-10))  # d_max 2: kappa <= 17
    49
    """
    d_max = float(ops.degree.max()) if ops.n else 0.0
    return 0.5 * math.sqrt(1.0 + mu * (2.0 * d_max) ** order) * math.log(2.0 / tol)


LANCZOS_SHIFTED_MAX_STEPS = 2000  # lanczos_shifted gives up (returns None) after this many steps
FILTER_LANCZOS_TOL = 1e-10  # the factor-free filters' lanczos_shifted tolerance: over 10 steps the coefficients' change
# levels off at 3e-12 to 6e-12 of their norm (the recurrence's rounding, no reorthogonalisation) on a 51,200-vertex torus at
# mu = 6,522, order 3, so 1e-12 was never met there and the filter fell back to a factorisation of I + mu L^3 (minutes);
# 1e-10 of the correction mu f(L) L^p X (noise-sized) is far below anything a filter result shows
DRAFT_LANCZOS_TOL = 1e-6  # ... and on a run that only stands for the border option's free pass (a core's ``rough``):
# its result is read for the border's normal moves and as the held run's start or draft, the held run solving to its
# own tolerance. face000 (p = 3): sobolev_gls' draft at mu 34 0.68 -> 0.47 s, 3e-7 of the mean move from 1e-10's;
# sobolev_axes' three axes 187 -> 120 steps, 0.57 -> 0.33 s, 2e-6 of the mean move

def lanczos_shifted(ops: Operators, X: np.ndarray, mu: float, order: int, tol: float = 1e-10,
                    max_steps: int = LANCZOS_SHIFTED_MAX_STEPS, growth: float = 0.0) -> np.ndarray | None:
    """:math:`(I + \\mu L^p)^{-1} X` by two Lanczos passes on ``L``, no factorisation, no pinned rows.

    .. math:: (I + \\mu L^p)^{-1} X = X - \\mu\\, f(L)\\, L^p X, \\qquad f(t) = \\frac{1}{1 + \\mu t^p},

    the correction by the Lanczos approximation :math:`\\|c\\|\\, Q_k f(T_k) e_1` of each column
    ``c`` of :math:`L^p X` (:meth:`LanczosQuadrature.apply`, the basis regenerated in a second pass:
    nothing of size ``n x k`` kept). The poles of ``f`` lie at distance about :math:`\\mu^{-1/p}` from
    the spectrum of ``L``, so the steps grow like :math:`\\mu^{1/(2p)}` (times a log), where CG on
    :math:`I + \\mu L^p` needs about :math:`\\sqrt{\\mu}\\,(2 d_{max})^{p/2}` iterations of ``p``
    products each. Converged when the Lanczos coefficients change by less than ``tol`` (relative)
    over 10 steps; ``None`` when ``max_steps`` is reached first. The order-2 case is
    :func:`meshdenoise.plugins.sobolev_bilaplacian.lanczos_bilaplacian`.

    Parameters
    ----------
    ops : Operators
    X : ndarray, shape (n,) or (n, k)
    mu : float, > 0
    order : int, >= 1
    tol : float in (0, 1)
    max_steps : int, >= 1
    growth : float, >= 0
        Spacing of the convergence tests (:meth:`LanczosQuadrature.apply`): 0 tests every 10 steps.

    Returns
    -------
    ndarray of the shape of ``X``, or None

    Examples
    --------
    >>> import numpy as np
    >>> from meshdenoise.shapes import icosphere
    >>> from meshdenoise.operators import get_operators
    >>> V, F = icosphere(2)
    >>> ops = get_operators(F, len(V))
    >>> Y = lanczos_shifted(ops, V, 0.5, 3)
    >>> A = np.eye(len(V)) + 0.5 * np.linalg.matrix_power(ops.L.toarray(), 3)
    >>> bool(np.allclose(A @ Y, V, atol=1e-9))
    True
    """
    if not (isinstance(mu, (int, float, np.integer, np.floating)) and mu > 0 and np.isfinite(mu)):
        raise ValueError(f"lanczos_shifted: mu must be a finite number > 0, got {mu!r}")
    if isinstance(order, (bool, np.bool_)) or not isinstance(order, (int, np.integer)) or order < 1:
        raise ValueError(f"lanczos_shifted: order must be an int >= 1, got {order!r}")
    if not (isinstance(tol, (float, int)) and 0 < tol < 1):
        raise ValueError(f"lanczos_shifted: tol must be a number in (0, 1), got {tol!r}")
    X = np.asarray(X, dtype=np.float64)
    X2 = X.reshape(X.shape[0], -1)
    c = X2
    for _ in range(int(order)):
        c = spmm(ops.L, np.ascontiguousarray(c))
    p = int(order)
    mu = float(mu)
    Y = LanczosQuadrature(ops.L, c, max_steps=max_steps).apply(ShiftedInverse(mu, p), rtol=tol, growth=growth)
    if Y is None:
        return None
    return (X2 - mu * Y).reshape(X.shape)

class LanczosRows(LanczosQuadrature):
    r""":math:`g(M)\, B` on a few rows only, for any ``g``, from one Lanczos run that keeps those rows of its basis.

    The Lanczos approximation :math:`g(M) b \approx \|b\|\, Q_k\, g(T_k)\, e_1` (as
    :meth:`LanczosQuadrature.apply`) needs the basis :math:`Q_k` only at the rows wanted: they are
    recorded as the recurrence runs (``len(rows) x steps`` per column, nothing of size
    ``n x steps``), so every further ``g`` (every candidate weight of a search) costs a few small
    tridiagonal eigenproblems and no sparse product unless the run must be extended.

    Parameters
    ----------
    M : scipy.sparse matrix, shape (n, n), symmetric
    B : ndarray, shape (n, k)
    rows : ndarray of int, shape (r,)
    max_steps : int

    Examples
    --------
    >>> import numpy as np, scipy.sparse as sp
    >>> M = sp.csr_matrix(np.diag([0.0, 1.0, 2.0, 4.0]))
    >>> run = LanczosRows(M, np.ones((4, 1)), np.array([1, 3]))
    >>> np.round(run.rows_apply(lambda t: 1.0 / (1.0 + t)).ravel(), 12).tolist()
    [0.5, 0.2]
    """

    def __init__(self, M: sp.spmatrix, B: np.ndarray, rows: np.ndarray, *, max_steps: int = 1000):
        super().__init__(M, B, max_steps=max_steps)
        self.rows = np.asarray(rows, dtype=np.int64)
        self._kept: list[np.ndarray] = []  # q_i at the rows, (r, k) per step

    def extend(self, steps: int) -> None:
        """Run ``steps`` more steps, recording the basis vectors at :attr:`rows`."""
        for _ in range(int(steps)):
            before = self.steps
            self._kept.append(self._q[self.rows].copy())
            super().extend(1)
            if self.steps == before:  # every column exhausted: nothing was run
                self._kept.pop()
                break

    def rows_apply(self, g: Callable[[np.ndarray], np.ndarray], *, rtol: float = 1e-10,
                   check: int = 10, growth: float = 0.0) -> np.ndarray | None:
        """:math:`(g(M) B)` at :attr:`rows`, shape (r, k); converged as :meth:`LanczosQuadrature.apply`, else ``None``."""
        kcols = self._q.shape[1]
        coef = self._converged_coefficients(g, rtol, check, growth=growth)
        if coef is None:
            return None
        out = np.zeros((self.rows.size, kcols))
        for j, c in enumerate(coef):
            if c.size:
                out[:, j] = np.stack([q[:, j] for q in self._kept[: c.size]], axis=1) @ c
        return out


def column_function(g: Callable | Sequence[Callable], j: int) -> Callable:
    """``g``, or column ``j``'s function ``g[j % len(g)]`` of a sequence of functions (one per axis of a frame).

    >>> column_function((abs, round), 3) is round
    True
    """
    return g if callable(g) else g[j % len(g)]


REGENERATE_RING_BYTES = 128 * 2**20  # CompiledLanczos.apply_many: the ring of basis vectors whose accumulation into
# several functions' results is done at once (at most this many bytes; below three vectors, one accumulation per step)


class CompiledLanczos(LanczosQuadrature):
    r""":class:`LanczosQuadrature` whose steps are compiled passes over the rows, both passes of :meth:`apply` alike.

    Each step is :func:`~meshdenoise.kernels.lanczos_product` (:math:`W = MQ`, the :math:`\alpha` sums),
    :func:`~meshdenoise.kernels.lanczos_update` (the three-term recurrence, the :math:`\beta` sums) and
    :func:`~meshdenoise.kernels.lanczos_scale`, on numba's threads, the sums by fixed blocks of rows
    (:data:`~meshdenoise.kernels.CG_BLOCK`: the same numbers on any thread count); the second pass of
    :meth:`apply` does their arithmetic in one sweep of the rows per step with the first pass's :math:`\alpha`,
    :math:`\beta` (:func:`~meshdenoise.kernels.lanczos_regenerate`, the results summed in the same sweep), so it
    regenerates the first pass's basis to the bit. Per step
    a few compiled passes where the numpy recurrence makes about ten, with no Python work per column
    (the spectral searches run hundreds of steps, :mod:`meshdenoise.tuning.spectral`). The numbers
    differ from :class:`LanczosQuadrature`'s in the last places (sums in another order).

    Parameters
    ----------
    M : scipy.sparse matrix, shape (n, n), symmetric
    B : ndarray, shape (n, k)
    max_steps : int
    duals : sequence of ndarray, each (n, k), optional
        Their projections on each basis vector are recorded as the run goes (:class:`LanczosDots`).
    keep_basis : int
        Bytes of basis vectors kept as the run goes (default 0: none): while the run's basis fits,
        :meth:`apply_many` sums the kept vectors (the same numbers to the bit) instead of regenerating them by a
        second pass of sparse products; a run that outgrows it drops them and regenerates. Held by the object,
        freed with it (a search asking many functions of one run: :class:`~meshdenoise.tuning.spectral.SpectralSearch`).

    Examples
    --------
    >>> import numpy as np, scipy.sparse as sp
    >>> M = sp.csr_matrix(np.diag([0.0, 1.0, 2.0, 4.0]))
    >>> np.round(CompiledLanczos(M, np.ones((4, 1))).apply(lambda t: 1.0 / (1.0 + t)).ravel(), 12).tolist()
    [1.0, 0.5, 0.333333333333, 0.2]
    """

    def __init__(self, M: sp.spmatrix, B: np.ndarray, *, max_steps: int = 1000, duals: Sequence[np.ndarray] = (),
                 keep_basis: int = 0):
        super().__init__(M, B, max_steps=max_steps)
        n, k = self._B.shape
        if isinstance(keep_basis, (bool, np.bool_)) or not isinstance(keep_basis, (int, np.integer)) or keep_basis < 0:
            raise ValueError(f"CompiledLanczos: keep_basis must be an int >= 0 (bytes), got {keep_basis!r}")
        budget = int(keep_basis)
        # the kept basis q_0, q_1, ... (allocated as it fills: pages are touched only as vectors are written)
        self._basis_cap = min(budget // max(8 * n * k, 1), self.max_steps + 1)
        self._basis: np.ndarray | None = np.empty((self._basis_cap, n, k)) if self._basis_cap >= 2 else None
        self._kept = 0
        self._keep(np.ascontiguousarray(self._q))
        self.M.sort_indices()
        self._U = np.ascontiguousarray(np.stack([np.asarray(U, dtype=np.float64) for U in duals])) if len(duals) \
            else np.zeros((0, n, k))
        if self._U.shape[1:] != (n, k):
            raise ValueError(f"CompiledLanczos: a dual has shape {self._U.shape[1:]}, B {(n, k)}")
        self._blocks = (n + kernels.CG_BLOCK - 1) // kernels.CG_BLOCK
        self._proj: list[np.ndarray] = []  # per step, (duals, k): u_j . q_i
        self._eig: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}
        self._q = np.ascontiguousarray(self._q)
        self._q_prev = np.ascontiguousarray(self._q_prev)

    def _step(self, q: np.ndarray, q_prev: np.ndarray, W: np.ndarray, alpha: np.ndarray | None, beta_prev: np.ndarray,
              duals: bool = False):
        """One step into ``W``: returns ``(alpha, beta, projections)`` (``alpha`` summed here unless given)."""
        k = q.shape[1]
        U = self._U if duals else self._U[:0]
        pa, pd, pb = np.empty((self._blocks, k)), np.empty((U.shape[0], self._blocks, k)), np.empty((self._blocks, k))
        kernels.lanczos_product(self.M.indptr, self.M.indices, self.M.data, q, W, U, pa, pd)
        if alpha is None:
            alpha = pa.sum(axis=0)
        kernels.lanczos_update(q, q_prev, W, alpha, beta_prev, pb)
        return alpha, np.sqrt(pb.sum(axis=0)), pd.sum(axis=1)

    def _keep(self, q: np.ndarray) -> None:
        """Keep basis vector ``q`` while they fit in ``keep_basis`` bytes, else drop them all."""
        if self._basis is None:
            return
        if self._kept >= self._basis_cap:
            self._basis = None  # outgrown: apply_many regenerates
            return
        self._basis[self._kept] = q
        self._kept += 1

    def extend(self, steps: int) -> None:
        """Run ``steps`` more steps on the columns still active (recording the duals' projections)."""
        kernels.set_threads()
        k = self._q.shape[1]
        alphas, betas = np.zeros((steps, k)), np.zeros((steps, k))
        W = np.empty_like(self._q)
        for i in range(steps):
            if not self._active.any():
                alphas, betas = alphas[:i], betas[:i]
                break
            a, b, proj = self._step(self._q, self._q_prev, W, None, self._beta_prev, duals=True)
            a[~self._active] = 0.0
            alphas[i] = a
            self._proj.append(proj)
            self.lengths[self._active] += 1
            self._active &= b > 1e-13 * self._scale  # an exhausted Krylov space: the rule is exact
            b[~self._active] = 0.0
            betas[i] = b
            inv = np.divide(1.0, b, out=np.zeros(k), where=self._active)
            kernels.lanczos_scale(W, inv, self._q_prev)  # q_prev is not needed any more: its buffer takes q_next
            self._q_prev, self._q = self._q, self._q_prev
            self._beta_prev = b
            self._keep(self._q)
        self._alpha = np.vstack([self._alpha, alphas])
        self._beta = np.vstack([self._beta, betas])

    def _coefficients(self, g: Callable[[np.ndarray], np.ndarray], j: int, k: int) -> np.ndarray:
        """:meth:`LanczosQuadrature._coefficients`, the tridiagonal eigenproblems kept per (column, size): a search asks
        every candidate at the run's few sizes (a bounded number kept, the newest)."""
        k = max(0, min(int(k), int(self.lengths[j])))
        if k == 0:
            return np.zeros(0)
        f = column_function(g, j)
        if isinstance(f, ShiftedInverse) and f.power == 1:
            return self._shifted_coefficients(f, j, k)
        if (j, k) not in self._eig:
            from scipy.linalg import eigh_tridiagonal

            if len(self._eig) >= 4 * self._B.shape[1]:
                self._eig.clear()
            self._eig[(j, k)] = eigh_tridiagonal(self._alpha[:k, j], self._beta[: k - 1, j])
        theta, U = self._eig[(j, k)]
        return math.sqrt(self.norms2[j]) * (U @ (column_function(g, j)(theta) * U[0]))

    def apply(self, g: Callable[[np.ndarray], np.ndarray], *, rtol: float = 1e-10, check: int = 10, columns=None,
              growth: float = 0.0) -> np.ndarray | None:
        """:meth:`LanczosQuadrature.apply`, its second pass compiled (on ``columns`` alone when given: each
        column's basis depends on its own recurrence only)."""
        out = self.apply_many([g], rtol=rtol, check=check, growth=growth, columns=columns)
        return None if out is None else out[0]

    def apply_many(self, gs: Sequence[Callable | Sequence[Callable]], *, rtol: float = 1e-10, check: int = 10,
                   growth: float = 0.0, columns=None) -> list[np.ndarray] | None:
        """:meth:`apply` for each function of ``gs``, in one second pass (each converged as :meth:`apply`;
        ``None`` if one is not within :attr:`max_steps`). An entry of ``gs`` may be a sequence of functions,
        column ``j`` then taking ``g[j % len(g)]`` (:func:`column_function`). ``columns``: those columns
        only, in that order (the result ``(n, len(columns))`` each). The results are views of one
        ``(len(gs), n, k)`` array (no copies: a caller keeping one keeps them all)."""
        cols = list(range(self._B.shape[1])) if columns is None else [int(j) for j in columns]
        coefs = []
        for g in gs:
            coef = self._converged_coefficients(g, rtol, check, cols, growth)
            if coef is None:
                return None
            # the coefficients fall geometrically: the steps past where their tail is under rtol / 10 of their norm
            # change nothing the test could see, and a run extended for a stronger function has many of them
            for j, c in enumerate(coef):
                tail = np.sqrt(np.cumsum((c * c)[::-1]))[::-1]  # tail[i]: the norm of c[i:]
                keep = int(np.count_nonzero(tail > 0.1 * rtol * tail[0])) if c.size else 0
                coef[j] = c[:max(keep, 1)] if c.size else c
            coefs.append(coef)
        kernels.set_threads()
        n, k = self._B.shape[0], len(cols)
        B = self._B if columns is None else np.ascontiguousarray(self._B[:, cols])
        norms2, alpha, beta = self.norms2[cols], self._alpha[:, cols], self._beta[:, cols]
        steps = max((c.size for coef in coefs for c in coef), default=0)
        Y = np.zeros((steps, len(gs), k))  # the coefficients of step i, per function and column
        for m, coef in enumerate(coefs):
            for j, c in enumerate(coef):
                Y[: c.size, m, j] = c
        inv = np.divide(1.0, np.sqrt(norms2), out=np.zeros(k), where=norms2 > 0)
        out = np.zeros((len(gs), n, k))
        if self._basis is not None and 0 < steps <= self._kept:  # the first pass's basis, kept: no second pass
            basis = self._basis if columns is None else np.ascontiguousarray(self._basis[:steps][:, :, cols])
            kernels.lanczos_accumulate_steps(basis, np.arange(steps, dtype=np.int64), np.ascontiguousarray(Y), out)
            return list(out)
        M = self.M
        depth = int(REGENERATE_RING_BYTES // max(8 * n * k, 1)) - 2  # steps accumulated at once
        if len(gs) > 1 and depth >= 2:
            return list(self._regenerate_by_blocks(B * inv, alpha, beta, Y, out, min(depth, max(steps, 1))))
        q_prev, q = np.zeros_like(B), np.ascontiguousarray(B * inv)
        beta_prev = np.zeros(k)
        for i in range(steps):  # accumulate, product, recurrence and scaling in one sweep: the first pass's basis
            b = np.ascontiguousarray(beta[i])
            kernels.lanczos_regenerate(M.indptr, M.indices, M.data, q, q_prev, np.ascontiguousarray(alpha[i]), beta_prev,
                                       np.divide(1.0, b, out=np.zeros(k), where=b > 0), np.ascontiguousarray(Y[i]), out)
            q_prev, q = q, q_prev
            beta_prev = b
        return list(out)

    def _regenerate_by_blocks(self, q0: np.ndarray, alpha: np.ndarray, beta: np.ndarray, Y: np.ndarray, out: np.ndarray,
                              depth: int) -> np.ndarray:
        """:meth:`apply_many`'s second pass for several functions: the basis vectors kept in a ring of ``depth + 2``
        buffers (:func:`~meshdenoise.kernels.lanczos_next`) and ``out`` accumulated every ``depth`` steps
        (:func:`~meshdenoise.kernels.lanczos_accumulate_steps`, the steps in order: the same numbers as one
        accumulation per step), so that ``out``, ``len(Y[0])`` times the basis, is read and written once per
        ``depth`` steps instead of every step (the bunny scanner's ten candidates of ``sobolev_normal``: 1.29 s)."""
        M = self.M
        steps, k = Y.shape[0], q0.shape[1]
        ring = np.zeros((depth + 2,) + q0.shape)
        ring[0] = q0
        beta_prev = np.zeros(k)
        done = 0  # steps accumulated
        for i in range(steps):
            b = np.ascontiguousarray(beta[i])
            if i + 1 - done > depth:  # the ring is about to overwrite a step not accumulated yet
                slots = np.array([s % (depth + 2) for s in range(done, i)], dtype=np.int64)
                kernels.lanczos_accumulate_steps(ring, slots, np.ascontiguousarray(Y[done:i]), out)
                done = i
            kernels.lanczos_next(M.indptr, M.indices, M.data, ring[i % (depth + 2)], ring[(i - 1) % (depth + 2)],
                                 np.ascontiguousarray(alpha[i]), beta_prev, np.divide(1.0, b, out=np.zeros(k), where=b > 0),
                                 ring[(i + 1) % (depth + 2)])
            beta_prev = b
        if steps > done:
            slots = np.array([s % (depth + 2) for s in range(done, steps)], dtype=np.int64)
            kernels.lanczos_accumulate_steps(ring, slots, np.ascontiguousarray(Y[done:steps]), out)
        return out


class LanczosDots(CompiledLanczos):
    r""":math:`u_j^T g(M)\, b_j` for every column :math:`b_j` of ``B`` and its dual columns :math:`u_j`, any ``g``,
    from one Lanczos run that records the duals' projections on its basis.

    The Lanczos approximation :math:`g(M)\, b \approx \|b\|\, Q_k\, g(T_k)\, e_1`
    (:meth:`LanczosQuadrature.apply`) dotted with ``u`` needs only :math:`Q_k^T u`: the
    projections are summed as the recurrence runs (``k`` numbers per column and dual, nothing of
    size ``n x k``; :class:`CompiledLanczos`), so every further ``g`` (every candidate weight of a
    search) costs one small tridiagonal eigenproblem per column (kept per size; ``p`` tridiagonal solves for a
    :class:`ShiftedInverse`) and no sparse product unless the run must be extended. With :math:`T_k = U \Theta U^T`:

    .. math:: u^T g(M)\, b \approx \|b\| \sum_{i=1}^k (U^T Q_k^T u)_i\; g(\theta_i)\; U_{1i}

    Parameters
    ----------
    M : scipy.sparse matrix, shape (n, n), symmetric
    B : ndarray, shape (n, k)
    duals : sequence of ndarray, each of shape (n, k)
        Column ``j`` of each is dotted with :math:`g(M) b_j`.
    max_steps : int

    Examples
    --------
    >>> import numpy as np, scipy.sparse as sp
    >>> M = sp.csr_matrix(np.diag([0.0, 1.0, 2.0, 4.0]))
    >>> run = LanczosDots(M, np.ones((4, 1)), [np.array([[1.0], [0.0], [0.0], [2.0]])])
    >>> np.round(run.dots(lambda t: 1.0 / (1.0 + t)), 12).tolist()  # 1 + 2/5
    [[1.4]]
    """

    def __init__(self, M: sp.spmatrix, B: np.ndarray, duals: Sequence[np.ndarray], *, max_steps: int = 1000):
        B = np.asarray(B, dtype=np.float64)
        for U in duals:
            if np.shape(U) != B.shape:
                raise ValueError(f"LanczosDots: a dual has shape {np.shape(U)}, B {B.shape}")
        super().__init__(M, B, max_steps=max_steps, duals=duals)
        self.dual_norms = np.sqrt(np.einsum("fij,fij->fj", self._U, self._U))
        self._rules: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        self._stacked = np.zeros((0, self._U.shape[0], self._B.shape[1]))

    def _rules_at(self, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every column's rule after ``k`` steps (a shorter column's padded with zero weights): nodes (columns, k),
        :math:`\\|b\\| U_{1i}` (columns, k) and the duals' :math:`U^T Q_k^T u` (duals, columns, k); the last few sizes kept."""
        if k not in self._rules:
            from scipy.linalg import eigh_tridiagonal

            ncols, duals = self._q.shape[1], self._U.shape[0]
            if self._stacked.shape[0] != len(self._proj):
                self._stacked = np.stack(self._proj)  # (steps, duals, columns)
            theta, w, proj = np.zeros((ncols, k)), np.zeros((ncols, k)), np.zeros((duals, ncols, k))
            for j in range(ncols):
                kj = max(0, min(int(k), int(self.lengths[j])))
                if kj:
                    t, U = eigh_tridiagonal(self._alpha[:kj, j], self._beta[: kj - 1, j])
                    theta[j, :kj], w[j, :kj] = t, math.sqrt(self.norms2[j]) * U[0]
                    proj[:, j, :kj] = (U.T @ self._stacked[:kj, :, j]).T
            if len(self._rules) >= 4:  # the sizes a search reads again are the last few
                self._rules.pop(next(iter(self._rules)))
            self._rules[k] = (theta, w, proj)
        return self._rules[k]

    def _estimate(self, g: Callable[[np.ndarray], np.ndarray], k: int) -> tuple[np.ndarray, np.ndarray]:
        """The ``k``-step estimates (duals, columns) and the norms of the approximations of :math:`g(M) b_j`."""
        fs = [column_function(g, j) for j in range(self._q.shape[1])]
        if fs and all(isinstance(f, ShiftedInverse) and f.power == 1 and not f.lift for f in fs):
            return self._shifted_estimate(fs, k)
        theta, w, proj = self._rules_at(max(int(k), 0))
        if callable(g):
            c = g(theta) * w  # zero where a column has fewer nodes
        else:  # one function per column j, g[j % len(g)] (the axes of a frame)
            c = np.empty_like(theta)
            for a, ga in enumerate(g):
                c[a::len(g)] = ga(theta[a::len(g)]) * w[a::len(g)]
        return np.einsum("fjk,jk->fj", proj, c), np.sqrt(np.einsum("jk,jk->j", c, c))

    def _shifted_estimate(self, fs: list[ShiftedInverse], k: int) -> tuple[np.ndarray, np.ndarray]:
        r""":meth:`_estimate` when every column's function is a :class:`ShiftedInverse` (power 1): the coefficients
        :math:`c = \|b_j\| (I + \mu T_k^p)^{-1} e_1 = \|b_j\| U g(\Theta) U^T e_1` by ``p`` tridiagonal solves
        (:func:`~meshdenoise.kernels.shifted_tridiagonal_solves`, time linear in ``k``) and the estimates
        :math:`(Q_k^T u)^T c`: no eigenproblem per column and size (face000's ``sobolev_axes`` normals search: 6,000
        of them, 1.1 s). The same numbers as the eigenvalue route up to rounding."""
        ncols, nduals = self._q.shape[1], self._U.shape[0]
        steps = max(0, min(int(k), self.steps))
        sizes = np.minimum(self.lengths, steps).astype(np.int64)
        kmax = int(sizes.max()) if sizes.size else 0
        if not kmax:
            return np.zeros((nduals, ncols)), np.zeros(ncols)
        if self._stacked.shape[0] != len(self._proj):
            self._stacked = np.stack(self._proj)  # (steps, duals, columns)
        coef = np.zeros((kmax, ncols))
        groups: dict[tuple[float, int], list[int]] = {}
        for j, f in enumerate(fs):
            groups.setdefault((f.mu, f.order), []).append(j)
        for (mu, order), cols in groups.items():
            out = np.zeros((kmax, len(cols)))
            if mu == 0.0:  # g = 1 (an axis left as it is): the recurrences' roots would be at infinity
                out[0] = 1.0
            else:
                kernels.shifted_tridiagonal_solves(np.ascontiguousarray(self._alpha[:kmax, cols]),
                                                   np.ascontiguousarray(self._beta[:kmax, cols]), sizes[cols], mu,
                                                   order, out)
            coef[:, cols] = out * np.sqrt(self.norms2[cols])[None, :]
        return np.einsum("ifj,ij->fj", self._stacked[:kmax], coef), np.sqrt(np.einsum("ij,ij->j", coef, coef))

    def dots(self, g: Callable[[np.ndarray], np.ndarray], *, rtol: float = 1e-10, check: int = 10,
             growth: float = 0.0) -> np.ndarray | None:
        """:math:`u_j^T g(M)\\, b_j`, shape (duals, columns), the run extended until converged; ``None`` if
        :attr:`max_steps` is reached first. ``g`` may be a sequence of functions, column ``j`` taking
        ``g[j % len(g)]`` (:func:`column_function`).

        Converged when no estimate of an active column moved by more than ``rtol`` times
        :math:`\\|u_j\\|\\, \\|g(M) b_j\\|` (its Cauchy-Schwarz scale) over the last ``check`` steps;
        ``growth`` as for :meth:`LanczosQuadrature.apply` (tests at geometrically growing sizes).
        """
        if self.steps < check:
            self.extend(check - self.steps)
        while True:
            k = self.steps
            now, norms = self._estimate(g, k)
            before, _ = self._estimate(g, k - check)
            moved = np.abs(now - before) > rtol * self.dual_norms * norms
            if not (moved & self._active).any():
                return now
            if k >= self.max_steps:
                return None
            self.extend(min(max(check, int(growth * k)), self.max_steps - k))

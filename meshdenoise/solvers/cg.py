"""Conjugate gradients: the Jacobi-preconditioned block CG of :class:`CGSolver` (no factorisation, which wins on
very large, well-conditioned systems such as ``I + mu L`` with moderate ``mu``) and the preconditioned CG that the
held and one-ring solvers run (:func:`preconditioned_cg`)."""

from __future__ import annotations

import warnings
from typing import Callable

import numpy as np
import scipy.sparse as sp

from .. import kernels
from ..operators import spmm
from .factor import DirichletSystem

__all__ = ["block_cg", "CGSolver", "preconditioned_cg", "HELD_CG_TOL"]

HELD_CG_TOL = 1e-10  # the held and one-ring solvers' relative residual (as the filters' factor-free solves,
# lanczos.FILTER_LANCZOS_TOL)


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


def preconditioned_cg(A: sp.csr_matrix | Callable[[np.ndarray], np.ndarray], b: np.ndarray,
                       precondition: Callable[[np.ndarray], np.ndarray], tol: float,
                       maxiter: int, x0: np.ndarray | None = None) -> tuple[np.ndarray, int] | None:
    """``A x = b`` (SPD ``A``, ``b`` (m, c)) by CG preconditioned by ``precondition``, started from ``x0`` (m, c) or else
    from the preconditioner's answer, every column to a relative residual ``tol``: ``(x, steps)``, or ``None`` past
    ``maxiter`` steps (the held solvers then factorise). ``A`` a matrix or its product on (m, c) blocks, column ``j``
    of the result being column ``j``'s own system's (:class:`~meshdenoise.solvers.pcg.ShiftedPCGFamily`: one weight per column).
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

"""Conjugate gradients on :math:`I + \\mu L^p` preconditioned by one Cholesky factor of a one-ring matrix
(``L``'s pattern): :class:`ShiftedPCG` for one weight, :class:`ShiftedPCGFamily` for one weight per column, and the
one-ring factor and solve they share with ``sobolev_gls``' held correction."""

from __future__ import annotations

from typing import Sequence

import numpy as np
import scipy.sparse as sp

from ..cache import nbytes
from ..operators import Operators, spmm
from .cg import HELD_CG_TOL, preconditioned_cg
from .config import SolverConfig
from .factor import DirichletSystem, SPDSolver
from .matrices import shifted_matrix

__all__ = ["held_row_share", "one_ring_factor", "one_ring_solve", "SHIFTED_PCG_MAXITER", "ShiftedPCG",
           "ShiftedPCGFamily"]


def held_row_share(order: int) -> float:
    """:class:`ShiftedPCG`'s diagonal share ``(p - 1) / p`` of each free row's coupling to held rows (0 for ``p = 1``,
    where :math:`(L^p)_{ff} = L_{ff}`). Measured, steps to 1e-10 with shares 0 / 0.5 / 0.65 / 0.8: face000's 4,111 held
    border vertices, p = 3: 50 / 31 / 29 / 32 (mu 24.5), 68 / 42 / 39 / 41 (mu 103), 77 / 47 / 44 / 46 (mu 184); p = 4,
    mu 50: 170 / 89 / 80 / 78; p = 2: 16 / 13 / 15 / 17 (mu 5), 23 / 17 / 19 / 20 (mu 50); a 150 x 150 grid's border, p = 3:
    22 / 19 / 19 / 20 (mu 1) to 62 / 32 / 30 / 33 (mu 300); Bunny0.2's 223, p = 3: 19 / 22 / 23 / 25 at mu 0.1, 69 / 46 /
    44 / 43 at mu 100."""
    return (int(order) - 1) / int(order)


def one_ring_factor(ops: Operators, shift: float, order: int, pinned: np.ndarray | None = None, *,
                    config: SolverConfig | None = None) -> SPDSolver:
    r"""The factor of :class:`ShiftedPCG`'s one-ring matrix on the free rows, :math:`L_{ff} + a I + s\, H`:
    ``shift`` ``a`` (:math:`\mu^{-1/p}` for :math:`I + \mu L^p`), :math:`H` the diagonal of each free row's coupling
    to the held rows and :math:`s` = :func:`held_row_share` ``(p)`` (held rows make :math:`(L^p)_{ff}` exceed
    :math:`(L_{ff})^p` next to them; a diagonal share of their coupling stands for it). :math:`\mu^{-1}` times ``p``
    solves with it approximate :math:`(I + \mu L^p)_{ff}^{-1}`. ``config``: the factor's back end (:class:`SPDSolver`).

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
    return SPDSolver(sp.csr_matrix(L + sp.diags(diagonal, format="csr")), config=config)


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
    :data:`SHIFTED_PCG_MAXITER` steps the held system is factorised after all (kept for the next solves); ``config``
    chooses the factors' back end (:class:`SPDSolver`).
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

    def __init__(self, ops: Operators, mu: float, order: int, pinned: np.ndarray | None = None, *,
                 config: SolverConfig | None = None):
        if isinstance(order, (bool, np.bool_)) or not isinstance(order, (int, np.integer)) or order < 1:
            raise ValueError(f"ShiftedPCG: order must be an int >= 1, got {order!r}")
        if not (isinstance(mu, (int, float, np.integer, np.floating)) and mu > 0 and np.isfinite(mu)):
            raise ValueError(f"ShiftedPCG: mu must be a finite number > 0, got {mu!r}")
        self._matrix = shifted_matrix(ops, mu, order)
        super().__init__(self._matrix, pinned)
        self.mu, self.order = float(mu), int(order)
        self._config = config
        self.factor = one_ring_factor(ops, self.mu ** (-1.0 / self.order), self.order, self.pinned, config=config)
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
        start = self._start(x0, X)
        found = preconditioned_cg(self.A, b, self.precondition, tol,
                                   SHIFTED_PCG_MAXITER if maxiter is None else int(maxiter), start)
        if found is None:  # far from the bound: factorise
            self._fallback = SPDSolver(self._matrix, self.pinned, config=self._config)
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
    held system is factorised (``config``: the factors' back end, as for :class:`ShiftedPCG`).

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

    def __init__(self, ops: Operators, mus: Sequence[float], order: int, pinned: np.ndarray | None = None, *,
                 config: SolverConfig | None = None):
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
        self._config = config
        self.factor = one_ring_factor(ops, float(np.exp(np.mean(np.log(weights ** (-1.0 / self.order))))), self.order,
                                      self.pinned, config=config)
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
        start = self._start(x0, X)
        found = preconditioned_cg(self._product, b, self.precondition, tol,
                                   SHIFTED_PCG_MAXITER if maxiter is None else int(maxiter), start)
        if found is None:  # far from the bound: factorise each column's system
            return np.column_stack([SPDSolver(shifted_matrix(self._ops, mu, self.order), self.pinned,
                                              config=self._config).solve(X2[:, j])
                                    for j, mu in enumerate(self.mus)])
        x, self.iterations = found
        return self._expand(X2, x)

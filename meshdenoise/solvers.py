"""Factorised symmetric positive definite systems with Dirichlet (fixed) rows, cached per topology.

The implicit filters (Sobolev, higher-order Sobolev) all solve ``A Y = X`` with
``A = I + (positive semi-definite)``; with pinned vertices, on the free rows only.
"""

from __future__ import annotations

from collections import OrderedDict
from typing import Callable

import numpy as np
import scipy.sparse as sp
from cholespy import CholeskySolverD, MatrixType

from .operators import Operators, mask_key

__all__ = ["SPDSolver", "cached_solver"]

FACTORS_PER_FAMILY = 4  # a parameter sweep keeps only the last few factorisations of each filter


class SPDSolver:
    """A sparse Cholesky factorisation (cholespy) of SPD ``A``, reduced to free rows when some are fixed.

    Solves ``A Y = X`` on the free rows with ``Y = X`` on the fixed ones, i.e. the reduced
    system :math:`A_{ff} Y_f = X_f - A_{fp} X_p`; every ``A_ff`` of an SPD ``A`` is SPD.

    Examples
    --------
    >>> import numpy as np, scipy.sparse as sp
    >>> A = sp.csr_matrix(np.array([[2.0, -1, 0], [-1, 2, -1], [0, -1, 2]]))
    >>> SPDSolver(A, np.array([False, True, False])).solve(np.array([[1.0], [5.0], [1.0]])).ravel()
    array([3., 5., 3.])
    """

    def __init__(self, A: sp.spmatrix, fixed: np.ndarray | None = None):
        A = sp.csr_matrix(A)
        self.n = A.shape[0]
        self.fixed = None if fixed is None or not fixed.any() else fixed.copy()
        if self.fixed is None:
            self.free = None
        else:
            self.free = np.flatnonzero(~self.fixed)
            self._pinned = np.flatnonzero(self.fixed)
            A_free = A[self.free]
            self._coupling = A_free[:, self._pinned]  # moves the pinned values to the right-hand side
            A = sp.csr_matrix(A_free[:, self.free])
        A.sort_indices()
        self.size = A.shape[0]
        self._solver = (
            CholeskySolverD(
                self.size, A.indptr.astype(np.int32), A.indices.astype(np.int32), A.data.astype(np.float64),
                MatrixType.CSR,
            )
            if self.size
            else None
        )

    def solve(self, X: np.ndarray) -> np.ndarray:
        """``Y`` of the shape of ``X`` (n,) or (n, k), with ``(A Y)_f = X_f`` and ``Y_p = X_p``."""
        X = np.asarray(X, dtype=np.float64)
        if X.shape[0] != self.n:
            raise ValueError(f"{type(self).__name__}.solve: X has {X.shape[0]} rows, the system {self.n}")
        X2 = X.reshape(self.n, -1)
        if self.free is None:
            rhs = np.array(X2, dtype=np.float64, order="C")  # cholespy needs a writable C array
        else:
            rhs = np.ascontiguousarray(X2[self.free] - self._coupling @ X2[self._pinned])
        out = np.empty_like(rhs)
        if self._solver is not None:
            self._solver.solve(rhs, out)
        if self.free is None:
            Y = out
        else:
            Y = X2.copy()
            Y[self.free] = out
        return Y.reshape(X.shape)


def cached_solver(
    ops: Operators, family: str, param: float, fixed: np.ndarray | None, build: Callable[[], SPDSolver]
) -> SPDSolver:
    """The solver of ``family`` for ``(param, fixed mask)`` stored on this topology, built on first use.

    Keeps the last :data:`FACTORS_PER_FAMILY` of each family (least recently used first out).
    """
    factors = ops.cache.setdefault(family, OrderedDict())
    key = (float(param), mask_key(fixed if fixed is not None and fixed.any() else None))
    if key in factors:
        factors.move_to_end(key)
        return factors[key]
    solver = build()
    factors[key] = solver
    while len(factors) > FACTORS_PER_FAMILY:
        factors.popitem(last=False)
    return solver

""":math:`I + \\mu L^p` and its factorisations: the powers of ``L``, the matrix, the product of its real factors
(:class:`ShiftedProduct`), a factorised solver of it not stored (:func:`shifted_factor`) and CG's iteration bound
(:func:`shifted_cg_bound`)."""

from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sp

from ..operators import Operators
from .config import SolverConfig
from .factor import SPDSolver

__all__ = ["laplacian_power", "shifted_matrix", "shifted_factor_matrices", "ShiftedProduct", "shifted_factor",
           "shifted_cg_bound"]


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

    def __init__(self, ops: Operators, mu: float, order: int, *, config: SolverConfig | None = None):
        self.n, self.mu, self.order = ops.n, float(mu), int(order)
        self.factors = [SPDSolver(M, config=config) for M in shifted_factor_matrices(ops, self.mu, self.order)]

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


def shifted_factor(ops: Operators, mu: float, order: int = 1, pinned: np.ndarray | None = None, *,
                   config: SolverConfig | None = None) -> SPDSolver | ShiftedProduct:
    """A factorised solver of :math:`(I + \\mu L^p) Y = X`, not stored: :class:`ShiftedProduct` from ``p = 3``
    with no pinned rows, else one Cholesky factor of the matrix (:class:`SPDSolver`, its back end by ``config``)."""
    if order >= 3 and (pinned is None or not np.any(pinned)):
        return ShiftedProduct(ops, mu, order, config=config)
    return SPDSolver(shifted_matrix(ops, mu, order), pinned, config=config)


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

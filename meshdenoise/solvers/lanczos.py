"""Factor-free solves by Lanczos runs on ``L``: :math:`(I + \\mu L^p)^{-1} X` (:func:`lanczos_shifted`, with the
filters' tolerances) and :math:`g(M)\\, B` on a few rows (:class:`LanczosRows`)."""

from __future__ import annotations

from typing import Callable

import numpy as np
import scipy.sparse as sp

from ..operators import Operators, spmm
from .quadrature import LanczosQuadrature, ShiftedInverse

__all__ = ["LANCZOS_SHIFTED_MAX_STEPS", "FILTER_LANCZOS_TOL", "DRAFT_LANCZOS_TOL", "lanczos_shifted", "LanczosRows"]


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

"""Gauss quadrature of :math:`b^T g(M)\\, b` and the Lanczos approximation of :math:`g(M)\\, B` by one Lanczos run on
the columns of ``B`` (:class:`LanczosQuadrature`), and :class:`ShiftedInverse`, the functions of ``L`` the shifted
systems apply, whose rules and coefficients it computes by tridiagonal solves."""

from __future__ import annotations

import math
from typing import Callable, Sequence

import numpy as np
import scipy.sparse as sp

from .. import kernels
from ..operators import spmm

__all__ = ["ShiftedInverse", "LanczosQuadrature", "column_function"]


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



def column_function(g: Callable | Sequence[Callable], j: int) -> Callable:
    """``g``, or column ``j``'s function ``g[j % len(g)]`` of a sequence of functions (one per axis of a frame).

    >>> column_function((abs, round), 3) is round
    True
    """
    return g if callable(g) else g[j % len(g)]

"""Lanczos runs whose steps are compiled passes over the rows (:class:`CompiledLanczos`, both passes of its
:meth:`~CompiledLanczos.apply` alike) and the run that records its duals' projections (:class:`LanczosDots`)."""

from __future__ import annotations

import math
from typing import Callable, Sequence

import numpy as np
import scipy.sparse as sp

from .. import kernels
from .config import SolverConfig, resolve
from .quadrature import LanczosQuadrature, ShiftedInverse, column_function

__all__ = ["CompiledLanczos", "LanczosDots"]


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
    config : SolverConfig, optional
        :attr:`~meshdenoise.solvers.config.SolverConfig.regenerate_ring_bytes`, the second pass's ring for several
        functions; default :data:`~meshdenoise.solvers.config.DEFAULT`.

    Examples
    --------
    >>> import numpy as np, scipy.sparse as sp
    >>> M = sp.csr_matrix(np.diag([0.0, 1.0, 2.0, 4.0]))
    >>> np.round(CompiledLanczos(M, np.ones((4, 1))).apply(lambda t: 1.0 / (1.0 + t)).ravel(), 12).tolist()
    [1.0, 0.5, 0.333333333333, 0.2]
    """

    def __init__(self, M: sp.spmatrix, B: np.ndarray, *, max_steps: int = 1000, duals: Sequence[np.ndarray] = (),
                 keep_basis: int = 0, config: SolverConfig | None = None):
        super().__init__(M, B, max_steps=max_steps)
        self.config = resolve(config)
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
        depth = int(self.config.regenerate_ring_bytes // max(8 * n * k, 1)) - 2  # steps accumulated at once
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
    config : SolverConfig, optional
        As for :class:`CompiledLanczos`.

    Examples
    --------
    >>> import numpy as np, scipy.sparse as sp
    >>> M = sp.csr_matrix(np.diag([0.0, 1.0, 2.0, 4.0]))
    >>> run = LanczosDots(M, np.ones((4, 1)), [np.array([[1.0], [0.0], [0.0], [2.0]])])
    >>> np.round(run.dots(lambda t: 1.0 / (1.0 + t)), 12).tolist()  # 1 + 2/5
    [[1.4]]
    """

    def __init__(self, M: sp.spmatrix, B: np.ndarray, duals: Sequence[np.ndarray], *, max_steps: int = 1000,
                 config: SolverConfig | None = None):
        B = np.asarray(B, dtype=np.float64)
        for U in duals:
            if np.shape(U) != B.shape:
                raise ValueError(f"LanczosDots: a dual has shape {np.shape(U)}, B {B.shape}")
        super().__init__(M, B, max_steps=max_steps, duals=duals, config=config)
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

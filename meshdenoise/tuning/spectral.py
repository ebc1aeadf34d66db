r"""A linear smoother as a function of one symmetric matrix, for searches that score many of its weights.

Generic machinery: it knows a transfer function on the spectrum of a symmetric positive semi-definite
matrix ``M``, never a filter. A filter's rule describes its map in its rule's configuration as

.. math:: H = S^{-1}\, g(M)\, S, \qquad S = \mathrm{diag}(s),

the same on every column (the Sobolev filters: :math:`M = L`, :math:`g(y) = 1/(1 + \mu y^p)`; the
averaging filters: :math:`M = I - D^{-1/2} W D^{-1/2}`, :math:`s = \sqrt{d}`,
:math:`D^{-1} W = S^{-1}(I - M)S`), or one function per axis of a frame (``sobolev_axes``).
A search over the weight then needs no factorisation and no run of the filter per candidate: the
coordinates :math:`HX = X - S^{-1} h(M)\, M S X`, :math:`h(y) = (1 - g(y))/y`, come from one Lanczos
run on ``M`` (:class:`~meshdenoise.solvers.CompiledLanczos`, a second pass over three columns for a
few candidates at once), and the probes' terms :math:`u^T H b = (S^{-1}u)^T g(M)\, (S b)` from one run
that records the duals' projections (:class:`~meshdenoise.solvers.LanczosDots`, no second pass).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
import scipy.sparse as sp

from ..operators import Operators, spmm
from ..solvers import CompiledLanczos, LanczosDots, ShiftedInverse
from .config import SPECTRAL, SpectralConfig, resolve

__all__ = ["Spectral", "SpectralFailed", "SpectralSearch", "StartDual", "shifted_spectral", "averaging_spectral",
           "heat_kernel_spectral", "normalized_laplacian", "SpectralConfig", "SPECTRAL_WINDOW"]

SPECTRAL_WINDOW = 2  # SpectralSearch.coordinates: a candidate's coordinates with this many neighbours on each side
_TINY = 1e-300  # h at y = 0 is its limit: every h below is written without cancellation, so h(1e-300) is that limit


@dataclass(frozen=True)
class Spectral:
    r"""The map :math:`H = S^{-1} g(M)\, S` on every column, or on the axes of a frame one function each.

    With a ``frame`` :math:`E` (3, 3, orthonormal columns) and three functions, each coordinate triple
    ``B`` (n, 3) maps to :math:`\sum_d S^{-1} g_d(M) S\, (B e_d)\, e_d^T` (``sobolev_axes``).

    Attributes
    ----------
    M : scipy.sparse.csr_matrix, shape (n, n)
        Symmetric positive semi-definite.
    g : callable, or tuple of three callables (with ``frame``)
        The transfer function on eigenvalues of ``M`` (an array), :math:`g(0) = 1`.
    h : callable, or tuple of three callables
        :math:`(1 - g(y)) / y`, written without cancellation (its limit at 0).
    scale : ndarray, shape (n,), optional
        The diagonal of ``S`` (default the identity).
    frame : ndarray, shape (3, 3), optional
    """

    M: sp.csr_matrix
    g: Callable[[np.ndarray], np.ndarray] | tuple
    h: Callable[[np.ndarray], np.ndarray] | tuple
    scale: np.ndarray | None = None
    frame: np.ndarray | None = None

    def dense(self, axis: int = 0) -> np.ndarray:
        """``H`` (the function of ``axis`` with a frame) as a dense matrix, by an eigendecomposition of ``M``
        (tests and small meshes only)."""
        theta, U = np.linalg.eigh(self.M.toarray())
        g = self.g if callable(self.g) else self.g[axis]
        H = (U * g(np.maximum(theta, 0.0))) @ U.T
        if self.scale is not None:
            H = H * self.scale[None, :] / self.scale[:, None]
        return H

    def apply_dense(self, B: np.ndarray) -> np.ndarray:
        """The map on a block ``B`` (n, 3k) of coordinate triples, by :meth:`dense` (tests only)."""
        B = np.asarray(B, dtype=np.float64)
        if self.frame is None:
            return self.dense() @ B
        n, k = B.shape[0], B.shape[1] // 3
        C = B.reshape(n, k, 3) @ self.frame
        out = np.stack([self.dense(d) @ C[:, :, d] for d in range(3)], axis=2)
        return (out @ self.frame.T).reshape(n, 3 * k)


def shifted_spectral(ops: Operators, mu: float, order: int = 1) -> Spectral:
    r""":math:`(I + \mu L^p)^{-1}`: :math:`M = L = D - W`, :math:`g(y) = 1/(1 + \mu y^p)`.

    >>> import numpy as np
    >>> from meshdenoise.operators import Operators
    >>> ops = Operators(np.array([[0, 1, 2], [0, 2, 3]]), 4)
    >>> H = shifted_spectral(ops, 0.5, 2).dense()
    >>> bool(np.allclose(H, np.linalg.inv(np.eye(4) + 0.5 * np.linalg.matrix_power(ops.L.toarray(), 2))))
    True
    """
    mu, p = float(mu), int(order)
    g = ShiftedInverse(mu, p)  # the same function, recognised by LanczosDots: its terms by tridiagonal solves

    def h(y: np.ndarray) -> np.ndarray:
        y = np.maximum(y, 0.0)
        return mu * y ** (p - 1) / (1.0 + mu * y**p)

    return Spectral(ops.L, g, h)


def normalized_laplacian(ops: Operators) -> tuple[sp.csr_matrix, np.ndarray]:
    r""":math:`M = I - D^{-1/2} W D^{-1/2}` (zero rows at isolated vertices) and :math:`s = \sqrt d` (1 there),
    so that ``ops.P`` :math:`= D^{-1}W = S^{-1}(I - M)S` (cached on ``ops``).

    >>> import numpy as np
    >>> from meshdenoise.operators import Operators
    >>> ops = Operators(np.array([[0, 1, 2], [0, 2, 3]]), 5)  # vertex 4 isolated
    >>> M, s = normalized_laplacian(ops)
    >>> bool(np.allclose((np.eye(5) - M.toarray()) * s[None, :] / s[:, None], ops.P.toarray()))
    True
    """
    if "normalized_laplacian" not in ops.cache:
        keep = ~ops.isolated
        s = np.ones(ops.n)
        s[keep] = np.sqrt(ops.degree[keep])
        inv = 1.0 / s
        S = sp.diags(inv) @ ops.W @ sp.diags(inv)
        M = sp.csr_matrix(sp.diags(keep.astype(np.float64)) - S)
        M.sort_indices()
        ops.cache["normalized_laplacian"] = (M, s)
    return ops.cache["normalized_laplacian"]


def averaging_spectral(ops: Operators, steps: Sequence[float], count: int) -> Spectral:
    r"""``count`` times the steps :math:`Y \leftarrow Y + c\,(PY - Y)`, one per ``c`` in ``steps``, with ``P = ops.P``.

    On :math:`M = I - D^{-1/2}WD^{-1/2}` a step is :math:`1 - c\,y`:
    :math:`g(y) = \prod_c (1 - c\,y)^{k}` (``filtering``: ``steps`` (1,); ``heat``: (tau,); ``taubin``: (lam, mu)).

    >>> import numpy as np
    >>> from meshdenoise.operators import Operators
    >>> ops = Operators(np.array([[0, 1, 2], [0, 2, 3]]), 4)
    >>> A = np.eye(4) + 0.5 * (ops.P.toarray() - np.eye(4)); B = np.eye(4) - 0.53 * (ops.P.toarray() - np.eye(4))
    >>> bool(np.allclose(averaging_spectral(ops, (0.5, -0.53), 3).dense(), np.linalg.matrix_power(B @ A, 3)))
    True
    """
    M, s = normalized_laplacian(ops)
    cs, k = np.array([float(c) for c in steps]), int(count)

    def g(y: np.ndarray) -> np.ndarray:
        y = np.maximum(y, 0.0)
        return np.prod([(1.0 - c * y) ** k for c in cs], axis=0)

    def h(y: np.ndarray) -> np.ndarray:
        y = np.maximum(y, _TINY)
        factors = 1.0 - cs[:, None] * y[None, :]
        positive = (factors > 0).all(axis=0)
        logs = np.sum(np.log1p(-cs[:, None] * np.where(positive, y, 0.0)[None, :]), axis=0)
        smooth = -np.expm1(k * logs) / y  # no cancellation at small y, where 1 - g(y) ~ k y sum(c)
        return np.where(positive, smooth, (1.0 - g(y)) / y)

    return Spectral(M, g, h, s)


def heat_kernel_spectral(ops: Operators, t: float, steps: int, iterations: int, debias: bool = True) -> Spectral:
    r"""``iterations`` times :math:`2G - G^2` (``debias``) or :math:`G`, :math:`G = (I + \tfrac{t}{s} L)^{-s}`
    (``s = steps``): ``sinkhorn``'s map with the graph Laplacian and the uniform measure.

    With :math:`e(y) = 1 - (1 + ty/s)^{-s}`: :math:`g = (1 - e^2)^k` (:math:`2\gamma - \gamma^2 = 1 - (1 - \gamma)^2`).

    >>> import numpy as np
    >>> from meshdenoise.operators import Operators
    >>> ops = Operators(np.array([[0, 1, 2], [0, 2, 3]]), 4)
    >>> G = np.linalg.inv(np.eye(4) + 0.7 * ops.L.toarray())
    >>> bool(np.allclose(heat_kernel_spectral(ops, 0.7, 1, 2).dense(), np.linalg.matrix_power(2 * G - G @ G, 2)))
    True
    """
    t, sub, k = float(t), int(steps), int(iterations)

    def log_step(y: np.ndarray) -> np.ndarray:  # log of one iteration's gain
        log_gamma = -sub * np.log1p(t * y / sub)
        if not debias:
            return log_gamma
        e = -np.expm1(log_gamma)
        return np.log1p(-e * e)

    def g(y: np.ndarray) -> np.ndarray:
        return np.exp(k * log_step(np.maximum(y, 0.0)))

    def h(y: np.ndarray) -> np.ndarray:
        y = np.maximum(y, _TINY)
        return -np.expm1(k * log_step(y)) / y

    return Spectral(ops.L, g, h)


@dataclass(frozen=True)
class StartDual:
    r"""A dual of :meth:`SpectralSearch.probes` that is the probes themselves times a power of a matrix,
    :math:`u_j = A^k b_j` (``matrix`` :math:`A`, default the search's ``M``; ``power`` :math:`k`).

    Where the search's map has no ``scale`` and :math:`A` is its ``M`` (or :math:`k = 0`), the run starts from the
    probes (each triple in the frame, as the dual), so :math:`u_j^T H b_j = b_j^T M^k g(M)\, b_j`: a Gauss rule of the
    probes' own run, of :math:`x^k g(x)`, with no projection recorded as the run goes (the elephant's Dirichlet
    search, 96 steps of 51 columns: 3.5 -> 2.5 ms a step without its two duals). Otherwise :math:`A^k B` is formed
    and recorded as any dual: the same terms either way, to the search's tolerance.
    """

    power: int = 0
    matrix: sp.spmatrix | None = None

    def __post_init__(self) -> None:
        if isinstance(self.power, (bool, np.bool_)) or not isinstance(self.power, (int, np.integer)) or self.power < 0:
            raise ValueError(f"StartDual: power must be an int >= 0, got {self.power!r}")


def _same_matrix(A: sp.spmatrix, B: sp.spmatrix) -> bool:
    """``A`` and ``B`` hold the same sparse matrix (the same object, or equal CSR arrays)."""
    if A is B:
        return True
    if A.shape != B.shape or A.nnz != B.nnz:
        return False
    A, B = sp.csr_matrix(A), sp.csr_matrix(B)
    A.sort_indices()
    B.sort_indices()
    return bool(np.array_equal(A.indptr, B.indptr) and np.array_equal(A.indices, B.indices)
                and np.array_equal(A.data, B.data))


def _lifted(g: Callable[[np.ndarray], np.ndarray], power: int) -> Callable[[np.ndarray], np.ndarray]:
    """:math:`x^k g(x)` (``x`` clipped at 0); a :class:`~meshdenoise.solvers.ShiftedInverse` stays one (its ``lift``),
    so that its Gauss rules need no eigenproblem."""
    if power == 0:
        return g
    if isinstance(g, ShiftedInverse):
        return ShiftedInverse(g.mu, g.order, g.power, g.lift + power)
    return lambda y: np.maximum(y, 0.0) ** power * g(y)


def _start_rules(run: LanczosDots, g: Callable[[np.ndarray], np.ndarray], power: int, columns: range,
                 dual_norms: np.ndarray, rtol: float) -> np.ndarray | None:
    """The Gauss rules :math:`b_j^T M^k g(M)\\, b_j` of ``run`` on ``columns`` (``k = power``), converged to ``rtol``
    times :math:`\\|M^k b_j\\|\\, \\|g(M)\\, b_j\\|` (``dual_norms`` the first factors; the second the rule of
    :math:`g^2`): the test :meth:`~meshdenoise.solvers.LanczosDots.dots` makes for a recorded dual
    (:meth:`~meshdenoise.solvers.LanczosQuadrature.evaluate` with that ``scale``). ``None`` past the run's
    ``max_steps``."""
    square = ShiftedInverse(g.mu, g.order, 2, 2 * g.lift) if isinstance(g, ShiftedInverse) and g.power == 1 \
        else (lambda y: g(y) ** 2)
    cols = list(columns)
    return run.evaluate(_lifted(g, power), cols, rtol=rtol, growth=0.25,
                        scale=lambda k: dual_norms * np.sqrt(np.maximum(run.quadrature(square, cols, k), 0.0)))


class SpectralFailed(RuntimeError):
    """A Lanczos run did not converge within ``SpectralConfig.max_steps``: run the filter instead."""


class SpectralSearch:
    r"""The coordinates :math:`HX` and the probes' terms :math:`u^T H b` of every candidate of a search.

    ``family(value)`` gives the candidate's :class:`Spectral`; every candidate shares ``M``,
    ``scale`` and ``frame`` (those of the first asked for). The coordinates' run starts at the
    high-pass :math:`M S X` (three columns; its tolerance is relative to the correction, not to
    the coordinates), kept for the whole search; :meth:`probes` starts a run for one set of
    probes and their duals.

    Parameters
    ----------
    V : ndarray, shape (n, 3)
    family : callable
        ``family(value) -> Spectral``.
    tol : float, optional
        The runs' relative tolerance (:meth:`~meshdenoise.solvers.CompiledLanczos.apply_many`,
        :meth:`~meshdenoise.solvers.LanczosDots.dots`); default ``config.tol``.
    candidates : sequence of float, optional
        The search's values in order: :meth:`coordinates` computes a value's neighbours with it.
    config : SpectralConfig, optional
        The runs' settings (:class:`~meshdenoise.tuning.config.SpectralConfig`: tolerance, most steps, basis kept);
        ``None``: its default.

    Examples
    --------
    >>> import numpy as np
    >>> from meshdenoise.shapes import icosphere
    >>> from meshdenoise.operators import get_operators
    >>> V, F = icosphere(2)
    >>> ops = get_operators(F, len(V))
    >>> search = SpectralSearch(V, lambda mu: shifted_spectral(ops, mu, 2), tol=1e-10)
    >>> bool(np.allclose(search.coordinates(0.3), shifted_spectral(ops, 0.3, 2).dense() @ V, atol=1e-12))
    True
    """

    def __init__(self, V: np.ndarray, family: Callable[[float], Spectral], tol: float | None = None,
                 candidates: Sequence[float] = (), config: SpectralConfig | None = None):
        self.V = np.asarray(V, dtype=np.float64)
        self.config = resolve(config, SPECTRAL)
        self.family, self.tol = family, float(self.config.tol if tol is None else tol)
        self.candidates = [float(c) for c in candidates]
        self._first: Spectral | None = None
        self._coords: CompiledLanczos | None = None
        self._done: dict[float, np.ndarray] = {}  # HX per candidate value (at most len(candidates) + 1 of (n, 3))
        self._specs: dict = {}  # the Spectral of each value asked for (functions and shared arrays: small)

    def spectral(self, value: float) -> Spectral:
        """The candidate's :class:`Spectral`, checked to share the first one's ``M``, ``scale`` and ``frame``
        (asked of ``family`` once per value: a frame is read from the mesh each time it is built)."""
        if value in self._specs:
            return self._specs[value]
        spec = self.family(value)
        if self._first is None:
            self._first = spec
        elif (spec.M is not self._first.M or spec.scale is not self._first.scale
              or (spec.frame is None) != (self._first.frame is None)
              or (spec.frame is not None and not np.array_equal(spec.frame, self._first.frame))):
            raise ValueError("SpectralSearch: every candidate must share the first one's M, scale and frame")
        self._specs[value] = spec
        return spec

    def _scaled(self, A: np.ndarray, inverse: bool = False) -> np.ndarray:
        """``S A`` (``S^-1 A``), each triple of columns in the frame (out of it with ``inverse``)."""
        A = np.asarray(A, dtype=np.float64)
        E, s = self._first.frame, self._first.scale
        if E is not None and not inverse:
            A = (A.reshape(A.shape[0], -1, 3) @ E).reshape(A.shape)
        if s is not None:
            A = A / s[:, None] if inverse else A * s[:, None]
        if E is not None and inverse:
            A = (A.reshape(A.shape[0], -1, 3) @ E.T).reshape(A.shape)
        return np.ascontiguousarray(A)

    def _dual(self, U: np.ndarray) -> np.ndarray:
        """:math:`S^{-1} U`, each triple in the frame: :math:`u^T H b = (S^{-1} u E)^T g(M) (S b E)` per axis."""
        U = np.asarray(U, dtype=np.float64)
        E, s = self._first.frame, self._first.scale
        if E is not None:
            U = (U.reshape(U.shape[0], -1, 3) @ E).reshape(U.shape)
        return np.ascontiguousarray(U if s is None else U / s[:, None])

    def _coordinates_run(self, spec: Spectral) -> CompiledLanczos:
        if self._coords is None:
            self._coords = CompiledLanczos(spec.M, spmm(spec.M, self._scaled(self.V)), max_steps=self.config.max_steps,
                                           keep_basis=self.config.basis_bytes)
        return self._coords

    def coordinates_many(self, values: Sequence) -> list[np.ndarray]:
        """:math:`HX` (n, 3) at each of ``values`` (any hashable values ``family`` takes), in one second pass, nothing
        kept; :class:`SpectralFailed` when the run does not converge."""
        specs = [self.spectral(v) for v in values]
        Z = self._coordinates_run(specs[0]).apply_many([spec.h for spec in specs], rtol=self.tol, growth=0.25)
        if Z is None:
            raise SpectralFailed(f"SpectralSearch: the coordinates at {list(values)!r} did not converge")
        return [self.V - self._scaled(z, inverse=True) for z in Z]

    def coordinates(self, value: float) -> np.ndarray:
        """:math:`HX` (n, 3) at ``value``; :class:`SpectralFailed` when the run does not converge.

        A value among ``candidates`` is computed with its neighbours, up to :data:`SPECTRAL_WINDOW`
        on each side not yet computed, in one second pass (a search asks for them next)."""
        value = float(value)
        if value not in self._done:
            values = [value]
            if value in self.candidates:
                i = self.candidates.index(value)
                near = self.candidates[max(0, i - SPECTRAL_WINDOW): i + SPECTRAL_WINDOW + 1]
                values = [v for v in near if v not in self._done]
            self._done.update(zip(values, self.coordinates_many(values)))
        return self._done[value].copy()

    def probes(self, B: np.ndarray, duals: Sequence[np.ndarray | StartDual]) -> Callable[[float], np.ndarray]:
        """``terms(value)``: :math:`u_j^T H b_j` for every column ``b_j`` of ``B`` and each dual, shape (duals, columns).

        One run on the columns of :math:`S B` recording the projections of :math:`S^{-1} U`; a :class:`StartDual`
        is read from the run's own Gauss rules where it can be (no scale), else formed and recorded.
        :class:`SpectralFailed` when a candidate's estimates do not converge.
        """
        if self._first is None:
            raise ValueError("SpectralSearch.probes: ask for a candidate first (coordinates or spectral)")
        first = self._first
        B = np.asarray(B, dtype=np.float64)
        direct: list[tuple[int, int]] = []  # (row of the result, power): Gauss rules of the run itself
        recorded: list[tuple[int, np.ndarray]] = []
        for i, U in enumerate(duals):
            if isinstance(U, StartDual):
                A = first.M if U.matrix is None else U.matrix
                if first.scale is None and (U.power == 0 or _same_matrix(A, first.M)):
                    direct.append((i, int(U.power)))
                    continue
                formed = B
                for _ in range(U.power):
                    formed = spmm(A, formed)
                U = formed
            recorded.append((i, np.asarray(U, dtype=np.float64)))
        start = self._scaled(B)
        run = LanczosDots(first.M, start, [self._dual(U) for _, U in recorded], max_steps=self.config.max_steps)
        columns = B.shape[1]
        dual_norms = {}  # ||M^k b_j|| per power: the Cauchy-Schwarz scale LanczosDots.dots tests against
        for _, power in direct:
            U = start
            for _ in range(power):
                U = spmm(first.M, U)
            dual_norms[power] = np.sqrt(np.einsum("ij,ij->j", U, U))

        def terms(value: float) -> np.ndarray:
            g = self.spectral(value).g
            out = np.empty((len(duals), columns))
            if recorded:
                got = run.dots(g, rtol=self.tol, growth=0.25)
                if got is None:
                    raise SpectralFailed(f"SpectralSearch: the probes' terms at {value!r} did not converge")
                out[[i for i, _ in recorded]] = got
            for i, power in direct:  # per axis of a frame: column j takes g[j % 3]
                gs = [g] if callable(g) else list(g)
                for a, ga in enumerate(gs):
                    cols = range(a, columns, len(gs))
                    got = _start_rules(run, ga, power, cols, dual_norms[power][a::len(gs)], self.tol)
                    if got is None:
                        raise SpectralFailed(f"SpectralSearch: the probes' terms at {value!r} did not converge")
                    out[i, a::len(gs)] = got
            return out

        return terms

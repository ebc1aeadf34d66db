"""The stored solvers of :math:`(I + \\mu L^p) Y = X`: :func:`shifted_solver`, the one place the package builds them
(a factor, held rows by :class:`HeldByProduct`, CG or one-ring preconditioned CG), the factorisations kept per
family on the topology (:func:`cached_solver`) and more of them inside :func:`retain_factors`."""

from __future__ import annotations

import contextlib
from collections import OrderedDict
from typing import Callable, Iterator

import numpy as np

from ..cache import nbytes
from ..operators import Operators, mask_key, trim_cache
from .cg import HELD_CG_TOL, CGSolver, preconditioned_cg
from .config import DEFAULT, SolverConfig, resolve
from .factor import DirichletSystem, SPDSolver
from .matrices import ShiftedProduct, shifted_factor, shifted_matrix
from .pcg import ShiftedPCG

__all__ = ["FACTORS_PER_FAMILY", "retain_factors", "cached_solver", "HeldByProduct", "SHIFTED_METHODS",
           "shifted_solver"]

FACTORS_PER_FAMILY = 4  # a parameter sweep keeps only the last few factorisations of each filter


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


SHIFTED_METHODS = ("cholesky", "cg", "pcg")
HELD_CG_MAXITER = 200  # HeldByProduct.solve: past this many steps the held system is factorised after all


class HeldByProduct(DirichletSystem):
    r""":math:`(I + \mu L^p) Y = X` with held (pinned) rows, ``p >= 3``, by conjugate gradients on the free rows
    preconditioned by the free system's factors restricted to them, :math:`z = (A^{-1} [r; 0])_f`.

    The product form (:class:`~meshdenoise.solvers.matrices.ShiftedProduct`, a third to a quarter of the cost of factorising :math:`A = I + \mu L^p`)
    has no held rows; a factor of :math:`A_{ff}` with them is of the whole ``p``-ring pattern. But
    :math:`(A^{-1})_{ff} = (A_{ff} - A_{fp} A_{pp}^{-1} A_{pf})^{-1}` differs from :math:`A_{ff}^{-1}` by a term of rank
    at most the held count, so CG preconditioned by it converges in about that many steps at most, and in far fewer
    when a border is held (Bunny0.2, 223 border vertices: 22). ``product`` is the free solver (stored on ``ops`` by
    :func:`shifted_solver`); :attr:`product` also serves callers wanting an approximate inverse (a preconditioner).
    ``config`` (:class:`~meshdenoise.solvers.config.SolverConfig`): the factors' back end.

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

    def __init__(self, ops: Operators, mu: float, order: int, pinned: np.ndarray, *, config: SolverConfig | None = None):
        if int(order) < 3:
            raise ValueError(f"HeldByProduct: order must be >= 3 (the product form), got {order!r}")
        self._matrix = shifted_matrix(ops, mu, order)
        super().__init__(self._matrix, pinned)
        self._config = config
        self.product = shifted_solver(ops, mu, order, config=config)
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
        found = preconditioned_cg(self.A, b, precondition, tol, HELD_CG_MAXITER if maxiter is None else int(maxiter))
        if found is None:  # far from the free system: factorise
            self._factor = SPDSolver(self._matrix, self.pinned, config=self._config)
            return self._factor.solve(X)
        return self._expand(X2, found[0]).reshape(np.shape(X))


def shifted_solver(
    ops: Operators, mu: float, order: int = 1, pinned: np.ndarray | None = None, method: str = "cholesky", *,
    config: SolverConfig | None = None,
) -> SPDSolver | ShiftedProduct | HeldByProduct | ShiftedPCG | CGSolver:
    """The solver of :math:`(I + \\mu L^p) Y = X` on this topology (pinned rows as Dirichlet data), stored on ``ops``.

    The one place the package builds this family of systems: the Sobolev filters of every
    order and the automatic-parameter searches share its factorisations (the last
    :data:`FACTORS_PER_FAMILY` per (order, method), least recently used first out). From ``p = 3``
    with no pinned rows a ``"cholesky"`` solver factorises the real factors of :math:`1 + \\mu x^p`
    (:func:`shifted_factor`), a third to a quarter of the cost of factorising :math:`I + \\mu L^p`; with a few held
    rows on a large mesh (:attr:`~meshdenoise.solvers.config.SolverConfig.held_by_product_min_vertices`,
    :attr:`~meshdenoise.solvers.config.SolverConfig.held_by_product_max_held`) it solves them by
    :class:`HeldByProduct`.

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
    config : SolverConfig, optional
        The factorisations' back end and the sizes choosing the held solver; default
        :data:`~meshdenoise.solvers.config.DEFAULT`. Solvers of another configuration are stored apart.

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
    config = resolve(config)
    family = f"shifted-p{order}-{method}" + ("" if config == DEFAULT else f" {config!r}")
    if method == "cholesky":
        held = (pinned is not None and 0 < np.count_nonzero(pinned) <= config.held_by_product_max_held and order >= 3
                and ops.n >= config.held_by_product_min_vertices)
        return cached_solver(ops, family, mu, pinned,
                             (lambda: HeldByProduct(ops, mu, order, pinned, config=config)) if held
                             else (lambda: shifted_factor(ops, mu, order, pinned, config=config)))
    if method == "pcg":
        return cached_solver(ops, family, mu, pinned, lambda: ShiftedPCG(ops, mu, order, pinned, config=config))
    return cached_solver(ops, family, mu, pinned, lambda: CGSolver(shifted_matrix(ops, mu, order), pinned))


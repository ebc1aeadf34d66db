"""Searches over a smoother's parameter: along an iterative run, and over a log-scaled weight.

Generic machinery: a search knows a score (a :class:`~meshdenoise.tuning.risk.Criterion`)
and a way to evaluate candidates, never a filter. The same searches serve the automatic
choice (SURE, GCV) and the oracle (the true error against a clean mesh).
"""

from __future__ import annotations

import math
import warnings
from typing import Callable, Iterator

import numpy as np
import scipy.sparse as sp

from ..operators import Operators, spmm
from ..solvers import shifted_solver
from .memo import MEMO, digest
from .risk import Criterion, Point, as_criterion, probe_block

__all__ = [
    "averaging_step",
    "iterative_path",
    "best_on_path",
    "past_minimum",
    "search_log",
    "solve_shifted",
    "solve_point",
    "best_shifted",
    "sure_smoothed",
    "mu_guess",
]


def averaging_step(A: sp.csr_matrix, lam: float) -> Callable[[np.ndarray], np.ndarray]:
    """One step ``Y <- Y + lam (A Y - Y)`` (``A Y`` when ``lam`` = 1), on any number of columns."""

    def step(Y: np.ndarray) -> np.ndarray:
        AY = spmm(A, Y)  # threaded on wide probe blocks; each row summed as A @ Y sums it (bit-identical)
        return AY if lam == 1.0 else Y + lam * (AY - Y)

    return step


def iterative_path(
    V: np.ndarray, ops: Operators, step: Callable, exact: bool | None = None, seed: int = 0
) -> Iterator[Point]:
    """Yield (k, ||H_k X - X||^2, tr H_k, H_k X) for k = 0, 1, ... with H_k = step^k (linear).

    The trace probes (:func:`~meshdenoise.tuning.risk.probe_block`) go through the same
    steps as the coordinates, so the whole curve costs one run.
    """
    n = V.shape[0]
    Z, s = probe_block(n, exact, seed=seed)
    Y = np.hstack([np.array(V, dtype=np.float64), Z])
    k = 0
    while True:
        X = Y[:, :3]
        yield Point(k, float(np.sum((X - V) ** 2)), s * float(np.sum(Z * Y[:, 3:])), X.copy())
        Y = step(Y)
        k += 1


PAST_MINIMUM_FACTOR, PAST_MINIMUM_MARGIN = 2, 20


def past_minimum(k: int, k_best: int) -> bool:
    """The one stopping rule of every walk along an iterative run: ``k >= 2 k_best + 20``.

    The score curves of the smoothers here are unimodal in practice (bias grows, variance
    falls, both monotone), so a walk twice as long as the best step count, and 20 past
    it, has passed the minimum. Used by :func:`best_on_path` and by the paper's
    SNR-along-a-run searches (:mod:`meshdenoise.reproduce`).

    Examples
    --------
    >>> past_minimum(20, 0), past_minimum(29, 5), past_minimum(30, 5)
    (True, False, True)
    """
    return k >= PAST_MINIMUM_FACTOR * k_best + PAST_MINIMUM_MARGIN


def best_on_path(
    path: Iterator[Point], n: int, rho: float | None, criterion: Criterion | str, max_steps: int = 20000
) -> Point:
    """Walk a path until its score has risen well past its minimum; return the minimum.

    Stops when :func:`past_minimum` and the score exceeds the minimum.
    """
    criterion = as_criterion(criterion)
    best: Point | None = None
    for p in path:
        p.score = criterion.score(p, n, rho)
        if best is None or p.score < best.score:
            best = p
        if past_minimum(p.value, best.value) and p.score > best.score:
            return best
        if p.value >= max_steps:
            warnings.warn(
                f"choose_parameters: the criterion still decreased after {max_steps} steps; "
                "the noise may be too strong for this filter, consider sobolev or a larger step size",
                UserWarning,
                stacklevel=3,
            )
            return best
    raise RuntimeError("best_on_path: the path ended before its score rose past the minimum")


def search_log(evaluate: Callable[[float], Point], center: float, golden_steps: int = 8,
               lo_limit: float = -8.0, hi_limit: float = 10.0) -> Point:
    """Minimise ``evaluate(10**t).score`` over ``t`` (a decimal logarithm).

    Five points 0.75 decades apart around ``center``, extended while the minimum sits
    at an end of the grid, then golden-section search between the minimum's
    neighbours (1.5 decades shrink to about 0.03 decades in 8 steps).
    """
    cache: dict[float, Point] = {}

    def at(t: float) -> Point:
        t = round(t, 12)
        if t not in cache:
            cache[t] = evaluate(10.0**t)
        return cache[t]

    c0 = math.log10(center)
    grid = [c0 + 0.75 * j for j in range(-2, 3)]
    while True:
        scores = [at(t).score for t in grid]
        i = int(np.argmin(scores))
        if i == 0 and grid[0] > lo_limit:
            grid.insert(0, grid[0] - 0.75)
        elif i == len(grid) - 1 and grid[-1] < hi_limit:
            grid.append(grid[-1] + 0.75)
        else:
            break
    a, b = grid[max(i - 1, 0)], grid[min(i + 1, len(grid) - 1)]
    g = (math.sqrt(5) - 1) / 2
    c, d = b - g * (b - a), a + g * (b - a)
    for _ in range(golden_steps):
        if at(c).score < at(d).score:
            b, d = d, c
            c = b - g * (b - a)
        else:
            a, c = c, d
            d = a + g * (b - a)
    return min(cache.values(), key=lambda p: p.score)


def solve_shifted(ops: Operators, order: int, mu: float, rhs: np.ndarray, key: str | None = None) -> np.ndarray:
    """``(I + mu L^order)^{-1} rhs`` through :func:`~meshdenoise.solvers.shifted_solver`, memoised on (topology, order, rhs, mu).

    ``key`` (a :func:`~meshdenoise.tuning.memo.digest` of the topology, order and ``rhs``)
    saves hashing ``rhs`` again when one search solves it for many ``mu``.
    """
    key = key or digest(ops.F, order, rhs)
    return MEMO.get(("solve", key, float(mu)), lambda: shifted_solver(ops, mu, order).solve(rhs))


def solve_point(V: np.ndarray, ops: Operators, order: int, mu: float, Z: np.ndarray, s: float,
                key: str | None = None) -> Point:
    """The :class:`Point` of :math:`(I + \\mu L^p)^{-1}` at ``mu``: coordinates and trace probes in one solve."""
    rhs = np.hstack([V, Z])
    out = solve_shifted(ops, order, mu, rhs, key)
    X = out[:, :3].copy()
    return Point(mu, float(np.sum((X - V) ** 2)), s * float(np.sum(Z * out[:, 3:])), X)


def best_shifted(
    V: np.ndarray, ops: Operators, order: int, rho: float | None, criterion: Criterion | str,
    exact: bool | None = None, center: float = 1.0, golden_steps: int = 8,
) -> Point:
    """Minimise the criterion of :math:`(I + \\mu L^p)^{-1}` over log mu (:func:`search_log`).

    ``center`` is a guess from the cheap averaging path (:func:`mu_guess`); each point is
    one sparse Cholesky factorisation, with the same probes for every mu (a smooth curve).
    """
    criterion = as_criterion(criterion)
    n = V.shape[0]
    Z, s = probe_block(n, exact)
    key = digest(ops.F, order, np.hstack([V, Z]))

    def evaluate(mu: float) -> Point:
        p = solve_point(V, ops, order, mu, Z, s, key)
        p.score = criterion.score(p, n, rho)
        return p

    return search_log(evaluate, center, golden_steps)


def sure_smoothed(V: np.ndarray, ops: Operators, rho: float | None, criterion: Criterion | str = "sure",
                  exact: bool | None = None) -> Point:
    """The best point of plain averaging ``X <- D^-1 W X`` (an estimate of the clean mesh, and its step count)."""
    return best_on_path(iterative_path(V, ops, averaging_step(ops.P, 1.0), exact), ops.n, rho, criterion)


def mu_guess(V: np.ndarray, ops: Operators, rho: float | None, criterion: Criterion | str, exact: bool | None,
             order: int) -> float:
    """A starting weight for :math:`(I + \\mu L^p)`: :math:`(k / \\bar d)^p`, ``k`` the best number of averaging steps.

    Both filters damp the eigenmode of :math:`I - D^{-1}W` with eigenvalue :math:`\\lambda`
    by about half when :math:`k\\lambda \\approx \\mu \\bar d \\lambda \\approx 1`.
    """
    k = sure_smoothed(V, ops, rho, criterion, exact).value
    dbar = float(np.mean(ops.degree[~ops.isolated])) if (~ops.isolated).any() else 1.0
    return max(k, 0.5) ** order / dbar**order

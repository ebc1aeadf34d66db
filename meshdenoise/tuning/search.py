"""Searches over a smoother's parameter: along an iterative run, and over a log-scaled weight.

Generic machinery: a search knows a score (a :class:`~meshdenoise.tuning.risk.Criterion`)
and a way to evaluate candidates, never a filter. The same searches serve the automatic
choice (SURE, GCV) and the oracle (the true error against a clean mesh).
"""

from __future__ import annotations

import dataclasses
import math
import threading
import warnings
from typing import Callable, Iterator

import numpy as np
import scipy.sparse as sp

from ..operators import Operators, spmm
from ..solvers import (CompiledLanczos, LanczosQuadrature, ShiftedInverse, shifted_cg_bound, shifted_factor,
                       shifted_solver)
from .config import SEARCH, SearchConfig, resolve
from .memo import MEMO, digest
from .risk import N_PROBES, Criterion, Point, as_criterion, probe_block
from .walk import past_minimum, walk

__all__ = [
    "averaging_step",
    "iterative_path",
    "best_on_path",
    "past_minimum",
    "search_log",
    "LogSearch",
    "solve_shifted",
    "solve_point",
    "best_shifted",
    "sure_smoothed",
    "mu_guess",
    "probe_count",
    "PathCurve",
    "path_curve",
    "best_on_curve",
    "shifted_quadrature",
    "quadrature_coordinates",
    "SHIFTED_SEARCHES",
    "QUADRATURE_TOL",
    "region_rule",
    "region_shape",
    "shifted_reach",
    "SearchConfig",
]

PROBE_REFERENCE_VERTICES = 50_000  # up to this size every search keeps N_PROBES probes (all quality-table meshes)
MIN_PROBES = 4
SHIFTED_SEARCHES = ("auto", "quadrature", "factor")
QUADRATURE_BASE_ORDER = 2  # shifted_quadrature's run on the columns L^min(p, this) X: the searches of orders 2 and 3
# on the same coordinates and probes share it (sobolev_gls' pilot and sweep weights on the elephant: 187 steps, 0.26 s)
QUADRATURE_TOL = 1e-6  # shifted_quadrature: each Gauss rule to this relative change over 10 steps; against 1e-10:
# sobolev_gls' run on the elephant (its order-3 and order-2 searches) 120 Lanczos steps, not 187; the same choices on the
# 56 cells whose rules search these weights (default, the Sobolev filters, two_stage), weights to 1e-9


def probe_count(n: int, most: int = N_PROBES, reference: int = PROBE_REFERENCE_VERTICES) -> int:
    """Hutchinson probes for a smoother of ``n`` vertices: ``most`` (``N_PROBES``) up to ``reference`` (50,000)
    vertices, then fewer.

    ``m = max(MIN_PROBES, ceil(most * reference / n))``, at most ``most``: 24 up to 50k
    vertices, 12 at 100k, 4 from 300k. Why fewer probes are enough on a large mesh: with
    Rademacher probes the trace estimate has standard deviation
    :math:`\\sqrt{2(\\|H\\|_F^2 - \\sum_i H_{ii}^2)/m} \\le \\sqrt{2\\,\\mathrm{tr} H / m}` (``H``
    symmetric with eigenvalues in [0, 1], so :math:`\\|H\\|_F^2 \\le \\mathrm{tr} H \\le n`),
    and SURE carries it times :math:`2\\rho^2`: relative to the noise energy
    :math:`n\\rho^2` (the scale of SURE) at most :math:`2\\sqrt{2/(m n)}`, which falls with
    ``n``. Keeping ``m n >= 24 x 50,000`` keeps that bound at or below its value for 24 probes
    on a 50k-vertex mesh, 0.26 %; measured at 400k vertices with 4 probes, docs/scale.md. A rule whose
    probes cost more (each a many-column solve) passes its own ``most`` and ``reference``, and ``n`` the vertices
    it scores (the bound is over the scored rows' risk).

    Examples
    --------
    >>> probe_count(25_000), probe_count(100_000), probe_count(400_000), probe_count(1_600_000)
    (24, 12, 4, 4)
    >>> probe_count(8_000, most=8, reference=10_000), probe_count(24_955, most=8, reference=10_000)
    (8, 4)
    """
    if isinstance(n, (bool, np.bool_)) or not isinstance(n, (int, np.integer)) or n < 0:
        raise ValueError(f"probe_count: n must be an int >= 0, got {n!r}")
    if not (isinstance(most, (int, np.integer)) and most >= MIN_PROBES) or not (
            isinstance(reference, (int, np.integer)) and reference >= 1):
        raise ValueError(f"probe_count: most must be an int >= {MIN_PROBES} and reference an int >= 1, "
                         f"got {most!r}, {reference!r}")
    return int(min(most, max(MIN_PROBES, math.ceil(most * reference / max(n, 1)))))


def averaging_step(A: sp.csr_matrix, lam: float) -> Callable[[np.ndarray], np.ndarray]:
    """One step ``Y <- Y + lam (A Y - Y)`` (``A Y`` when ``lam`` = 1), on any number of columns.

    The step is one matrix, :math:`M = (1 - \\lambda) I + \\lambda A`, built once: each step is a
    single threaded product (no passes over the block to combine ``AY`` and ``Y``), and the
    same row sums on three columns as on a wide probe block (bit-identical coordinates).
    """
    if lam == 1.0:
        M = A
    else:
        M = sp.csr_matrix(lam * sp.csr_matrix(A) + sp.diags(np.full(A.shape[0], 1.0 - lam)))
        M.sort_indices()

    def step(Y: np.ndarray) -> np.ndarray:
        return spmm(M, Y)  # threaded on wide probe blocks

    return step


def iterative_path(
    V: np.ndarray, ops: Operators, step: Callable, exact: bool | None = None, seed: int = 0
) -> Iterator[Point]:
    """Yield (k, ||H_k X - X||^2, tr H_k, H_k X) for k = 0, 1, ... with H_k = step^k (linear).

    The trace probes (:func:`~meshdenoise.tuning.risk.probe_block`) go through the same
    steps as the coordinates, so the whole curve costs one run.
    """
    n = V.shape[0]
    Z, s = probe_block(n, exact, n_probes=probe_count(n), seed=seed)
    Y = np.hstack([np.array(V, dtype=np.float64), Z])
    k = 0
    while True:
        X = Y[:, :3]
        yield Point(k, float(np.sum((X - V) ** 2)), s * float(np.sum(Z * Y[:, 3:])), X.copy())
        Y = step(Y)
        k += 1


class PathCurve:
    """The residuals and traces of an iterative linear run, kept and extended on demand (no noise level in them).

    The terms of :func:`iterative_path` (``||H_k X - X||^2`` and the Hutchinson trace of
    ``H_k = step^k``, same probes, same arithmetic) do not depend on rho or on the
    criterion, so one run serves every walk along it: :func:`estimate_noise` (two rhos),
    the start guess of the Sobolev searches and the ``filtering`` / ``heat`` rules read the
    same averaging curve (:func:`path_curve` memoises it). The coordinates of a step are not
    stored: :meth:`coordinates` runs ``step`` again on the three columns alone (the same
    row sums, so the same numbers). From ``config.curve_kernel_min_vertices`` vertices the two
    sums of a step are one compiled pass (:func:`meshdenoise.kernels.curve_terms`), equal to
    numpy's to the last few places.
    """

    def __init__(self, V: np.ndarray, ops: Operators, step: Callable, exact: bool | None = None, seed: int = 0,
                 probes: tuple[np.ndarray, float] | None = None, config: SearchConfig | None = None):
        n = V.shape[0]
        self.kernel_from = resolve(config, SEARCH).curve_kernel_min_vertices
        self.V = np.array(V, dtype=np.float64)
        self.step = step
        self.Z, self.s = probes if probes is not None else probe_block(n, exact, n_probes=probe_count(n), seed=seed)
        self.Y = np.hstack([self.V, self.Z])
        self.terms: list[tuple[float, float]] = []
        self._record()

    def _record(self) -> None:
        if self.V.shape[0] >= self.kernel_from:  # one compiled pass
            from ..kernels import curve_terms

            r, t = curve_terms(self.Y, self.V, self.Z)
            self.terms.append((r, self.s * t))
            return
        D = self.Y[:, :3] - self.V
        self.terms.append((float(np.einsum("ij,ij->", D, D)), self.s * float(np.einsum("ij,ij->", self.Z, self.Y[:, 3:]))))

    def points(self) -> Iterator[Point]:
        """Points ``(k, ||H_k X - X||^2, tr H_k, X=None)`` for k = 0, 1, ..., extending the run as needed."""
        k = 0
        while True:
            while len(self.terms) <= k:
                self.Y = self.step(self.Y)
                self._record()
            r, t = self.terms[k]
            yield Point(k, r, t, None)
            k += 1

    def coordinates(self, k: int) -> np.ndarray:
        """``H_k X`` (n, 3): ``k`` steps on the coordinates."""
        X = self.V.copy()
        for _ in range(int(k)):
            X = self.step(X)
        return np.array(X, dtype=np.float64)


def path_curve(V: np.ndarray, ops: Operators, step: Callable, name: tuple, exact: bool | None = None) -> PathCurve:
    """The :class:`PathCurve` of ``step`` (described by the hashable ``name``) from ``V``, memoised in the tuning memo."""
    n = V.shape[0]
    Z, s = probe_block(n, exact, n_probes=probe_count(n))
    key = ("path", digest(ops.F, V, Z, s), name)  # the probes themselves: however they were drawn or coloured
    return MEMO.get(key, lambda: PathCurve(V, ops, step, exact, probes=(Z, s)))


def best_on_curve(curve: PathCurve, n: int, rho: float | None, criterion: Criterion | str,
                  coordinates: bool = True) -> Point:
    """:func:`best_on_path` along a memoised curve (not for the oracle, whose score needs every step's coordinates);
    the best point's coordinates are recomputed unless ``coordinates=False`` (then ``X`` is None)."""
    best = best_on_path(curve.points(), n, rho, criterion)
    MEMO.trim()  # the curve grew in place
    if coordinates:
        best.X = curve.coordinates(best.value)
    return best


def best_on_path(
    path: Iterator[Point], n: int, rho: float | None, criterion: Criterion | str, max_steps: int = 20000
) -> Point:
    """Walk a path until its score has risen well past its minimum (:func:`~meshdenoise.tuning.walk.walk`); return the minimum."""
    criterion = as_criterion(criterion)

    def score(p: Point) -> float:
        p.score = criterion.score(p, n, rho)
        return p.score

    found = walk(path, score, max_steps=max_steps)
    if found.stop == "max_steps":
        warnings.warn(
            f"choose_parameters: the criterion still decreased after {max_steps} steps; "
            "the noise may be too strong for this filter, consider sobolev or a larger step size",
            UserWarning,
            stacklevel=3,
        )
    elif found.stop == "end":
        raise RuntimeError("best_on_path: the path ended before its score rose past the minimum")
    return found.best[0].item


def _parabola_vertex(xl: float, fl: float, x0: float, f0: float, xr: float, fr: float) -> tuple[float, float] | None:
    """``(t, f)`` at the vertex of the parabola through three points ``xl < x0 < xr``; ``None`` unless ``f0`` lies
    below the chord of its neighbours (the parabola opens upwards)."""
    d1, d2 = (f0 - fl) / (x0 - xl), (fr - f0) / (xr - x0)
    a = (d2 - d1) / (xr - xl)  # f(x) = f0 + b (x - x0) + a (x - x0)^2
    if not a > 0:
        return None
    b = d1 + a * (x0 - xl)
    return x0 - b / (2.0 * a), f0 - b * b / (4.0 * a)


class LogSearch:
    """Minimise ``evaluate(10**t).score`` over ``t`` (a decimal logarithm) in two phases a caller can separate.

    :meth:`bracket`: ``2 half_width + 1`` points ``spacing`` decades apart around ``center``
    (default: five points 0.75 decades apart), extended while the minimum sits at an end of the
    grid (within ``lo_limit`` and ``hi_limit``). :meth:`refine`: golden-section search between
    the grid minimum's neighbours (1.5 decades shrink to about 0.03 decades in 8 steps).
    :meth:`predicted`: the least score the refinement can be expected to reach, from the parabola
    through the grid minimum and its two neighbours, so that a caller comparing several searches
    (one per order of a filter, say) refines only those that can still win.
    :func:`search_log` runs both phases. Every ``t`` is evaluated once (rounded to 1e-12).
    ``evaluate_many(mus)``, optional: the points of several ``mu`` at once, as ``evaluate`` gives them (the
    first grid is asked for in one call: a caller that can share work between candidates).

    Examples
    --------
    >>> from meshdenoise.tuning.risk import Point
    >>> f = lambda mu: Point(mu, 0.0, 0.0, None, (np.log10(mu) - 0.3) ** 2)
    >>> s = LogSearch(f, 1.0)
    >>> round(float(np.log10(s.bracket().value)), 2), round(s.predicted(), 6)
    (0.0, 0.0)
    >>> round(float(np.log10(s.refine().value)), 1)
    0.3
    """

    def __init__(self, evaluate: Callable[[float], Point], center: float, lo_limit: float = -8.0,
                 hi_limit: float = 10.0, spacing: float = 0.75, half_width: int = 2,
                 evaluate_many: Callable[[list], list] | None = None):
        if not (spacing > 0 and int(half_width) >= 1):
            raise ValueError(f"search_log: spacing must be > 0 and half_width >= 1, got {spacing!r}, {half_width!r}")
        if not (center > 0 and math.isfinite(center)):
            raise ValueError(f"search_log: center must be a finite number > 0, got {center!r}")
        self.evaluate, self.center, self.evaluate_many = evaluate, float(center), evaluate_many
        self.lo_limit, self.hi_limit, self.spacing, self.half_width = lo_limit, hi_limit, float(spacing), int(half_width)
        self.cache: dict[float, Point] = {}
        self._grid: list[float] | None = None
        self._i = 0

    def at(self, t: float) -> Point:
        """The point at ``mu = 10**t``, evaluated once."""
        t = round(t, 12)
        if t not in self.cache:
            self.cache[t] = self.evaluate(10.0**t)
        return self.cache[t]

    def first_grid(self) -> list[float]:
        """The ``mu`` of the first grid (:meth:`bracket`'s, before any extension) not yet evaluated: a caller may
        evaluate them together with other searches' and :meth:`add` the points."""
        c0 = math.log10(self.center)
        grid = [round(c0 + self.spacing * j, 12) for j in range(-self.half_width, self.half_width + 1)]
        return [10.0**t for t in grid if t not in self.cache]

    def add(self, mu: float, point: Point) -> None:
        """Record ``point`` as the evaluation at ``mu`` (from :meth:`first_grid`; ``evaluate`` is not called for it)."""
        self.cache[round(math.log10(mu), 12)] = point

    @property
    def best(self) -> Point:
        """The least-score point evaluated so far (the first of equal ones)."""
        return min(self.cache.values(), key=lambda p: p.score)

    def bracket(self) -> Point:
        """Run the grid phase (once) and return its least-score point."""
        if self._grid is None:
            c0 = math.log10(self.center)
            grid = [c0 + self.spacing * j for j in range(-self.half_width, self.half_width + 1)]
            todo = [round(t, 12) for t in grid if round(t, 12) not in self.cache]
            if self.evaluate_many is not None and len(todo) > 1:  # the first grid at once (the same points)
                self.cache.update(zip(todo, self.evaluate_many(self.first_grid())))
            while True:
                scores = [self.at(t).score for t in grid]
                i = int(np.argmin(scores))
                if i == 0 and grid[0] > self.lo_limit:
                    grid.insert(0, grid[0] - self.spacing)
                elif i == len(grid) - 1 and grid[-1] < self.hi_limit:
                    grid.append(grid[-1] + self.spacing)
                else:
                    break
            self._grid, self._i = grid, i
        return self.at(self._grid[self._i])

    def predicted(self) -> float:
        """The minimum of the parabola in ``t`` through the grid minimum and its two neighbours (its score when
        at an end of the grid or where the three are not convex)."""
        self.bracket()
        grid, i = self._grid, self._i
        f0 = self.at(grid[i]).score
        if i == 0 or i == len(grid) - 1:
            return float(f0)
        vertex = _parabola_vertex(grid[i - 1], self.at(grid[i - 1]).score, grid[i], f0, grid[i + 1],
                                  self.at(grid[i + 1]).score)
        return float(f0 if vertex is None else vertex[1])

    def refine(self, golden_steps: int = 8) -> Point:
        """Golden-section search between the grid minimum's neighbours; returns the least-score point evaluated."""
        self.bracket()
        grid, i = self._grid, self._i
        a, b = grid[max(i - 1, 0)], grid[min(i + 1, len(grid) - 1)]
        g = (math.sqrt(5) - 1) / 2
        c, d = b - g * (b - a), a + g * (b - a)
        for _ in range(golden_steps):
            if self.at(c).score < self.at(d).score:
                b, d = d, c
                c = b - g * (b - a)
            else:
                a, c = c, d
                d = a + g * (b - a)
        return self.best

    def refine_parabolic(self, tol: float = 0.02, max_steps: int = 8) -> Point:
        """Successive parabolic interpolation between the grid minimum's neighbours; the least-score point evaluated.

        Each step fits the parabola in ``t`` through the best point so far and its nearest evaluated
        neighbours on either side and evaluates its vertex (the golden-section point of the wider
        side where the three are not convex, or where the vertex falls outside them); it stops when the
        vertex lies within ``tol / 2`` decades of the best point (the minimum is located to about
        ``tol``), the neighbours are within ``2 tol`` of each other, or after ``max_steps``
        evaluations. On a smooth score 2 to 4 evaluations where :meth:`refine` takes 9 for 0.03
        decades; one on an exact parabola.
        """
        if not (tol > 0 and int(max_steps) >= 0):
            raise ValueError(f"refine_parabolic: tol must be > 0 and max_steps >= 0, got {tol!r}, {max_steps!r}")
        self.bracket()
        grid, i = self._grid, self._i
        lo, hi = round(grid[max(i - 1, 0)], 12), round(grid[min(i + 1, len(grid) - 1)], 12)  # as the cache's keys
        g = (3.0 - math.sqrt(5.0)) / 2.0  # the golden section's share of an interval
        for _ in range(int(max_steps)):
            inside = sorted((t, p.score) for t, p in self.cache.items() if lo <= t <= hi)
            j = min(range(len(inside)), key=lambda k: inside[k][1])
            if j == 0 or j == len(inside) - 1:
                break  # the best at the bracket's end: no parabola (the grid's minimum is interior unless at a limit)
            (xl, fl), (x0, f0), (xr, fr) = inside[j - 1], inside[j], inside[j + 1]
            if xr - xl <= 2.0 * tol:
                break
            vertex = _parabola_vertex(xl, fl, x0, f0, xr, fr)
            v = math.nan if vertex is None else vertex[0]
            if not (xl < v < xr):  # not convex (NaN), or outside the neighbours
                v = x0 + g * (xr - x0) if xr - x0 >= x0 - xl else x0 - g * (x0 - xl)
            elif abs(v - x0) < tol / 2.0:
                break
            self.at(v)
        return self.best


def search_log(evaluate: Callable[[float], Point], center: float, golden_steps: int = 8,
               lo_limit: float = -8.0, hi_limit: float = 10.0, spacing: float = 0.75, half_width: int = 2,
               parabolic: bool = False) -> Point:
    """Minimise ``evaluate(10**t).score`` over ``t`` (a decimal logarithm): :class:`LogSearch`'s two phases.

    ``2 half_width + 1`` points ``spacing`` decades apart around ``center`` (default: five points
    0.75 decades apart), extended while the minimum sits at an end of the grid, then
    golden-section search between the minimum's neighbours (1.5 decades shrink to about 0.03
    decades in 8 steps), or with ``parabolic`` successive parabolic interpolation to 0.02
    decades (:meth:`LogSearch.refine_parabolic`, at most ``golden_steps`` candidates, usually 1
    to 4). A narrower grid (``spacing`` 0.2, ``half_width`` 1) refines a choice already known roughly.
    """
    search = LogSearch(evaluate, center, lo_limit, hi_limit, spacing, half_width)
    search.bracket()
    return search.refine_parabolic(max_steps=golden_steps) if parabolic else search.refine(golden_steps)


def solve_shifted(ops: Operators, order: int, mu: float, rhs: np.ndarray, key: str | None = None,
                  memo: bool = True) -> np.ndarray:
    """``(I + mu L^order)^{-1} rhs`` through :func:`~meshdenoise.solvers.shifted_solver`, memoised on (topology, order, rhs, mu).

    ``key`` (a :func:`~meshdenoise.tuning.memo.digest` of the topology, order and ``rhs``)
    saves hashing ``rhs`` again when one search solves it for many ``mu``. ``memo=False``: a
    factor of its own, neither stored on ``ops`` nor its result in the memo (a search that
    evaluates each ``mu`` once on a region: nothing held after it, one factor at a time).
    """
    if not memo:
        return shifted_factor(ops, mu, order).solve(rhs)
    key = key or digest(ops.F, order, rhs)
    return MEMO.get(("solve", key, float(mu)), lambda: shifted_solver(ops, mu, order).solve(rhs))


def solve_point(V: np.ndarray, ops: Operators, order: int, mu: float, Z: np.ndarray, s: float,
                key: str | None = None) -> Point:
    """The :class:`Point` of :math:`(I + \\mu L^p)^{-1}` at ``mu``: coordinates and trace probes in one solve."""
    rhs = np.hstack([V, Z])
    out = solve_shifted(ops, order, mu, rhs, key)
    X = out[:, :3].copy()
    return Point(mu, float(np.sum((X - V) ** 2)), s * float(np.sum(Z * out[:, 3:])), X)


class _SharedRun:
    """A :func:`shifted_quadrature` run held in the tuning memo, with the lock its extensions take (a run grows as
    searches ask it for more steps: two threads on the same mesh must not extend it at once)."""

    def __init__(self, quad: CompiledLanczos):
        self.quad, self.lock = quad, threading.Lock()

    @property
    def nbytes(self) -> int:
        """The run's own arrays (:attr:`~meshdenoise.solvers.LanczosQuadrature.nbytes`; the matrix is ``ops``')."""
        return self.quad.nbytes


def shifted_quadrature(V: np.ndarray, ops: Operators, order: int, Z: np.ndarray, s: float,
                       max_steps: int = 600, tol: float = QUADRATURE_TOL,
                       config: SearchConfig | None = None) -> Callable[[float], Point | None]:
    """Residual and trace of :math:`H_\\mu = (I + \\mu L^p)^{-1}` for every ``mu`` from one Lanczos run on ``L``.

    ``H_mu`` is a function of ``L``, so both terms of SURE are quadratic forms of ``L``
    (:class:`~meshdenoise.solvers.LanczosQuadrature`, nodes :math:`\\theta` of ``L``):

    .. math:: \\|H_\\mu X - X\\|_F^2 = \\sum_{c} c^T \\frac{\\mu^2 L^{2(p-q)}}{(1 + \\mu L^p)^2}\\, c, \\quad c = L^q X
              \\text{ (columns)}, \\qquad
              \\mathrm{tr} H_\\mu \\approx s \\sum_k z_k^T \\frac{1}{1 + \\mu L^p}\\, z_k

    (:math:`H_\\mu X - X = -\\mu H_\\mu L^p X`; the high-pass ``c`` keeps the large, smooth part
    of ``X`` out of the rule, which then needs no cancellation), :math:`q = \\min(p,` ``QUADRATURE_BASE_ORDER``:math:`)`.
    Lanczos on ``L`` rather than
    :math:`L^p`: the poles of :math:`1/(1 + \\mu\\lambda^p)` lie at distance
    :math:`\\mu^{-1/p}` from the spectrum, so the rule converges in about
    :math:`\\mu^{1/(2p)}` steps times a log, 30 to 150 steps for the weights SURE picks.
    The run depends on ``p`` only through ``q``: it is kept in the tuning memo (up to
    ``config.shared_run_max_bytes``) under the digest of the faces, ``q``, ``V``, ``Z`` and ``max_steps``, so that a search
    of another order on the same coordinates and probes goes on with it (``sobolev_gls``: its sweep's weight at order
    3, then its pilot's at order 2; the elephant 0.26 s less). A run extended for one search gives another the rule of
    more steps: the same values to the convergence test's ``tol``.

    Each rule is extended until it changes by at most ``tol`` (relative) over 10 steps
    (:meth:`~meshdenoise.solvers.LanczosQuadrature.evaluate`; default ``QUADRATURE_TOL``).

    Returns ``evaluate(mu)``: a :class:`Point` with ``X = None`` (the coordinates are not
    formed), or ``None`` when the rule has not converged in ``max_steps`` steps; ``evaluate.quadrature`` is the run,
    ``evaluate.base`` its ``q`` and ``evaluate.lock`` the lock to hold while using the run
    (:func:`quadrature_coordinates`).
    """
    base = min(int(order), QUADRATURE_BASE_ORDER)
    lift = int(order) - base

    def run() -> _SharedRun:
        c = np.array(V, dtype=np.float64)
        for _ in range(base):
            c = spmm(ops.L, c)
        # compiled steps: the same rule to ~1e-13
        return _SharedRun(CompiledLanczos(ops.L, np.hstack([c, Z]), max_steps=max_steps))

    if 8 * 3 * V.shape[0] * (3 + Z.shape[1]) <= resolve(config, SEARCH).shared_run_max_bytes:
        shared = MEMO.get(("lanczos", digest(ops.F, base, V, Z, int(max_steps))), run)
    else:
        shared = run()  # a scan's run: not worth evicting the memo's other entries
    quad = shared.quad
    res_cols, probe_cols = range(3), range(3, 3 + Z.shape[1])

    def evaluate(mu: float) -> Point | None:
        # (1 + mu x^p)^-2 and ^-1 by tridiagonal solves: no eigenproblem per column and size (the elephant: 0.4 s)
        with shared.lock:
            r = quad.evaluate(ShiftedInverse(mu, order, 2, 2 * lift), res_cols, rtol=tol, growth=0.25)
            t = quad.evaluate(ShiftedInverse(mu, order), probe_cols, rtol=tol, growth=0.25)
        if r is None or t is None:
            return None
        return Point(mu, mu**2 * float(r.sum()), s * float(t.sum()), None)

    evaluate.quadrature = quad  # the run (columns L^q X, then the probes): best_shifted's coordinates by its second pass
    evaluate.base = base
    evaluate.lock = shared.lock
    return evaluate


def quadrature_coordinates(V: np.ndarray, quad: LanczosQuadrature, order: int, mu: float,
                           tol: float = 1e-10, base: int | None = None) -> np.ndarray | None:
    """:math:`(I + \\mu L^p)^{-1} V` from a :func:`shifted_quadrature` run: its first three columns ``c = L^q V``
    (``q = base``, default ``order``: the run's ``evaluate.base``).

    .. math:: (I + \\mu L^p)^{-1} V = V - \\mu f(L)\\, c, \\qquad f(t) = \\frac{t^{p - q}}{1 + \\mu t^p}

    by the Lanczos approximation of :meth:`~meshdenoise.solvers.LanczosQuadrature.apply` on those
    columns (its coefficients converged to ``tol``; the run extended if they need it), so the
    coordinates cost the second pass on three columns only: the first pass is the search's own.
    ``None`` when the run's ``max_steps`` is reached first.
    """
    base = int(order) if base is None else int(base)
    if not 0 <= base <= int(order):
        raise ValueError(f"quadrature_coordinates: base must be between 0 and order {order}, got {base!r}")
    Y = quad.apply(ShiftedInverse(mu, order, lift=int(order) - base), rtol=tol, columns=range(3))
    return None if Y is None else np.asarray(V, dtype=np.float64) - mu * Y


def shifted_coordinates(V: np.ndarray, ops: Operators, order: int, mu: float, tol: float = 1e-10) -> np.ndarray:
    """:math:`(I + \\mu L^p)^{-1} V` by Jacobi-preconditioned CG started from ``V`` (relative residual ``tol``), no factor.

    Iteration cap: four times the bound :math:`\\tfrac12\\sqrt\\kappa \\ln(2/\\mathrm{tol})` with
    :math:`\\kappa \\le 1 + \\mu (2 d_{max})^p` (Gershgorin), plus 50.
    """
    d_max = float(ops.degree.max()) if ops.n else 0.0
    kappa = 1.0 + mu * (2.0 * d_max) ** order
    cap = int(4 * math.ceil(0.5 * math.sqrt(kappa) * math.log(2.0 / tol))) + 50
    return shifted_solver(ops, mu, order, None, "cg").solve(V, tol=tol, x0=V, maxiter=cap)


def best_shifted(
    V: np.ndarray, ops: Operators, order: int, rho: float | None, criterion: Criterion | str,
    exact: bool | None = None, center: float = 1.0, golden_steps: int = 8, search: str = "auto",
    coordinates: bool = True, coordinates_by: str = "cg", config: SearchConfig | None = None,
) -> Point:
    """Minimise the criterion of :math:`(I + \\mu L^p)^{-1}` over log mu (:func:`search_log`).

    ``center`` is a guess from the cheap averaging path (:func:`mu_guess`); the same probes
    serve every mu (a smooth curve). Two ways to evaluate a candidate, same candidates:

    - ``search="factor"``: one sparse Cholesky factorisation per mu, right-hand sides the
      coordinates and the probes (:func:`solve_point`);
    - ``search="quadrature"``: every candidate from one Lanczos run on ``L``
      (:func:`shifted_quadrature`); only the best point's coordinates are solved, by CG
      (:func:`shifted_coordinates`). A candidate whose rule has not converged (a very
      large mu) falls back to its factorisation. Not with the oracle (its score is not a
      quadratic form of ``L``).
    - ``"auto"``: quadrature from ``config.quadrature_min_vertices`` vertices, factor below.

    The two agree to the rules' tolerance (``QUADRATURE_TOL``, 1e-6 relative change; about 1e-12 relative on every
    term run to 1e-10, tests/test_scale_search.py), and chose the same mu on every benchmark row. With
    ``coordinates=False`` a
    quadrature search returns the best point with ``X = None`` (a rule that needs only the
    weight saves the solve; the filter solves it anyway). ``coordinates_by="lanczos"``: a quadrature
    search's best coordinates by the second pass of the search's own Lanczos run on its three
    coordinate columns (:func:`quadrature_coordinates`) instead of CG (:func:`shifted_coordinates`,
    the default): the same coordinates to the tolerance 1e-10 of either, and at 400k vertices
    (order 2, mu = 1.1) about 60 products with 3 columns against about 90 CG iterations; past
    ``config.coordinates_cg_bound`` CG iterations by that second pass too. ``config``: a
    :class:`~meshdenoise.tuning.config.SearchConfig` (``None``: its default).
    """
    config = resolve(config, SEARCH)
    if search not in SHIFTED_SEARCHES:
        raise ValueError(f"best_shifted: search must be one of {SHIFTED_SEARCHES}, got {search!r}")
    if coordinates_by not in ("cg", "lanczos"):
        raise ValueError(f"best_shifted: coordinates_by must be 'cg' or 'lanczos', got {coordinates_by!r}")
    criterion = as_criterion(criterion)
    n = V.shape[0]
    Z, s = probe_block(n, exact, n_probes=probe_count(n))
    keys: list[str] = []

    def by_factor(mu: float) -> Point:
        if not keys:
            keys.append(digest(ops.F, order, np.hstack([V, Z])))
        return solve_point(V, ops, order, mu, Z, s, keys[0])

    use_quadrature = not criterion.oracle and (search == "quadrature"
                                               or (search == "auto" and n >= config.quadrature_min_vertices))
    at = shifted_quadrature(V, ops, order, Z, s, config=config) if use_quadrature else by_factor

    def evaluate(mu: float) -> Point:
        p = at(mu)
        if p is None:
            p = by_factor(mu)
        p.score = criterion.score(p, n, rho)
        return p

    best = search_log(evaluate, center, golden_steps)
    strong = (best.X is None and coordinates
              and shifted_cg_bound(ops, best.value, order, 1e-10) > config.coordinates_cg_bound)
    if best.X is None and coordinates and (coordinates_by == "lanczos" or strong):
        with at.lock:
            best.X = quadrature_coordinates(V, at.quadrature, order, best.value, base=at.base)
    if best.X is None and coordinates:
        best.X = shifted_coordinates(V, ops, order, best.value)
    return best


def sure_smoothed(V: np.ndarray, ops: Operators, rho: float | None, criterion: Criterion | str = "sure",
                  exact: bool | None = None) -> Point:
    """The best point of plain averaging ``X <- D^-1 W X`` (an estimate of the clean mesh, and its step count).

    Read along the memoised averaging curve (:func:`path_curve`): calls with other rhos or
    criteria on the same mesh extend the same run instead of starting a new one.
    """
    criterion = as_criterion(criterion)
    if criterion.oracle:
        return best_on_path(iterative_path(V, ops, averaging_step(ops.P, 1.0), exact), ops.n, rho, criterion)
    return best_on_curve(path_curve(V, ops, averaging_step(ops.P, 1.0), ("P", 1.0), exact), ops.n, rho, criterion)


def mu_guess(V: np.ndarray, ops: Operators, rho: float | None, criterion: Criterion | str, exact: bool | None,
             order: int) -> float:
    """A starting weight for :math:`(I + \\mu L^p)`: :math:`(k / \\bar d)^p`, ``k`` the best number of averaging steps.

    Both filters damp the eigenmode of :math:`I - D^{-1}W` with eigenvalue :math:`\\lambda`
    by about half when :math:`k\\lambda \\approx \\mu \\bar d \\lambda \\approx 1`.
    """
    criterion = as_criterion(criterion)
    if criterion.oracle:
        k = sure_smoothed(V, ops, rho, criterion, exact).value
    else:  # only the count: read off the memoised averaging curve, no coordinates formed
        k = best_on_curve(path_curve(V, ops, averaging_step(ops.P, 1.0), ("P", 1.0), exact), ops.n, rho, criterion,
                          coordinates=False).value
    dbar = float(np.mean(ops.degree[~ops.isolated])) if (~ops.isolated).any() else 1.0
    return max(k, 0.5) ** order / dbar**order


REGION_MAX_MARGIN = 16  # region_shape: at most this many rings of margin


def region_shape(ctx, size: int, patches: int, margin: int) -> tuple[int, int]:
    """``(size, margin)`` of a rule's sampled region, grown with the reach of the smoothing the noise calls for.

    Near a cut a region has a free border the mesh has not, and its influence on a smoother's
    result reaches about as far as the smoother does: the SURE-best number ``k`` of plain
    averaging steps (memoised, read on the averaging run :func:`estimate_noise` made) spreads
    over about :math:`\\sqrt k` rings. Scored vertices are kept ``max(margin, ceil(2 sqrt(k)))``
    rings from a cut (at most :data:`REGION_MAX_MARGIN`), and the region holds at least
    ``patches x 19 x margin^2`` vertices (balls of radius about 2.5 margins, a ball of ``r`` rings
    holding about ``3 r^2`` vertices), so that a third of it stays scored. Measured on a
    sphere whose SURE-best weight is large (a flat spectrum of the shape): a fixed 4-ring margin
    chose mu = 1.7 where the whole mesh chose 35 (4 dB lost).
    """
    k = int(ctx.smoothed("sure").value) if ctx.rho else 0
    m = int(min(REGION_MAX_MARGIN, max(margin, math.ceil(2.0 * math.sqrt(k)))))
    return int(max(size, patches * 19 * m * m)), m


def shifted_reach(mu: float, order: int, headroom: float = 3.0, decays: float = 3.0) -> int:
    """Rings within which a cut still moves :math:`(I + \\mu L^p)^{-1}`'s result by more than about :math:`e^{-3}`.

    The response of :math:`1 + \\mu \\lambda^p` to a border decays like :math:`e^{-d/\\ell}` over ``d`` rings,
    :math:`\\ell = (\\mu h)^{1/(2p)} / \\sin(\\pi / 2p)` (the roots of :math:`1 + \\mu (-k^2)^p`; ``h`` =
    ``headroom``, so that weights a few times larger are scored right too); returns
    ``ceil(decays x l)``. Measured on a 6,000-vertex torus at mu = 82, p = 3: the region's result 8
    rings from a cut still differed by 0.43 rho from the whole mesh's (``l`` = 4.2 rings).

    Examples
    --------
    >>> shifted_reach(1.0, 2), shifted_reach(82.0, 3)
    (6, 16)
    """
    return int(math.ceil(decays * (mu * headroom) ** (1.0 / (2 * order)) / math.sin(math.pi / (2 * order))))


def region_rule(ctx, rule: Callable, size: int, patches: int, margin: int = 0, seed: int = 0,
                min_vertices: int | None = None, given: Callable[[], dict] | None = None,
                reach: Callable[[dict], int] | None = None, restart: bool = False, pin: int = 0,
                boundary: Callable[[np.ndarray], Callable] | None = None) -> tuple[dict, Point]:
    """Run an automatic ``rule`` on a sampled region of about ``size`` vertices, its choice carried to the whole mesh.

    For rules whose parameters are a property of the noise per edge length and of the local
    shape (the Sobolev weights of ``sobolev_normal`` and ``sobolev_gls``: ``mu`` weighs the
    combinatorial Laplacian, the same on any part of a mesh of one sampling density), whose cost
    per candidate is a factorisation and a many-column solve of the whole mesh. The region
    (:class:`~meshdenoise.tuning.region.SampledRegion`, ``patches`` balls of rings of vertices) is
    cut out as a mesh of its own and the rule runs on it as ``rule(sub_ctx, scored)``, ``scored``
    the region's vertices more than ``margin`` rings from a cut (the rule scores those only: near
    a cut the region has a border the mesh has not), with the whole mesh's noise level (a
    correlated noise model is rebuilt on the region with the same level and correlation length)
    and, held fixed, the parameters ``given()`` returns (statistics of the whole mesh the rule
    would otherwise compute on the region). On the whole mesh the rule runs as ``rule(ctx, None)``.
    Below ``min_vertices`` (default the context's ``SearchConfig.region_min_vertices``), in oracle mode, or when
    the region would be the whole mesh, the rule runs on the whole mesh as before.

    ``reach(chosen)`` (optional): the margin in rings the chosen parameters need (a cut's
    influence on the filter, :func:`shifted_reach`); a free border penalises strong smoothing, so
    while the choice needs more than the margin used, the region is cut again with that margin
    (at most :data:`REGION_MAX_MARGIN`, the region grown by :func:`region_shape`'s rule) and the
    rule run again: at most three runs. With ``restart`` the rule is called on a run after the
    first as ``rule(sub_ctx, scored, previous)``, ``previous`` the choice of the run before (a
    search that only refines it: the larger region moves the choice by its border's pull, not
    from scratch).

    ``pin`` rings and ``boundary``: the region's vertices fewer than ``pin`` rings from a cut
    are held as Dirichlet data instead of leaving the cut a free border. ``boundary(rows)``
    (``rows`` their indices in the whole mesh) returns ``values(**candidate)``: the whole mesh's
    result at those rows for a candidate's parameters, ``(len(rows), 3)``, or ``None`` (then the
    border is left free for it); the rule gets ``boundary=(pinned, values)`` (``pinned`` bool (k,)
    on the region). A free border lets the region's low modes drift under strong smoothing and
    its pull does not decay with depth, which biased the choice low (docs/scale.md, the torus);
    held at the whole mesh's own result the region's free rows are the whole mesh's result (with
    ``pin >= p`` the free rows of the region's :math:`L^p` are the whole mesh's).

    Returns the rule's choice (with the ``given()`` values) and its best point, the point's score
    and residual scaled by ``n / k`` (``k`` the region's scored vertices) so that a SURE score still estimates the whole
    mesh's squared error; its ``X`` is the result on the region (``None`` coordinates are kept).
    """
    n = ctx.ops.n
    limit = ctx.config_for(SEARCH).region_min_vertices if min_vertices is None else int(min_vertices)
    if ctx.oracle or n < limit or n <= size:
        return rule(ctx, None)
    size, margin = region_shape(ctx, size, patches, margin)
    if n <= size:
        return rule(ctx, None)
    from .region import SampledRegion

    held = {**(given() if given is not None else {}), **ctx.given}
    previous: dict | None = None
    for _ in range(3):
        region = SampledRegion(ctx.F, ctx.ops, int(size), int(patches), int(margin), seed)
        if region.whole:
            return rule(ctx, None)
        extra = {}
        if pin > 0 and boundary is not None:
            pinned = region.cut_rings(pin - 1) <= pin - 1
            if pinned.any():
                extra["boundary"] = (pinned, boundary(region.vertices[pinned]))
        if restart and previous is not None:
            chosen, point = _on_region(ctx, lambda c, s, p=previous, e=extra: rule(c, s, p, **e), region, held)
        else:
            chosen, point = _on_region(ctx, lambda c, s, e=extra: rule(c, s, **e), region, held)
        previous = chosen
        need = min(REGION_MAX_MARGIN, reach(chosen)) if reach is not None else margin
        if need <= margin:
            break
        margin = need
        size = max(size, patches * 19 * margin * margin)
        if n <= size:
            return rule(ctx, None)
    chosen = {**{name: value for name, value in held.items() if name not in ctx.given}, **chosen}
    scale = n / max(int(region.inner.sum()), 1)
    point = Point(point.value, point.residual_sq * scale, point.trace * scale, point.X, point.score * scale)
    return chosen, point


def _on_region(ctx, rule: Callable, region, held: dict) -> tuple[dict, Point]:
    """``rule(sub_ctx, region.inner)`` on ``region`` cut out of ``ctx``'s mesh, ``held`` parameters fixed."""
    from .risk import noise_colouring

    k = region.vertices.size
    V = np.ascontiguousarray(ctx.V[region.vertices], dtype=np.float64)
    F = region.F
    ops = Operators(F, k)  # not in the operators cache: the region's factors go with it when the rule returns
    model = ctx.noise
    if model is not None and getattr(model, "correlated", False):
        with noise_colouring(None):  # the region's own smoothing: its probes are not the whole mesh's rows
            smoothed = sure_smoothed(V, ops, ctx.rho).X
        # the model's own class (a covariance.NoiseModel, above this module) on the region's smoothed mesh
        model = type(model)(ctx.rho, float(model.correlation_length), smoothed, F)
    # the context's own class (a context.TuningContext, above this module) on the region
    sub = dataclasses.replace(ctx, V=V, F=F, ops=ops, given=held, noise=model)
    with noise_colouring(model):
        return rule(sub, region.inner)

"""``sobolev_normal``'s automatic rule: ``mu``, ``order`` and ``tangential`` by Monte-Carlo SURE (or GCV) of the
projected update, on a sampled region of a large mesh with its border held at the whole mesh's result."""

from __future__ import annotations

import numpy as np

from ..geometry import area_normals, vertex_normals
from ..operators import spmm
from ..registry import get_filter
from ..solvers import LANCZOS_SHIFTED_MAX_STEPS, CompiledLanczos, LanczosRows, SPDSolver, ShiftedInverse, shifted_matrix
from ..tuning.config import SPECTRAL
from ..tuning.context import TuningContext
from ..tuning.memo import digest
from ..tuning.noise_level import mean_edge_length, normal_trust
from ..tuning.risk import MC_SURE_STEP, Point, gcv
from ..tuning.search import LogSearch, region_rule, solve_shifted
from ._normal_projection import DEFAULT, SOBOLEV_NORMAL_ORDERS, project_update

__all__ = ["choose_sobolev_normal", "choose_sobolev_normal_whole", "whole_result_at"]

SOBOLEV_NORMAL_PROBES = 16  # Monte-Carlo SURE probes (along the normals) of sobolev_normal
SOBOLEV_NORMAL_QUADRATURE_MAX_STEPS = 1000  # tangential 1: the quadrature run's steps before a candidate is solved instead
SOBOLEV_NORMAL_MARGIN = 8  # a region's scored vertices: more than this many rings from a cut ...
SOBOLEV_NORMAL_REGION_PROBES = 16  # ... with this many probes (48 moved no choice at 100k: the spread is the content)
SOBOLEV_NORMAL_PIN_MAX_STEPS = 1000  # whole_result_at: Lanczos steps before a candidate's border is left free


def _projected_divergence(V: np.ndarray, F: np.ndarray, out: np.ndarray, Bp: np.ndarray, t: float, delta: float,
                          chunk_bytes: int = DEFAULT.divergence_chunk_bytes) -> float:
    """Monte-Carlo divergence of ``sobolev_normal`` along probes ``Bp`` (n, 3K), from ``out = H [V, Bp]``.

    .. math:: \\frac1K \\sum_k b_k^T \\big(f(V + \\delta b_k) - f(V)\\big) / \\delta, \\qquad
              f(V + \\delta b) = \\mathrm{proj}(V + \\delta b,\\; HV + \\delta H b)

    (``H`` linear: the solve of the perturbed input is ``HV + delta Hb``, read from ``out``).
    Each probe's perturbed mesh, its area normals and projected update by one compiled kernel, a probe
    per thread (:func:`~meshdenoise.kernels.projected_divergence_terms`: numpy's arithmetic, the same
    terms; 5.4 -> 1.3 ms a probe on the 34,834-vertex bunny), each probe's sum by numpy; ``chunk_bytes`` bounds the
    probes' terms held at once.
    """
    from ..kernels import projected_divergence_terms, set_threads

    V, F = np.ascontiguousarray(V, dtype=np.float64), np.ascontiguousarray(F)
    Y = np.ascontiguousarray(out[:, :3], dtype=np.float64)
    X = project_update(V, Y, area_normals(Y, F), t)
    O, B = np.ascontiguousarray(out[:, 3:], dtype=np.float64), np.ascontiguousarray(Bp, dtype=np.float64)
    n, K = V.shape[0], Bp.shape[1] // 3
    chunk = max(1, min(K, int(chunk_bytes) // max(24 * n, 1)))
    terms = np.empty((chunk, n, 3))
    set_threads()
    div = 0.0
    for k0 in range(0, K, chunk):  # over probes, not vertices
        c = min(chunk, K - k0)
        projected_divergence_terms(V, F, Y, X, O, B, float(t), float(delta), k0, terms[:c])
        for j in range(c):
            div += float(np.sum(terms[j])) / delta
    return div / K


def choose_sobolev_normal(ctx: TuningContext) -> tuple[dict, Point]:
    """:func:`choose_sobolev_normal_whole`, from ``SearchConfig.region_min_vertices`` vertices
    on a sampled region of ``SobolevNormalConfig.region`` vertices (:func:`~meshdenoise.tuning.search.region_rule`,
    scored on the vertices more than ``SOBOLEV_NORMAL_MARGIN`` rings from a cut), the whole mesh below.

    ``tangential`` is a statistic of the whole mesh (the noise per mean edge length of its
    SURE-smoothed copy, read on the memoised averaging run) and is computed there, so the region
    search uses the whole mesh's value (it also decides GCV against SURE). docs/scale.md: the
    region's choice at 100k against the whole mesh's.
    """
    def whole_tangential() -> dict:
        if "tangential" in ctx.given or not ctx.rho:
            return {}
        return {"tangential": normal_trust(ctx.rho, mean_edge_length(ctx.smoothed("sure").X, ctx.ops))}

    # One cut, no reach loop: the region's outer rings are held at the whole mesh's result for each
    # candidate, so its free rows are the whole mesh's result whatever the weight, and a larger margin is not needed
    # for strong smoothing (a reach loop grew the region to 38,900 of 51,200 vertices on a torus, docs/scale.md).
    config = ctx.config_for(DEFAULT)
    return region_rule(ctx, choose_sobolev_normal_whole, config.region, config.patches,
                       SOBOLEV_NORMAL_MARGIN, given=whole_tangential,
                       pin=config.pin, boundary=lambda rows: whole_result_at(ctx, rows))


def whole_result_at(ctx: TuningContext, rows: np.ndarray):
    """``values(mu, order)``: rows ``rows`` of :math:`Y = (I + \\mu L^p)^{-1} X` on the whole mesh, any ``mu`` and ``p``.

    .. math:: Y = X - \\mu\\, g(L)\\, L X, \\qquad g(t) = \\frac{t^{p-1}}{1 + \\mu t^p},

    from one Lanczos run on ``L`` started at the high-pass ``L X`` that keeps its basis at ``rows``
    only (:class:`~meshdenoise.solvers.LanczosRows`): every candidate of the region search, of
    either order, costs small tridiagonal eigenproblems (the run is extended when one needs more
    steps). ``None`` for a candidate not converged in ``SOBOLEV_NORMAL_PIN_MAX_STEPS`` steps.
    """
    rows = np.asarray(rows, dtype=np.int64)
    run = LanczosRows(ctx.ops.L, spmm(ctx.ops.L, np.ascontiguousarray(ctx.V, dtype=np.float64)), rows,
                      max_steps=SOBOLEV_NORMAL_PIN_MAX_STEPS)
    X = np.asarray(ctx.V, dtype=np.float64)[rows]

    def values(mu: float, order: int) -> np.ndarray | None:
        p = int(order)
        Z = run.rows_apply(lambda t: np.maximum(t, 0.0) ** (p - 1) / (1.0 + mu * np.maximum(t, 0.0) ** p), rtol=1e-8,
                           growth=0.25)  # strong weights need hundreds of steps: test convergence at growing sizes
        return None if Z is None else X - mu * Z

    return values


def choose_sobolev_normal_whole(ctx: TuningContext, scored: np.ndarray | None = None,
                                boundary: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[dict, Point]:
    """``mu`` and ``order`` (in {2, 3}) of ``sobolev_normal`` by GCV or Monte-Carlo SURE; ``tangential`` from rho.

    The filter :math:`f(X) = X + \\Pi(Y)(Y - X)`, :math:`Y = H X`, :math:`H = (I + \\mu L^p)^{-1}`,
    is not linear (the projector :math:`\\Pi` uses the normals of ``Y``), so the trace of
    the smoother is replaced by the divergence along the noise directions (Ramani, Blu and
    Unser 2008) with ``K = SOBOLEV_NORMAL_PROBES`` Rademacher probes :math:`b_k = z_k \\odot \\hat N`
    (unit normals of the SURE-smoothed mesh, as for ``two_stage``), :math:`\\delta = 0.1\\rho`:

    .. math:: d = \\frac1K \\sum_k b_k^T \\big(f(X + \\delta b_k) - f(X)\\big)/\\delta, \\qquad
              \\mathrm{GCV} = \\frac{n \\|f(X) - X\\|^2}{(n - d)^2}

    (Craven and Wahba 1979; Li 1985 for its asymptotic optimality with an unknown variance),
    over the ``n`` normal coordinates, used when ``tangential`` = 0 (below half an edge length
    of noise): the update is then along the normals only, one coordinate per vertex. GCV needs
    no ``rho``, which SURE (:math:`\\|f(X) - X\\|^2 - n\\rho^2 + 2\\rho^2 d`) needs and which
    :func:`estimate_noise` over-estimates where the clean mesh has its own vertex-scale detail
    and the noise is far below an edge length (Nefertiti at rho = 0.015: 0.0205 for 0.0153; an
    over-estimate adds :math:`2(\\hat\\rho^2 - \\rho^2) d` and picks a larger mu: SURE lost
    0.77 dB there, GCV 0.40). With ``tangential`` > 0 the update also moves vertices along the
    surface, the residual is no longer one coordinate per vertex, and Monte-Carlo SURE is used
    (there rho comes from the residual energy and is accurate; GCV lost 0.27 dB on the bunny at
    0.5 %, ``tangential`` 0.64, where SURE loses 0.02).

    ``H`` is linear, so :math:`f(X + \\delta b) = Y + \\delta H b` projected on the normals of
    that point: one factorisation per ``mu`` serves the ``3 + 3K`` right-hand sides (with ``tangential`` 1 the
    update is :math:`HX` itself and both terms are Gauss quadratures of ``L`` from one Lanczos run, no solve per
    candidate: the elephant's rule 5.2 -> 1.7 s, the same choice). Using
    :math:`\\mathrm{tr} H` instead (normals held pinned) under-estimates the risk of strong
    smoothing (Nefertiti rho = 0.2: divergence 70.7 vs trace 53.7 at the best mu).
    ``tangential`` = :func:`_tangential_share` of the noise per edge length of that mesh
    (normals of ``Y`` are meaningless above one edge length of noise). ``mu`` by the log
    search of ``sobolev`` for each order (:class:`~meshdenoise.tuning.search.LogSearch`): each
    order's grid, then, for the orders whose grid parabola predicts a score within
    ``SobolevNormalConfig.order_margin`` (2 %) of the least grid score, successive parabolic
    interpolation to 0.02 decades (:meth:`~meshdenoise.tuning.search.LogSearch.refine_parabolic`,
    1 to 4 candidates where the golden section took 9). On the eight benchmark rows: 28 -> 14 s
    on Bunny0.2, 22 -> 10 s on the bunny scanner, normal errors within 0.5 % of the golden
    section's (docs/automatic-parameters.md). The smaller score wins.

    ``scored`` (bool (n,), optional): SURE or GCV of the scored vertices only (the residual
    summed over them, the probes zero elsewhere, so the divergence is the trace of the scored
    block of the Jacobian; ``n`` their count), with ``SOBOLEV_NORMAL_REGION_PROBES`` probes. For a
    region cut out of a larger mesh, whose vertices near a cut see a border the mesh does not have.
    ``boundary`` (``(pinned, values)``, optional): the rows ``pinned`` (bool (n,)) held at
    ``values(mu, order)`` ((pinned count, 3), the whole mesh's result there; ``None``: left free) in
    every solve (Dirichlet data at a region's cut, :func:`whole_result_at`; no pinned row may be scored).
    """
    spec = get_filter("sobolev_normal")
    full = spec.resolve(ctx.given, where="choose_parameters(method='sobolev_normal')")
    if ctx.criterion.name == "gcv":
        raise ValueError("choose_parameters: sobolev_normal is not a linear smoother; use criterion 'sure' or 'oracle'")
    n = ctx.ops.n
    if ctx.rho == 0 and ctx.reference is None:
        return {"mu": 0.0}, Point(0, 0.0, float(n), ctx.V, 0.0)
    smooth = ctx.smoothed("sure").X
    t = float(full["tangential"]) if "tangential" in ctx.given else normal_trust(ctx.rho, mean_edge_length(smooth, ctx.ops))
    orders = [int(full["order"])] if "order" in ctx.given else list(SOBOLEV_NORMAL_ORDERS)
    use_gcv = ctx.reference is None and t == 0.0  # normal-only update: n coordinates; rho not needed
    K = SOBOLEV_NORMAL_PROBES if scored is None else SOBOLEV_NORMAL_REGION_PROBES
    Nh = vertex_normals(smooth, ctx.F)
    z = ctx.colour(np.random.default_rng(0).choice([-1.0, 1.0], size=(n, K)), 1.0 / K)  # Sigma^{1/2} xi if correlated
    Bp = np.hstack([z[:, [k]] * Nh for k in range(K)])  # (n, 3K): probe k in columns 3k..3k+2
    rows = slice(None) if scored is None else np.asarray(scored, dtype=bool)
    n_scored = n if scored is None else int(rows.sum())
    if scored is not None:
        Bp[~rows] = 0.0
    delta = MC_SURE_STEP * ctx.rho
    rhs = np.hstack([ctx.V, Bp])
    pinned = None
    if boundary is not None:
        pinned = np.asarray(boundary[0], dtype=bool)
        if scored is not None and (pinned & rows).any():
            raise ValueError("choose_sobolev_normal_whole: a pinned vertex is scored; pin fewer rings than the margin")
        pinned_values = boundary[1]
    # the whole mesh from config.rule_lanczos_min_vertices: every candidate of either order from one Lanczos
    # run on L (H rhs = rhs - mu f(L) L rhs, f(t) = t^(p-1) / (1 + mu t^p)), a compiled second pass each, no factor
    run, d_max = None, float(ctx.ops.degree.max()) if n else 0.0
    config, spectral = ctx.config_for(DEFAULT), ctx.config_for(SPECTRAL)
    tol = spectral.tol  # a search's scores, to about 1e-6 (tuning/spectral.py), not the filter's 1e-10
    # tangential 1 (noise past an edge length): the update is H X itself, the filter linear, and SURE's two terms are
    # quadratures of L, ||HX - X||^2 = c^T mu^2 (I + mu L^p)^-2 c (c = L^p X) and b^T H b, from one Lanczos run for
    # every candidate of both orders, no solve (the divergence through perturbed normals is b^T H b to rounding)
    quad = None
    if (t == 1.0 and pinned is None and scored is None and ctx.reference is None
            and n >= spectral.min_vertices):
        highs = []
        for order in orders:
            c = np.ascontiguousarray(ctx.V, dtype=np.float64)
            for _ in range(order):
                c = spmm(ctx.ops.L, c)
            highs.append(c)
        quad = CompiledLanczos(ctx.ops.L, np.hstack(highs + [Bp]), max_steps=SOBOLEV_NORMAL_QUADRATURE_MAX_STEPS)
    elif pinned is None and scored is None and n >= config.rule_lanczos_min_vertices:
        run = CompiledLanczos(ctx.ops.L, spmm(ctx.ops.L, np.ascontiguousarray(rhs)), max_steps=LANCZOS_SHIFTED_MAX_STEPS)

    def linear_point(mu: float, order: int) -> Point | None:
        """The candidate's SURE terms by quadrature (``quad``); ``None`` if a rule has not converged."""
        i = orders.index(order)
        # to 1e-10 as the Sobolev rules' quadrature (search.shifted_quadrature): Gauss rules need no second pass, and
        # at 1e-6 the refinement's parabola moved the elephant's mu by 1.6e-6
        r = quad.evaluate(ShiftedInverse(mu, order, 2), range(3 * i, 3 * i + 3), growth=0.25)
        tr = quad.evaluate(ShiftedInverse(mu, order), range(3 * len(orders), 3 * len(orders) + Bp.shape[1]), growth=0.25)
        if r is None or tr is None:
            return None
        p = Point(mu, mu**2 * float(r.sum()), float(tr.sum()) / K, None)
        p.score = ctx.criterion.score(p, n_scored, ctx.rho)
        return p
    searches: dict[int, LogSearch] = {}

    def by_lanczos(mu: float, order: int) -> bool:
        return run is not None and d_max * mu ** (1.0 / order) <= config.rule_lanczos_reach

    def g(mu: float, order: int) -> ShiftedInverse:
        # x^(p-1) / (1 + mu x^p): a lifted ShiftedInverse, its coefficients by tridiagonal solves and products where
        # the plain function took an eigenproblem per column and test (the bunny scanner: 714 of them, 0.12 s)
        return ShiftedInverse(mu, order, lift=order - 1)

    def point(mu: float, out: np.ndarray) -> Point:
        Y = out[:, :3]
        X = project_update(ctx.V, Y, area_normals(Y, ctx.F), t)
        div = (float(n) if ctx.reference is not None
               else _projected_divergence(ctx.V, ctx.F, out, Bp, t, delta, config.divergence_chunk_bytes))
        p = Point(mu, float(np.sum((X - ctx.V)[rows] ** 2)), div, X)
        p.score = gcv(p.residual_sq, div, n_scored) if use_gcv else ctx.criterion.score(p, n_scored, ctx.rho)
        return p

    for order in orders:
        key = digest(ctx.ops.F, order, rhs)

        def evaluate(mu: float, order=order, key=key) -> Point:
            if quad is not None and (p := linear_point(mu, order)) is not None:
                return p
            held = pinned_values(mu, order) if pinned is not None else None
            if held is not None:  # the probes are zero there, and the held values do not follow them
                rhs_p = rhs.copy()
                rhs_p[pinned, :3] = held
                rhs_p[pinned, 3:] = 0.0
                return point(mu, SPDSolver(shifted_matrix(ctx.ops, mu, order), pinned).solve(rhs_p))
            if by_lanczos(mu, order):
                Z = run.apply(g(mu, order), rtol=tol, growth=0.25)
                if Z is not None:
                    return point(mu, rhs - mu * Z)
            return point(mu, solve_shifted(ctx.ops, order, mu, rhs, key, memo=scored is None))  # a region: nothing kept

        def evaluate_many(mus: list, order=order) -> list:  # a grid's candidates in one second pass of the run
            batch = [mu for mu in mus if by_lanczos(mu, order)]
            Zs = run.apply_many([g(mu, order) for mu in batch], rtol=tol, growth=0.25) if batch else None
            done = dict(zip(batch, Zs)) if Zs is not None else {}
            return [point(mu, rhs - mu * done[mu]) if mu in done else evaluate(mu) for mu in mus]

        searches[order] = LogSearch(evaluate, ctx.mu_guess(order), evaluate_many=evaluate_many if run is not None else None)
    if run is not None:  # both orders' first grids in one second pass of the run (in groups of bounded size)
        todo = [(order, mu) for order, search in searches.items() for mu in search.first_grid() if by_lanczos(mu, order)]
        per = max(1, config.batch_bytes // (8 * n * rhs.shape[1]))
        for i in range(0, len(todo), per):
            group = todo[i:i + per]
            Zs = run.apply_many([g(mu, order) for order, mu in group], rtol=tol, growth=0.25)
            if Zs is None:
                break  # a candidate past max_steps: the searches' own calls fall back to the factor
            for (order, mu), Z in zip(group, Zs):
                searches[order].add(mu, point(mu, rhs - mu * Z))
            del Zs
    for search in searches.values():
        search.bracket()
    # each order's grid, then the refinement only for the orders that can still win: those whose parabola through
    # the grid minimum predicts a score within config.order_margin of the least grid score (a refinement
    # gains about 1 % on a grid 0.75 decades apart; the other order's search was half the rule's factorisations)
    least = min(s.bracket().score for s in searches.values())
    best, best_order = None, None
    for order, search in searches.items():
        if search.predicted() <= least + config.order_margin * abs(least):
            search.refine_parabolic()
        p = search.best
        if best is None or p.score < best.score:
            best, best_order = p, order
    return {"mu": float(best.value), "order": best_order, "tangential": t}, best

"""``sinkhorn``'s automatic rule: ``t`` and ``iterations`` by SURE along one run of the linear configuration (graph
Laplacian, uniform measure, debiased), on a sampled region of a large mesh; its settings (:class:`SinkhornConfig`) and the
held-out sweep of its normals criterion (``SINKHORN_NORMALS``)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..registry import get_filter
from ..solvers import shifted_cg_bound
from ..tuning import search
from ..tuning.config import SEARCH, SPECTRAL, check_fields
from ..tuning.context import TuningContext
from ..tuning.memo import MEMO, digest
from ..tuning.risk import Point, probe_block
from ..tuning.search import region_rule, search_log, shifted_reach
from ..tuning.spectral import SpectralFailed, SpectralSearch, heat_kernel_spectral
from ..tuning.sweep import HeldOutRule, Sweep, geometric

__all__ = ["choose_sinkhorn", "choose_sinkhorn_whole", "SinkhornConfig", "SINKHORN_NORMALS", "sinkhorn_reach"]

SINKHORN_MAX_ITERATIONS = 8
SINKHORN_MARGIN = 4  # the region's scored vertices at least this many rings from a cut


@dataclass(frozen=True)
class SinkhornConfig:
    """The sinkhorn rule's settings (``choose_parameters(..., config=SinkhornConfig(...))``): the values, and where
    they were measured.

    Attributes
    ----------
    patience : int
        A run over k stops after this many iterations past its best score (not with the oracle).
    spectral_max_iterations : int
        The rule's runs over k by Lanczos (all k at once) up to this many iterations ...
    spectral_max_bound : float
        ... and for a t whose substep (I + (t/s) L) has a CG bound (solvers.shifted_cg_bound, a proxy of the Lanczos
        steps) at most this: the steps grow like sqrt(t) where a factor's path costs the same at any t (the
        elephant's grid reached t = 200: 1.6 s by Lanczos, 0.2 s by factors).
    region : int
        From ``SearchConfig.region_min_vertices`` the rule runs on a sampled region of this many vertices ...
    patches : int
        ... in this many balls (each candidate t is a factorisation and up to 16 solves of 3 + probes columns of the
        whole mesh: face000, 85k vertices, 54 s).
    """

    patience: int = 2
    spectral_max_iterations: int = 16
    spectral_max_bound: float = 100
    region: int = 32_000
    patches: int = 8

    def __post_init__(self) -> None:
        check_fields(self, positive=("patience", "region", "patches"),
                     nonnegative=("spectral_max_iterations", "spectral_max_bound"))


DEFAULT = SinkhornConfig()


def sinkhorn_reach(chosen: dict) -> int:
    """Rings over which a cut moves the result of ``chosen``'s :math:`(2G - G^2)^k`, :math:`G = (I + tL)^{-1}`.

    The ``2k`` solves with ``G`` spread about as far as one with :math:`(I + 2kt\\, L)^{-1}`
    (:func:`~meshdenoise.tuning.search.shifted_reach` at ``mu = 2 k t``, order 1; for small ``t``
    both are the heat kernel at time ``2kt``).

    Examples
    --------
    >>> sinkhorn_reach({"t": 0.2, "iterations": 8})
    10
    """
    return shifted_reach(2.0 * float(chosen["t"]) * max(int(chosen.get("iterations", 1)), 1), 1)


def choose_sinkhorn(ctx: TuningContext) -> tuple[dict, Point]:
    """:func:`choose_sinkhorn_whole`, from ``SearchConfig.region_min_vertices`` vertices on a
    sampled region of ``SinkhornConfig.region`` vertices (:func:`~meshdenoise.tuning.search.region_rule`: the vertices
    more than :func:`sinkhorn_reach` rings from a cut scored, the region cut again while the choice reaches further),
    on the whole mesh below. ``t`` weighs the combinatorial Laplacian and ``iterations`` counts solves, both
    properties of the noise per edge and of the local shape, so the region's choice carries to the whole mesh.
    """
    spec = get_filter("sinkhorn")
    full = spec.resolve(ctx.given, where="choose_parameters(method='sinkhorn')")
    if full["laplacian"] != "graph" or full["measure"] != "uniform" or not full["debias"]:
        raise ValueError(
            "choose_parameters: sinkhorn is a linear smoother only with laplacian='graph', measure='uniform' and "
            f"debias=True (got laplacian={full['laplacian']!r}, measure={full['measure']!r}, debias={full['debias']!r}); "
            "automatic parameters need that configuration"
        )
    config = ctx.config_for(DEFAULT)
    margin = (first_margin(ctx) if ctx.n >= ctx.config_for(SEARCH).region_min_vertices and not ctx.oracle
              else SINKHORN_MARGIN)
    return region_rule(ctx, choose_sinkhorn_whole, config.region, config.patches, margin, reach=sinkhorn_reach)


def first_margin(ctx: TuningContext) -> int:
    """The first region's margin: :func:`sinkhorn_reach` of the search's start (``t`` from the averaging path,
    the most iterations), at least ``SINKHORN_MARGIN``, at most ``REGION_MAX_MARGIN`` rings. A narrower cut pulled
    ``t`` low and was cut again (400k elephant: three cuts, 48 s; one at 16 rings, a third of that)."""
    start = {"t": ctx.mu_guess(1), "iterations": ctx.given.get("iterations", SINKHORN_MAX_ITERATIONS)}
    return int(max(SINKHORN_MARGIN, min(search.REGION_MAX_MARGIN, sinkhorn_reach(start))))


def choose_sinkhorn_whole(ctx: TuningContext, scored: np.ndarray | None = None) -> tuple[dict, Point]:
    """``t`` and ``iterations`` of the OT filter with the uniform measure and graph Laplacian.

    That configuration is linear: :math:`T = G = (I + \\tfrac{t}{s} L)^{-s}` (the
    Sinkhorn scaling of a doubly stochastic kernel is 1), and ``k`` twiced iterations
    give :math:`H_k = (2G - G^2)^k = (I - (I - G)^2)^k`. For each ``t`` the SURE curve over
    ``k = 1 .. SINKHORN_MAX_ITERATIONS`` is read along one run (probes carried through the
    same Cholesky solves); ``t`` minimises the best of it (:func:`~meshdenoise.tuning.search.search_log`, starting at
    the ``sobolev`` guess). A given ``iterations`` is held. The run for one ``t`` stops ``SinkhornConfig.patience``
    iterations after its best score (each iteration smooths more: the score over ``k`` is taken to have one
    minimum): on face000 the best count is 1, and the SURE rule made 148 solves instead of 224.

    ``scored`` (bool (n,), optional; a sampled region's inner vertices): the risk of those
    vertices only, the residual and the probes' products :math:`z_i (H z)_i` summed over them
    (:math:`\\sum_{i \\in S} (H \\Sigma)_{ii}`, the coupling to the unscored rows included, which
    zeroing the probes outside would drop under correlated noise), SURE with their count.
    """
    from ..ot import MeshHeatKernel

    full = get_filter("sinkhorn").resolve(ctx.given, where="choose_parameters(method='sinkhorn')")
    config, spectral_config = ctx.config_for(DEFAULT), ctx.config_for(SPECTRAL)
    steps = full["steps"]
    held = ctx.given.get("iterations")
    ks = [held] if held is not None else list(range(1, SINKHORN_MAX_ITERATIONS + 1))
    n = ctx.ops.n
    Z, s = probe_block(n, ctx.exact)
    rows = slice(None) if scored is None else np.asarray(scored, dtype=bool)
    count = n if scored is None else int(np.count_nonzero(rows))

    def score(p: Point) -> float:
        return ctx.criterion.score(p, count, ctx.rho)

    best_k: dict[float, int] = {}

    early = held is None and not ctx.oracle  # a run's length then depends on the score: rho and criterion in the key
    key = digest(ctx.F, ctx.V, Z, steps, max(ks),
                 *((ctx.criterion.name, float(ctx.rho or 0.0), config.patience) if early else ()),
                 *(() if scored is None else (rows,)))

    def stop(out: list, scores: list, t: float) -> bool:  # early: past config.patience iterations after the best
        scores.append(score(Point(t, out[-1][1], out[-1][2], None)))
        return len(scores) - 1 - int(np.argmin(scores)) >= config.patience

    def path(t: float) -> list:
        K = MeshHeatKernel(ctx.V, ctx.F, t, laplacian="graph", mass="uniform", steps=steps)
        Y, out, scores = np.hstack([ctx.V, Z]), [], []
        for _ in range(max(ks)):
            GY = K.solve(Y)
            Y = 2.0 * GY - K.solve(GY)
            X = Y[:, :3].copy()
            out.append((X, float(np.sum((X - ctx.V)[rows] ** 2)), s * float(np.sum(Z[rows] * Y[rows, 3:]))))
            if early and stop(out, scores, t):
                break
        return out

    # the map is g(L) (heat_kernel_spectral): every (t, k) from two Lanczos runs, the probes' one shared by the whole
    # search (tuning/spectral.py), no factorisation; the same terms to about 1e-10, the same early stop
    lanczos = (not ctx.oracle and Z.shape[1] < n and n >= spectral_config.min_vertices
               and max(ks) <= config.spectral_max_iterations)
    if lanczos:
        family = lambda tk: heat_kernel_spectral(ctx.ops, tk[0], steps, tk[1])  # noqa: E731
        spectral = SpectralSearch(ctx.V, family, config=spectral_config)
        spectral.spectral((ctx.mu_guess(1), 1))  # the search's start: its matrix (every (t, k)'s) for the probes' run
        terms = spectral.probes(Z, [np.where(np.asarray(rows)[:, None], Z, 0.0) if scored is not None else Z])
        exact_path = path

        def path(t: float) -> list:  # noqa: F811
            if shifted_cg_bound(ctx.ops, t / steps, 1, spectral.tol) > config.spectral_max_bound:
                return exact_path(t)  # Lanczos's steps grow like sqrt(t): a strong kernel by its factor
            try:
                Xs = spectral.coordinates_many([(t, k) for k in range(1, max(ks) + 1)])
                out, scores = [], []
                for k, X in enumerate(Xs, start=1):
                    out.append((X, float(np.sum((X - ctx.V)[rows] ** 2)), s * float(np.sum(terms((t, k))[0]))))
                    if early and stop(out, scores, t):
                        break
                return out
            except SpectralFailed:  # a run past SpectralConfig.max_steps: the factor's path
                return exact_path(t)

    def evaluate(t: float) -> Point:
        best = None
        for k, (X, res, tr) in enumerate(MEMO.get(("sinkhorn", key, float(t)), lambda: path(t)), start=1):
            if k in ks:
                p = Point(t, res, tr, X)
                p.score = score(p)
                if best is None or p.score < best.score:
                    best, best_k[t] = p, k
        return best

    if held == 0:
        return {"t": float(get_filter("sinkhorn").param("t").default)}, Point(0, 0.0, float(n), ctx.V, 0.0)
    p = search_log(evaluate, ctx.mu_guess(1), parabolic=True)  # 1 to 4 runs where the golden section took 9
    return {"t": float(p.value), "iterations": int(best_k[p.value])}, p


# criterion "normals": t from 0.05 to 200 in steps of 2^(1/3), 3 projections, the least held-out face-normal loss: on
# the corpus's tune half 1.21 times the sweep's best error (geometric mean; 1.15 on the 13 cases where the normal-risk
# search it replaced read 1.59) (benchmarks/results/held-out-sweeps.md)
SINKHORN_NORMALS = HeldOutRule((Sweep("t", geometric(0.05, 200.0, 2 ** (1 / 3)), (("iterations", 3),)),))

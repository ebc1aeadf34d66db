"""``sobolev_gls``' automatic rule: ``mu`` and ``beta`` by SURE (or GCV), on a sampled region of a large mesh,
and the held-out sweep of its normals criterion (``GLS_NORMALS``)."""

from __future__ import annotations

import logging
import math
from typing import Any

import numpy as np

from ..geometry import coherent_normals, coherent_normals_derivative, vertex_normals
from ..multishift import shifted_family_cg
from ..registry import get_filter
from ..solvers import shifted_solver
from ..tuning.config import SEARCH
from ..tuning.context import TuningContext
from ..tuning.noise_level import mean_edge_length, normal_spread, normal_trust
from ..tuning.risk import Point, gcv
from ..tuning.search import best_shifted, probe_count, region_rule, search_log, shifted_reach, solve_shifted
from ..tuning.sweep import HeldOutRule, Sweep, geometric
from ._gls_solve import CG_MAXITER, CG_TOL, DEFAULT, apply_weight, correction_rhs, normal_weighted_solve

__all__ = ["choose_sobolev_gls", "choose_sobolev_gls_whole", "GLS_NORMALS", "SOBOLEV_GLS_BETAS"]

log = logging.getLogger("meshdenoise.auto")

SOBOLEV_GLS_BETAS = (1.0, 2.0, 3.0, 5.0, 8.0, 12.0)  # candidate tangential weights
SOBOLEV_GLS_PROBES = 8  # Hutchinson probes of the divergence (the same for every candidate) up to ...
SOBOLEV_GLS_PROBE_REFERENCE = 10_000  # ... this many scored vertices, then fewer (search.probe_count: m x scored >=
# 80,000, the trace's relative error no larger than 8 probes' on 10k; at least 4). Each probe is three columns of
# every solve: the elephant's whole-mesh sweep 8 -> 4 probes, 4.6 -> 3.4 s, beta 5 -> 3 (18.53 -> 18.35 degrees,
# the oracle 18.06; 8 probes chose 5, 3, 5 for seeds 0, 1, 2, where 4 chose 3 for all three)
SOBOLEV_GLS_EXACT_MAX = 400  # exact traces up to this many vertices: 3n right-hand sides through CG per candidate
SOBOLEV_GLS_REGION = 10_000  # from SearchConfig.region_min_vertices the rule runs on a sampled region of this many vertices
SOBOLEV_GLS_PATCHES = 8  # ... made of this many balls of vertices
SOBOLEV_GLS_MARGIN = 8  # ... scoring only its vertices more than this many rings from a cut
SOBOLEV_GLS_SPREAD_SAMPLES = 4  # simulated noise draws of the parametric bootstrap of the normals' spread
SOBOLEV_GLS_LOOSE_TOL = 1e-3  # on a region, or before the normals search: CG's relative residual per candidate (1e-9
# on a whole mesh), each solve started from the nearest candidate's solution. Measured on the 8 rows of
# benchmarks/filter_time.py against 1e-6: every sweep score within 9.6e-5 (relative; 1e-4: 8.8e-6), the best beta ahead of
# the next by 2.0e-3 or more (the elephant: 21 times the error), the same choices; the elephant's sweep 27 -> 19 (1e-4)
# -> 14 (1e-3) preconditioner solves
SOBOLEV_GLS_SWEEP_TOL = 1e-2  # ... and for a sweep over beta alone (mu held: before the normals search), whose candidates
# are 26 % or more apart: measured on the 8 rows of benchmarks/filter_time.py against 1e-6, every score's gap to the best
# moved by at most 4.2 % of itself (the bunny scanner; the elephant 4.0 %), the same betas; the elephant's sweep
# 0.88 -> 0.59 s (15 -> 9 steps), the bunny scanner's 0.52 -> 0.29 s
SOBOLEV_GLS_LOOSE_WARM = 4  # ... each solve started from the nearest of the last this many candidates


def _normals_derivative(X0: np.ndarray, F: np.ndarray, S: Any, B: np.ndarray) -> np.ndarray:
    """:math:`\\dot N_k = N'(X_0)[S b_k]` for every probe ``b_k`` of ``B`` (n, 3, k): the normals' derivative
    :func:`_normals_divergence` reads, the same for every ``beta`` at one ``mu`` (a sweep computes it once)."""
    n, _, k = B.shape
    return coherent_normals_derivative(X0, F, S.solve(B.reshape(n, -1)).reshape(n, 3, k))


def _normals_divergence(
    X0: np.ndarray, F: np.ndarray, r: np.ndarray, N: np.ndarray, beta: float, S: Any, B: np.ndarray, AiB: np.ndarray,
    dN: np.ndarray | None = None,
) -> float:
    """The part of :math:`\\sum_k b_k^T J b_k` of ``sobolev_gls`` that comes from its normals following the input.

    With :math:`A = W(N) + \\mu L^p \\otimes I_3`, :math:`W = I + (\\beta - 1) P`, :math:`P = I - N N^T`, the
    output is :math:`X = X_0 + A^{-1} (\\beta - 1) P (V - X_0)`; differentiating through
    :math:`N = N(X_0)`, :math:`X_0 = S V`, along :math:`b` adds

    .. math:: A^{-1} g(b), \\qquad g(b) = -(\\beta - 1)\\, \\big[\\dot N (N \\cdot r) + N (\\dot N \\cdot r)\\big],
              \\quad \\dot N = N'(X_0)[S b], \\quad r = V - X

    to the pinned-normal Jacobian, so :math:`b^T A^{-1} g(b) = (A^{-1} b)^T g(b)` (``A`` symmetric; ``AiB`` holds
    :math:`A^{-1} b_k`, solved with the rest). ``B``, ``AiB`` (n, 3, k); returns the sum over ``k``. ``dN``:
    :func:`_normals_derivative`'s result when the caller has it.
    """
    if dN is None:
        dN = _normals_derivative(X0, F, S, B)
    g = dN * np.sum(N * r, axis=1)[:, None, None] + N[:, :, None] * np.sum(dN * r[:, :, None], axis=1, keepdims=True)
    return -(beta - 1.0) * float(np.sum(AiB * g))


def choose_sobolev_gls(ctx: TuningContext) -> tuple[dict, Point]:
    """:func:`choose_sobolev_gls_whole` on a sampled region of ``SOBOLEV_GLS_REGION`` vertices from
    ``SearchConfig.region_min_vertices`` vertices (:func:`~meshdenoise.tuning.search.region_rule`),
    on the whole mesh below (docs/scale.md: the same choice at 100k and 400k, a bounded cost).
    """
    order = int(get_filter("sobolev_gls").resolve(ctx.given, where="choose_parameters(method='sobolev_gls')")["order"])

    def on_region(sub: TuningContext, scored: np.ndarray | None, previous: dict | None = None) -> tuple[dict, Point]:
        return choose_sobolev_gls_whole(sub, scored, previous, loose=scored is not None)

    # a region grown for a strong weight refines only mu, beta held at the smaller region's choice
    # (choose_sobolev_gls_whole's previous): with mu held here too it would change nothing (the bunny scanner: 1.9 s)
    return region_rule(ctx, on_region, SOBOLEV_GLS_REGION, SOBOLEV_GLS_PATCHES, SOBOLEV_GLS_MARGIN,
                       reach=lambda chosen: shifted_reach(chosen["mu"], order) if chosen.get("mu") else 0, restart=True)


def choose_sobolev_gls_whole(ctx: TuningContext, scored: np.ndarray | None = None,
                             previous: dict | None = None, loose: bool = False) -> tuple[dict, Point]:
    """``mu`` and ``beta`` of ``sobolev_gls``: SURE (GCV at low noise) with the filter's full divergence.

    The filter is :math:`f(X) = X_0 + A^{-1} (\\beta - 1) P (X - X_0)`, :math:`X_0 = (I + \\mu L^p)^{-1} X`,
    :math:`A = W + \\mu L^p \\otimes I_3`, with :math:`W = I + (\\beta - 1) P` and :math:`P = I - \\hat N \\hat N^T`
    built from the normals :math:`\\hat N` of :math:`X_0`. For pinned normals it is the linear map
    :math:`H = A^{-1} W`; its Jacobian :math:`J` adds the normals following the input
    (:func:`_normals_divergence`, through the analytic derivative of
    :func:`~meshdenoise.geometry.coherent_normals`). With the normals held pinned the divergence is
    under-counted where they follow the noise, and SURE picked ``mu`` too small (Nefertiti at
    rho = 1, 3 edge lengths of noise: auto loss 0.63 dB over 5 seeds, 0.35 with :math:`J`).
    The model's noise covariance is :math:`\\rho^2 N_i N_i^T` with
    :math:`N_i` the *clean* mesh's vertex normals, unknown; they are modelled as spread
    around the normals :math:`\\bar N_i` of the SURE-best bi-Laplacian estimate
    :math:`X_s = H_s X` (as in :func:`_choose_sobolev_axes`) with mean :math:`\\sin^2` angle :math:`\\tau`:

    .. math:: \\hat\\Sigma_i = \\rho^2 \\big[(1 - \\tau) \\bar N_i \\bar N_i^T
              + \\tfrac{\\tau}{2} (I - \\bar N_i \\bar N_i^T)\\big],

    :math:`\\tau` by a parametric bootstrap (:func:`~meshdenoise.tuning.noise_level.normal_spread`): noise of the model drawn on
    :math:`X_s`, smoothed by :math:`H_s`, and the spread of the resulting normals around
    :math:`\\bar N` (``SOBOLEV_GLS_SPREAD_SAMPLES`` draws; it follows the clean normals' spread
    around :math:`\\bar N`, measured: Fandisk0.3 0.020 vs 0.021, Block0.4 0.022 vs 0.025, Nefertiti
    rho = 0.2 0.080 vs 0.080, elephant rho = 0.2 0.121 vs 0.126). Without :math:`\\tau` the
    tangential noise that a large ``beta`` keeps is not counted and SURE picks ``beta`` too large
    (elephant at rho = 0.2: 26.9 dB instead of 28.3). It was first read from the tangential
    residual :math:`X - X_s`, which also holds the shape's own tangential residual (the drift of
    irregular sampling): 0.113 on Fandisk0.3 where the clean normals' spread is 0.021, so ``beta``
    came out too small on low-noise meshes (Bunny0.2: beta 5, 52.23 dB against 53.02 for the
    oracle's beta = 12).
    Then

    .. math:: \\mathrm{SURE}(\\mu, \\beta) = \\|HX - X\\|_F^2 - \\mathrm{tr}\\,\\hat\\Sigma
              + 2\\, \\mathrm{tr}(\\hat\\Sigma H), \\qquad
              \\mathrm{tr}(\\hat\\Sigma J) \\approx \\frac1m \\sum_k b_k^T J b_k, \\quad b_{k,i} = \\hat\\Sigma_i^{1/2} z_{k,i},

    (:math:`\\|HX - X\\|` standing for :math:`\\|f(X) - X\\|`), Hutchinson's estimator with Rademacher
    :math:`z_{k,i} \\in \\{\\pm 1\\}^3` (``SOBOLEV_GLS_PROBES`` of them up to ``SOBOLEV_GLS_PROBE_REFERENCE``
    scored vertices, fewer above, :func:`~meshdenoise.tuning.search.probe_count`; exact, one probe per coordinate,
    up to ``SOBOLEV_GLS_EXACT_MAX`` vertices: 3n right-hand sides per candidate). :math:`A^{-1} b_k`
    is solved with the coordinates in one block conjugate-gradient run and serves both parts:
    :math:`b^T A^{-1} W b = (A^{-1} b)^T W b`. Below half an edge length of noise
    (:func:`_tangential_share` 0) the update is along the normals and the score is GCV over the
    normal coordinates, as for ``sobolev_normal``:

    .. math:: \\mathrm{GCV} = \\frac{d\\, \\|f(X) - X\\|_F^2}{(d - \\mathrm{tr}(\\hat\\Sigma J) / \\rho^2)^2},
              \\qquad d = \\mathrm{tr}\\, \\hat\\Sigma / \\rho^2 = n,

    :math:`d` taken by the same probes as the trace, so that their errors cancel as :math:`J \\to I`
    (with :math:`n` itself, 8 probes drove the search to ``mu`` = 0 on a 642-vertex sphere). GCV
    needs no noise level, which :func:`estimate_noise` over-reads on small meshes at low noise
    (Nefertiti rho = 0.015: auto loss 0.75 dB with SURE, 0.23 with GCV, 5 seeds).
    Search: ``mu`` by :func:`~meshdenoise.tuning.search.search_log` at ``beta = 3``, then ``beta`` over
    ``SOBOLEV_GLS_BETAS`` at that ``mu``, then ``mu`` again at the best ``beta``; with ``mu`` given, the
    sweep over ``beta`` only (as :func:`choose_sobolev_gls` runs it when the normals criterion follows).

    ``scored`` (bool (n,), optional): the risk of the scored vertices only (residual summed over
    them, probes zero elsewhere: the trace of the scored block of :math:`\\hat\\Sigma J`), for a
    region cut out of a larger mesh (:func:`~meshdenoise.tuning.search.region_rule`). With ``loose``
    (set there, and for the sweep before the normals search) each candidate's CG stops at a relative residual of
    ``SOBOLEV_GLS_LOOSE_TOL`` (``SOBOLEV_GLS_SWEEP_TOL`` with ``mu`` given: a sweep over ``beta`` alone) and starts
    from the nearest of the last candidates' solutions. ``previous`` (the
    choice on a smaller region, whose border pulled ``mu`` down): ``beta`` is held at its value and ``mu``
    refined around its ``mu`` (:func:`~meshdenoise.tuning.search.search_log` on three points 0.2 decades apart,
    4 golden steps).
    """
    spec = get_filter("sobolev_gls")
    full = spec.resolve(ctx.given, where="choose_parameters(method='sobolev_gls')")
    if ctx.criterion.name == "gcv":
        raise ValueError("choose_parameters: sobolev_gls is not a linear smoother; use criterion 'sure' or 'oracle'")
    n, order = ctx.ops.n, full["order"]
    if ctx.rho == 0 and ctx.reference is None:
        return {"mu": 0.0, "beta": float(full["beta"])}, Point(0, 0.0, float(n), ctx.V, 0.0)
    exact = ctx.exact if ctx.exact is not None else n <= SOBOLEV_GLS_EXACT_MAX
    config = ctx.config_for(DEFAULT)
    if ctx.reference is None:
        # noise directions: normals Nn of the SURE-best bi-Laplacian estimate Xs; the true ones (the clean mesh's
        # vertex normals) spread around them by tau = E sin^2(angle), by a parametric bootstrap (_normal_spread)
        # its coordinates by the factor the bootstrap smooths with (one more 3-column solve), not by the search's own
        # CG or Lanczos run: the bunny scanner's region 0.08 s less
        best_s = best_shifted(ctx.V, ctx.ops, 2, ctx.rho, "sure", ctx.exact, center=ctx.mu_guess(2), coordinates=False,
                              config=ctx.config_for(SEARCH))
        mu_s = best_s.value
        Xs = best_s.X if best_s.X is not None else solve_shifted(ctx.ops, 2, mu_s, ctx.V)
        Nn = vertex_normals(Xs, ctx.F)
        tau = normal_spread(Xs, ctx.F, lambda Y: solve_shifted(ctx.ops, 2, mu_s, Y), ctx.rho, SOBOLEV_GLS_SPREAD_SAMPLES)
        if exact:
            z = np.eye(3 * n).reshape(n, 3, 3 * n)
            s = 1.0
        else:
            m = probe_count(n if scored is None else int(np.count_nonzero(scored)), SOBOLEV_GLS_PROBES,
                            SOBOLEV_GLS_PROBE_REFERENCE)
            z = np.random.default_rng(0).choice([-1.0, 1.0], size=(n, 3, m))
            s = 1.0 / m
        z = ctx.colour(z.reshape(n, -1), s / 3.0).reshape(z.shape)  # correlated noise: each coordinate Sigma^{1/2} xi
        zn = np.sum(Nn[:, :, None] * z, axis=1, keepdims=True) * Nn[:, :, None]
        B = math.sqrt(1.0 - tau) * zn + math.sqrt(tau / 2.0) * (z - zn)  # probes b = Sigma^{1/2} z / rho
        if scored is not None:
            B[~np.asarray(scored, dtype=bool)] = 0.0
        noise_sq = ctx.rho**2 * float(np.sum(B * B)) * s
        # below half an edge length of noise the normals hardly move and GCV (no rho) scores the n normal
        # coordinates, as for sobolev_normal; rho is over-read there on small meshes (Nefertiti 0.015)
        use_gcv = normal_trust(ctx.rho, mean_edge_length(Xs, ctx.ops)) == 0.0
        # GCV's n - tr(H) is tr(Sigma (I - J)) / rho^2; n taken by the same probes as tr, so that their errors
        # cancel as J -> I (with n itself, 8 probes' error drove the search to mu -> 0 on a 642-vertex sphere)
        noise_dof = noise_sq / ctx.rho**2
        log.info("sobolev_gls: tangential share of the noise tau = %.4g", tau)
    rows = slice(None) if scored is None else np.asarray(scored, dtype=bool)
    evaluated: dict[tuple, Point] = {}
    tol = (SOBOLEV_GLS_SWEEP_TOL if "mu" in ctx.given else SOBOLEV_GLS_LOOSE_TOL) if loose else CG_TOL
    warm: list[tuple[float, float, np.ndarray]] = []  # (log10 mu, log10 beta, solution) of the last candidates

    def start(mu: float, beta: float) -> np.ndarray | None:
        if not warm:
            return None
        near = min(warm, key=lambda w: abs(w[0] - math.log10(mu)) + abs(w[1] - math.log10(beta)))
        return near[2]

    presolved: dict[tuple, np.ndarray] = {}  # a sweep's solves at one mu, by one CG run for all its betas
    isotropic: dict[float, tuple] = {}  # the last mu's solver, X0 and normals: a sweep's betas share them
    derivative: dict[float, np.ndarray] = {}  # the last mu's normals derivative along the probes: so do they

    def isotropic_at(mu: float) -> tuple:
        if mu not in isotropic:
            isotropic.clear()
            derivative.clear()
            S = shifted_solver(ctx.ops, mu, order)
            X0 = S.solve(ctx.V)
            isotropic[mu] = (S, X0, coherent_normals(X0, ctx.F))
        return isotropic[mu]

    def derivative_at(mu: float) -> np.ndarray:
        if mu not in derivative:
            S, X0, _ = isotropic_at(mu)
            derivative[mu] = _normals_derivative(X0, ctx.F, S, B)
        return derivative[mu]

    def presolve(mu: float, betas: tuple) -> None:
        """The sweep's systems :math:`(I + \\mu L^p + (\\beta - 1) P_T) Y = [P_T (X - X_0), B]` for every ``beta``
        (> 1, not yet evaluated) at once (:func:`~meshdenoise.multishift.shifted_family_cg`: one CG run preconditioned
        by the factor of :math:`I + \\mu L^p`, the correction's right-hand side scaled by :math:`\\beta - 1` after)."""
        todo = [b for b in betas if b != 1.0 and (round(math.log10(mu), 9), float(b)) not in evaluated]
        if ctx.reference is not None or n <= config.dense_max_vertices or len(todo) < config.family_min_betas:
            return
        S, X0, N = isotropic_at(mu)
        rhs = np.concatenate([correction_rhs(N, 2.0, ctx.V, X0)[:, :, None], B], axis=2)  # beta 2: P_T (X - X0)
        outs = shifted_family_cg(lambda Y: S.solve(Y.reshape(n, -1)).reshape(Y.shape),
                                 lambda Y: Y - N[:, :, None] * np.sum(N[:, :, None] * Y, axis=1, keepdims=True),
                                 rhs, [b - 1.0 for b in todo], tol=tol, maxiter=CG_MAXITER)
        for b, out in zip(todo, outs):
            out[:, :, 0] *= b - 1.0
            presolved[(round(math.log10(mu), 9), float(b))] = out

    def evaluate(mu: float, beta: float) -> Point:
        key = (round(math.log10(mu), 9), float(beta))
        if key not in evaluated:
            S, X0, N = isotropic_at(mu)
            if ctx.reference is not None:
                X = X0 if beta == 1.0 else X0 + normal_weighted_solve(ctx.ops, N, beta, mu, order,
                                                                      correction_rhs(N, beta, ctx.V, X0), config=config)
                p = Point(mu, float(np.sum((X - ctx.V) ** 2)), 0.0, X)
                p.score = float(np.sum((X - ctx.reference) ** 2))
            else:
                if beta == 1.0:
                    X = X0
                    HB = S.solve(B.reshape(n, -1)).reshape(B.shape)
                    tr = s * float(np.sum(B * HB))
                else:
                    # A^-1 b only: b^T A^-1 W b = (A^-1 b)^T W b (A symmetric), and the normals' part needs A^-1 b too
                    out = presolved.pop(key, None)
                    if out is None:
                        rhs = np.concatenate([correction_rhs(N, beta, ctx.V, X0)[:, :, None], B], axis=2)
                        out = normal_weighted_solve(ctx.ops, N, beta, mu, order, rhs, tol=tol,
                                                    x0=start(mu, beta) if loose else None, config=config)
                    if loose:
                        warm.append((math.log10(mu), math.log10(beta), out))
                        del warm[:-SOBOLEV_GLS_LOOSE_WARM]
                    X, AiB = X0 + out[:, :, 0], out[:, :, 1:]
                    fixed_normals = float(np.sum(AiB * apply_weight(N, beta, B)))
                    tr = s * (fixed_normals + _normals_divergence(X0, ctx.F, ctx.V - X, N, beta, S, B, AiB,
                                                                  derivative_at(mu)))
                p = Point(mu, float(np.sum((X - ctx.V)[rows] ** 2)), tr, X)
                p.score = gcv(p.residual_sq, tr, noise_dof) if use_gcv else p.residual_sq - noise_sq + 2.0 * ctx.rho**2 * tr
            evaluated[key] = (p, beta)
            log.debug("sobolev_gls: mu %.6g beta %g score %.9g", mu, beta, p.score)
        return evaluated[key][0]

    if previous is not None and not ({"mu", "beta"} <= set(ctx.given)):  # refine a smaller region's choice
        beta = float(full["beta"]) if "beta" in ctx.given else float(previous["beta"])
        mu = float(full["mu"]) if "mu" in ctx.given else float(
            search_log(lambda m: evaluate(m, beta), float(previous["mu"]), golden_steps=4, spacing=0.2,
                       half_width=1).value)
        return {"mu": float(mu), "beta": float(beta)}, evaluate(mu, beta)
    beta = float(full["beta"]) if "beta" in ctx.given else 3.0
    held_mu = "mu" in ctx.given
    mu = float(full["mu"]) if held_mu else float(search_log(lambda m: evaluate(m, beta), ctx.mu_guess(order), golden_steps=6).value)
    if "beta" not in ctx.given:
        presolve(mu, SOBOLEV_GLS_BETAS)
        beta = min(SOBOLEV_GLS_BETAS, key=lambda b: evaluate(mu, b).score)
        if not held_mu:
            mu = float(search_log(lambda m: evaluate(m, beta), mu, golden_steps=6).value)
    best = evaluate(mu, beta)
    return {"mu": float(mu), "beta": float(beta)}, best


# criterion "normals": mu from 0.01 to 10^6 in steps of 2^(1/3), beta 3, the least held-out face-normal loss: on the
# corpus's tune half 1.16 times the sweep's best error (geometric mean; 1.09 on the 12 cases where the normal-risk
# search it replaced read 1.49) (benchmarks/results/held-out-sweeps.md)
GLS_NORMALS = HeldOutRule((Sweep("mu", geometric(0.01, 1e6, 2 ** (1 / 3)), (("beta", 3.0),)),))

"""Polyharmonic Sobolev smoothing with a data term weighted along the estimated normals."""

from __future__ import annotations

import logging
import math
import warnings
from typing import Any, Callable

import numpy as np
import scipy.linalg as sla

from ..geometry import coherent_normals  # re-exported: the filter's normals
from ..geometry import coherent_normals_derivative, vertex_normals
from ..multishift import shifted_family_cg
from ..operators import Operators, mask_key, spmm
from ..registry import AutoRule, Param, get_filter, register
from ..solvers import (DRAFT_LANCZOS_TOL, FILTER_LANCZOS_TOL, lanczos_shifted, laplacian_power, one_ring_factor,
                       one_ring_solve, shifted_cg_bound, shifted_solver)
from ..tuning.config import SEARCH, resolve
from ..tuning.context import TuningContext
from ..tuning.noise_level import mean_edge_length, normal_spread, normal_trust
from ..tuning.risk import Point, gcv
from ..tuning.search import best_shifted, probe_count, region_rule, search_log, shifted_reach, solve_shifted
from ..tuning.sweep import HeldOutRule, Sweep, geometric
from ._gls_solve import CG_TOL, DEFAULT, GlsConfig, normal_weighted_cg

log = logging.getLogger("meshdenoise.auto")

__all__ = ["sobolev_gls", "normal_weighted_solve", "normal_weighted_cg", "coherent_normals", "GlsConfig"]

CG_MAXITER = 300


def _apply_weight(N: np.ndarray, beta: float, Y: np.ndarray) -> np.ndarray:
    """:math:`W Y`, :math:`W_i = \\beta I - (\\beta - 1) N_i N_i^T`, for ``Y`` (n, 3) or (n, 3, k)."""
    if Y.ndim == 2:
        return beta * Y - (beta - 1.0) * N * np.sum(N * Y, axis=1, keepdims=True)
    return beta * Y - (beta - 1.0) * N[:, :, None] * np.sum(N[:, :, None] * Y, axis=1, keepdims=True)


def normal_weighted_solve(
    ops: Operators, N: np.ndarray, beta: float, mu: float, order: int, B: np.ndarray,
    pinned: np.ndarray | None = None, x0: np.ndarray | None = None, prec: Any = None, tol: float = CG_TOL,
    config: GlsConfig | None = None,
) -> np.ndarray:
    """Solve :math:`(W + \\mu\\, L^p \\otimes I_3)\\, Y = B` by conjugate gradients, for one or several right-hand sides.

    :math:`W` is block diagonal, :math:`W_i = \\beta I - (\\beta - 1) N_i N_i^T`
    (``N`` (n, 3) unit rows, ``beta >= 1``); ``B`` is (n, 3) or (n, 3, k) (k independent
    systems, each an (n, 3) array). The preconditioner is :math:`(I + \\mu L^p)^{-1}` on each
    coordinate (the cached Cholesky factor of ``sobolev_axes``): :math:`I \\preceq W \\preceq \\beta I`,
    so the preconditioned matrix has its spectrum in :math:`[1, \\beta]` and CG converges in
    :math:`O(\\sqrt\\beta)` iterations whatever the mesh. With ``pinned`` vertices their rows
    of ``x0`` are kept and the free rows solve the reduced system. ``prec`` (optional) applies
    :math:`(I + \\mu L^p)^{-1}`, or an SPD approximation of it (zero on pinned rows), to an (n, c) array instead of the
    factor. ``tol``: the
    relative residual every system reaches. Up to ``config.dense_max_vertices`` vertices (:class:`GlsConfig`,
    ``None``: its default) the system is solved directly instead (:func:`_dense_normal_weighted_solve`; ``tol`` and
    ``prec`` unused).
    """
    many = B.ndim == 3
    Bk = B if many else B[:, :, None]
    n, _, k = Bk.shape
    if n <= resolve(config, DEFAULT).dense_max_vertices:
        start = x0 if x0 is None or many else x0[:, :, None]
        Y = _dense_normal_weighted_solve(ops, N, beta, mu, order, Bk, pinned, start)
        return Y if many else Y[:, :, 0]
    M = laplacian_power(ops, order)
    if prec is None:
        S = shifted_solver(ops, mu, order, pinned)
        # held rows with the product form (HeldByProduct): its free factors are the preconditioner (R is zero on the
        # held rows and Z is zeroed there, so it is (A^-1)_ff: two more iterations on Bunny0.2, no inner CG)
        S = getattr(S, "product", S)

        def prec(R):
            return S.solve(R.reshape(n, 3 * k)).reshape(n, 3, k)
    else:
        apply_inverse = prec

        def prec(R):
            return apply_inverse(R.reshape(n, 3 * k)).reshape(n, 3, k)

    def A(Y):  # (n, 3, k)
        return _apply_weight(N, beta, Y) + mu * (M @ Y.reshape(n, 3 * k)).reshape(n, 3, k)

    Y = np.zeros_like(Bk) if x0 is None else np.array(x0 if many else x0[:, :, None], dtype=np.float64)
    free = None if pinned is None or not pinned.any() else ~pinned
    R = Bk - A(Y)
    if free is not None:
        R[~free] = 0.0
    Z = prec(R)
    if free is not None:
        Z[~free] = 0.0
    P = Z.copy()
    rz = np.einsum("ijk,ijk->k", R, Z)
    norm0 = np.sqrt(np.einsum("ijk,ijk->k", Bk, Bk)) + 1e-300
    for _ in range(CG_MAXITER):
        if np.all(np.sqrt(np.einsum("ijk,ijk->k", R, R)) <= tol * norm0):
            break
        AP = A(P)
        if free is not None:
            AP[~free] = 0.0
        pap = np.einsum("ijk,ijk->k", P, AP)
        alpha = np.where(pap > 0, rz / np.where(pap > 0, pap, 1.0), 0.0)
        Y += alpha * P
        R -= alpha * AP
        Z = prec(R)
        if free is not None:
            Z[~free] = 0.0
        rz_new = np.einsum("ijk,ijk->k", R, Z)
        P = Z + np.where(rz > 0, rz_new / np.where(rz > 0, rz, 1.0), 0.0) * P
        rz = rz_new
    else:
        warnings.warn(
            f"sobolev_gls: conjugate gradients did not reach a relative residual of {tol:g} in {CG_MAXITER} "
            f"iterations (beta = {beta:g}); a smaller beta converges faster",
            UserWarning,
            stacklevel=3,
        )
    return Y if many else Y[:, :, 0]


def _dense_normal_weighted_solve(
    ops: Operators, N: np.ndarray, beta: float, mu: float, order: int, Bk: np.ndarray,
    pinned: np.ndarray | None, x0: np.ndarray | None,
) -> np.ndarray:
    """:func:`normal_weighted_solve` on a small mesh: :math:`A = W + \\mu L^p \\otimes I_3` (index ``3i + d``)
    formed densely and factorised by Cholesky, exact where CG stops at its tolerance. ``Bk`` (n, 3, k); pinned
    rows keep ``x0``'s values (zero without it) and the free rows solve the reduced system, as CG does."""
    n, _, k = Bk.shape
    A = mu * np.kron(laplacian_power(ops, order).toarray(), np.eye(3))
    blocks = A.reshape(n, 3, n, 3)
    i = np.arange(n)
    blocks[i, :, i, :] += beta * np.eye(3) - (beta - 1.0) * N[:, :, None] * N[:, None, :]
    B2 = np.ascontiguousarray(Bk, dtype=np.float64).reshape(3 * n, k)
    if pinned is None or not np.any(pinned):
        return sla.cho_solve(sla.cho_factor(A, check_finite=False), B2, check_finite=False).reshape(n, 3, k)
    Y = np.zeros((3 * n, k)) if x0 is None else np.array(x0, dtype=np.float64).reshape(3 * n, k)
    free = np.repeat(~np.asarray(pinned, dtype=bool), 3)
    rhs = B2[free] - A[np.ix_(free, ~free)] @ Y[~free]
    Y[free] = sla.cho_solve(sla.cho_factor(A[np.ix_(free, free)], check_finite=False), rhs, check_finite=False)
    return Y.reshape(n, 3, k)



# ----------------------------------------------------------------------------- automatic rule
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
        rhs = np.concatenate([_correction_rhs(N, 2.0, ctx.V, X0)[:, :, None], B], axis=2)  # beta 2: P_T (X - X0)
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
                                                                      _correction_rhs(N, beta, ctx.V, X0), config=config)
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
                        rhs = np.concatenate([_correction_rhs(N, beta, ctx.V, X0)[:, :, None], B], axis=2)
                        out = normal_weighted_solve(ctx.ops, N, beta, mu, order, rhs, tol=tol,
                                                    x0=start(mu, beta) if loose else None, config=config)
                    if loose:
                        warm.append((math.log10(mu), math.log10(beta), out))
                        del warm[:-SOBOLEV_GLS_LOOSE_WARM]
                    X, AiB = X0 + out[:, :, 0], out[:, :, 1:]
                    fixed_normals = float(np.sum(AiB * _apply_weight(N, beta, B)))
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


@register(
    "sobolev_gls",
    scale_free=True,
    auto=AutoRule(("mu", "beta"), choose_sobolev_gls, normals="mu", held_out=GLS_NORMALS),
    summary="Polyharmonic Sobolev with the data term weighted beta times more across the estimated normals",
    params=[
        Param("mu", float, 1000.0, low=0.0, help="weight of the penalty ||L^{p/2} Y||^2 (0 returns the input)"),
        Param("beta", float, 3.0, low=1.0, help="weight of the tangential data term relative to the normal one (1: sobolev)"),
        Param("order", int, 3, low=1, high=4, help="power p of the Laplacian in the penalty"),
    ],
    linear=False,
    # the border option's free run: the isotropic pass alone, its normal moves at the border (the correction is
    # tangential); face000 with scanner noise: 5.0 -> 4.4 s, 8.42 -> 8.39 degrees, the border's error the same. The
    # held run then takes its normals from it (draft): one correction solve, no held isotropic pass
    border_draft=lambda values: {**values, "beta": 1.0},
    rough_free_run=True,  # ... by Lanczos to DRAFT_LANCZOS_TOL (face000: 0.68 -> 0.47 s)
)
def sobolev_gls(V, F, *, ops, pinned, mu, beta, order, draft=None, rough=False, config=None):
    """Polyharmonic Sobolev smoothing whose data term trusts the tangential directions more.

    The paper's noise moves each vertex along its normal only, so a denoiser should
    change positions across the surface much more than along it. With :math:`\\hat N_i`
    the vertex normals (:func:`coherent_normals`) of the isotropic estimate :math:`\\hat X = (I + \\mu L^p)^{-1} X`
    (the same penalty, :math:`\\beta = 1`), the result minimises

    .. math:: \\sum_i (Y_i - X_i)^T W_i\\, (Y_i - X_i) + \\mu \\sum_{d=1}^3 y_d^T L^p y_d,
              \\qquad W_i = \\hat N_i \\hat N_i^T + \\beta\\, (I - \\hat N_i \\hat N_i^T),

    i.e. :math:`(W + \\mu L^p \\otimes I_3)\\, Y = W X`: a weighted (generalised) least
    squares fit whose weight is the inverse of a noise covariance
    :math:`\\propto \\hat N_i \\hat N_i^T + \\beta^{-1}(I - \\hat N_i \\hat N_i^T)`, flattened along the
    normal (Aitken's generalised least squares; a Tikhonov / Sobolev prior as in the paper).
    :math:`\\beta = 1` is the isotropic polyharmonic Sobolev filter; large :math:`\\beta`
    keeps the tangential coordinates (the uniform Laplacian's tangential drift, which
    costs SNR, is held back). ``beta`` is finite because the estimated normals of a
    heavily smoothed surface are off the true noise directions by several degrees.
    The system couples the three coordinates; it is solved by conjugate gradients
    preconditioned with the cached Cholesky factor of :math:`I + \\mu L^p`
    (:func:`normal_weighted_solve`, spectrum in :math:`[1, \\beta]`), for the correction
    :math:`Y - \\hat X`; with no factor stored, from 200,000 vertices, or from 20,000 while the weight is weak
    (``GlsConfig.factor_free_cg_bound``), nothing is factorised (:func:`normal_weighted_cg`), and from 20,000 past that
    weight both solves are preconditioned by one factor of a one-ring matrix instead
    (:class:`~meshdenoise.solvers.ShiftedPCG`). For pinned normals
    the map is linear; the filter is translation and rotation equivariant. In ``boundary_motion="normal"`` the held
    run is given the free isotropic pass (``draft``, the ``border_draft``'s result) and takes its normals and
    :math:`\\hat X` from it: one correction solve with the border as Dirichlet data (:func:`_held_from_draft`),
    where a held isotropic pass came first (face000: 8.392 -> 8.386 degrees, 70.603 -> 70.606 dB, the held run
    2.8 -> about 1.1 s with the one-ring preconditioner's factor alone).
    ``meshdenoise.choose_parameters`` picks ``mu`` and ``beta`` by SURE; ``denoise(mesh,
    method="sobolev_gls")`` chooses ``mu`` for the face normals instead (criterion ``"normals"``: the least
    held-out face-normal loss over ``mu``, ``beta`` 3, :data:`GLS_NORMALS`).

    Choosing ``mu`` for a scan: the oracle's ``mu`` for noise of 0.1, 0.3 and 1 mean edge lengths
    was 0.10, 1.2 and 16 on a sphere and 4.3, 11 and 28 on a torus (``benchmarks/results/parameter-scale.md``), and
    the default 1000 is far above all of these: use the automatic choice, which also picks ``beta``.

    Parameters
    ----------
    mesh : (V, F) tuple, pymeshlab.MeshSet or Mesh, or open3d.geometry.TriangleMesh
    mu : float, >= 0
        Weight of the polyharmonic penalty (0 returns the input).
    beta : float, >= 1
        Tangential weight of the data term.
    order : int, 1 <= order <= 4
        Power ``p`` of the Laplacian.
    pinned, region, preserve_volume, operators
        Options shared by every filter; see the README.
    config : GlsConfig, optional
        The array core's (``get_filter("sobolev_gls").core``) solve paths and tolerance; ``None``: its default.

    Returns
    -------
    Same type as ``mesh``

    References
    ----------
    A. C. Aitken, "On least squares and linear combination of observations", Proc. R. Soc. Edinb. 55, 1935.
    M. Desbrun, M. Meyer, P. Schröder, A. Barr, "Implicit fairing of irregular meshes
    using diffusion and curvature flow", SIGGRAPH 1999.
    A. Vaillant-Tenzer, "Mesh Denoising", 2022 (Sobolev regularisation, noise model).

    Examples
    --------
    >>> import numpy as np
    >>> from meshdenoise.shapes import grid
    >>> V, F = grid(6, 6)
    >>> Vn = V + [0, 0, 0.01] * np.random.default_rng(0).standard_normal((len(V), 1))
    >>> V1, _ = sobolev_gls((Vn, F), mu=5.0, beta=10.0)
    >>> Vi, _ = sobolev_gls((Vn, F), mu=5.0, beta=1.0)  # isotropic: drifts along the plane
    >>> drift = lambda Y: np.abs(Y[:, :2] - Vn[:, :2]).max()
    >>> bool(V1[:, 2].std() < 0.5 * Vn[:, 2].std()), bool(drift(V1) < 0.5 * drift(Vi))
    (True, True)
    """
    X = np.array(V, dtype=np.float64)
    if F.shape[0] == 0 or mu == 0:
        return X
    held = pinned is not None and bool(np.any(pinned))
    config = resolve(config, DEFAULT)
    start = None if draft is None else np.asarray(draft, dtype=np.float64)
    if start is not None and held and beta != 1.0:
        return _held_from_draft(X, F, ops, mu, beta, order, pinned, start, config)
    # rough: the border option's free run (its draft), read for the border's moves and the held run's normals
    draft_tol = DRAFT_LANCZOS_TOL if rough else None
    if _iterative(ops, mu, order, pinned, config):
        return _sobolev_gls_iterative(X, F, ops, mu, beta, order, pinned, start, draft_tol, config)
    # no factor of I + mu L^p stored on a mesh from config.factor_free_min_vertices: CG preconditioned by a one-ring
    # factor's (L + a I)^-p for both solves (ShiftedPCG; the bunny scanner's solves 0.72 -> 0.57 s, face000's held run
    # 1.8 s where its factor took 3.0 s)
    by_pcg = _by_one_ring(ops, mu, order, pinned, config)
    if by_pcg and beta == 1.0 and not held:
        # the isotropic pass alone with no held rows (the border option's draft, border_draft): two Lanczos passes,
        # no factor (face000 at mu 34: 0.7 s against 0.3 s for the one-ring factor and 0.75 s of its CG)
        Y = lanczos_shifted(ops, X, mu, order, tol=draft_tol or FILTER_LANCZOS_TOL, growth=0.25)
        if Y is not None:
            return Y
    S = shifted_solver(ops, mu, order, pinned, "pcg" if by_pcg else "cholesky")
    X0 = S.solve(X, x0=start) if by_pcg and start is not None else S.solve(X)  # a draft: the held pass's start
    if beta == 1.0:
        return X0
    N = coherent_normals(X0, F)
    return X0 + normal_weighted_solve(ops, N, beta, mu, order, _correction_rhs(N, beta, X, X0), pinned,
                                      tol=config.filter_tol, config=config,
                                      prec=_on_free_rows(ops.n, pinned, S.precondition) if by_pcg else None)


def _on_free_rows(n: int, pinned: np.ndarray | None, apply: Callable[[np.ndarray], np.ndarray]):
    """``apply`` (an approximate inverse on the free rows' (f, c) blocks: the one-ring preconditioner) as
    :func:`normal_weighted_solve`'s ``prec`` on (n, c) blocks, zero on held rows."""
    free = np.arange(n) if pinned is None or not np.any(pinned) else np.flatnonzero(~np.asarray(pinned, dtype=bool))

    def prec(R: np.ndarray) -> np.ndarray:
        Z = np.zeros_like(R)
        Z[free] = apply(R[free])
        return Z

    return prec


def _held_from_draft(X: np.ndarray, F: np.ndarray, ops: Operators, mu: float, beta: float, order: int,
                     pinned: np.ndarray, X0: np.ndarray, config: GlsConfig = DEFAULT) -> np.ndarray:
    """The border option's held run from its draft ``X0``, the isotropic pass on the free border (``border_draft``):
    :math:`Y = X_0 + D` with the normals :math:`\\hat N` of :math:`X_0` and

    .. math:: (W + \\mu L^p \\otimes I_3)\\, D = (W - I)(X - X_0) \\ \\text{on the free rows}, \\qquad
              D = X - X_0 \\ \\text{on the held ones},

    the weighted system :math:`(W + \\mu L^p) Y = W X` itself, since :math:`\\mu L^p X_0 = X - X_0` on the rows
    the draft left free (its held rows are held here too). One correction solve, by the path the filter takes for
    the held system (block-Jacobi CG, the one-ring factor's CG or a factor), where the held run took a held
    isotropic pass and then the correction: face000's held run 0.5 s less, its result within 0.006 degrees
    (8.3916 -> 8.3857, 70.6027 -> 70.6059 dB, the border's error the same). The solve is for :math:`D` minus the
    held rows' values, to ``config.filter_tol`` of the reduced system's whole right-hand side (the tangential residual
    and the held rows' pull): face000's 45 -> 28 steps, the result within 5e-4 of the mean move of a solve to 1e-8
    (3.7e-4 rho on average, 2e-3 rho at most), the same normal error and SNR to 1e-6."""
    N = coherent_normals(X0, F)
    # D = D_held + E: D_held the held rows' values (zero elsewhere), E zero on them; E's right-hand side is the
    # reduced system's whole one (the tangential residual and the held rows' pull), the tolerance relative to it
    D_held = np.zeros_like(X)
    D_held[pinned] = X[pinned] - X0[pinned]
    pull = D_held
    for _ in range(int(order)):  # L^p D_held by p products with L (no L^p formed: the factor-free paths form none)
        pull = spmm(ops.L, pull)
    rhs = _correction_rhs(N, beta, X, X0) - _apply_weight(N, beta, D_held) - mu * pull
    rhs[pinned] = 0.0
    tol = config.filter_tol
    if _iterative(ops, mu, order, pinned, config):
        E, ok = normal_weighted_cg(ops, N, beta, mu, order, rhs, tol=tol, pinned=pinned,
                                   maxiter=config.jacobi_max_iterations)
        if not ok:
            E = normal_weighted_solve(ops, N, beta, mu, order, rhs, pinned, x0=E, config=config)
    elif _by_one_ring(ops, mu, order, pinned, config):
        # the one-ring preconditioner mu^-1 (L_ff + a I + share)^-p alone: ShiftedPCG's held system (I + mu L^p)_ff
        # and its coupling are not needed here (face000: 0.2 s of slicing a 3-ring matrix)
        factor = one_ring_factor(ops, mu ** (-1.0 / order), order, pinned)
        E = normal_weighted_solve(ops, N, beta, mu, order, rhs, pinned, tol=tol, config=config,
                                  prec=_on_free_rows(ops.n, pinned, lambda R: one_ring_solve(factor, R, order, mu)))
    else:
        E = normal_weighted_solve(ops, N, beta, mu, order, rhs, pinned, tol=tol, config=config)
    Y = X0 + D_held + E
    Y[pinned] = X[pinned]  # the held values bit for bit (X0 + (X - X0) rounds)
    return Y


def _by_one_ring(ops: Operators, mu: float, order: int, pinned: np.ndarray | None, config: GlsConfig = DEFAULT) -> bool:
    """Whether a mesh the factor-free paths leave (:func:`_iterative` false) solves by CG preconditioned by a one-ring
    factor: from ``config.factor_free_min_vertices`` vertices with no factor of :math:`I + \\mu L^p` stored."""
    return ops.n >= config.factor_free_min_vertices and not _factor_stored(ops, mu, order, pinned)


def _factor_stored(ops: Operators, mu: float, order: int, pinned: np.ndarray | None) -> bool:
    """Whether a factor of :math:`I + \\mu L^p` is stored on ``ops`` for ``pinned``'s held rows, or free (held rows'
    product form preconditions by it)."""
    stored = ops.cache.get(f"shifted-p{order}-cholesky", {})
    held = pinned is not None and bool(np.any(pinned))
    return (float(mu), None) in stored or (held and (float(mu), mask_key(pinned)) in stored)


def _iterative(ops: Operators, mu: float, order: int, pinned: np.ndarray | None, config: GlsConfig = DEFAULT) -> bool:
    """Whether :func:`sobolev_gls` factorises nothing: no factor of :math:`I + \\mu L^p` stored already (with
    ``pinned``'s rows held, or free: held rows' product form preconditions by it), and from
    ``config.iterative_min_vertices`` vertices with none held, or from ``config.factor_free_min_vertices`` while CG's
    bound (:func:`~meshdenoise.solvers.shifted_cg_bound` at ``config.filter_tol``) is at most
    ``config.factor_free_cg_bound`` (:class:`GlsConfig`)."""
    if _factor_stored(ops, mu, order, pinned):
        return False
    if ops.n >= config.iterative_min_vertices and (pinned is None or not np.any(pinned)):
        return True
    return (ops.n >= config.factor_free_min_vertices
            and shifted_cg_bound(ops, mu, order, config.filter_tol) <= config.factor_free_cg_bound)


def _sobolev_gls_iterative(X: np.ndarray, F: np.ndarray, ops: Operators, mu: float, beta: float, order: int,
                           pinned: np.ndarray | None = None, start: np.ndarray | None = None,
                           draft_tol: float | None = None, config: GlsConfig = DEFAULT) -> np.ndarray:
    """:func:`sobolev_gls` without a factor: :math:`X_0` by two Lanczos passes (:func:`~meshdenoise.solvers.lanczos_shifted`)
    or, with held rows, by Jacobi CG on the free rows (from the input, as ``sobolev_axes``' held run); the correction
    by block-Jacobi CG (:func:`normal_weighted_cg`), else by CG preconditioned by Lanczos solves (a factor with held
    rows). ``start``: a nearby result the held isotropic pass starts from (:func:`sobolev_gls`'s draft). ``draft_tol``: the
    free isotropic pass's Lanczos tolerance for the border option's draft (:data:`~meshdenoise.solvers.DRAFT_LANCZOS_TOL`;
    ``None``: 1e-12)."""
    held = pinned is not None and bool(np.any(pinned))

    def shifted(R: np.ndarray, tol: float = 1e-12) -> np.ndarray:
        Y = lanczos_shifted(ops, R, mu, order, tol=tol)
        return shifted_solver(ops, mu, order).solve(R) if Y is None else Y

    if held:
        bound = shifted_cg_bound(ops, mu, order, FILTER_LANCZOS_TOL)
        X0 = shifted_solver(ops, mu, order, pinned, "cg").solve(X, tol=FILTER_LANCZOS_TOL,
                                                               x0=X if start is None else start,
                                                               maxiter=int(4 * math.ceil(bound)) + 50)
    else:
        X0 = shifted(X) if draft_tol is None else shifted(X, draft_tol)
    if beta == 1.0:
        return X0
    N = coherent_normals(X0, F)
    rhs = _correction_rhs(N, beta, X, X0)
    D, ok = normal_weighted_cg(ops, N, beta, mu, order, rhs, tol=config.filter_tol, pinned=pinned,
                               maxiter=config.jacobi_max_iterations)
    if not ok:  # a very large mu: the factor-preconditioned iteration, its count bounded by sqrt(beta)
        D = normal_weighted_solve(ops, N, beta, mu, order, rhs, pinned, x0=D, prec=None if held else shifted,
                                  config=config)
    return X0 + D


def _correction_rhs(N: np.ndarray, beta: float, X: np.ndarray, X0: np.ndarray) -> np.ndarray:
    """Right-hand side of the system for :math:`D = Y - X_0`: :math:`(\\beta - 1)(I - N N^T)(X - X_0)`.

    From :math:`(I + \\mu K) X_0 = X`: :math:`(W + \\mu K) D = W X - (W + \\mu K) X_0 = (W - I)(X - X_0)`.
    It does not see a translation of the mesh (unlike :math:`W X`), so the iterative
    solve's tolerance is relative to the correction, not to the coordinates' magnitude. ``X``, ``X0``: (n, 3), or
    (n, 3, k) for k systems.
    """
    R = X - X0
    Nb = N if R.ndim == 2 else N[:, :, None]
    return (beta - 1.0) * (R - Nb * np.sum(Nb * R, axis=1, keepdims=True))

"""``sobolev_axes``' automatic rule: one ``mu`` per principal axis of the normals by SURE, each axis's noise share
read from the frame, and the normals criterion's map of the filter (``sobolev_axes_map``, ``sobolev_axes_spectral``)."""

from __future__ import annotations

import logging
import math

import numpy as np

from ..geometry import vertex_normals
from ..operators import Operators, spmm
from ..registry import get_filter
from ..solvers import LanczosDots, LanczosQuadrature, ShiftedInverse, shifted_solver
from ..tuning.config import SEARCH
from ..tuning.context import TuningContext
from ..tuning.memo import MEMO, digest
from ..tuning.noise_level import fourth_difference, mean_edge_length, normal_trust
from ..tuning.risk import N_PROBES, Point, probe_block
from ..tuning.search import best_shifted, probe_count, solve_shifted
from ..tuning.spectral import Spectral, shifted_spectral
from ._axes_frame import DEFAULT, normal_frame

__all__ = ["choose_sobolev_axes", "sobolev_axes_map", "sobolev_axes_spectral", "AXES_NORMAL_REGION"]

AXES_NORMAL_REGION = 8_000  # the normals criterion's search on a region of this size from twice as many vertices: each
# candidate factorises I + mu L^3 three times (3.3 s each at 35k vertices; the whole-mesh search took 170 s on Bunny0.2)

log = logging.getLogger("meshdenoise.auto")


def _read_only(A: np.ndarray) -> np.ndarray:
    """``A``, no longer writeable (a memoised value is shared by its readers)."""
    A.flags.writeable = False
    return A


# ----------------------------------------------------------------------------- automatic rule
def _axis_share_correction(V: np.ndarray, ops: Operators, E: np.ndarray, c: np.ndarray, rho: float, smooth: np.ndarray) -> np.ndarray:
    """Per-axis factors ``a_d`` (3,) that make the noise shares ``c`` agree with the residual energy on each axis.

    The noise part of :math:`B x_d`, :math:`x_d = X e_d`, :math:`B = (I - D^{-1}W)^2`, has
    energy :math:`\\mathbb E \\|B \\varepsilon_d\\|^2 = \\rho^2 \\sum_j b_j c^*_{jd}`,
    :math:`b_j = \\sum_i B_{ij}^2`, with :math:`c^*_{jd} = (N_j \\cdot e_d)^2` the true
    (clean-normal) shares, whatever the normals: a measurement of the per-axis noise
    energy that needs no normal. Normals of a smoothed estimate are unreliable once the
    noise exceeds the edge length ``h`` (Nefertiti at 3 edge lengths: axis totals off by
    30 %), while the shape's own part of :math:`\\|B x_d\\|^2` is then negligible. So

    .. math:: a_d = \\Big(\\frac{T_d / \\sum_e T_e}{P_d / \\sum_e P_e}\\Big)^{w}, \\qquad
              T_d = \\|B x_d\\|^2,\\; P_d = \\sum_j b_j c_{jd},

    with the weight :math:`w = \\mathrm{clip}((\\rho/h - 1/2)/(1/2), 0, 1)` of
    :func:`estimate_noise` (normals below half an edge length of noise, energy above one).
    """
    w = normal_trust(rho, mean_edge_length(smooth, ops))
    if w == 0:
        return np.ones(3)
    B = fourth_difference(ops)
    b = np.asarray(B.multiply(B).sum(axis=0)).ravel()
    T = np.sum(np.asarray(B @ (V @ E)) ** 2, axis=0)
    P = b @ c
    if T.sum() <= 0 or np.any(P <= 0) or np.any(T <= 0):
        return np.ones(3)
    return ((T / T.sum()) / (P / P.sum())) ** w


def choose_sobolev_axes(ctx: TuningContext) -> tuple[dict, Point]:
    """``mu1, mu2, mu3`` (and ``frame_steps``) of ``sobolev_axes``: SURE on each principal axis.

    ``frame_steps`` is the SURE-best number of averaging steps (the smoothing the noise
    normals of :func:`estimate_noise` come from). In the frame :math:`E` of those normals
    the filter acts on each coordinate :math:`x_d = X e_d` separately, and the noise on
    it is :math:`\\rho\\, \\varepsilon_i (n_i \\cdot e_d)`, of variance
    :math:`\\rho^2 c_{id}`, :math:`c_{id} = (n_i \\cdot e_d)^2`. So the risk splits
    into one SURE per axis,

    .. math:: \\mathrm{SURE}_d(\\mu) = \\|H_\\mu x_d - x_d\\|^2 - \\rho^2 \\sum_i c_{id}
              + 2\\rho^2 \\sum_i (H_\\mu)_{ii}\\, c_{id}, \\qquad H_\\mu = (I + \\mu L^p)^{-1},

    whose weighted trace is Hutchinson's :math:`\\mathbb E\\, (c_d \\odot z)^T H z = \\sum_i H_{ii} c_{id}`:
    one solve :math:`H z` per probe serves the three axes, each dotting it with its own weighted probe
    (not :math:`(z \\odot \\sqrt{c_d})^T H (z \\odot \\sqrt{c_d})`, the same sum in expectation by
    three times the solves: face000's rule 1.2 s against 1.6 s), exact (identity probes) on small meshes. One
    factorisation per ``mu`` serves the three axes: a half-decade grid around the ``sobolev`` guess, extended until
    every axis's minimum is inside, then refined to an eighth of a decade around each minimum.

    Above half an edge length of noise the shares' axis totals are rescaled to the
    residual energy on each axis (:func:`_axis_share_correction`): the smoothed normals
    misplace up to 30 % of an axis's noise on Nefertiti at rho = 1 (3 edge lengths),
    which made the per-axis SURE pick mu2 = 0.08 instead of about 10 on two of five seeds.

    From ``SearchConfig.quadrature_min_vertices`` vertices (not the oracle, not exact traces) the candidates are the same and
    their scores come from one Lanczos run on ``L`` (Gauss quadrature of both terms, which are
    quadratic forms of functions of ``L``, as :func:`~meshdenoise.tuning.search.shifted_quadrature`;
    the probes :func:`~meshdenoise.tuning.search.probe_count`; the weighted probes as the duals of
    :class:`~meshdenoise.solvers.LanczosDots`), no factorisation per ``mu``; a
    candidate whose rule has not converged in 600 steps falls back to its factor.
    """
    spec = get_filter("sobolev_axes")
    full = spec.resolve(ctx.given, where="choose_parameters(method='sobolev_axes')")
    if ctx.criterion.name == "gcv":
        raise ValueError("choose_parameters: sobolev_axes needs a noise level per axis; use criterion 'sure' or 'oracle'")
    n, order = ctx.ops.n, full["order"]
    if "frame_steps" in ctx.given:
        steps = full["frame_steps"]
    else:
        steps = int(ctx.smoothed("sure" if ctx.rho is not None else ctx.criterion).value)
    smooth = ctx.smoothed("sure").X if ctx.rho else ctx.V
    E, _ = normal_frame(ctx.V, ctx.F, ctx.ops, steps)
    # noise directions: normals of the SURE-best bi-Laplacian estimate (smoother than `steps` averagings,
    # whose normals at 0.4 edge lengths of noise are still noisy and would bias the per-axis shares)
    rho_sure = ctx.rho if ctx.rho is not None else 0.0
    config, search = ctx.config_for(DEFAULT), ctx.config_for(SEARCH)
    by = "lanczos" if n >= config.scale_min_vertices else "cg"  # large: the search's own run, no CG (400k: 4.6 s)
    Xs = best_shifted(ctx.V, ctx.ops, 2, rho_sure, "sure", ctx.exact, center=ctx.mu_guess(2), coordinates_by=by,
                      config=search).X
    c = (vertex_normals(Xs, ctx.F) @ E) ** 2  # (n, 3) noise share of each axis per vertex
    if ctx.rho:
        c = c * _axis_share_correction(ctx.V, ctx.ops, E, c, ctx.rho, smooth)[None, :]
    Xf = ctx.V @ E
    Yf = None if ctx.reference is None else ctx.reference @ E
    Z, s = probe_block(n, ctx.exact, n_probes=probe_count(n))  # probe_count: N_PROBES, probe_block's own, to 50k
    m = Z.shape[1]
    # a factor per mu costs 1 to 5 s at 35k vertices for L^3 (Bunny0.2: 10 of them); exact traces (identity probes,
    # a Lanczos run per column) keep it
    use_quadrature = n >= search.quadrature_min_vertices and Yf is None and m <= N_PROBES
    # axis d's weighted trace sum_i c_id H_ii as E z^T diag(c_d) H z: the three axes from one set of m solves (H z),
    # each dotted with its own weighted probes c_d * z (E (z * sqrt c_d)^T H (z * sqrt c_d), the same sum, took 3m)
    def weighted(d: int) -> np.ndarray:  # (n, m): made when needed, not held
        return np.ascontiguousarray(Z * c[:, [d]])

    held = [f"mu{d + 1}" in ctx.given for d in range(3)]
    evaluated: dict[float, list[float]] = {}  # log10 mu -> per-axis score
    keys: list[str] = []  # the factor path's memo key (topology, order, right-hand sides), hashed on first use
    quad = None
    if use_quadrature:  # every candidate's terms from Lanczos runs on L (as search.shifted_quadrature)
        hp = Xf
        for _ in range(order):
            hp = spmm(ctx.ops.L, np.ascontiguousarray(hp))
        # one run per column, each extended as far as its own column needs: a step's work arrays are (n, 1), not
        # (n, 3 + m) (at 1.6M vertices 12.8 MB a column), and numpy's passes over one contiguous column
        # cost less per number than over (n, k) blocks (30 steps at 400k: 2.0 CPU s for 15 one-column runs, 2.4 for
        # one 15-column run, 3.0 for three 5-column runs)
        if n < config.one_run_max_vertices:  # one compiled run of all the columns: per-step work, not per column
            # the weighted probes are the duals of the probe columns (zero on the coordinates')
            one = LanczosDots(ctx.ops.L, np.hstack([hp, Z]),
                              [np.hstack([np.zeros((n, 3)), weighted(d)]) for d in range(3)], max_steps=600)
            quad = None
        else:
            quad = [LanczosQuadrature(ctx.ops.L, np.ascontiguousarray(hp[:, [j]]), max_steps=600) for j in range(3)] + [
                LanczosDots(ctx.ops.L, np.ascontiguousarray(Z[:, [k]]),
                            [np.ascontiguousarray(weighted(d)[:, [k]]) for d in range(3)], max_steps=600)
                for k in range(m)]

    def by_quadrature(mu: float) -> list | None:
        """Per-axis SURE: :math:`\\|H x_d - x_d\\|^2 = c_d^T \\mu^2 (I + \\mu L^p)^{-2} c_d`, :math:`c_d = L^p x_d`,
        and the weighted traces :math:`q^T (I + \\mu L^p)^{-1} q`, Gauss quadrature on the Lanczos runs."""
        # (1 + mu x^p)^-2 and ^-1 (ShiftedInverse: by tridiagonal solves, no eigenproblems)
        tol, residual, trace = config.quadrature_tol, ShiftedInverse(mu, order, 2), ShiftedInverse(mu, order)
        if quad is None:
            parts = [one.evaluate(residual, columns=range(3), rtol=tol, growth=0.25),
                     one.dots(trace, rtol=tol, growth=0.25)]
        else:  # growth: tests at geometrically spaced sizes (the elephant's strong weights: 4.5 -> 4.0 s)
            parts = [run.evaluate(residual, rtol=tol, growth=0.25) for run in quad[:3]] + [
                run.dots(trace, rtol=tol, growth=0.25) for run in quad[3:]]
        if any(part is None for part in parts):
            return None
        # q[d]: the sum over probes of (c_d z)^T H z
        r, q = (parts[0], parts[1][:, 3:].sum(axis=1)) if quad is None else (
            np.concatenate(parts[:3]), np.sum([part[:, 0] for part in parts[3:]], axis=0))
        r = mu**2 * r
        return [float(r[d]) - ctx.rho**2 * float(c[:, d].sum()) + 2 * ctx.rho**2 * s * float(q[d]) for d in range(3)]

    def at(t: float) -> list:
        t = round(t, 9)
        if t not in evaluated and use_quadrature:
            scores = by_quadrature(10.0**t)
            if scores is not None:
                evaluated[t] = scores
        if t not in evaluated:
            mu = 10.0**t
            if not keys:
                keys.append(digest(ctx.ops.F, order, np.hstack([Xf, Z])))
            out = solve_shifted(ctx.ops, order, mu, np.hstack([Xf, Z]), keys[0])
            scores = []
            for d in range(3):
                y = out[:, d]
                if Yf is not None:
                    score = float(np.sum((y - Yf[:, d]) ** 2))
                else:
                    tr = s * float(np.sum(weighted(d) * out[:, 3:]))
                    score = float(np.sum((y - Xf[:, d]) ** 2)) - ctx.rho**2 * float(c[:, d].sum()) + 2 * ctx.rho**2 * tr
                scores.append(score)
            evaluated[t] = scores
        log.debug("sobolev_axes: log10 mu %.4f scores %s", t, evaluated[t])
        return evaluated[t]

    def best_t(d: int) -> float:
        return min(evaluated, key=lambda t: evaluated[t][d])

    if ctx.rho == 0 and Yf is None:
        return {**{f"mu{d + 1}": 0.0 for d in range(3) if not held[d]}, "frame_steps": steps}, Point(0, 0.0, float(n), ctx.V, 0.0)
    c0 = math.log10(ctx.mu_guess(order))
    for j in range(-2, 3):
        at(c0 + 0.5 * j)
    for _ in range(40):  # extend the grid while an axis's minimum sits at an end
        lo, hi = min(evaluated), max(evaluated)
        ends = {best_t(d) for d in range(3) if not held[d]}
        if lo in ends and lo > -10:
            at(lo - 0.5)
        elif hi in ends and hi < 14:
            at(hi + 0.5)
        else:
            break
    for step in (0.25, 0.125):
        for d in range(3):
            if not held[d]:
                t = best_t(d)
                at(t - step), at(t + step)
    chosen = {f"mu{d + 1}": float(10.0 ** best_t(d)) for d in range(3) if not held[d]}
    total = sum(evaluated[best_t(d)][d] for d in range(3) if not held[d])
    return {**chosen, "frame_steps": steps}, Point(0, 0.0, 0.0, ctx.V, total)


def sobolev_axes_map(V: np.ndarray, F: np.ndarray, ops: Operators, params: dict):
    """The filter with its frame taken from ``V`` and held, as a map of ``(n, 3k)`` blocks of coordinate triples.

    :math:`Y = \\sum_d (I + \\mu_d L^p)^{-1} (B e_d)\\, e_d^T` for each triple ``B``: linear, the
    frame :math:`E` of :func:`normal_frame` read from ``V`` (``AutoRule.linear_map``, for the
    probes of :func:`~meshdenoise.tuning.normal_risk.refine_for_normals`; on ``V`` itself it is the filter).
    """
    E, _ = normal_frame(V, F, ops, int(params["frame_steps"]))
    mus, order = (float(params["mu1"]), float(params["mu2"]), float(params["mu3"])), int(params["order"])

    def apply(block: np.ndarray) -> np.ndarray:
        B = np.asarray(block, dtype=np.float64)
        n, k = B.shape[0], B.shape[1] // 3
        C = B.reshape(n, k, 3) @ E  # each triple in the frame
        out = np.empty_like(C)
        for d, mu in enumerate(mus):
            out[:, :, d] = C[:, :, d] if mu == 0 else shifted_solver(ops, mu, order).solve(
                np.ascontiguousarray(C[:, :, d]))
        return (out @ E.T).reshape(n, 3 * k)

    return apply


def sobolev_axes_spectral(V: np.ndarray, F: np.ndarray, ops: Operators, params: dict) -> Spectral:
    """:func:`sobolev_axes_map` as functions of ``L`` on the axes of its frame: :math:`g_d(y) = 1/(1 + \\mu_d y^p)`
    (:class:`~meshdenoise.tuning.spectral.Spectral` with ``frame``; ``AutoRule.spectral``). The frame is memoised
    (:data:`~meshdenoise.tuning.memo.MEMO`): a search asks for every candidate weight on one mesh, the same frame
    (the elephant's 38 averaging steps: 14 ms each, ten candidates)."""
    steps = int(params["frame_steps"])
    E = MEMO.get(("normal_frame", digest(V, F, steps)), lambda: _read_only(normal_frame(V, F, ops, steps)[0]))
    order = int(params["order"])
    axes = [shifted_spectral(ops, float(params[name]), order) for name in ("mu1", "mu2", "mu3")]
    return Spectral(ops.L, tuple(a.g for a in axes), tuple(a.h for a in axes), frame=E)

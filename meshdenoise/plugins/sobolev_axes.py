"""Polyharmonic Sobolev smoothing with one weight per principal axis of the surface normals."""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from ..geometry import vertex_normals
from ..operators import Operators
from ..registry import MAX_ITERATIONS, AutoRule, Param, get_filter, register
from ..operators import mask_key, spmm
from ..solvers import (DRAFT_LANCZOS_TOL, FILTER_LANCZOS_TOL, LANCZOS_SHIFTED_MAX_STEPS, CompiledLanczos, LanczosDots,
                       LanczosQuadrature, ShiftedInverse, ShiftedPCGFamily, lanczos_shifted, shifted_cg_bound,
                       shifted_solver)
from ..tuning.context import TuningContext
from ..tuning.memo import MEMO, digest
from ..tuning.noise_level import fourth_difference, mean_edge_length, normal_trust
from ..tuning.risk import N_PROBES, Point, probe_block
from ..tuning.config import SEARCH, check_fields, resolve
from ..tuning.search import best_shifted, probe_count, solve_shifted
from ..tuning.spectral import Spectral, shifted_spectral


@dataclass(frozen=True)
class AxesConfig:
    """``sobolev_axes``' paths by size, for its filter (``core(..., config=)``) and its rule
    (``choose_parameters(..., config=)``): the values, and where they were measured.

    Attributes
    ----------
    scale_min_vertices : int
        The rule's frame estimate takes its smoothed coordinates from the search's Lanczos run, no CG, from this size
        (400k vertices: 4.6 s).
    lanczos_min_vertices : int
        The filter runs without a factor from this size: two Lanczos passes per axis, and ...
    pinned_cg_bound : float
        ... with held vertices CG while its bound is at most this (a factor of I + mu L^3 with a held border took
        1.2 s per axis on Bunny0.2, 3.5 of the filter's 4.9 s); past it CG preconditioned by one one-ring factor.
    lanczos_max_steps : int
        The filter's one Lanczos run of the axes gives up after this many steps (each axis then on its own):
        :data:`~meshdenoise.solvers.LANCZOS_SHIFTED_MAX_STEPS`.
    quadrature_tol : float
        The rule's quadrature (from ``SearchConfig.quadrature_min_vertices`` vertices): each rule to this relative
        change over its last steps, as the normals searches' ``SpectralConfig.tol``: the grid's candidates compared,
        no parabola. Measured against 1e-10 on the 7 rows of benchmarks/filter_time.py it runs on: every per-axis
        score within 2.7e-5 of 1e-10's (the elephant; the others 8e-8 or less), each axis's best ahead of its next by
        1.7e-4 (Twelve0.5Impulsive) to 9e-3, the same choices; the elephant 187 -> 120 steps, 3.2 -> 2.8 s.
    one_run_max_vertices : int
        Below this size the rule's quadrature is one compiled Lanczos run of its 3 + m columns
        (solvers.CompiledLanczos: Bunny0.2's 75 one-column numpy runs took 1.3 s), above it one run per column (memory).
    """

    scale_min_vertices: int = 50_000
    lanczos_min_vertices: int = 20_000
    pinned_cg_bound: float = 600
    lanczos_max_steps: int = LANCZOS_SHIFTED_MAX_STEPS
    quadrature_tol: float = 1e-6
    one_run_max_vertices: int = 100_000

    def __post_init__(self) -> None:
        check_fields(self, positive=("lanczos_max_steps", "quadrature_tol"),
                     nonnegative=("scale_min_vertices", "lanczos_min_vertices", "pinned_cg_bound",
                                  "one_run_max_vertices"))


DEFAULT = AxesConfig()
AXES_NORMAL_REGION = 8_000  # the normals criterion's search on a region of this size from twice as many vertices: each
# candidate factorises I + mu L^3 three times (3.3 s each at 35k vertices; the whole-mesh search took 170 s on Bunny0.2)

log = logging.getLogger("meshdenoise.auto")

__all__ = ["sobolev_axes", "normal_frame", "choose_sobolev_axes", "sobolev_axes_map", "AxesConfig"]


def _read_only(A: np.ndarray) -> np.ndarray:
    """``A``, no longer writeable (a memoised value is shared by its readers)."""
    A.flags.writeable = False
    return A


def normal_frame(X: np.ndarray, F: np.ndarray, ops: Operators, steps: int) -> tuple[np.ndarray, np.ndarray]:
    """Principal axes of the vertex normals of the mesh smoothed by ``steps`` averaging steps.

    .. math:: T = \\sum_i \\tilde n_i \\tilde n_i^T = E \\,\\mathrm{diag}(w)\\, E^T, \\qquad
              \\tilde X = (D^{-1}W)^{s} X

    Returns ``(E, w)``: the orthonormal eigenvectors (3, 3) as columns, by increasing
    eigenvalue ``w`` (3,). Under the paper's noise model (displacements along the normals)
    the noise energy along axis ``e_d`` is :math:`\\rho^2 \\sum_i (n_i \\cdot e_d)^2`: the
    axes separate directions with little and much noise. ``T`` is quadratic in the
    normals, so the frame does not depend on their orientation, and it rotates with
    the mesh.

    Examples
    --------
    >>> from meshdenoise.shapes import grid
    >>> from meshdenoise.operators import get_operators
    >>> V, F = grid(5, 5)  # flat in z = 0: every normal is +-e_z, the last axis
    >>> E, w = normal_frame(V, F, get_operators(F, len(V)), steps=0)
    >>> [round(abs(float(c)), 6) for c in E[:, 2]], round(float(w[2]), 6)
    ([0.0, 0.0, 1.0], 25.0)
    """
    Y = np.array(X, dtype=np.float64)
    for _ in range(steps):
        Y = ops.P @ Y
    N = vertex_normals(Y, F)
    w, E = np.linalg.eigh(N.T @ N)
    return E, w


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


@register(
    "sobolev_axes",
    auto=AutoRule(("mu1", "mu2", "mu3"), choose_sobolev_axes, normals=("mu1", "mu2", "mu3"),
                  linear_map=sobolev_axes_map, normals_region=AXES_NORMAL_REGION,
                  spectral=sobolev_axes_spectral),
    summary="Polyharmonic Sobolev (I + mu_d L^p) y_d = x_d, one mu per principal axis of the normals",
    warm_start=True,
    params=[
        Param("mu1", float, 1.0, low=0.0, help="weight on the axis the normals point along least (0 keeps it)"),
        Param("mu2", float, 1.0, low=0.0, help="weight on the middle axis"),
        Param("mu3", float, 1.0, low=0.0, help="weight on the axis the normals point along most"),
        Param("order", int, 3, low=1, high=4, help="power p of the Laplacian in the penalty ||L^{p/2} y||^2"),
        Param("frame_steps", int, 10, low=0, high=MAX_ITERATIONS, help="averaging steps before the normals that define the axes"),
    ],
    linear=False,
    rough_free_run=True,  # the border option's free run: Lanczos to DRAFT_LANCZOS_TOL (face000 0.57 -> 0.33 s)
)
def sobolev_axes(V, F, *, ops, pinned, mu1, mu2, mu3, order, frame_steps, start=None, rough=False, config=None):
    """Polyharmonic Sobolev smoothing, with its own strength on each principal axis of the normals.

    With :math:`E = (e_1, e_2, e_3)` the principal axes of the normals of the mesh
    smoothed by ``frame_steps`` averaging steps (:func:`normal_frame`, increasing
    eigenvalues of :math:`\\sum_i n_i n_i^T`), each coordinate in that frame is
    smoothed separately:

    .. math:: (I + \\mu_d L^p)\\, y_d = X e_d, \\quad d = 1, 2, 3, \\qquad
              Y = \\sum_d y_d\\, e_d^T, \\qquad L = D - W

    i.e. :math:`y_d = \\arg\\min_y \\|y - X e_d\\|^2 + \\mu_d\\, y^T L^p y`. Why one
    weight per axis: the paper's noise moves vertex ``i`` along its normal, so the
    noise energy along :math:`e_d` is :math:`\\rho^2 \\sum_i (n_i \\cdot e_d)^2`, small
    on :math:`e_1` and large on :math:`e_3` (a flat region has all of its noise on one
    axis), while the shape's own energy is spread differently: the best strength
    differs per axis. ``meshdenoise.choose_parameters`` picks the three weights by
    SURE, one axis at a time (the risk is a sum over axes). ``p = 3`` (a transfer
    function :math:`1/(1 + \\mu k^3)` on the Laplacian eigenvalue ``k``) is flatter on
    the shape and steeper on the noise than the bi-Laplacian's; ``p = 1, 2`` are the
    ``sobolev`` / ``sobolev_bilaplacian`` penalties. The result is translation and
    rotation equivariant (the frame rotates with the mesh; :math:`L 1 = 0`); for a
    pinned frame it is linear. Each :math:`I + \\mu_d L^p` is factorised once per
    (topology, p, mu, pinned mask) with cholespy and cached; pinned vertices are
    solved as in ``sobolev_bilaplacian``.

    Choosing ``mu1`` (``mu2``, ``mu3``) for a scan: no rule of thumb holds across shapes (the oracle's
    ``mu1`` for noise of 0.1, 0.3 and 1 mean edge lengths: 0.035, 0.50 and 17 on a sphere, 2.6, 6.6
    and 17 on a torus, ``benchmarks/results/parameter-scale.md``); use the automatic choice.

    Parameters
    ----------
    mesh : (V, F) tuple, pymeshlab.MeshSet or Mesh, or open3d.geometry.TriangleMesh
    mu1, mu2, mu3 : float, >= 0
        Weights on the axes :math:`e_1, e_2, e_3` (0 leaves that coordinate as is).
    order : int, 1 <= order <= 4
        Power ``p`` of the Laplacian.
    frame_steps : int, >= 0
        Averaging steps applied before taking the normals that define the axes.
    pinned, region, preserve_volume, operators
        Options shared by every filter; see the README.
    config : AxesConfig, optional
        The array core's (``get_filter("sobolev_axes").core``) solver paths by size; ``None``: :data:`DEFAULT`.

    Returns
    -------
    Same type as ``mesh``

    References
    ----------
    M. Desbrun, M. Meyer, P. Schröder, A. Barr, "Implicit fairing of irregular meshes
    using diffusion and curvature flow", SIGGRAPH 1999 (higher-order implicit fairing).
    C. Stein, "Estimation of the mean of a multivariate normal distribution", 1981.
    A. Vaillant-Tenzer, "Mesh Denoising", 2022 (Sobolev regularisation, noise model).

    Examples
    --------
    >>> import numpy as np
    >>> from meshdenoise.shapes import grid
    >>> V, F = grid(6, 6)
    >>> Vn = V + [0, 0, 0.01] * np.random.default_rng(0).standard_normal((len(V), 1))
    >>> V1, _ = sobolev_axes((Vn, F), mu1=0.0, mu2=0.0, mu3=5.0)
    >>> bool(V1[:, 2].std() < 0.5 * Vn[:, 2].std()), bool(np.allclose(V1[:, :2], Vn[:, :2], atol=1e-3))
    (True, True)
    """
    X = np.array(V, dtype=np.float64)
    if F.shape[0] == 0:
        return X
    E, _ = normal_frame(X, F, ops, frame_steps)
    C = X @ E
    # the held runs' conjugate gradients start from a nearby result when given (the border option's free run: the
    # residual is then only near the border, face000's three held axes 195 -> 150 steps), else from the input
    C0 = C if start is None else np.asarray(start, dtype=np.float64) @ E
    out = np.empty_like(C)
    held = pinned is not None and pinned.any()
    config = resolve(config, DEFAULT)
    factor_free = ops.n >= config.lanczos_min_vertices and not held
    stored = ops.cache.get(f"shifted-p{order}-cholesky", {})
    mus = (mu1, mu2, mu3)
    # a 100k factor of I + mu L^3: 20 s. The axes without a stored factor by one compiled Lanczos run on their columns,
    # one function of L per column (the elephant: 0.42 s; three numpy runs of one column each: 0.65 s)
    free = [d for d, mu in enumerate(mus) if mu != 0 and factor_free and (float(mu), None) not in stored]
    tol = DRAFT_LANCZOS_TOL if rough else FILTER_LANCZOS_TOL  # rough: the border option's free run, a draft
    lanczos = (_axes_by_lanczos(ops, C[:, free], [float(mus[d]) for d in free], order, tol, config.lanczos_max_steps)
               if free else None)
    # held vertices (the border option's second run), no stored factor: CG while its bound is small, else CG
    # preconditioned by a one-ring factor for those axes together (solvers.ShiftedPCGFamily), where a factor of
    # I + mu L^p with the held rows took 2.8 s per axis on face000 (4,111 held border vertices)
    bounds = {d: shifted_cg_bound(ops, mu, order, FILTER_LANCZOS_TOL) for d, mu in enumerate(mus)
              if mu != 0 and held and ops.n >= config.lanczos_min_vertices and (float(mu), mask_key(pinned)) not in stored}
    family = [d for d, bound in bounds.items() if bound > config.pinned_cg_bound and order > 1]
    together = None
    if family:  # one factor, one run for the axes (face000's three: 3 factors and 2.5 s -> 1 and 1.5 s)
        together = ShiftedPCGFamily(ops, [mus[d] for d in family], order, pinned).solve(
            C[:, family], tol=FILTER_LANCZOS_TOL, x0=None if start is None else C0[:, family])
    for d, mu in enumerate(mus):
        y = None
        if lanczos is not None and d in free:
            y = lanczos[:, free.index(d)]
        elif mu != 0 and factor_free and (float(mu), None) not in stored:
            y = lanczos_shifted(ops, C[:, d], mu, order, tol=tol, growth=0.25)
        elif together is not None and d in family:
            y = together[:, family.index(d)]
        elif d in bounds and bounds[d] <= config.pinned_cg_bound:  # CG from the input, no factor
            y = shifted_solver(ops, mu, order, pinned, "cg").solve(C[:, d], tol=FILTER_LANCZOS_TOL, x0=C0[:, d],
                                                                 maxiter=int(4 * math.ceil(bounds[d])) + 50)
        if y is None:
            y = C[:, d] if mu == 0 else shifted_solver(ops, mu, order, pinned).solve(C[:, d])
        out[:, d] = y
    return out @ E.T


def _axes_by_lanczos(ops: Operators, C: np.ndarray, mus: list[float], order: int,
                     tol: float = FILTER_LANCZOS_TOL, max_steps: int = LANCZOS_SHIFTED_MAX_STEPS) -> np.ndarray | None:
    """:math:`(I + \\mu_j L^p)^{-1} c_j` for each column ``c_j`` of ``C`` (n, k) by one compiled Lanczos run on ``L``
    started at :math:`L^p C` (:meth:`~meshdenoise.solvers.CompiledLanczos.apply_many`, column ``j`` taking its own
    function, to ``tol``, :data:`~meshdenoise.solvers.FILTER_LANCZOS_TOL` by default), as
    :func:`~meshdenoise.solvers.lanczos_shifted` gives each; ``None`` past ``max_steps`` steps."""
    c = np.ascontiguousarray(C, dtype=np.float64)
    for _ in range(int(order)):
        c = spmm(ops.L, c)
    gs = tuple(ShiftedInverse(mu, order) for mu in mus)
    Y = CompiledLanczos(ops.L, c, max_steps=max_steps).apply_many([gs], rtol=tol, growth=0.25)
    return None if Y is None else C - np.asarray(mus)[None, :] * Y[0]

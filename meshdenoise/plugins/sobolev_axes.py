"""Polyharmonic Sobolev smoothing with one weight per principal axis of the surface normals."""

from __future__ import annotations

import math

import numpy as np

from ..operators import Operators, mask_key, spmm
from ..registry import MAX_ITERATIONS, AutoRule, Param, register
from ..solvers import (DRAFT_LANCZOS_TOL, FILTER_LANCZOS_TOL, LANCZOS_SHIFTED_MAX_STEPS, CompiledLanczos,
                       ShiftedInverse, ShiftedPCGFamily, lanczos_shifted, shifted_cg_bound, shifted_solver)
from ..tuning.config import resolve
from ._axes_frame import DEFAULT, AxesConfig, normal_frame
from .sobolev_axes_rule import AXES_NORMAL_REGION, choose_sobolev_axes, sobolev_axes_map, sobolev_axes_spectral

__all__ = ["sobolev_axes", "normal_frame", "AxesConfig"]


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

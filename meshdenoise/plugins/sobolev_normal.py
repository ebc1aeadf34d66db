"""Polyharmonic Sobolev smoothing whose update moves each vertex along its normal only."""

from __future__ import annotations

import math

import numpy as np

from ..geometry import area_normals
from ..operators import mask_key
from ..registry import AutoRule, Param, register
from ..solvers import FILTER_LANCZOS_TOL, lanczos_shifted, shifted_cg_bound, shifted_solver
from ..tuning.config import resolve
from ._normal_projection import DEFAULT, SobolevNormalConfig, project_update
from .sobolev_normal_rule import choose_sobolev_normal

__all__ = ["sobolev_normal", "project_update", "area_normals", "SobolevNormalConfig"]


@register(
    "sobolev_normal",
    scale_free=True,
    auto=AutoRule(("mu",), choose_sobolev_normal),
    summary="Polyharmonic Sobolev (I + mu L^p) Y = X, each vertex moved along the normal of Y only",
    params=[
        Param("mu", float, 1.0, low=0.0, help="weight of the penalty ||L^{p/2} Y||^2 (0 returns the input)"),
        Param("order", int, 2, low=1, high=4, help="power p of the Laplacian"),
        Param("tangential", float, 0.0, low=0.0, high=1.0, help="share of the tangential part of the update kept (1: plain Sobolev)"),
    ],
    linear=False,
)
def sobolev_normal(V, F, *, ops, pinned, mu, order, tangential, config=None):
    """Sobolev smoothing whose displacement is projected on the normals of the smoothed mesh.

    .. math:: (I + \\mu L^p)\\, Y = X, \\qquad
              x'_i = x_i + \\big(n_i n_i^T + t\\,(I - n_i n_i^T)\\big)(y_i - x_i),
              \\qquad n_i = \\text{area-weighted normal of } Y \\text{ at } i

    Why: the paper's noise moves each vertex along its normal, so the tangential part of
    a Laplacian smoother's update removes no noise: it only slides vertices towards their
    neighbours' centroid (tangential drift on irregular sampling), which the error to the
    clean mesh counts in full. Keeping the normal part (``t = 0``) removes that bias.
    The normals are those of ``Y`` (:func:`area_normals`: a face that smoothing
    collapsed has no vote), a smooth surface: under noise larger than the edge
    length no normal survives and ``t = 1`` (plain ``(I + mu L^p)^{-1}``) is the safe
    choice; ``meshdenoise.choose_parameters`` sets ``t`` from the estimated noise per edge length and
    chooses ``mu`` (and ``order`` in {2, 3}) by Monte-Carlo SURE. Not linear (the
    normals depend on the input); translation and rotation equivariant. The factors of
    :math:`I + \\mu L^p` are cached per (topology, p, mu, pinned mask) as for
    ``sobolev_axes``; pinned vertices do not move (their update is zero). From
    ``SobolevNormalConfig.lanczos_min_vertices`` vertices, with no pinned vertex and no stored factor,
    ``Y`` comes from two Lanczos passes on ``L`` (:func:`~meshdenoise.solvers.lanczos_shifted`), no
    factorisation (the same ``Y`` to about 1e-13 of the coordinates); with pinned vertices from
    Jacobi-preconditioned CG while its iteration bound (:func:`~meshdenoise.solvers.shifted_cg_bound`)
    is at most ``SobolevNormalConfig.pinned_cg_bound`` (the same ``Y`` to about 1e-9).

    Choosing ``mu`` for a scan: no rule of thumb holds across shapes (with noise of 0.1, 0.3 and 1
    mean edge lengths along the normals the oracle chose 21, 31 and 12 on a sphere, 4.5, 11 and 24
    on a torus: a sphere's normals are its own fixed point, ``benchmarks/results/parameter-scale.md``); use the automatic
    choice (``denoise(method="sobolev_normal")``).

    Parameters
    ----------
    mesh : (V, F) tuple, pymeshlab.MeshSet or Mesh, or open3d.geometry.TriangleMesh
    mu : float, >= 0
        Smoothing weight.
    order : int, 1 <= order <= 4
        Power ``p`` of the graph Laplacian ``L = D - W``.
    tangential : float in [0, 1]
        Share ``t`` of the tangential update kept.
    pinned, region, preserve_volume, operators
        Options shared by every filter; see the README.
    config : SobolevNormalConfig, optional
        The array core's (``get_filter("sobolev_normal").core``) solver paths by size; ``None``: :data:`DEFAULT`.

    Returns
    -------
    Same type as ``mesh``

    References
    ----------
    M. Desbrun, M. Meyer, P. Schröder, A. Barr, "Implicit fairing of irregular meshes
    using diffusion and curvature flow", SIGGRAPH 1999 (motion along the normal only).
    A. Vaillant-Tenzer, "Mesh Denoising", 2022 (noise model along the normals).

    Examples
    --------
    >>> import numpy as np
    >>> from meshdenoise.shapes import grid
    >>> V, F = grid(6, 6)
    >>> Vn = V + [0.01, 0.0, 0.01] * np.random.default_rng(0).standard_normal((len(V), 1))
    >>> V1, _ = sobolev_normal((Vn, F), mu=5.0)
    >>> bool(np.allclose(V1[:, :2], Vn[:, :2], atol=1e-3)), bool(V1[:, 2].std() < 0.5 * Vn[:, 2].std())
    (True, True)
    """
    X = np.array(V, dtype=np.float64)
    if F.shape[0] == 0 or mu == 0:
        return X
    Y = None
    held = pinned is not None and pinned.any()
    stored = ((float(mu), mask_key(pinned if held else None)) in ops.cache.get(f"shifted-p{order}-cholesky", {}))
    config = resolve(config, DEFAULT)
    if ops.n >= config.lanczos_min_vertices and not stored:
        if not held:
            Y = lanczos_shifted(ops, X, mu, order, tol=FILTER_LANCZOS_TOL, growth=0.25)  # a 100k factor of I + mu L^3: 20 s
        elif (bound := shifted_cg_bound(ops, mu, order, FILTER_LANCZOS_TOL)) <= config.pinned_cg_bound:
            # held vertices (the border option's second run): CG from the input, no factor
            Y = shifted_solver(ops, mu, order, pinned, "cg").solve(X, tol=FILTER_LANCZOS_TOL, x0=X,
                                                                 maxiter=int(4 * math.ceil(bound)) + 50)
    if Y is None:
        Y = shifted_solver(ops, mu, order, pinned).solve(X)
    return project_update(X, Y, area_normals(Y, F), tangential)

"""Polyharmonic Sobolev smoothing with a data term weighted along the estimated normals."""

from __future__ import annotations

import math
from typing import Callable

import numpy as np

from ..geometry import coherent_normals  # re-exported: the filter's normals
from ..operators import Operators, mask_key, spmm
from ..registry import AutoRule, Param, register
from ..solvers import (DRAFT_LANCZOS_TOL, FILTER_LANCZOS_TOL, lanczos_shifted, one_ring_factor, one_ring_solve,
                       shifted_cg_bound, shifted_solver)
from ..tuning.config import resolve
from ._gls_solve import DEFAULT, GlsConfig, apply_weight, correction_rhs, normal_weighted_cg, normal_weighted_solve
from .sobolev_gls_rule import GLS_NORMALS, choose_sobolev_gls

__all__ = ["sobolev_gls", "normal_weighted_solve", "normal_weighted_cg", "coherent_normals", "GlsConfig"]


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
    return X0 + normal_weighted_solve(ops, N, beta, mu, order, correction_rhs(N, beta, X, X0), pinned,
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
    rhs = correction_rhs(N, beta, X, X0) - apply_weight(N, beta, D_held) - mu * pull
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
    rhs = correction_rhs(N, beta, X, X0)
    D, ok = normal_weighted_cg(ops, N, beta, mu, order, rhs, tol=config.filter_tol, pinned=pinned,
                               maxiter=config.jacobi_max_iterations)
    if not ok:  # a very large mu: the factor-preconditioned iteration, its count bounded by sqrt(beta)
        D = normal_weighted_solve(ops, N, beta, mu, order, rhs, pinned, x0=D, prec=None if held else shifted,
                                  config=config)
    return X0 + D



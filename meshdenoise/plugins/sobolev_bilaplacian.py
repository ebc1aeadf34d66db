"""Higher-order Sobolev regularisation: solve (I + mu L^2) Y = X by cached sparse Cholesky."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..operators import Operators, mask_key, spmm
from ..registry import AutoRule, Param, register
from ..solvers import LanczosQuadrature, ShiftedInverse, shifted_cg_bound, shifted_solver
from ..tuning.config import check_fields, resolve
from ..tuning.spectral import shifted_spectral
from . import sobolev as _sobolev
from .sobolev import SobolevConfig
from .sobolev_bilaplacian_rule import choose_sobolev_bilaplacian

SOLVERS = ("auto", "cholesky", "cg", "lanczos")
LANCZOS_MAX_STEPS = 1000

__all__ = ["sobolev_bilaplacian", "bilaplacian_cg_bound", "lanczos_bilaplacian",
           "BilaplacianConfig"]


@dataclass(frozen=True)
class BilaplacianConfig:
    """``solver="auto"``'s choice for ``sobolev_bilaplacian`` (``core(..., config=)``): the values, and where they
    were measured.

    Attributes
    ----------
    lanczos_min_vertices : int
        Without pinned vertices two Lanczos passes from this size (100k, load 15: 2.9 s against a 15 s factorisation
        of I + mu L^2, same SNR to 13 digits; from 20,000 it is 2-3 times faster than a factor for one run, but a
        choice that ran the filter at one mu once per probe took the elephant's whole call from 2.2 to 7.7 s).
    pinned_cg_min_vertices : int
        With pinned vertices (the border option's one run) a factor below this size, ...
    pinned_cg_bound : float
        ... CG from it while its bound is at most this (the Bunny0.2's border at mu 0.26: bound 135, 0.09 s against
        a 0.49 s factor; face000 at 12: 496, 0.76 against 1.19 s; the elephant at 163: 2,726, 1.5 against 0.14 s),
        from ``SobolevConfig.cg_min_vertices`` vertices the bound ``SobolevConfig.cg_max_iterations`` as for sobolev.
    """

    lanczos_min_vertices: int = 50_000
    pinned_cg_min_vertices: int = 20_000
    pinned_cg_bound: float = 500

    def __post_init__(self) -> None:
        check_fields(self, nonnegative=("lanczos_min_vertices", "pinned_cg_min_vertices", "pinned_cg_bound"))


DEFAULT = BilaplacianConfig()


def bilaplacian_cg_bound(ops: Operators, mu: float, tol: float) -> float:
    """:func:`~meshdenoise.solvers.shifted_cg_bound` for :math:`I + \\mu L^2`."""
    return shifted_cg_bound(ops, mu, 2, tol)


def _choose_solver(ops: Operators, mu: float, pinned: np.ndarray | None, tol: float,
                   config: BilaplacianConfig | None = None, large: SobolevConfig | None = None) -> str:
    """``solver="auto"``: as :func:`~meshdenoise.plugins.sobolev.choose_solver` for :math:`I + \\mu L^2`.

    Cholesky when its factor is stored; without pinned vertices two Lanczos passes
    (:func:`lanczos_bilaplacian`) from ``config.lanczos_min_vertices`` vertices, Cholesky below; with
    them Cholesky below ``config.pinned_cg_min_vertices`` vertices, else CG while :func:`bilaplacian_cg_bound` is at
    most ``config.pinned_cg_bound`` (from ``large.cg_min_vertices`` vertices ``large.cg_max_iterations``),
    Cholesky otherwise (the 400k scale mesh at the chosen mu = 1.1: a 14 s factorisation, 4.4 s of
    CG, 2.1 s of Lanczos on a loaded machine). ``None``: :data:`DEFAULT`, ``sobolev``'s default.
    """
    config, large = resolve(config, DEFAULT), resolve(large, _sobolev.DEFAULT)
    stored = ops.cache.get("shifted-p2-cholesky", {})
    if (float(mu), mask_key(pinned if pinned is not None and pinned.any() else None)) in stored:
        return "cholesky"
    if pinned is None or not pinned.any():  # its steps grow like mu^(1/4): no bound needed (a factor at 1.6M took
        return "lanczos" if ops.n >= config.lanczos_min_vertices else "cholesky"  # over 3 minutes and 6.7 GB)
    if ops.n < config.pinned_cg_min_vertices:
        return "cholesky"
    bound = config.pinned_cg_bound if ops.n < large.cg_min_vertices else large.cg_max_iterations
    return "cg" if bilaplacian_cg_bound(ops, mu, tol) <= bound else "cholesky"


def lanczos_bilaplacian(ops: Operators, V: np.ndarray, mu: float, tol: float) -> np.ndarray | None:
    """:math:`(I + \\mu L^2)^{-1} V = V - \\mu (I + \\mu L^2)^{-1} L^2 V` by two Lanczos passes on ``L`` (no pinned rows).

    The correction :math:`\\mu f(L) c`, :math:`f(t) = 1/(1 + \\mu t^2)`, :math:`c = L^2 V`, is the
    Lanczos approximation :math:`\\|c\\| Q_k f(T_k) e_1` (:meth:`LanczosQuadrature.apply`):
    the poles of ``f`` lie at distance :math:`\\mu^{-1/2}` from the spectrum of ``L``, so ``k``
    grows like :math:`\\mu^{1/4}` (50 to 60 steps on a torus at mu 0.3 to 5), against CG on
    :math:`I + \\mu L^2` whose iterations grow like :math:`\\sqrt\\mu\\, d_{max}` and each of
    which costs 2.7 products with ``L``. ``None`` if not converged in ``LANCZOS_MAX_STEPS``.
    """
    c = spmm(ops.L, spmm(ops.L, np.asarray(V, dtype=np.float64)))
    Y = LanczosQuadrature(ops.L, c, max_steps=LANCZOS_MAX_STEPS).apply(ShiftedInverse(mu, 2), rtol=tol)
    return None if Y is None else np.array(V, dtype=np.float64) - mu * Y


@register(
    "sobolev_bilaplacian",
    auto=AutoRule(("mu",), choose_sobolev_bilaplacian, normals="mu",
                  spectral=lambda V, F, ops, p: shifted_spectral(ops, p["mu"], 2)),
    summary="Higher-order Sobolev regularisation: solve (I + mu L^2) Y = X by cached sparse Cholesky",
    params=[
        Param("mu", float, 1.0, low=0.0, help="weight of the bending term ||L Y||^2 (0 returns the input)"),
        Param("solver", str, "auto", choices=SOLVERS,
              help="'cholesky' (cached factor), 'cg' or 'lanczos' (iterative, no factor), "
                   "or 'auto': lanczos (cg with pinned vertices) for a one-off solve on a large mesh"),
        Param("tol", float, 1e-10, low=1e-14, high=1e-2,
              help="relative residual at which 'cg' stops; 'lanczos': relative change of its coefficients"),
    ],
    linear=True,
)
def sobolev_bilaplacian(V, F, *, ops, pinned, mu, solver="auto", tol=1e-10, config=None):
    """Second-order Sobolev regularisation: penalise the Laplacian of the result, not its gradient.

    .. math:: Y = \\arg\\min_Y \\|Y - X\\|_F^2 + \\mu \\|L Y\\|_F^2
              \\iff (I + \\mu L^2)\\, Y = X, \\qquad L = D - W

    :math:`L^2` is symmetric positive semi-definite, so :math:`I + \\mu L^2` is positive
    definite and is factorised once per (topology, ``mu``, pinned mask) with cholespy;
    later calls cost two triangular solves. Its transfer function
    :math:`1/(1 + \\mu k^2)` on a Laplacian eigenvalue :math:`k` is flatter at low
    frequencies and steeper at high ones than the first-order
    :math:`1/(1 + \\mu k)`: less shrinkage of large shapes for the same noise removal
    (a plane and, away from the boundary, any linear function is kept exactly).
    With pinned vertices the rows of the free vertices are solved,
    :math:`(I + \\mu L^2)_{ff} Y_f = X_f - \\mu (L^2)_{fp} X_p`.

    With ``solver="cg"`` nothing is factorised: Jacobi-preconditioned block CG from ``X``
    (as ``sobolev``), stopped at relative residual ``tol``; its iterations grow like
    :math:`\\sqrt{\\mu}\\, d_{max}` (:func:`bilaplacian_cg_bound`), not with ``n``.

    Choosing ``mu`` for a scan: with noise of 0.1, 0.3 and 1 mean edge lengths ``h`` along the
    normals the oracle chose 0.02-0.58, 0.20-1.38 and 1.37-4.15 on a sphere, a torus and the
    bunny (``benchmarks/results/parameter-scale.md``): it depends on the surface's curvature at the
    edge-length scale more than first-order ``mu`` does, so prefer the automatic choice
    (``denoise(method="sobolev_bilaplacian")``); by hand, start near ``mu = 2 s`` for noise of
    ``s`` edge lengths and compare renders (``meshdenoise render BEFORE AFTER``).

    Parameters
    ----------
    mesh : (V, F) tuple, pymeshlab.MeshSet or Mesh, or open3d.geometry.TriangleMesh
    mu : float, >= 0
    solver : {"auto", "cholesky", "cg", "lanczos"}
        Cached sparse Cholesky factor, block conjugate gradient, two Lanczos passes on ``L``
        (:func:`lanczos_bilaplacian`; with pinned vertices CG is used), or ``"auto"`` (default):
        ``"lanczos"`` from 50,000 vertices, Cholesky below or when the factor is already stored;
        with pinned vertices Cholesky below 200,000 vertices, else ``"cg"`` while its iteration
        bound is at most 300.
    tol : float, 1e-14 <= tol <= 1e-2
        Relative residual at which ``"cg"`` stops (ignored by ``"cholesky"``).
    pinned, region, preserve_volume, operators
        Options shared by every filter; see the README.

    Returns
    -------
    Same type as ``mesh``

    References
    ----------
    M. Desbrun, M. Meyer, P. Schröder, A. Barr, "Implicit fairing of irregular meshes
    using diffusion and curvature flow", SIGGRAPH 1999 (higher-order implicit fairing).
    A. Vaillant-Tenzer, "Mesh Denoising", 2022 (first-order Sobolev).

    Examples
    --------
    >>> import numpy as np
    >>> V = np.array([[0., 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    >>> F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    >>> V1, _ = sobolev_bilaplacian((V, F), mu=1.0)  # on K4, L = 4I - 11^T: x - c shrinks by 1/(1 + 16)
    >>> V1[0]
    array([0.23529412, 0.23529412, 0.23529412])
    """
    if mu == 0:
        return np.array(V, dtype=np.float64)
    if solver == "auto":
        solver = _choose_solver(ops, mu, pinned, tol, config)
    if solver == "lanczos" and (pinned is None or not pinned.any()):
        Y = lanczos_bilaplacian(ops, V, mu, tol)
        if Y is not None:
            return Y
        solver = "cg"  # not converged (a very large mu): CG, which warns if it does not either
    if solver in ("cg", "lanczos"):
        cap = int(4 * math.ceil(bilaplacian_cg_bound(ops, mu, tol))) + 50
        return shifted_solver(ops, mu, 2, pinned, "cg").solve(V, tol=tol, x0=V, maxiter=cap)
    return shifted_solver(ops, mu, 2, pinned).solve(V)

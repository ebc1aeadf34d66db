"""Sobolev regularisation: solve (I + mu L) Y = X by cached sparse Cholesky, or by block CG."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..operators import Operators
from ..registry import AutoRule, Param, register
from ..solvers import SPDSolver, shifted_matrix, shifted_solver
from ..tuning.config import check_fields, resolve
from .sobolev_rule import SOBOLEV_NORMALS, choose_sobolev

__all__ = ["sobolev", "SobolevSolver", "choose_solver", "SOLVERS", "SobolevConfig"]

SOLVERS = ("auto", "cholesky", "cg")


@dataclass(frozen=True)
class SobolevConfig:
    """``solver="auto"``'s choice for ``sobolev`` (``core(..., config=)``, :func:`choose_solver`), also the bound of
    ``sobolev_bilaplacian``'s held runs from its size.

    Attributes
    ----------
    cg_min_vertices : int
        Below this many vertices a factorisation costs under a few seconds and is kept for reuse ...
    cg_max_iterations : float
        ... and from it CG while its iteration bound stays under this (a one-off solve on a scan-sized mesh: 1.5 s
        instead of a 28 s factorisation at 1.6M vertices, README "Speed").
    """

    cg_min_vertices: int = 200_000
    cg_max_iterations: float = 300

    def __post_init__(self) -> None:
        check_fields(self, nonnegative=("cg_min_vertices", "cg_max_iterations"))


DEFAULT = SobolevConfig()


def choose_solver(ops: Operators, mu: float, pinned: np.ndarray | None, tol: float,
                  config: SobolevConfig | None = None) -> str:
    """``"cg"`` or ``"cholesky"`` for ``solver="auto"``.

    Cholesky when a factor of ``I + mu L`` (same ``mu`` and pinned mask) is already stored
    on the topology, or the mesh has fewer than ``config.cg_min_vertices`` vertices (the
    factor is cheap and kept for the next call); otherwise CG while its iteration bound
    :math:`\\tfrac12\\sqrt{2(1 + \\mu d_{max})}\\,\\ln(2/\\mathrm{tol})` is at most
    ``config.cg_max_iterations``, Cholesky for larger ``mu`` (:class:`SobolevConfig`; ``None``: its default).
    """
    config = resolve(config, DEFAULT)
    from ..operators import mask_key

    stored = ops.cache.get("shifted-p1-cholesky", {})
    if (float(mu), mask_key(pinned if pinned is not None and pinned.any() else None)) in stored:
        return "cholesky"
    if ops.n < config.cg_min_vertices:
        return "cholesky"
    d_max = float(ops.degree.max()) if ops.n else 0.0
    bound = 0.5 * math.sqrt(2.0 * (1.0 + mu * d_max)) * math.log(2.0 / tol)
    return "cg" if bound <= config.cg_max_iterations else "cholesky"


class SobolevSolver(SPDSolver):
    """A factorised ``I + mu L`` (restricted to free vertices when some are pinned), reusable for any X.

    Parameters
    ----------
    ops : Operators
        The topology's operators (``L = D - W``).
    mu : float, > 0
    pinned : ndarray of bool, shape (n,), optional
        Vertices held at their input position (Dirichlet data).

    Examples
    --------
    >>> import numpy as np
    >>> from meshdenoise.operators import get_operators
    >>> F = np.array([[0, 1, 2], [0, 2, 3]])
    >>> solver = SobolevSolver(get_operators(F, 4), mu=1.0)
    >>> X = np.eye(4)[:, :3]
    >>> A = np.eye(4) + get_operators(F, 4).L.toarray()
    >>> bool(np.allclose(A @ solver.solve(X), X))
    True
    """

    def __init__(self, ops: Operators, mu: float, pinned: np.ndarray | None = None):
        if not mu > 0:
            raise ValueError(f"SobolevSolver: mu must be > 0, got {mu!r}")
        self.mu = float(mu)
        super().__init__(shifted_matrix(ops, self.mu), pinned)


def cg_iteration_cap(ops: Operators, mu: float, tol: float) -> int:
    """Four times the CG iteration bound for ``I + mu L`` with Jacobi preconditioning, plus 50.

    Uses :math:`\\kappa \\le 2 (1 + \\mu d_{max})` and the CG bound of
    :math:`\\tfrac12 \\sqrt\\kappa \\ln(2/\\mathrm{tol})` iterations; reaching four times
    that means rounding has stalled the iteration, not that it needed more time.
    """
    d_max = float(ops.degree.max()) if ops.n else 0.0
    kappa = 2.0 * (1.0 + mu * d_max)
    return int(4 * math.ceil(0.5 * math.sqrt(kappa) * math.log(2.0 / tol))) + 50


@register(
    "sobolev",
    auto=AutoRule(("mu",), choose_sobolev, normals="mu", held_out=SOBOLEV_NORMALS),
    summary="Sobolev regularisation: solve (I + mu L) Y = X, L = D - W, by cached sparse Cholesky or block CG",
    params=[
        Param("mu", float, 1.0, low=0.0, help="regularisation weight (0 returns the input)"),
        Param("solver", str, "auto", choices=SOLVERS,
              help="'cholesky' (cached factor), 'cg' (iterative, no factor), or 'auto': cg for a one-off solve on a large mesh"),
        Param("tol", float, 1e-10, low=1e-14, high=1e-2, help="relative residual at which 'cg' stops"),
    ],
    linear=True,
)
def sobolev(V, F, *, ops, pinned, mu, solver="auto", tol=1e-10, config=None):
    """Sobolev (Tikhonov) regularisation with the graph Laplacian (the paper's third method).

    .. math:: Y = \\arg\\min_Y \\|Y - X\\|_F^2 + \\mu\\, \\mathrm{tr}(Y^T L Y)
              \\iff (I + \\mu L)\\, Y = X, \\qquad L = D - W

    The three coordinate columns are solved at once with a sparse Cholesky
    factorisation (cholespy, CHOLMOD ordering). The factor is cached per (topology,
    ``mu``, pinned mask), so a second call on the same faces with other coordinates
    costs only the triangular solves. With pinned vertices the reduced system
    :math:`(I + \\mu L)_{ff} Y_f = X_f - \\mu L_{fp} X_p` is solved on the free vertices.

    With ``solver="cg"`` nothing is factorised: the three columns run a
    Jacobi-preconditioned block conjugate gradient
    (:func:`meshdenoise.solvers.block_cg`, one threaded sparse product per iteration),
    started from the input ``X`` (a good guess: :math:`Y - X = -\\mu L Y` is small on a
    mildly noisy mesh) and stopped per column when
    :math:`\\|b - A_{ff} Y_f\\|_2 \\le \\mathrm{tol}\\, \\|b\\|_2`, with
    :math:`b = X_f - \\mu L_{fp} X_p` the right-hand side of the reduced system. With :math:`M = I + \\mu D` the Jacobi
    preconditioner, :math:`M^{-1/2} (I + \\mu L) M^{-1/2} = I - \\mu M^{-1/2} W M^{-1/2}` has
    its eigenvalues in :math:`[1 / (1 + \\mu d_{max}),\\ 2)` (the smallest eigenvalue of
    :math:`I + \\mu L` is at least 1; Gershgorin bounds the largest), so

    .. math:: \\kappa \\le 2\\,(1 + \\mu d_{max}) \\approx 1 + 2 \\mu d_{max}
              \\quad\\text{and}\\quad
              \\text{iterations} \\lesssim \\tfrac12 \\sqrt\\kappa\\, \\ln(2/\\mathrm{tol})
              = O\\big(\\sqrt{\\mu d_{max}}\\, \\log(1/\\mathrm{tol})\\big),

    independent of the number of vertices: the cost is linear in ``n``. The result equals
    the Cholesky one to about ``tol`` relative (times :math:`\\sqrt\\kappa`, the
    residual-to-error factor). The iteration cap is four times the bound plus 50;
    reaching it emits a :class:`UserWarning`. Prefer ``"cg"`` on meshes of a million
    vertices and more with moderate ``mu`` (no factorisation to pay); prefer
    ``"cholesky"`` for large ``mu`` (iterations grow like :math:`\\sqrt\\mu`) or for many
    solves on the same topology (the cached factor makes each re-solve cheap).

    Choosing ``mu`` for a scan: ``mu`` has no unit (the graph Laplacian counts neighbours), and
    the best value follows the noise measured in mean edge lengths ``h``. With Gaussian noise
    along the normals the oracle chose 0.08-0.13 at 0.1 h, 0.28-0.33 at 0.3 h and 0.67-0.87 at
    1 h on a sphere, a torus and the bunny (``benchmarks/results/parameter-scale.md``): start from
    ``mu`` about the noise in edge lengths (``meshdenoise denoise --dry-run`` prints it), or let
    ``choose_parameters`` / ``denoise(method="sobolev")`` choose it.

    Parameters
    ----------
    mesh : (V, F) tuple, pymeshlab.MeshSet or Mesh, or open3d.geometry.TriangleMesh
    mu : float, >= 0
        Weight of the smoothness term; ``mu = 0`` returns the input.
    solver : {"auto", "cholesky", "cg"}
        Cached sparse Cholesky factor, block conjugate gradient, or ``"auto"`` (default):
        :func:`choose_solver`, Cholesky below 200,000 vertices or when the factor is
        already stored, CG for a one-off solve on a larger mesh with moderate ``mu``.
    tol : float, 1e-14 <= tol <= 1e-2
        Relative residual at which ``"cg"`` stops (ignored by ``"cholesky"``).
    pinned, region, preserve_volume, operators
        Options shared by every filter; see the README.
    config : SobolevConfig, optional
        The array core's (``get_filter("sobolev").core``) ``"auto"`` choice by size; ``None``: :data:`DEFAULT`.

    Returns
    -------
    Same type as ``mesh``

    References
    ----------
    A. Vaillant-Tenzer, "Mesh Denoising", 2022, section on Sobolev regularisation.
    Y. Saad, "Iterative Methods for Sparse Linear Systems", 2nd ed., SIAM 2003, sections
    6.11 (CG convergence) and 9.2 (preconditioned CG).

    Examples
    --------
    >>> import numpy as np
    >>> V = np.array([[0., 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    >>> F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    >>> V1, _ = sobolev((V, F), mu=1.0)  # on K4, y_i = (x_i + mu sum_j x_j) / (1 + 4 mu)
    >>> V1[0]
    array([0.2, 0.2, 0.2])
    >>> V2, _ = sobolev((V, F), mu=1.0, solver="cg", tol=1e-12)
    >>> bool(np.allclose(V2, V1, rtol=0, atol=1e-12))
    True
    """
    if mu == 0:
        return np.array(V, dtype=np.float64)
    if solver == "auto":
        solver = choose_solver(ops, mu, pinned, tol, config)
    if solver == "cg":
        return shifted_solver(ops, mu, 1, pinned, "cg").solve(V, tol=tol, x0=V, maxiter=cg_iteration_cap(ops, mu, tol))
    return shifted_solver(ops, mu, 1, pinned).solve(V)

"""Sobolev regularisation: solve (I + mu L) Y = X by cached sparse Cholesky, or by block CG."""

from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sp

from ..operators import Operators
from ..registry import Param, register
from ..solvers import CGSolver, SPDSolver, cached_solver

__all__ = ["sobolev", "SobolevSolver", "sobolev_solver", "sobolev_cg_solver", "SOLVERS"]

SOLVERS = ("cholesky", "cg")


class SobolevSolver(SPDSolver):
    """A factorised ``I + mu L`` (restricted to free vertices when some are fixed), reusable for any X.

    Parameters
    ----------
    ops : Operators
        The topology's operators (``L = D - W``).
    mu : float, > 0
    fixed : ndarray of bool, shape (n,), optional
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

    def __init__(self, ops: Operators, mu: float, fixed: np.ndarray | None = None):
        if not mu > 0:
            raise ValueError(f"SobolevSolver: mu must be > 0, got {mu!r}")
        self.mu = float(mu)
        super().__init__(sp.identity(ops.n, format="csr") + self.mu * ops.L, fixed)


def sobolev_solver(ops: Operators, mu: float, fixed: np.ndarray | None = None) -> SobolevSolver:
    """The cached :class:`SobolevSolver` of this topology for ``(mu, fixed)``, built on first use."""
    return cached_solver(ops, "sobolev", mu, fixed, lambda: SobolevSolver(ops, mu, fixed))


def cg_iteration_cap(ops: Operators, mu: float, tol: float) -> int:
    """Four times the CG iteration bound for ``I + mu L`` with Jacobi preconditioning, plus 50.

    Uses :math:`\\kappa \\le 2 (1 + \\mu d_{max})` and the CG bound of
    :math:`\\tfrac12 \\sqrt\\kappa \\ln(2/\\mathrm{tol})` iterations; reaching four times
    that means rounding has stalled the iteration, not that it needed more time.
    """
    d_max = float(ops.degree.max()) if ops.n else 0.0
    kappa = 2.0 * (1.0 + mu * d_max)
    return int(4 * math.ceil(0.5 * math.sqrt(kappa) * math.log(2.0 / tol))) + 50


def sobolev_cg_solver(ops: Operators, mu: float, fixed: np.ndarray | None = None) -> CGSolver:
    """The cached :class:`~meshdenoise.solvers.CGSolver` of ``I + mu L`` for ``(mu, fixed)`` (no factorisation)."""
    if not mu > 0:
        raise ValueError(f"sobolev_cg_solver: mu must be > 0, got {mu!r}")
    return cached_solver(
        ops, "sobolev_cg", mu, fixed, lambda: CGSolver(sp.identity(ops.n, format="csr") + float(mu) * ops.L, fixed)
    )


@register(
    "sobolev",
    summary="Sobolev regularisation: solve (I + mu L) Y = X, L = D - W, by cached sparse Cholesky or block CG",
    params=[
        Param("mu", float, 1.0, low=0.0, help="regularisation weight (0 returns the input)"),
        Param("solver", str, "cholesky", choices=SOLVERS, help="'cholesky' (cached factor) or 'cg' (iterative, no factor)"),
        Param("tol", float, 1e-10, low=0.0, high=1e-2, low_open=True, help="relative residual at which 'cg' stops"),
    ],
    linear=True,
)
def sobolev(V, F, *, ops, fixed, mu, solver="cholesky", tol=1e-10):
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

    Parameters
    ----------
    mesh : (V, F) tuple, pymeshlab.MeshSet or Mesh, or open3d.geometry.TriangleMesh
    mu : float, >= 0
        Weight of the smoothness term; ``mu = 0`` returns the input.
    solver : {"cholesky", "cg"}
        Cached sparse Cholesky factor (default) or block conjugate gradient.
    tol : float, 0 < tol <= 1e-2
        Relative residual at which ``"cg"`` stops (ignored by ``"cholesky"``).
    pinned, region, preserve_volume, operators
        Options shared by every filter; see the README.

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
    if solver == "cg":
        return sobolev_cg_solver(ops, mu, fixed).solve(V, tol=tol, x0=V, maxiter=cg_iteration_cap(ops, mu, tol))
    return sobolev_solver(ops, mu, fixed).solve(V)

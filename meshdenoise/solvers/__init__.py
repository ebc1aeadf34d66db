"""Symmetric positive definite systems with Dirichlet (pinned) rows: factorised or iterative, and Lanczos runs.

The implicit filters (Sobolev, higher-order Sobolev) all solve ``A Y = X`` with
``A = I + (positive semi-definite)``; with pinned vertices, on the free rows only.
:class:`SPDSolver` factorises once (sparse Cholesky) and caches; :class:`CGSolver`
runs a Jacobi-preconditioned block conjugate gradient with no factorisation, which
wins on very large, well-conditioned systems such as ``I + mu L`` with moderate ``mu``.

The modules, bottom up (each imports only those above it):

- :mod:`~meshdenoise.solvers.config`: :class:`SolverConfig`, the back end and the sizes that choose a path;
- :mod:`~meshdenoise.solvers.factor`: :class:`DirichletSystem`, :class:`SPDSolver` (CHOLMOD or cholespy) and the
  symbolic analyses kept;
- :mod:`~meshdenoise.solvers.cg`: :func:`block_cg`, :class:`CGSolver` and the preconditioned CG of the held solvers;
- :mod:`~meshdenoise.solvers.matrices`: :math:`I + \\mu L^p`, its product form and CG's bound on it;
- :mod:`~meshdenoise.solvers.pcg`: CG preconditioned by a one-ring factor (:class:`ShiftedPCG`,
  :class:`ShiftedPCGFamily`);
- :mod:`~meshdenoise.solvers.shifted`: :func:`shifted_solver`, the one place the package builds the stored solvers of
  :math:`I + \\mu L^p`, :class:`HeldByProduct` and :func:`retain_factors`;
- :mod:`~meshdenoise.solvers.quadrature`: :class:`LanczosQuadrature` and :class:`ShiftedInverse`;
- :mod:`~meshdenoise.solvers.lanczos`: :func:`lanczos_shifted` and :class:`LanczosRows`;
- :mod:`~meshdenoise.solvers.compiled_lanczos`: :class:`CompiledLanczos` and :class:`LanczosDots`.

A test or a caller replacing a function to count or spy on its calls replaces it in the module that calls it
(``meshdenoise.solvers.shifted.shifted_factor``, ``meshdenoise.solvers.factor._cholmod_factor``): the names here are
the same objects, read by no solver.
"""

from .cg import HELD_CG_TOL, CGSolver, block_cg
from .compiled_lanczos import CompiledLanczos, LanczosDots
from .config import CHOLMOD, DEFAULT, SolverConfig
from .factor import DirichletSystem, SPDSolver, clear_symbolic
from .lanczos import DRAFT_LANCZOS_TOL, FILTER_LANCZOS_TOL, LANCZOS_SHIFTED_MAX_STEPS, LanczosRows, lanczos_shifted
from .matrices import (ShiftedProduct, laplacian_power, shifted_cg_bound, shifted_factor, shifted_factor_matrices,
                       shifted_matrix)
from .pcg import SHIFTED_PCG_MAXITER, ShiftedPCG, ShiftedPCGFamily, held_row_share, one_ring_factor, one_ring_solve
from .quadrature import LanczosQuadrature, ShiftedInverse, column_function
from .shifted import (FACTORS_PER_FAMILY, HELD_CG_MAXITER, SHIFTED_METHODS, HeldByProduct, cached_solver,
                      retain_factors, shifted_solver)

__all__ = [
    "SolverConfig", "DEFAULT", "CHOLMOD", "DirichletSystem", "SPDSolver", "clear_symbolic", "CGSolver", "block_cg",
    "HELD_CG_TOL", "cached_solver", "retain_factors", "FACTORS_PER_FAMILY", "laplacian_power", "shifted_matrix",
    "shifted_factor", "shifted_factor_matrices", "ShiftedProduct", "shifted_cg_bound", "shifted_solver",
    "SHIFTED_METHODS", "HeldByProduct", "HELD_CG_MAXITER", "ShiftedPCG", "ShiftedPCGFamily", "SHIFTED_PCG_MAXITER",
    "held_row_share", "one_ring_factor", "one_ring_solve", "ShiftedInverse", "LanczosQuadrature", "column_function",
    "lanczos_shifted", "LanczosRows", "LANCZOS_SHIFTED_MAX_STEPS", "FILTER_LANCZOS_TOL", "DRAFT_LANCZOS_TOL",
    "CompiledLanczos", "LanczosDots",
]

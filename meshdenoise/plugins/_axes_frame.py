"""``sobolev_axes``' settings and its frame, which its filter and its rule share.

:class:`AxesConfig` holds the sizes that choose the filter's and its rule's paths (``plugins/sobolev_axes.py`` and
``plugins/sobolev_axes_rule.py`` read them); :func:`normal_frame` gives the principal axes of the vertex normals that
both weigh the coordinates along."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry import vertex_normals
from ..operators import Operators
from ..solvers import LANCZOS_SHIFTED_MAX_STEPS
from ..tuning.config import check_fields

__all__ = ["AxesConfig", "DEFAULT", "normal_frame"]


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

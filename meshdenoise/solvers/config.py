"""The solvers' settings: the sizes and bounds that choose a back end or a path, in one frozen object.

A caller (a test, a benchmark) that wants another choice hands a :class:`SolverConfig` to the solver that reads it
(``SPDSolver(A, config=...)``, ``shifted_solver(..., config=...)``, ``CompiledLanczos(..., config=...)``); ``None``
is :data:`DEFAULT`, the measured values below.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["CHOLMOD", "SolverConfig", "DEFAULT", "resolve"]


def _cholmod_installed() -> bool:
    try:
        import sksparse.cholmod  # noqa: F401
    except ImportError:
        return False
    return True


CHOLMOD = _cholmod_installed()  # scikit-sparse (the "cholmod" extra) is installed: SolverConfig.cholmod's default


@dataclass(frozen=True)
class SolverConfig:
    """Which factorisation back end and which solver path, by size: the values, and where they were measured.

    Attributes
    ----------
    cholmod : bool
        Factorise by CHOLMOD (scikit-sparse, the ``cholmod`` extra; ``make`` installs it) with one symbolic analysis
        reused per sparsity pattern (:func:`~meshdenoise.solvers.factor._cholmod_factor`); default: whether it is
        installed (:data:`CHOLMOD`). ``False``: cholespy for every system, a plain pip install's path.
    cholmod_max_rows : int
        CHOLMOD factorises systems up to this many rows, cholespy larger ones: at 400k rows cholespy's factor is the
        faster (3.4 against 4.4 s), at 1.6M too (``benchmarks/factor_backend.py``, docs/benchmarks.md).
    cholmod_metis_max_rows : int
        METIS orders the patterns of up to this many rows, CHOLMOD's default (AMD, METIS tried when AMD fills much)
        larger ones: above, METIS's analysis costs more than it saves (face000's 85,182 vertices: 0.27 s for a
        one-ring matrix whose numeric factor takes 0.12 s; ``benchmarks/factor_backend.py``).
    symbolic_max : int
        Symbolic analyses kept (sparsity patterns), least recently used out when one more is stored
        (:func:`~meshdenoise.solvers.factor.clear_symbolic` drops them all).
    held_by_product_min_vertices : int
        :func:`~meshdenoise.solvers.shifted.shifted_solver` solves held rows with ``p >= 3`` by
        :class:`~meshdenoise.solvers.shifted.HeldByProduct` (CG preconditioned by the free product's factors) from
        this many vertices, instead of a factor of the whole :math:`I + \\mu L^p` with them (Bunny0.2's 223 border
        vertices, mu 0.107, p 3: 22 iterations, sobolev_gls' border run 2.1 -> 1.1 s) ...
    held_by_product_max_held : int
        ... while at most this many rows are held: the steps grow with their count (face000's 4,111 border vertices:
        308 steps at mu 24.5, over 400 at 103, 9-11 s against a 3 s factor).
    regenerate_ring_bytes : int
        :meth:`CompiledLanczos.apply_many <meshdenoise.solvers.compiled_lanczos.CompiledLanczos.apply_many>`: the ring
        of basis vectors whose accumulation into several functions' results is done at once holds at most this many
        bytes (below three vectors, one accumulation per step; the bunny scanner's ten candidates of
        ``sobolev_normal``: 1.29 s).

    Examples
    --------
    >>> SolverConfig(cholmod=False).cholmod_max_rows
    200000
    >>> resolve(None) is DEFAULT
    True
    """

    cholmod: bool = CHOLMOD
    cholmod_max_rows: int = 200_000
    cholmod_metis_max_rows: int = 50_000
    symbolic_max: int = 16
    held_by_product_min_vertices: int = 20_000
    held_by_product_max_held: int = 1_000
    regenerate_ring_bytes: int = 128 * 2**20


DEFAULT = SolverConfig()


def resolve(config: SolverConfig | None) -> SolverConfig:
    """``config``, or :data:`DEFAULT` when ``None``."""
    if config is None:
        return DEFAULT
    if not isinstance(config, SolverConfig):
        raise TypeError(f"config must be a SolverConfig or None, got {type(config).__name__}")
    return config

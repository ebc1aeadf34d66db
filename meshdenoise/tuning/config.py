"""The tuning machinery's settings: the sizes, bounds and budgets that choose a path, in frozen objects.

A caller (a test, a benchmark) that wants another choice hands one in: to the function that reads it
(``best_shifted(..., config=SearchConfig(...))``, ``SpectralSearch(..., config=...)``,
``noise_kernels.vertex_normals(V, F, config=...)``) or, for a filter's automatic rule, to
``choose_parameters(..., config=...)``, whose rules read theirs from the context
(:meth:`~meshdenoise.tuning.context.TuningContext.config_for`). ``None`` is the module's ``DEFAULT``, the
measured values below. The filters' own settings live with each filter (``plugins/<name>.py``).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import TypeVar

from .memo import MEMO_BYTES

__all__ = ["SearchConfig", "SpectralConfig", "NoiseKernelConfig", "check_fields", "resolve", "SEARCH", "SPECTRAL",
           "NOISE_KERNELS"]

T = TypeVar("T")


def resolve(config: T | None, default: T) -> T:
    """``config``, or ``default`` when ``None``; a TypeError when it is not of ``default``'s type.

    Examples
    --------
    >>> resolve(None, SEARCH) is SEARCH
    True
    """
    if config is None:
        return default
    if type(config) is not type(default):
        raise TypeError(f"config must be a {type(default).__name__} or None, got {type(config).__name__}")
    return config


def check_fields(config: object, positive: tuple = (), nonnegative: tuple = ()) -> None:
    """Raise a ValueError naming the first field of ``config`` that is not a number in its range.

    ``positive`` fields must be > 0, ``nonnegative`` ones >= 0, every other field a number (not a bool, not NaN).
    """
    name_of = type(config).__name__
    for f in fields(config):
        value = getattr(config, f.name)
        ok = isinstance(value, (int, float)) and not isinstance(value, bool) and value == value
        if ok and f.name in positive:
            ok = value > 0
        elif ok and f.name in nonnegative:
            ok = value >= 0
        if not ok:
            need = " > 0" if f.name in positive else " >= 0" if f.name in nonnegative else ""
            raise ValueError(f"{name_of}: {f.name} must be a number{need}, got {value!r}")


@dataclass(frozen=True)
class SearchConfig:
    """The searches' paths by size (:mod:`meshdenoise.tuning.search`): the values, and where they were measured.

    Attributes
    ----------
    coordinates_cg_bound : float
        :func:`~meshdenoise.tuning.search.best_shifted`: the best point's coordinates by CG while its iteration bound
        is at most this, else by the second pass of the search's own Lanczos run (the elephant's ``sobolev_axes``,
        order 2, mu = 129: bound 2,429, CG 1.36 s).
    quadrature_min_vertices : int
        ``best_shifted(search="auto")`` and ``sobolev_axes``' rule: Lanczos quadrature from this size (above the
        exact-trace meshes), one factor per mu below; the two choose the same mu (scores equal to 1e-12 relative,
        docs/scale.md).
    shared_run_max_bytes : int
        :func:`~meshdenoise.tuning.search.shifted_quadrature`: its run is kept in the tuning memo up to this size
        (its columns, two basis vectors: 16 MB on the elephant, 27 columns); above, a scan's whole-mesh run would sit
        in the memo for nothing (face000's ``sobolev_gls`` searches its pilot on a region: with a bound of 64 MB its
        peak memory 564 -> 604 MB).
    curve_kernel_min_vertices : int
        :class:`~meshdenoise.tuning.search.PathCurve` records its terms by ``kernels.curve_terms`` from this size
        (at 1.6M vertices numpy's record was 18 ms a step).
    region_min_vertices : int
        :func:`~meshdenoise.tuning.search.region_rule`: from this size a rule runs on a sampled region (every
        quality-table mesh is below it, so their choices are the whole mesh's).

    Examples
    --------
    >>> SearchConfig(region_min_vertices=1000).coordinates_cg_bound
    600
    >>> SearchConfig(region_min_vertices=-1)
    Traceback (most recent call last):
    ...
    ValueError: SearchConfig: region_min_vertices must be a number >= 0, got -1
    """

    coordinates_cg_bound: float = 600
    quadrature_min_vertices: int = 1_000
    shared_run_max_bytes: int = MEMO_BYTES // 8
    curve_kernel_min_vertices: int = 1 << 16
    region_min_vertices: int = 50_000

    def __post_init__(self) -> None:
        check_fields(self, nonnegative=tuple(f.name for f in fields(self)))


@dataclass(frozen=True)
class SpectralConfig:
    """The Lanczos runs that score a filter's candidates (:mod:`meshdenoise.tuning.spectral`).

    Attributes
    ----------
    tol : float
        Relative change over 10 Lanczos steps (of an estimate's Cauchy-Schwarz scale) at which a search's estimates
        are taken: its scores to about 1e-6 (tests/test_spectral.py: within 1e-5 of the filter runs'), where the
        probes' own Monte-Carlo spread is 1/sqrt(P) and the best candidate's nearer-scoring neighbour (26 % apart)
        scored 1.3e-4 to 9e-2 above it, median 6e-3, over the normals searches of the 8 benchmark rows x 5 filters;
        a tolerance of 1e-10 chose the same on all 88 cells (benchmarks/results/filter-time.md) with more steps.
    max_steps : int
        A run longer than this gives up (:class:`~meshdenoise.tuning.spectral.SpectralFailed`): the caller runs the
        filter instead.
    min_vertices : int
        Searches score by these Lanczos runs from this size (with Rademacher probes; the exact traces of small meshes
        are 3n columns, and a few solves of a small factor cost less).
    basis_bytes : int
        The coordinates' run keeps its basis up to this many bytes (``CompiledLanczos`` ``keep_basis``), every
        candidate's coordinates then summed from it instead of a second pass of sparse products: the elephant's
        normals searches (24,955 vertices, 3 columns, 233 and 291 steps: 140 and 175 MB); a longer run regenerates.

    Examples
    --------
    >>> SpectralConfig(tol=1e-10).max_steps
    2000
    """

    tol: float = 1e-6
    max_steps: int = 2000
    min_vertices: int = 2_000
    basis_bytes: int = 192 * 2**20

    def __post_init__(self) -> None:
        check_fields(self, positive=("tol", "max_steps"), nonnegative=("min_vertices", "basis_bytes"))


@dataclass(frozen=True)
class NoiseKernelConfig:
    """When the noise estimate's compiled kernels run (:mod:`meshdenoise.tuning.noise_kernels`).

    Attributes
    ----------
    min_vertices : int
        Below this many vertices the numpy/scipy code runs (the same numbers): loading the compiled code costs about
        0.2 s once per process, more than the kernels save on a small mesh (the vertex normals at 1.6M: 0.7 -> 0.1 s).

    Examples
    --------
    >>> NoiseKernelConfig(min_vertices=0).min_vertices
    0
    """

    min_vertices: int = 1 << 16

    def __post_init__(self) -> None:
        check_fields(self, nonnegative=("min_vertices",))


SEARCH = SearchConfig()
SPECTRAL = SpectralConfig()
NOISE_KERNELS = NoiseKernelConfig()

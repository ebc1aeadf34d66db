"""Which search each filter gets: a dedicated strategy, else a one-parameter grid, else none."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..registry import REGISTRY, list_filters
from .batch import NoisyBatch
from .filtering_search import search_filtering
from .grid_search import GRIDS, search_grid
from .heat_search import search_heat
from .paper import MU_GRID
from .result import SearchResult
from .sobolev_search import search_sobolev

__all__ = ["STRATEGIES", "PAPER_METHODS", "available_methods", "run_search", "Strategy"]

# A strategy receives every noise level of one mesh (they share the topology, so a factorisation
# can serve all of them), an ``advance(fraction)`` callback for the progress bar and ``quick``
# (a coarser grid where the search is costly).
Strategy = Callable[[list[NoisyBatch], Callable[[float], None], bool], list[SearchResult]]


def _per_batch(search: Callable[[NoisyBatch], SearchResult]) -> Strategy:
    def strategy(batches: list[NoisyBatch], advance: Callable[[float], None], quick: bool = False) -> list[SearchResult]:
        results = []
        for b in batches:
            results.append(search(b))
            advance(1.0)
        return results

    return strategy


def _sobolev(batches: list[NoisyBatch], advance: Callable[[float], None], quick: bool = False) -> list[SearchResult]:
    steps = []
    mus = np.concatenate([[0.0], MU_GRID[1::2]]) if quick else MU_GRID  # quick: 3 per decade, same ends
    results = search_sobolev(batches, mus, advance=lambda f: (advance(f * len(batches)), steps.append(f)))
    if not steps:  # the exact spectral path has no per-mu loop
        advance(float(len(batches)))
    return results


STRATEGIES: dict[str, Strategy] = {
    "filtering": _per_batch(search_filtering),
    "heat": _per_batch(search_heat),
    "sobolev": _sobolev,
}

PAPER_METHODS = ("filtering", "heat", "sobolev")


def available_methods() -> list[str]:
    """The paper's three methods, then every registered filter that has a :data:`GRIDS` entry.

    Examples
    --------
    >>> available_methods()[:3]
    ['filtering', 'heat', 'sobolev']"""
    list_filters()  # loads the plugins
    return list(PAPER_METHODS) + [name for name in GRIDS if name in REGISTRY and name not in PAPER_METHODS]


def run_search(
    name: str, batches: list[NoisyBatch], advance: Callable[[float], None] = lambda f: None, quick: bool = False
) -> list[SearchResult]:
    """Search the best parameter of filter ``name`` on every noise level of one mesh.

    Examples
    --------
    >>> from meshdenoise.reproduce.batch import make_batch
    >>> from meshdenoise.shapes import icosphere
    >>> V, F = icosphere(1)
    >>> batches = [make_batch("sphere", V, F, rho, (0,)) for rho in (0.01, 0.1)]
    >>> [(r.method, r.rho) for r in run_search("sobolev", batches)]
    [('sobolev', 0.01), ('sobolev', 0.1)]"""
    if name in STRATEGIES:
        return STRATEGIES[name](batches, advance, quick)
    if name in GRIDS:
        if name not in REGISTRY:
            raise ValueError(f"reproduce: filter '{name}' has a grid but is not registered in this installation")
        out = []
        for b in batches:
            out.append(search_grid(b, name, GRIDS[name], advance))
        return out
    raise ValueError(
        f"reproduce: no search for method '{name}'; searchable: {', '.join(available_methods())} "
        "(add a GridSpec to meshdenoise.reproduce.grid_search.GRIDS for another registered filter)"
    )

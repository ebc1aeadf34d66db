"""Reproduce the paper's tables and figures with parameter searches (``meshdenoise reproduce``).

A search strategy exists per filter name (:data:`STRATEGIES`: filtering, heat, sobolev);
any other registered filter with an entry in :data:`GRIDS` is searched over one declared
parameter, so a new filter joins the tables by adding one :class:`GridSpec`.
"""

from .batch import NoisyBatch, make_batch
from .grid_search import GRIDS, GridSpec, search_grid
from .paper import MESHES, MU_GRID, PAPER_MS, PAPER_SNR, TAU_GRID
from .result import SearchResult
from .runner import run_reproduction
from .strategies import STRATEGIES, available_methods, run_search

__all__ = [
    "run_reproduction", "run_search", "available_methods", "STRATEGIES", "GRIDS", "GridSpec", "search_grid",
    "SearchResult", "NoisyBatch", "make_batch", "MESHES", "PAPER_SNR", "PAPER_MS", "TAU_GRID", "MU_GRID",
]

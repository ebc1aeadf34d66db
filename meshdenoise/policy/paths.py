"""One run of a candidate family, state after state: the k-th state is the filter with its count at k."""

from __future__ import annotations

from typing import Callable, Iterator

import numpy as np

from ..operators import Operators, spmm
from .config import Family

__all__ = ["family_path"]


def family_path(family: Family, F: np.ndarray, ops: Operators, steps: int) -> Callable[[np.ndarray], Iterator[np.ndarray]]:
    """``path(Y)``: the family's positions after steps 1 .. ``steps`` of one run from ``Y`` (n, 3).

    ``two_stage`` and uniform ``taubin`` runs are read as they go (one run for every count); any
    other registered filter is called once per count.
    """
    p = dict(family.fixed)
    if family.method == "two_stage" and family.count == "iterations":
        from ..plugins.two_stage import outer_iterates

        def path(Y: np.ndarray) -> Iterator[np.ndarray]:
            yield from outer_iterates(Y, ops, None, steps, p["normal_iterations"], p["vertex_iterations"], p["sigma_r"],
                                      p["sigma_s"], p["guidance"], p["keep_tangential"], every=True,
                                      relax_tangential=p.get("relax_tangential", False))
        return path
    if family.method == "taubin" and family.count == "iterations" and p.get("weights") == "uniform":
        from ..plugins.taubin import pass_matrix

        passes = [pass_matrix(ops.P, f) for f in (p["lam"], p["mu"])]

        def path(Y: np.ndarray) -> Iterator[np.ndarray]:
            X, T = np.array(Y, dtype=np.float64), np.empty_like(Y, dtype=np.float64)
            for _ in range(steps):
                for M in passes:
                    spmm(M, X, out=T)
                    X, T = T, X
                yield X.copy()  # a new array: a caller may keep the states
        return path

    from ..registry import get_filter

    spec = get_filter(family.method)

    def path(Y: np.ndarray) -> Iterator[np.ndarray]:
        for k in range(1, steps + 1):
            yield spec.public((Y, F), **family.params(k), operators=ops)[0]
    return path

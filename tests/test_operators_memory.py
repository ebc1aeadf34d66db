"""Operators drop their matrices to free memory and build the same ones again."""

from __future__ import annotations

import numpy as np
import pytest

import meshdenoise as md
from meshdenoise.geometry import vertex_normals
from meshdenoise.operators import get_operators
from meshdenoise.registry import get_filter
from meshdenoise.shapes import box, grid, icosphere
from meshdenoise.tuning.covariance import NoiseModel


def test_drop_matrices_frees_them_and_they_come_back_the_same():
    V, F = box(5)
    ops = get_operators(F, len(V))
    W, P, L, edges = ops.W.copy(), ops.P.copy(), ops.L.copy(), ops.edges.copy()
    Pp = ops.permuted(ops.P, "P").copy()
    held = W.data.nbytes + P.data.nbytes + L.data.nbytes + edges.nbytes  # at least the values
    freed = ops.drop_matrices()
    assert freed >= held
    assert not {"W", "P", "L", "_undirected_edges"} & set(vars(ops))
    assert not [k for k in ops.cache if isinstance(k, tuple) and k[0] == "permuted"]
    assert ops.drop_matrices() == 0  # nothing left to drop
    for old, new in ((W, ops.W), (P, ops.P), (L, ops.L), (Pp, ops.permuted(ops.P, "P"))):
        assert (old != new).nnz == 0 and old.shape == new.shape
    np.testing.assert_array_equal(edges, ops.edges)



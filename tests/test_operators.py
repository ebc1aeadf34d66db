"""W, D, D^-1 W, L and the cache, against loops written for the test and dense linear algebra."""

import numpy as np
import pytest

from meshdenoise.operators import Operators, clear_cache, get_operators
from meshdenoise.shapes import grid, icosphere, torus


def adjacency_by_loop(F, n):
    """The slow reference: a Python loop over faces, collecting each undirected edge once."""
    W = np.zeros((n, n))
    for f in F:
        for a, b in ((f[0], f[1]), (f[1], f[2]), (f[2], f[0])):
            if a != b:
                W[a, b] = W[b, a] = 1.0
    return W


@pytest.mark.parametrize("mesh", [icosphere(1), grid(5, 4), torus(7, 5)], ids=["sphere", "plane", "torus"])
def test_operators_match_loop(mesh):
    V, F = mesh
    n = len(V)
    ops = Operators(F, n)
    W = adjacency_by_loop(F, n)
    np.testing.assert_array_equal(ops.W.toarray(), W)
    np.testing.assert_array_equal(ops.degree, W.sum(1))
    np.testing.assert_allclose(ops.P.toarray(), W / W.sum(1, keepdims=True), rtol=0, atol=1e-15)
    np.testing.assert_array_equal(ops.L.toarray(), np.diag(W.sum(1)) - W)
    assert ops.W.format == ops.P.format == ops.L.format == "csr"


def test_duplicate_degenerate_faces_and_isolated_vertices():
    V, F = grid(4, 4)
    n = len(V)
    extra = np.vstack([F, F[:3], [[0, 0, 5]], [[7, 7, 7]]])  # duplicates, a degenerate face, a point "face"
    ops = Operators(extra, n + 2)  # two unreferenced vertices at the end
    W = adjacency_by_loop(extra, n + 2)
    np.testing.assert_array_equal(ops.W.toarray(), W)
    assert ops.isolated[-2:].all() and ops.isolated.sum() == 2
    P = ops.P.toarray()
    np.testing.assert_array_equal(P[-2:, -2:], np.eye(2))  # isolated vertices map to themselves
    np.testing.assert_allclose(P.sum(1), 1.0)


def test_boundary_and_nonmanifold_edges():
    V, F = grid(4, 3)
    ops = Operators(F, len(V))
    assert len(ops.boundary_edges) == 2 * (3 + 2)  # perimeter of a 3 x 2 cell grid
    expected = np.zeros(len(V), bool)
    expected[[0, 1, 2, 3, 4, 7, 8, 9, 10, 11]] = True
    np.testing.assert_array_equal(ops.boundary_vertices, expected)
    fan = np.array([[0, 1, 2], [0, 1, 3], [0, 1, 4]])  # edge 0-1 in three faces
    assert Operators(fan, 5).nonmanifold_edges.tolist() == [[0, 1]]


def test_lambda_max_matches_dense_eigenvalues():
    V, F = icosphere(2)
    ops = Operators(F, len(V))
    dense = np.linalg.eigvals(np.eye(len(V)) - ops.P.toarray()).real.max()
    assert ops.lambda_max() == pytest.approx(dense, rel=1e-8)


def test_cache_returns_same_operators_for_same_faces():
    clear_cache()
    V, F = icosphere(2)
    a = get_operators(F, len(V))
    W = a.W
    b = get_operators(F.astype(np.int32).copy(), len(V))  # same content, another array and dtype
    assert b is a and b.W is W  # not rebuilt
    c = get_operators(F[::-1].copy(), len(V))
    assert c is not a


def test_fixed_rows_are_identity_rows():
    V, F = icosphere(1)
    ops = Operators(F, len(V))
    fixed = np.zeros(len(V), bool)
    fixed[[0, 5]] = True
    B = ops.with_pinned_rows(ops.P, fixed, "P").toarray()
    np.testing.assert_array_equal(B[fixed], np.eye(len(V))[fixed])
    np.testing.assert_array_equal(B[~fixed], ops.P.toarray()[~fixed])
    assert ops.with_pinned_rows(ops.P, fixed, "P") is ops.with_pinned_rows(ops.P, fixed.copy(), "P")


def test_operators_do_not_touch_the_callers_faces():
    V, F = icosphere(1)
    F = np.ascontiguousarray(F, dtype=np.int64)
    ops = Operators(F, len(V))
    assert F.flags.writeable and not np.shares_memory(ops.F, F)

"""The default's work outside its filter, reordered: the same bits as the whole-mesh computations it replaced.

The fold guard tests only the faces turned from their input and, after a move, the faces around the
moved vertices, reading neighbours from the faces instead of ``W`` and ``P``; the default hands the
filter the vertex order from the adjacency its choice built and drops the vertex matrices before the
run; ``two_stage`` takes faces already in locality order as they are and builds the guided filter's
lists only for the guided filter. Each is checked here against the computation it replaced, written
out, and the default's result on a small and a 100k-vertex mesh against the default run the old way.
"""

from __future__ import annotations

import importlib

import numpy as np
import pytest

import meshdenoise as md
from meshdenoise import kernels
from meshdenoise.geometry import face_normals, vertex_face_incidence
from meshdenoise.locality import Relabelling, relabelled_operators, relabelling
from meshdenoise.normal_filter import FaceNeighbourhood, two_stage_topology
from meshdenoise.operators import Operators, clear_cache, get_operators
from meshdenoise.folds import flipped_faces
from meshdenoise.policy import OTHER_FAMILIES
from meshdenoise.shapes import grid, icosphere, torus

folds_module = importlib.import_module("meshdenoise.folds")
run_module = importlib.import_module("meshdenoise.policy.run")


def _whole_mesh_turned_over(V, X, F, M):
    """The test of every face at once: ``M^T M N`` (the faces sharing a vertex, once per shared vertex)."""
    N = face_normals(X, F)
    around = M.T @ (M @ N) - 3.0 * N
    return (np.einsum("ij,ij->i", N, face_normals(V, F)) < 0) & (np.einsum("ij,ij->i", N, around) < 0)


def _whole_mesh_unfold(V, X, F, ops, rounds):
    """The unfolding rounds with products over the whole mesh (``W`` for the neighbours, ``P`` for their mean)."""
    X = np.array(X, dtype=np.float64)
    W = ops.W.tocsr()
    movable = np.any(X != V, axis=1) & (ops.degree > 0)
    movable[ops.boundary_vertices] = False
    M = vertex_face_incidence(F, len(V))
    for _ in range(rounds):
        folded = _whole_mesh_turned_over(V, X, F, M)
        if not folded.any():
            return X, 0
        near = np.zeros(len(X), dtype=bool)
        near[F[folded].ravel()] = True
        near |= W @ near.astype(np.float64) > 0
        idx = np.flatnonzero(near & movable)
        X[idx] = ops.P[idx] @ X
    return X, int(np.count_nonzero(_whole_mesh_turned_over(V, X, F, M)))


def _whole_mesh_guard(choice, V, F, ops, run, rounds=10):
    """:func:`meshdenoise.policy.choose.guard` with the whole-mesh fold test and unfolding."""
    X = run(choice.params)
    folds = int(np.count_nonzero(_whole_mesh_turned_over(V, X, F, vertex_face_incidence(F, len(V)))))
    if folds and rounds > 0:
        X, left = _whole_mesh_unfold(V, X, F, ops, rounds)
        choice.fallback = f"{folds} faces turned over by the filter, {folds - left} of them smoothed out"
        folds = left
    choice.flipped = folds
    h = choice.edge_length if choice.edge_length > 0 else 1.0
    move = np.linalg.norm(X - V, axis=1)
    along = np.einsum("ij,ij->i", X - V, md.geometry.vertex_normals(X, F))
    choice.noise = float(np.sqrt(np.mean(along ** 2)))
    choice.moved_rms = float(np.sqrt(np.mean(move ** 2))) / h
    choice.moved_max = float(move.max()) / h
    return X


@pytest.fixture(scope="module")
def wavy():
    """A 102,400-vertex height field with an open border, a little noise along z."""
    V, F = grid(320, 320, size=1.0)
    V = V.copy()
    V[:, 2] = 0.05 * np.sin(6 * V[:, 0]) * np.cos(5 * V[:, 1])
    V[:, 2] += 0.3 / 320 * np.random.default_rng(0).standard_normal(len(V))
    return V, F


@pytest.mark.parametrize("scale", [0.0, 0.3, 1.0, 3.0])
def test_the_fold_test_of_the_turned_faces_is_the_whole_mesh_test(wavy, scale):
    V, F = wavy
    X = V + scale / 320 * np.random.default_rng(1).standard_normal(V.shape)  # from none to many faces turned
    want = _whole_mesh_turned_over(V, X, F, vertex_face_incidence(F, len(V)))
    got = folds_module.turned_over(V, X, F)
    np.testing.assert_array_equal(got, want)
    assert flipped_faces(V, X, F) == int(want.sum())
    assert scale == 0.0 or want.any()


@pytest.mark.parametrize("scale, rounds", [(0.5, 1), (0.5, 10), (1.0, 3), (2.0, 10)])
def test_unfolding_moves_what_the_whole_mesh_rounds_move(wavy, scale, rounds):
    V, F = wavy
    ops = get_operators(F, len(V))
    X = V + scale / 320 * np.random.default_rng(2).standard_normal(V.shape)
    X[::7] = V[::7]  # vertices the filter left (pinned): not movable
    want, left = _whole_mesh_unfold(V, X, F, ops, rounds)
    got, got_left = folds_module.unfold(V, X, F, ops, rounds)
    assert got_left == left
    np.testing.assert_array_equal(got, want)
    assert not np.array_equal(got, X)  # something was unfolded
    border = ops.boundary_vertices
    np.testing.assert_array_equal(got[border], X[border])


def _shuffled_torus():
    """A 100,000-vertex noisy torus with its vertices in a random order (so the default relabels it)."""
    V, F = torus(400, 250)
    Vn, _ = md.add_normal_noise((V, F), 0.01, seed=3)  # about 1.1 mean edge lengths: the filter folds some faces
    perm = np.random.default_rng(4).permutation(len(V))
    inverse = np.empty_like(perm)
    inverse[perm] = np.arange(len(perm))
    return Vn[perm], inverse[F]


def _small_sphere():
    V, F = icosphere(4)
    return md.add_normal_noise((V, F), 0.02, seed=0)[0], F


# the run that leaves the tangential part as the fit leaves it (no longer a candidate of the default) folds faces
# on the torus: the guard's work is compared there
FOLDING = md.DefaultConfig(families=(OTHER_FAMILIES[1],))


@pytest.mark.parametrize("make", [_small_sphere, _shuffled_torus], ids=["small", "100k"])
def test_the_default_gives_the_bits_it_gave_with_its_work_done_over_the_whole_mesh(monkeypatch, make):
    V, F = make()
    config = FOLDING if len(V) > 50_000 else None
    clear_cache()
    (X, _), choice = md.denoise((V, F), return_params=True, config=config)
    with monkeypatch.context() as patch:  # the old way: a throwaway adjacency, W and P kept, whole-mesh folds
        patch.setattr(run_module, "relabelling", lambda F, n, ops=None: None)
        patch.setattr(Operators, "drop_matrices", lambda self: 0)
        patch.setattr(run_module, "guard", _whole_mesh_guard)
        clear_cache()
        (Y, _), old = md.denoise((V, F), return_params=True, config=config)
    clear_cache()
    assert (choice.method, choice.params, choice.flipped, choice.fallback) == (old.method, old.params, old.flipped,
                                                                               old.fallback)
    np.testing.assert_array_equal(X, Y)
    assert (choice.noise, choice.moved_rms, choice.moved_max) == (old.noise, old.moved_rms, old.moved_max)
    if len(V) > 50_000:
        assert choice.fallback  # the guard had folds to smooth out


def test_the_relabelling_from_given_operators_is_the_throwaway_adjacencys():
    V, F = _shuffled_torus()
    clear_cache()
    fresh = relabelling(F, len(V))
    clear_cache()
    ops = Operators(F, len(V))
    given = relabelling(F, len(V), ops)
    assert given is not fresh and relabelling(F.copy(), len(V)) is given  # kept for the filter's own call
    for a, b in ((given.order, fresh.order), (given.inverse, fresh.inverse), (given.faces, fresh.faces)):
        np.testing.assert_array_equal(a, b)
    with pytest.raises(ValueError, match="operators of"):
        clear_cache()
        relabelling(F, len(V), Operators(F[:-1], len(V)))
    clear_cache()


def test_the_relabelled_operators_carry_the_border_the_callers_operators_found(wavy):
    V, F = wavy
    perm = np.random.default_rng(7).permutation(len(V))
    inverse = np.empty_like(perm)
    inverse[perm] = np.arange(len(perm))
    F2 = inverse[F]  # vertex k of this mesh is vertex perm[k] of the grid
    clear_cache()
    ops = Operators(F2, len(V))
    r = relabelling(F2, len(V), ops)
    ops.boundary_vertices
    own = relabelled_operators(r, ops)
    assert own is get_operators(r.faces, len(V)) and "_undirected_edges" not in own.__dict__
    np.testing.assert_array_equal(own.boundary_vertices, Operators(r.faces, len(V)).boundary_vertices)
    clear_cache()


def test_relabelled_faces_are_sorted_by_their_least_corner_as_a_stable_argsort_sorts_them():
    rng = np.random.default_rng(5)
    F = rng.integers(0, 500, size=(3000, 3))
    order = rng.permutation(500)
    r = Relabelling.from_order(order, F)
    inverse = np.empty_like(order)
    inverse[order] = np.arange(500)
    G = inverse[F]
    np.testing.assert_array_equal(r.faces, G[np.argsort(G.min(axis=1), kind="stable")])


def test_two_stage_topology_takes_faces_in_locality_order_as_they_are():
    V, F = _shuffled_torus()
    r = relabelling(F, len(V))
    ops = Operators(r.faces, len(V))
    assert ops.in_locality_order
    topo = two_stage_topology(ops)
    # the general construction: vertices ranked by the order, faces sorted stably by their least corner
    rank = np.empty(len(V), dtype=np.int32)
    rank[ops.locality_order] = np.arange(len(V))
    G = rank[ops.F]
    face_order = np.argsort(G.min(axis=1), kind="stable")
    np.testing.assert_array_equal(face_order, np.arange(len(F)))
    np.testing.assert_array_equal(topo.F, G[face_order])
    np.testing.assert_array_equal(topo.face_order, face_order)
    corner_vertex = topo.F.ravel()
    np.testing.assert_array_equal(topo.corners, np.argsort(corner_vertex, kind="stable"))
    np.testing.assert_array_equal(topo.corner_ptr[1:], np.cumsum(np.bincount(corner_vertex, minlength=len(V))))
    clear_cache()


def test_the_guided_filters_lists_are_built_on_first_use_and_are_those_of_the_kernels():
    V, F = icosphere(3)
    perm = np.random.default_rng(6).permutation(len(F))
    nb = FaceNeighbourhood(F[perm], len(V), label=perm)  # row k is the caller's face perm[k]: pairs in the caller's order
    assert nb._edges is None and nb._patches is None
    small = nb.nbytes
    a, b = kernels.edge_side_pairs(F, len(V))
    back = np.argsort(perm)  # caller's face -> its row here
    np.testing.assert_array_equal(nb.edge_a, back[a])
    np.testing.assert_array_equal(nb.edge_b, back[b])
    ptr, edges = kernels.patch_edge_lists(nb.indptr, nb.indices, nb.edge_a, nb.edge_b)
    np.testing.assert_array_equal(nb.patch_ptr, ptr)
    np.testing.assert_array_equal(nb.patch_edge, edges)
    assert nb.nbytes > small
    Vn, _ = md.add_normal_noise((V, F), 0.02, seed=0)
    ops = get_operators(F, len(V))
    md.two_stage((Vn, F), iterations=2, guidance="bilateral", operators=ops)
    assert two_stage_topology(ops).nb._edges is None  # the bilateral filter reads none of them
    clear_cache()

"""The default (meshdenoise.policy) and its generic machinery (meshdenoise.tuning.holdout).

Independent computations: harmonic fills against a dense solve, the held-out loss against a loop
written out, each family's run state by state against the filter called with that count, flipped
faces against a loop over faces. Properties: the same surface numbered, oriented, rotated, moved or
scaled otherwise gives the same result (to 1e-6 of the motion); a noisy plane comes out flatter;
every mesh type.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import meshdenoise as md
from meshdenoise.geometry import face_normals
from meshdenoise.operators import get_operators
from meshdenoise.folds import flipped_faces
from meshdenoise.policy import FAMILIES, OTHER_FAMILIES, DefaultConfig, Family, HoldoutConfig, choose, guard
from meshdenoise.policy.choose import DefaultChoice, Score
from meshdenoise.policy.paths import family_path
from meshdenoise.registry import get_filter
from meshdenoise.shapes import box, grid, icosphere, torus
from meshdenoise.tuning.holdout import _keys, holdout, path_losses, region

FAST = DefaultConfig(holdout=HoldoutConfig(masks=2, patience=4), steps=12)


@pytest.fixture(scope="module")
def noisy_sphere():
    V, F = icosphere(3)
    Vn, _ = md.add_normal_noise((V, F), rho=0.03, seed=1)
    return V, Vn, F


# ----------------------------------------------------------------------------- holdout
@pytest.mark.parametrize("radius", [0, 1, 2])
def test_holes_are_rings_around_centres_that_neither_overlap_nor_touch(noisy_sphere, radius):
    _, Vn, F = noisy_sphere
    ops = get_operators(F, len(Vn))
    held = holdout(Vn, ops, radius, masks=2)
    W = ops.W.toarray() > 0
    hops = np.where(W, 1, 10 ** 6).astype(float)
    np.fill_diagonal(hops, 0)
    for k in range(len(Vn)):  # Floyd-Warshall: ring distances, independently of the code's ring growth
        hops = np.minimum(hops, hops[:, [k]] + hops[[k], :])
    for C, Y in zip(held.centres, held.filled):
        assert C.size > 0
        assert hops[np.ix_(C, C)][~np.eye(C.size, dtype=bool)].min() > 2 * radius + 1
        hole = (hops[C] <= radius).any(axis=0)
        assert np.array_equal(Y[~hole], Vn[~hole])
        assert not np.allclose(Y[hole], Vn[hole])
    assert len(set(held.centres[0]) & set(held.centres[1])) == 0


def test_a_hole_is_filled_with_the_harmonic_interpolation_of_its_surroundings(noisy_sphere):
    _, Vn, F = noisy_sphere
    ops = get_operators(F, len(Vn))
    held = holdout(Vn, ops, 1, masks=1)
    Y = held.filled[0]
    hole = np.any(Y != Vn, axis=1)
    L = ops.L.toarray()
    expected = np.linalg.solve(L[np.ix_(hole, hole)], -L[np.ix_(hole, ~hole)] @ Vn[~hole])  # dense
    np.testing.assert_allclose(Y[hole], expected, rtol=0, atol=1e-12)


def test_the_held_out_loss_is_the_mean_normal_disagreement_written_out(noisy_sphere):
    _, Vn, F = noisy_sphere
    ops = get_operators(F, len(Vn))
    held = holdout(Vn, ops, 1, masks=2)
    P = ops.P.toarray()

    def path(Y):
        X = Y.copy()
        while True:
            X = 0.5 * X + 0.5 * P @ X
            yield X

    got = path_losses(path, Vn, F, held, steps=5, patience=100)
    expected = np.zeros(5)
    scored = 0
    for C, Y in zip(held.centres, held.filled):
        faces = [f for f in range(len(F)) if set(F[f]) & set(C.tolist())]
        scored += len(faces)
        X = Y.copy()
        for k in range(5):
            X = 0.5 * X + 0.5 * P @ X
            for f in faces:
                a, b = face_normals(X, F[[f]])[0], face_normals(Vn, F[[f]])[0]
                expected[k] += 1.0 - a @ b
    np.testing.assert_allclose(got, expected / scored, rtol=1e-12)


def test_the_loss_falls_then_rises_along_a_smoothing_run(noisy_sphere):
    _, Vn, F = noisy_sphere
    ops = get_operators(F, len(Vn))
    held = holdout(Vn, ops, 1, masks=3)
    family = Family("taubin", (("lam", 0.5), ("mu", -0.53), ("weights", "uniform")))
    loss = path_losses(family_path(family, F, ops, 400), Vn, F, held, steps=400, patience=400)
    k = int(np.argmin(loss))
    assert 0 < k < 399 and loss[k] < loss[0] and loss[-1] > loss[k]


def test_a_small_mesh_gets_masks_until_enough_vertices_are_held_out(noisy_sphere):
    _, Vn, F = noisy_sphere
    ops = get_operators(F, len(Vn))
    few = holdout(Vn, ops, 1, masks=1)
    more = holdout(Vn, ops, 1, masks=1, centres=few.count + 1)
    assert len(few.centres) == 1 and len(more.centres) >= 2 and more.count > few.count
    capped = holdout(Vn, ops, 1, masks=1, centres=10 ** 9)
    assert len(capped.centres) <= 4  # at most 4 x masks
    np.testing.assert_array_equal(more.centres[0], few.centres[0])


def test_holdout_rejects_bad_arguments(noisy_sphere):
    _, Vn, F = noisy_sphere
    ops = get_operators(F, len(Vn))
    for radius, masks in ((-1, 1), (1.5, 1), (1, 0)):
        with pytest.raises(ValueError, match="radius|masks"):
            holdout(Vn, ops, radius, masks)
    with pytest.raises(ValueError, match="centres"):
        holdout(Vn, ops, 1, 1, centres=-1)


def test_a_region_is_its_mesh_when_small_and_balls_around_seeds_when_large():
    V, F = icosphere(4)
    ops = get_operators(F, len(V))
    whole = region(V, F, ops, size=len(V), patches=4, margin=2)
    assert whole.vertices.size == len(V) and whole.inner.all()
    part = region(V, F, ops, size=600, patches=4, margin=2)
    assert 600 <= part.vertices.size < len(V)
    np.testing.assert_array_equal(V[part.vertices][part.F], V[F[np.isin(F, part.vertices).all(axis=1)]])
    assert 0 < part.inner.sum() < part.vertices.size


def _region_by_whole_mesh_rings(V, F, ops, size, patches, margin):
    """region() as products over the whole mesh: seeds by a full sort, whole rings grown, the cut's margin grown from
    every vertex outside the part."""
    n = len(V)
    W = ops.W.tocsr()

    def grow(mask, rings):
        for _ in range(rings):
            mask = mask | (W @ mask.astype(np.float64) > 0)
        return mask

    key = np.where(ops.degree > 0, _keys(V, ops), np.inf)
    inside = np.zeros(n, dtype=bool)
    inside[np.argsort(key, kind="stable")[:patches]] = True
    while inside.sum() < size and grow(inside, 1).sum() > inside.sum():
        inside = grow(inside, 1)
    used = np.zeros(n, dtype=bool)
    used[F[inside[F].all(axis=1)].ravel()] = True
    return np.flatnonzero(used), ~grow(~used, margin)[used]


@pytest.mark.parametrize("size, patches, margin", [(500, 1, 0), (3000, 6, 1), (3000, 24, 6)])
def test_a_region_grown_from_its_frontier_is_the_whole_mesh_rings_one(size, patches, margin):
    V, F = torus(120, 60)
    V = V + 1e-3 * np.random.default_rng(0).standard_normal(V.shape)
    ops = get_operators(F, len(V))
    part = region(V, F, ops, size, patches, margin)
    vertices, inner = _region_by_whole_mesh_rings(V, F, ops, size, patches, margin)
    np.testing.assert_array_equal(part.vertices, vertices)
    np.testing.assert_array_equal(part.inner, inner)


# ----------------------------------------------------------------------------- candidates' runs
@pytest.mark.parametrize("family", FAMILIES + OTHER_FAMILIES, ids=lambda f: f.label)
def test_each_familys_run_is_the_filter_with_that_count(noisy_sphere, family):
    _, Vn, F = noisy_sphere
    ops = get_operators(F, len(Vn))
    states = list(family_path(family, F, ops, 4)(Vn))
    spec = get_filter(family.method)
    for k in (1, 4):
        expected = spec.public((Vn, F), **family.params(k), boundary_motion="free")[0]
        np.testing.assert_allclose(states[k - 1], expected, rtol=0, atol=1e-12)


# ----------------------------------------------------------------------------- config and records
@pytest.mark.parametrize("cls, field, value", [
    (HoldoutConfig, "radius", -1), (HoldoutConfig, "masks", 0), (HoldoutConfig, "centres", -5),
    (HoldoutConfig, "patience", True), (HoldoutConfig, "region_vertices", 0), (DefaultConfig, "steps", 1.5),
    (DefaultConfig, "unfold_rounds", -1), (DefaultConfig, "families", ()), (DefaultConfig, "holdout", {"masks": 2})])
def test_the_configs_refuse_bad_values(cls, field, value):
    with pytest.raises(ValueError, match=field):
        cls(**{field: value})


def test_the_configs_are_frozen():
    with pytest.raises(dataclasses.FrozenInstanceError):
        DefaultConfig().steps = 3
    with pytest.raises(dataclasses.FrozenInstanceError):
        HoldoutConfig().radius = 3


def test_flipped_faces_are_those_turned_from_their_input_and_their_neighbours_as_a_loop_counts(noisy_sphere):
    _, Vn, F = noisy_sphere
    ops = get_operators(F, len(Vn))
    X = Vn + 0.15 * np.random.default_rng(2).standard_normal(Vn.shape)  # turns some faces over
    N0, N = face_normals(Vn, F), face_normals(X, F)
    count = 0
    for f in range(len(F)):
        around = sum(N[g] * len(set(F[f]) & set(F[g])) for g in range(len(F)) if g != f and set(F[f]) & set(F[g]))
        count += (N[f] @ N0[f] < 0) and (N[f] @ around < 0)
    assert count > 0 and flipped_faces(Vn, X, F) == count
    assert flipped_faces(Vn, Vn, F) == 0  # the input has none of its own


def test_the_guard_smooths_out_a_fold_the_filter_made_and_says_so(noisy_sphere):
    _, Vn, F = noisy_sphere
    ops = get_operators(F, len(Vn))
    family = OTHER_FAMILIES[-1]  # Taubin
    choice = DefaultChoice(family.method, family.params(3), edge_length=1.0, noise=0.0,
                           scores=[Score(family, np.ones(3))])
    smooth = get_filter("taubin").public((Vn, F), **family.params(3))[0]
    v = F[0, 0]
    pushed = smooth.copy()
    pushed[v] = smooth[v] * 0.2  # a vertex pulled deep inside: its faces turn over
    assert flipped_faces(smooth, pushed, F) > 0

    X = guard(choice, smooth, F, ops, lambda params: pushed)
    assert choice.flipped == 0 and flipped_faces(smooth, X, F) == 0
    assert "turned over by the filter" in choice.fallback and "smoothed out" in choice.fallback
    moved = np.flatnonzero(np.any(X != pushed, axis=1))
    ring = np.flatnonzero(ops.W[v].toarray().ravel())
    assert v in moved and set(moved) <= set(ring) | {v} | set(np.flatnonzero((ops.W[ring].sum(axis=0) > 0).A1))


def test_the_guard_leaves_pinned_and_border_vertices_where_the_filter_put_them():
    V, F = grid(8, 8)
    ops = get_operators(F, len(V))
    X = V.copy()
    inner = 27  # an interior vertex of the 8 x 8 grid, pushed across its neighbours: a fold
    X[inner] = X[inner] + [0.3, 0.3, 0.0]
    X[0] += [0.0, 0.0, 0.01]  # a border vertex the filter moved
    choice = DefaultChoice("taubin", {"iterations": 1}, edge_length=1.0, noise=0.0)
    assert flipped_faces(V, X, F) > 0
    out = guard(choice, V, F, ops, lambda params: X)
    assert choice.fallback and not np.array_equal(out[inner], X[inner])
    assert np.array_equal(out[0], X[0])  # on the border
    unmoved = np.flatnonzero(np.all(X == V, axis=1))  # what the filter did not move (pinned, outside a region)
    assert np.array_equal(out[unmoved], V[unmoved])


# ----------------------------------------------------------------------------- the default
def _run(V, F, config=FAST):
    (X, _), choice = md.denoise((V, F), return_params=True, config=config)
    return X, choice


def test_the_default_smooths_a_noisy_sphere_and_says_so_in_three_lines(noisy_sphere):
    V, Vn, F = noisy_sphere
    X, choice = _run(Vn, F)
    assert md.normal_error_deg((V, F), X) < 0.6 * md.normal_error_deg((V, F), Vn)
    lines = choice.lines()
    assert len(lines) == 3 and "noise removed" in lines[0] and choice.method in lines[1] and "flipped" in lines[2]
    assert choice.moved_rms > 0 and choice.moved_max >= choice.moved_rms
    assert len(choice.explain()) == 1 + len(FAST.families)


def test_a_noisy_plane_comes_out_flatter():
    V, F = grid(20, 20)
    Vn = V + [0, 0, 0.01] * np.random.default_rng(3).standard_normal((len(V), 1))
    X, _ = _run(Vn, F, DefaultConfig())
    assert X[:, 2].std() < 0.3 * Vn[:, 2].std()


def _same(a, b, motion):
    assert np.max(np.abs(a - b)) <= 1e-6 * motion


@pytest.fixture(scope="module")
def reference():
    V, F = box(5)
    Vn, _ = md.add_normal_noise((V, F), rho=0.02, seed=4)
    X, choice = _run(Vn, F)
    return Vn, F, X, choice, float(np.max(np.abs(X - Vn)))


def _as(kind, V, F):
    """The mesh as ``kind`` and a reader of the default's result back to arrays."""
    if kind == "arrays":
        return (V, F), lambda out: out[0]
    if kind == "meshset":
        pymeshlab = pytest.importorskip("pymeshlab")
        ms = pymeshlab.MeshSet()
        ms.add_mesh(pymeshlab.Mesh(V, F.astype(np.int32)))
        return ms, lambda out: out.current_mesh().vertex_matrix()
    o3d = pytest.importorskip("open3d")
    tm = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(V), o3d.utility.Vector3iVector(F.astype(np.int32)))
    return tm, lambda out: np.asarray(out.vertices)


KINDS = ["arrays", "meshset", "open3d"]


@pytest.mark.parametrize("kind", KINDS)
def test_the_default_does_not_depend_on_the_vertex_order(reference, kind):
    Vn, F, X, choice, motion = reference
    perm = np.random.default_rng(0).permutation(len(Vn))
    inverse = np.argsort(perm)
    mesh, back = _as(kind, Vn[perm], inverse[F])
    out, cp = md.denoise(mesh, return_params=True, config=FAST)
    assert cp.params == choice.params
    _same(back(out)[inverse], X, motion)


@pytest.mark.parametrize("kind", KINDS)
def test_the_default_does_not_depend_on_the_faces_orientation(reference, kind):
    Vn, F, X, choice, motion = reference
    mesh, back = _as(kind, Vn, F[:, [0, 2, 1]])
    out, co = md.denoise(mesh, return_params=True, config=FAST)
    assert co.params == choice.params
    _same(back(out), X, motion)


def test_the_default_turns_and_moves_with_the_mesh(reference):
    Vn, F, X, choice, motion = reference
    R = Rotation.from_euler("xyz", [0.3, -1.1, 2.0]).as_matrix()
    t = np.array([5.0, -3.0, 2.0])
    Xr, cr = _run(Vn @ R.T + t, F)
    assert cr.params == choice.params
    _same(Xr, X @ R.T + t, motion)


@pytest.mark.parametrize("scale", [1e-150, 3.0, 1e150])
def test_the_default_scales_with_the_mesh(reference, scale):
    Vn, F, X, choice, motion = reference
    Xs, cs = _run(Vn * scale, F)
    assert cs.params == choice.params
    _same(Xs / scale, X, motion)
    assert np.isclose(cs.edge_length / scale, choice.edge_length, rtol=1e-12)


def test_the_default_on_every_mesh_type_gives_the_arrays_result(reference):
    pymeshlab = pytest.importorskip("pymeshlab")
    o3d = pytest.importorskip("open3d")
    Vn, F, X, _, _ = reference
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(Vn, F.astype(np.int32)))
    out = md.denoise(ms, config=FAST)
    np.testing.assert_allclose(out.current_mesh().vertex_matrix(), X, rtol=0, atol=1e-12)
    tm = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(Vn), o3d.utility.Vector3iVector(F.astype(np.int32)))
    out = md.denoise(tm, config=FAST)
    np.testing.assert_allclose(np.asarray(out.vertices), X, rtol=0, atol=1e-12)


def test_the_default_refuses_what_needs_a_method(reference):
    Vn, F, *_ = reference
    for kwargs in ({"criterion": "sure"}, {"noise": 0.1}, {"iterations": 3}):
        with pytest.raises(TypeError, match="method"):
            md.denoise((Vn, F), **kwargs)
    with pytest.raises(TypeError, match="config"):
        md.denoise((Vn, F), method="taubin", config=FAST)


def test_a_mesh_too_small_to_hold_anything_out_is_left_as_it_is_and_said_so():
    V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    X, choice = _run(V, F)
    assert np.array_equal(X, V) and choice.method == "none"
    assert "left as it is" in choice.lines()[1]


def test_choose_alone_runs_nothing_and_names_a_family(noisy_sphere):
    _, Vn, F = noisy_sphere
    choice = choose(Vn, F, get_operators(F, len(Vn)), FAST)
    assert any(s.family.method == choice.method and s.family.params(s.step) == choice.params for s in choice.scores)
    assert choice.centres > 0 and choice.scored_vertices == len(Vn)

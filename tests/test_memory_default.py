"""Memory work on the default (issue 17): the copy-free paths give the public adapter's results bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

import meshdenoise as md
from meshdenoise import default
from meshdenoise.geometry import vertex_normals
from meshdenoise.operators import get_operators
from meshdenoise.registry import get_filter
from meshdenoise.shapes import box, grid, icosphere
from meshdenoise.tuning.covariance import NoiseModel


@pytest.mark.parametrize("method, params", [
    ("two_stage", {"iterations": 2, "sigma_r": 0.3, "keep_tangential": True}),
    ("two_stage", {"iterations": 1, "guidance": "bilateral"}),
    ("sobolev_normal", {}),
    ("sobolev_bilaplacian", {}),
])
@pytest.mark.parametrize("size", [1.0, 3e3])  # 3e3: a scale-free filter works on V / 2^k (k != 0)
def test_core_run_is_the_public_adapter_bit_for_bit(method, params, size):
    V, F = box(4)
    Vn = size * md.add_normal_noise((V, F), 0.03, seed=2)[0]
    F32 = F.astype(np.int32)  # the public path takes any integer faces; ops.F is int64
    ops = get_operators(F32, len(Vn))
    spec = get_filter(method)
    if not params:  # the smooth priors' defaults need a mu: a small one
        params = {p.name: p.default for p in spec.params if p.default is not None}
    expected = np.asarray(spec.public((Vn, F32), operators=ops, **params)[0])
    got = default.core_run(spec, Vn, ops, spec.resolve(dict(params)))
    assert got.dtype == np.float64 and got.shape == Vn.shape
    np.testing.assert_array_equal(got, expected)
    assert not np.may_share_memory(got, Vn)


def test_feature_risk_output_is_the_public_filter_bit_for_bit_on_int32_faces():
    V, F = icosphere(3)
    Vn = md.add_normal_noise((V, F), 0.02, seed=3)[0]
    F32 = F.astype(np.int32)
    params = {"iterations": 2, "sigma_r": 0.35, "keep_tangential": True}
    risk, out = default.feature_risk(Vn, F32, params, NoiseModel(0.02), vertex_normals(V, F), probes=2, seed=1)
    np.testing.assert_array_equal(out, md.apply_filter("two_stage", (Vn, F32), **params)[0])
    assert np.isfinite(risk)


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


def test_choose_default_with_dropped_matrices_is_the_same_choice_and_result():
    # two candidates (two_stage and the smooth prior, above SMALL_MESH vertices): the matrices are dropped
    # before two_stage's risk runs; the choice must be what it is with them held (a fresh topology, same numbers)
    V, F = grid(46, 46)  # 2116 vertices > SMALL_MESH
    assert len(V) > default.SMALL_MESH
    Vn = md.add_normal_noise((V, F), 0.01, seed=4)[0]
    ops = get_operators(F, len(V))
    original = default.Operators.drop_matrices
    held = []  # whether the vertex matrices were held when two_stage's probes ran (the peak)
    runs = default.feature_runs
    try:
        default.feature_runs = lambda V, *a, **k: held.append("W" in vars(ops)) or runs(V, *a, **k)
        first = default.choose_default((Vn, F))
    finally:
        default.feature_runs = runs
    assert held == [False] or first.features.too_noisy  # dropped on this path (Taubin steps after may rebuild them)
    from meshdenoise.operators import clear_cache

    clear_cache()
    try:
        default.Operators.drop_matrices = lambda self: 0  # keep everything: the reference run
        second = default.choose_default((Vn, F))
    finally:
        default.Operators.drop_matrices = original
    assert (first.method, first.params, first.post_steps) == (second.method, second.params, second.post_steps)


def test_dihedral_angles_match_a_loop_over_edges_with_boundary_and_nonmanifold_edges():
    from meshdenoise.default import _dihedral_angles
    from meshdenoise.geometry import face_normals

    V, F = icosphere(1)
    rng = np.random.default_rng(5)
    V = V + 0.05 * rng.standard_normal(V.shape)
    F = np.vstack([F[1:], [[F[3, 0], F[3, 1], len(V)]]])  # a hole (boundary edges) and a fin on F[3]'s edge (3 sides)
    V = np.vstack([V, [[2.0, 0.0, 0.0]]])
    N = face_normals(V, F)
    sides: dict = {}
    for f, face in enumerate(F):
        for k in range(3):
            sides.setdefault(tuple(sorted((int(face[k]), int(face[(k + 1) % 3])))), []).append(f)
    expected = sorted(np.degrees(np.arccos(np.clip(N[fs[0]] @ N[fs[1]], -1, 1))) for fs in sides.values() if len(fs) == 2)
    got = _dihedral_angles(V, F, get_operators(F, len(V)))
    assert len(got) == len(expected) < len(sides)
    np.testing.assert_allclose(np.sort(got), expected, rtol=0, atol=1e-12)

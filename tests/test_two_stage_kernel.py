"""The compiled two-stage filter and Open3D-weight Taubin against the numpy code they replaced.

tests/reference_two_stage.py is the numpy ``two_stage`` as it was (vectorised over face
pairs, one sort per pass); the old Open3D-weight Taubin is written out below. The compiled
kernels must give the same coordinates to ~1e-12, on closed and open meshes, with sharp
edges, degenerate and non-manifold faces, pinned vertices, and in both guidance modes; and
``two_stage`` must not care about the mesh's scale.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from meshdenoise import add_normal_noise
from meshdenoise.geometry import face_areas, face_normals
from meshdenoise.operators import Operators, get_operators
from meshdenoise.normal_filter import (
    FaceNeighbourhood,
    bilateral_normals,
    face_neighbourhood,
    fit_vertices_to_normals,
    guidance_normals,
)
from meshdenoise.plugins.two_stage import two_stage
from meshdenoise.plugins.taubin import taubin
from meshdenoise.shapes import box, grid, icosphere

from . import reference_two_stage as ref


def rel(a, b):
    return np.linalg.norm(a - b) / np.linalg.norm(b)


def noisy(V, F, rho, seed=0):
    return add_normal_noise((V, F), rho, seed=seed)[0]


def awkward_mesh():
    """A noisy open grid plus a degenerate face, a duplicated face and a fin on an inner edge (non-manifold)."""
    V, F = grid(9, 8)
    V = noisy(V, F, 0.02, seed=5)
    n = len(V)
    a, b = F[20, 0], F[20, 1]
    V = np.vstack([V, V[a] + [0.0, 0.0, 0.3]])
    F = np.vstack([F, [[a, b, n]], [[F[3, 0], F[3, 0], F[3, 1]]], F[7:8]])
    return V, F


MESHES = {
    "sphere": lambda: (lambda V, F: (noisy(V, F, 0.03), F))(*icosphere(2)),
    "box": lambda: (lambda V, F: (noisy(V, F, 0.3 / 7, seed=3), F))(*box(8)),
    "awkward": awkward_mesh,
    "tied": lambda: (lambda V, F: (V * [1.0, 1.3, 0.8] + [3.0, 0.0, 0.0], F))(*icosphere(1)),  # exact patch ties
}


@pytest.fixture(params=sorted(MESHES))
def mesh(request):
    return MESHES[request.param]()


def test_relabelled_neighbourhood_is_the_same_in_the_callers_labels(mesh):
    V, F = mesh
    perm = np.random.default_rng(1).permutation(len(F))
    nb = FaceNeighbourhood(F[perm], len(V), label=perm)
    old = ref.FaceNeighbourhood(F, len(V))
    pairs = {(int(perm[f]), int(perm[g])) for f, g in zip(nb.rows, nb.cols)}
    assert pairs == set(zip(old.rows.tolist(), old.cols.tolist()))
    np.testing.assert_array_equal(perm[nb.edge_a], old.edge_a)  # same pairs, same order
    np.testing.assert_array_equal(perm[nb.edge_b], old.edge_b)
    got = {(int(perm[j]), int(e)) for j, e in zip(np.repeat(np.arange(nb.m), np.diff(nb.patch_ptr)), nb.patch_edge)}
    assert got == set(zip(old.patch.tolist(), old.patch_edge.tolist()))


def test_neighbourhood_is_the_pattern_of_the_face_incidence_product(mesh):
    V, F = mesh
    nb = face_neighbourhood(Operators(F, len(V)))
    old = ref.FaceNeighbourhood(F, len(V))
    np.testing.assert_array_equal(nb.rows, old.rows)
    np.testing.assert_array_equal(nb.cols, old.cols)
    np.testing.assert_array_equal(nb.starts, old.starts)
    np.testing.assert_array_equal(nb.edge_a, old.edge_a)
    np.testing.assert_array_equal(nb.edge_b, old.edge_b)
    got = np.repeat(np.arange(nb.m), np.diff(nb.patch_ptr)), nb.patch_edge
    np.testing.assert_array_equal(got[0], old.patch)
    np.testing.assert_array_equal(got[1], old.patch_edge)
    # and independently: g is in row f iff the faces share a vertex
    for f in (0, len(F) // 2, len(F) - 1):
        expected = [g for g in range(len(F)) if set(F[f]) & set(F[g])]
        assert list(nb.indices[nb.indptr[f] : nb.indptr[f + 1]]) == expected


@pytest.mark.parametrize("guided", [True, False])
def test_normal_filtering_matches_the_numpy_code(mesh, guided):
    V, F = mesh
    nb, old = face_neighbourhood(Operators(F, len(V))), ref.FaceNeighbourhood(F, len(V))
    N, A, C = face_normals(V, F), face_areas(V, F), V[F].mean(1)
    if guided:
        np.testing.assert_allclose(guidance_normals(N, A, nb), ref.guidance_normals(N, A, old), rtol=0, atol=1e-13)
    kw = dict(sigma_s=0.2, sigma_r=0.35, iterations=4, guided=guided)
    np.testing.assert_allclose(bilateral_normals(N, C, A, nb, **kw), ref.bilateral_normals(N, C, A, old, **kw), rtol=0, atol=1e-13)


def test_vertex_update_matches_the_numpy_code(mesh):
    V, F = mesh
    target = face_normals(V + 0.01, F)
    fixed = np.zeros(len(V), bool)
    fixed[::7] = True
    for mask in (None, fixed):
        got = fit_vertices_to_normals(V, F, target, 5, mask)
        np.testing.assert_allclose(got, ref.fit_vertices_to_normals(V, F, target, 5, mask), rtol=0, atol=1e-13)


@pytest.mark.parametrize(
    "params",
    [
        {},
        {"iterations": 2, "guidance": "bilateral", "sigma_r": 0.5, "sigma_s": 2.0},
        {"iterations": 1, "normal_iterations": 0, "vertex_iterations": 3},
        {"iterations": 2, "normal_iterations": 3, "vertex_iterations": 0},
        # several outer iterations on the run's shared buffers (normals swapped with the passes' output)
        {"iterations": 3, "normal_iterations": 4, "vertex_iterations": 5, "keep_tangential": True},
        {"iterations": 3, "normal_iterations": 3, "vertex_iterations": 4, "guidance": "bilateral", "keep_tangential": True},
    ],
)
def test_two_stage_matches_the_numpy_code(mesh, params):
    V, F = mesh
    got = two_stage((V, F), **params)[0]
    expected = ref.reference_two_stage(V, F, **params)
    assert np.abs(got - expected).max() <= 1e-12 * np.abs(V).max()
    if params.get("normal_iterations", 10) and params.get("vertex_iterations", 10):
        assert rel(got, V) > 1e-4  # it moved
    else:  # a mesh fitted to its own normals, or not fitted at all, stays
        assert rel(got, V) < 1e-12


def test_two_stage_with_pinned_vertices_matches_the_numpy_code():
    V, F = awkward_mesh()
    ops = get_operators(F, len(V))
    fixed = ops.boundary_vertices.copy()
    got = two_stage((V, F), pinned=fixed, iterations=2)[0]
    expected = ref.reference_two_stage(V, F, fixed=fixed, iterations=2)
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(got[fixed], V[fixed])


@pytest.mark.parametrize("factor", [1e80, 1e-80, 3.0e7, 2.0**-40])
def test_two_stage_is_scale_equivariant(factor):
    V, F = MESHES["box"]()
    base = two_stage((V, F), iterations=2)[0]
    with np.errstate(all="raise"):  # no overflow or underflow on the way
        scaled = two_stage((V * factor, F), iterations=2)[0] / factor
    assert np.abs(scaled - base).max() <= 1e-12 * np.abs(V).max()


def test_the_old_code_was_not_scale_equivariant():
    """Why the kernel normalises: the numpy code squares lengths and areas, which overflow at 1e80."""
    V, F = MESHES["box"]()
    base = ref.reference_two_stage(V, F, iterations=1)
    with np.errstate(all="ignore"):
        scaled = ref.reference_two_stage(V * 1e80, F, iterations=1) / 1e80
    assert not np.allclose(scaled, base, rtol=0, atol=1e-6)


def test_two_stage_on_an_empty_and_a_flat_mesh():
    V, F = grid(6, 5)
    np.testing.assert_allclose(two_stage((V, F))[0], V, atol=1e-15)
    Vn = noisy(V, F, 0.01)
    np.testing.assert_array_equal(two_stage((Vn, F), iterations=0)[0], Vn)


# --- Open3D-weight Taubin ---------------------------------------------------------------------
def old_open3d_taubin(V, F, iterations, lam, mu, fixed=None):
    """The numpy code before the compiled pass: inverse-distance operator rebuilt per pass, then A @ X."""
    ops = Operators(F, len(V))
    W = ops.W
    rows = np.repeat(np.arange(ops.n), np.diff(W.indptr))
    X = np.array(V, dtype=np.float64)
    for _ in range(iterations):
        for f in (lam, mu):
            w = 1.0 / (np.linalg.norm(X[rows] - X[W.indices], axis=1) + 1e-12)
            A = sp.csr_matrix((w, W.indices, W.indptr), shape=W.shape)
            s = np.asarray(A.sum(axis=1)).ravel()
            inv = np.zeros_like(s)
            np.divide(1.0, s, out=inv, where=s > 0)
            A = sp.csr_matrix(sp.diags(inv) @ A + sp.diags((s == 0).astype(np.float64)))
            AX = A @ X
            if fixed is not None:
                AX[fixed] = X[fixed]
            X = X + f * (AX - X)
    return X


def test_open3d_taubin_matches_the_numpy_code(mesh):
    V, F = mesh
    V = np.vstack([V, [[5.0, 5.0, 5.0]]])  # an isolated vertex stays
    got = taubin((V, F), iterations=6, lam=0.5, mu=-0.53, weights="open3d")[0]
    np.testing.assert_allclose(got, old_open3d_taubin(V, F, 6, 0.5, -0.53), rtol=0, atol=1e-13)
    assert np.array_equal(got[-1], V[-1])
    fixed = np.zeros(len(V), bool)
    fixed[::5] = True
    got = taubin((V, F), iterations=3, lam=0.33, mu=-0.34, weights="open3d", pinned=fixed)[0]
    np.testing.assert_allclose(got, old_open3d_taubin(V, F, 3, 0.33, -0.34, fixed), rtol=0, atol=1e-13)
    np.testing.assert_array_equal(got[fixed], V[fixed])


@pytest.mark.parametrize("dtype", [np.int32, np.int64])
def test_edge_side_pairs_are_the_stable_sorts(dtype):
    """kernels.edge_side_pairs against the stable argsort of the sides' keys; _csr_of_groups against argsort."""
    from meshdenoise import kernels

    rng = np.random.default_rng(2)
    n = 40
    F = rng.integers(0, n, size=(300, 3)).astype(dtype)  # many edges of 3+ sides, degenerate faces too
    a, b = F.ravel().astype(np.int64), F[:, [1, 2, 0]].ravel().astype(np.int64)
    key = np.minimum(a, b) * n + np.maximum(a, b)
    order = np.argsort(key, kind="stable")
    same = key[order][1:] == key[order][:-1]
    first, second = kernels.edge_side_pairs(F, n)
    np.testing.assert_array_equal(first, order[:-1][same] // 3)
    np.testing.assert_array_equal(second, order[1:][same] // 3)
    groups = F.ravel()
    ptr, members = kernels._csr_of_groups(groups, n + 5, np.int32)
    np.testing.assert_array_equal(members, np.argsort(groups, kind="stable"))
    np.testing.assert_array_equal(ptr, np.concatenate([[0], np.cumsum(np.bincount(groups, minlength=n + 5))]))


def test_the_guided_pass_exponential_is_within_one_ulp_of_numpys_and_zero_below_its_floor():
    from meshdenoise.kernels import EXP_FLOOR, exp_nonpositive

    rng = np.random.default_rng(0)
    x = -np.concatenate([rng.random(200_000) * 30, rng.random(20_000) * -EXP_FLOOR, np.logspace(-300, 2.8, 2_000),
                         [0.0, 5e-324, 1e-17, 0.5 * np.log(2), np.log(2), 699.99]])
    y = x.copy()
    exp_nonpositive(y, y.size)
    ref = np.exp(x)
    assert np.all(np.abs(y - ref) <= np.spacing(ref)), np.max(np.abs(y - ref) / np.spacing(ref))
    assert y[x == 0.0][0] == 1.0 and np.all(y[x.size - 6:x.size - 4] == 1.0)  # exp(-0) and exp(-5e-324) are 1 exactly
    below = np.array([EXP_FLOOR - 1e-9, -745.0, -1e300, -np.inf])
    exp_nonpositive(below, below.size)
    np.testing.assert_array_equal(below, 0.0)

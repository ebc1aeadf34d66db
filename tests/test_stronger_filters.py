"""Taubin, bi-Laplacian Sobolev, two-stage normal filtering and normal-direction filters,
against dense solves, loops written here and the real MeshLab / Open3D filters."""

import numpy as np
import pytest

import meshdenoise as md
from meshdenoise.operators import get_operators
from meshdenoise.plugins.sobolev_bilaplacian import sobolev_bilaplacian
from meshdenoise.plugins.taubin import taubin
from meshdenoise.shapes import grid

from .conftest import noisy_sphere


def dense_laplacian(F, n):
    W = np.zeros((n, n))
    for a, b in np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]):
        if a != b:
            W[a, b] = W[b, a] = 1
    return np.diag(W.sum(1)) - W, W


def noisy_grid(seed=0):
    V, F = grid(9, 7)
    rng = np.random.default_rng(seed)
    V = V + 0.02 * rng.standard_normal(V.shape)
    return V, F


def rel(a, b):
    return np.linalg.norm(a - b) / np.linalg.norm(b)


# --- higher-order Sobolev -----------------------------------------------------------------
def test_bilaplacian_matches_dense_solve():
    V, Vn, F = noisy_sphere(subdivisions=2)
    L, _ = dense_laplacian(F, len(V))
    for mu in (0.05, 1.0, 20.0):
        expected = np.linalg.solve(np.eye(len(V)) + mu * L @ L, Vn)
        np.testing.assert_allclose(sobolev_bilaplacian((Vn, F), mu=mu)[0], expected, rtol=0, atol=1e-10)
    np.testing.assert_array_equal(sobolev_bilaplacian((Vn, F), mu=0.0)[0], Vn)


def test_bilaplacian_with_pinned_vertices_solves_the_reduced_system():
    V, F = noisy_grid()
    n = len(V)
    L, _ = dense_laplacian(F, n)
    A = np.eye(n) + 2.0 * L @ L
    pinned = np.zeros(n, bool)
    pinned[get_operators(F, n).boundary_vertices] = True
    f, p = ~pinned, pinned
    expected = V.copy()
    expected[f] = np.linalg.solve(A[np.ix_(f, f)], V[f] - A[np.ix_(f, p)] @ V[p])
    Y, _ = sobolev_bilaplacian((V, F), mu=2.0, pinned=pinned)
    np.testing.assert_allclose(Y, expected, rtol=0, atol=1e-10)
    np.testing.assert_array_equal(Y[p], V[p])
    # the equations hold on the free rows
    np.testing.assert_allclose((A @ Y)[f], V[f], atol=1e-9)


def test_bilaplacian_keeps_a_plane_and_shrinks_less_than_first_order():
    V, F = grid(10, 10)
    Y, _ = sobolev_bilaplacian((V, F), mu=5.0)
    assert np.abs(Y[:, 2]).max() < 1e-12  # planar in, planar out
    V, Vn, F = noisy_sphere(rho=0.03, subdivisions=3)
    r2 = np.linalg.norm(sobolev_bilaplacian((Vn, F), mu=1.0)[0], axis=1).mean()
    r1 = np.linalg.norm(md.sobolev((Vn, F), mu=1.0)[0], axis=1).mean()
    assert abs(r2 - 1) < abs(r1 - 1)


# --- Taubin -----------------------------------------------------------------------------
def test_taubin_uniform_matches_a_dense_loop():
    V, Vn, F = noisy_sphere(subdivisions=2)
    L, W = dense_laplacian(F, len(V))
    P = W / W.sum(1, keepdims=True)
    X = Vn.copy()
    for _ in range(4):
        X = X + 0.6 * (P @ X - X)
        X = X - 0.64 * (P @ X - X)
    np.testing.assert_allclose(taubin((Vn, F), iterations=4, lam=0.6, mu=-0.64)[0], X, rtol=0, atol=1e-12)


@pytest.fixture(params=["closed", "open"])
def closed_or_open(request, nefertiti):
    if request.param == "open":
        return nefertiti
    V, Vn, F = noisy_sphere(rho=0.03, subdivisions=3)
    return Vn, F


@pytest.mark.parametrize("lam, mu, steps", [(0.5, -0.53, 10), (0.33, -0.34, 3)])
def test_taubin_open3d_matches_open3d(closed_or_open, lam, mu, steps):
    import open3d as o3d

    V, F = closed_or_open
    m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(V), o3d.utility.Vector3iVector(F.astype(np.int32)))
    expected = np.asarray(m.filter_smooth_taubin(steps, lambda_filter=lam, mu=mu).vertices)
    ours = taubin((V, F), iterations=steps, lam=lam, mu=mu, weights="open3d")[0]
    assert rel(ours, expected) < 1e-10
    assert rel(V, expected) > 1e-4


def test_taubin_does_not_shrink_like_plain_filtering():
    V, Vn, F = noisy_sphere(rho=0.03, subdivisions=3)
    r_t = np.linalg.norm(taubin((Vn, F), iterations=20)[0], axis=1).mean()
    r_f = np.linalg.norm(md.filtering((Vn, F), iterations=40)[0], axis=1).mean()
    assert abs(r_t - 1) < 0.2 * abs(r_f - 1)


def test_taubin_pinned_vertices_stay_and_bad_mu_is_refused():
    V, F = noisy_grid()
    ops = get_operators(F, len(V))
    for weights in ("uniform", "meshlab", "open3d"):
        Y, _ = taubin((V, F), weights=weights, pinned="boundary")
        np.testing.assert_array_equal(Y[ops.boundary_vertices], V[ops.boundary_vertices])
        assert rel(Y, V) > 1e-4
    with pytest.raises(ValueError, match=r"'mu' = 0.5 is out of range"):
        taubin((V, F), mu=0.5)


# --- two-stage normal filtering ---------------------------------------------------------------
from meshdenoise.geometry import face_areas, face_normals  # noqa: E402
from meshdenoise.normal_filter import (  # noqa: E402
    bilateral_normals,
    face_neighbourhood,
    fit_vertices_to_normals,
    guidance_normals,
)
from meshdenoise.plugins.two_stage import two_stage  # noqa: E402

from .conftest import data_mesh_path  # noqa: E402


def loop_neighbours(F):
    return [[g for g in range(len(F)) if set(F[f]) & set(F[g])] for f in range(len(F))]


def test_bilateral_normals_match_a_loop_over_faces():
    V, Vn, F = noisy_sphere(rho=0.05, subdivisions=1)
    ops = get_operators(F, len(V))
    N, A, C = face_normals(Vn, F), face_areas(Vn, F), Vn[F].mean(1)
    nbrs = loop_neighbours(F)
    expected = N.copy()
    for _ in range(2):
        new = np.zeros_like(expected)
        for f in range(len(F)):
            s = np.zeros(3)
            for g in nbrs[f]:
                ws = np.exp(-np.sum((C[f] - C[g]) ** 2) / (2 * 0.3**2))
                wr = np.exp(-np.sum((expected[f] - expected[g]) ** 2) / (2 * 0.4**2))
                s += A[g] * ws * wr * expected[g]
            new[f] = s / np.linalg.norm(s)
        expected = new
    ours = bilateral_normals(N, C, A, face_neighbourhood(ops), sigma_s=0.3, sigma_r=0.4, iterations=2, guided=False)
    np.testing.assert_allclose(ours, expected, atol=1e-12)


def test_guidance_normals_match_a_loop_over_patches():
    V, Vn, F = noisy_sphere(rho=0.05, subdivisions=1)
    N, A = face_normals(Vn, F), face_areas(Vn, F)
    nbrs = loop_neighbours(F)
    edge_pairs = [(a, b) for a in range(len(F)) for b in range(a + 1, len(F)) if len(set(F[a]) & set(F[b])) == 2]
    H, g = [], []
    for j in range(len(F)):
        P = nbrs[j]
        mean = sum(A[k] * N[k] for k in P)
        mean = mean / np.linalg.norm(mean)
        spread = max(np.linalg.norm(N[k] - mean) for k in P)
        phis = [np.linalg.norm(N[a] - N[b]) for a, b in edge_pairs if a in P and b in P]
        H.append(spread * max(phis) / (1e-9 + sum(phis)))
        g.append(mean)
    expected = np.array([g[min(nbrs[i], key=lambda j: (H[j], j))] for i in range(len(F))])
    ours = guidance_normals(N, A, face_neighbourhood(get_operators(F, len(V))))
    np.testing.assert_allclose(ours, expected, atol=1e-12)


def test_vertex_update_matches_a_loop():
    V, Vn, F = noisy_sphere(rho=0.05, subdivisions=1)
    target = face_normals(V, F)
    X = Vn.copy()
    for _ in range(3):
        C = X[F].mean(1)
        new = X.copy()
        for i in range(len(X)):
            faces = [f for f in range(len(F)) if i in F[f]]
            new[i] = X[i] + sum(target[f] * np.dot(target[f], C[f] - X[i]) for f in faces) / len(faces)
        X = new
    np.testing.assert_allclose(fit_vertices_to_normals(Vn, F, target, 3), X, atol=1e-12)


def test_two_stage_keeps_planes_and_pinned_vertices():
    V, F = grid(10, 8)
    Y, _ = two_stage((V, F))
    np.testing.assert_allclose(Y, V, atol=1e-12)  # a flat mesh is already a fixed point
    ops = get_operators(F, len(V))
    inner = ~ops.boundary_vertices
    Vn = V.copy()
    Vn[inner, 2] += 0.02 * np.random.default_rng(1).standard_normal(inner.sum())  # a flat, pinned frame
    for guidance in ("guided", "bilateral"):
        Y, _ = two_stage((Vn, F), pinned="boundary", guidance=guidance)
        np.testing.assert_array_equal(Y[~inner], V[~inner])
        assert Y[inner, 2].std() < 0.5 * Vn[inner, 2].std()


@pytest.mark.data
@pytest.mark.parametrize("name, noisy_deg, target_deg", [("Fandisk0.3", 28.4, 4.0), ("Block0.4", 33.7, 5.2)])
def test_two_stage_defaults_reach_the_feature_targets(name, noisy_deg, target_deg):
    """Issue 5's target: <= 4 degrees on Fandisk0.3; on Block0.4 under half of the best MeshLab/Open3D
    filter (10.46 degrees, MeshLab Taubin with oracle iterations; see benchmarks/features.py)."""
    from meshdenoise.io import load_arrays
    from meshdenoise.metrics import normal_error_deg

    Vn, F = load_arrays(data_mesh_path(f"benchmark/{name}/Noisy.obj"))
    V0, F0 = load_arrays(data_mesh_path(f"benchmark/{name}/Original.obj"))
    assert normal_error_deg((V0, F0), (Vn, F)) == pytest.approx(noisy_deg, abs=0.05)
    assert normal_error_deg((V0, F0), two_stage((Vn, F))) <= target_deg

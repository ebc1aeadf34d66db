"""Tests of meshdenoise.ot: Sinkhorn, barycenters, mesh heat kernels and the OT denoiser."""

from __future__ import annotations

import json
import time
import tracemalloc
import warnings
from pathlib import Path

import numpy as np
import ot as pot
import pytest
import scipy.sparse as sp

from meshdenoise import ot as mo



# --------------------------------------------------------------------------
# fixtures
# --------------------------------------------------------------------------
def icosphere(level):
    """Unit icosphere (12 * 4**level ... vertices) symmetric under x, y, z -> -x, -y, -z."""
    p = (1 + 5**0.5) / 2
    V = np.array(
        [[-1, p, 0], [1, p, 0], [-1, -p, 0], [1, -p, 0], [0, -1, p], [0, 1, p],
         [0, -1, -p], [0, 1, -p], [p, 0, -1], [p, 0, 1], [-p, 0, -1], [-p, 0, 1]], float)
    F = np.array(
        [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4],
         [11, 10, 2], [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8],
         [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]])
    V /= np.linalg.norm(V, axis=1, keepdims=True)
    for _ in range(level):
        verts = list(V)
        mid = {}

        def midpoint(i, j):
            key = (min(i, j), max(i, j))
            if key not in mid:
                x = verts[i] + verts[j]
                verts.append(x / np.linalg.norm(x))
                mid[key] = len(verts) - 1
            return mid[key]

        newF = []
        for a, b, c in F:
            ab, bc, ca = midpoint(a, b), midpoint(b, c), midpoint(c, a)
            newF += [[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]
        V, F = np.array(verts), np.array(newF)
    return V, F.astype(np.int64)


@pytest.fixture(scope="module")
def sphere3():
    return icosphere(3)  # 642 vertices


@pytest.fixture(scope="module")
def sphere4():
    return icosphere(4)  # 2562 vertices


def vertex_normals(V, F):
    fn = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    fn /= np.linalg.norm(fn, axis=1, keepdims=True)
    N = np.zeros_like(V)
    for k in range(3):
        np.add.at(N, F[:, k], fn)
    return N / np.linalg.norm(N, axis=1, keepdims=True)


def add_noise(V, F, rho, seed=0):
    rng = np.random.default_rng(seed)
    return V + rho * rng.standard_normal(len(V))[:, None] * vertex_normals(V, F)


def snr(X, Y):
    return -20 * np.log10(np.linalg.norm(X - Y) / np.linalg.norm(Y))


def problem(n=30, m=25, seed=0):
    rng = np.random.default_rng(seed)
    x, y = rng.random((n, 2)), rng.random((m, 2))
    a, b = rng.random(n) + 0.1, rng.random(m) + 0.1
    return a / a.sum(), b / b.sum(), pot.dist(x, y)


def hist1d(n=60):
    t = np.linspace(0, 1, n)
    A = np.stack([np.exp(-((t - 0.2) ** 2) / 0.003), np.exp(-((t - 0.7) ** 2) / 0.01), 0.1 + t], 1)
    return A / A.sum(0), (t[:, None] - t[None]) ** 2


def images():
    I = np.full((3, 30, 40), 1e-3)
    I[0, 3:10, 5:12] += 1
    I[1, 18:26, 25:35] += 1
    I[2] += np.exp(-((np.arange(30)[:, None] - 15) ** 2 + (np.arange(40)[None] - 20) ** 2) / 30)
    return I / I.sum((1, 2), keepdims=True)


W3 = np.array([0.2, 0.5, 0.3])


# --------------------------------------------------------------------------
# Sinkhorn
# --------------------------------------------------------------------------
@pytest.mark.parametrize("method", ["sinkhorn", "sinkhorn_log"])
@pytest.mark.parametrize("reg", [0.5, 0.05, 0.01])
def test_sinkhorn_matches_pot(method, reg):
    a, b, M = problem()
    P_ref = pot.sinkhorn(a, b, M, reg, method=method, stopThr=1e-13, numItermax=100000)
    P = mo.sinkhorn(a, b, M, reg, method=method, stopThr=1e-13, numItermax=100000)
    assert P.shape == (30, 25)
    np.testing.assert_allclose(P, P_ref, atol=1e-6, rtol=0)
    np.testing.assert_allclose(P.sum(1), a, atol=1e-10)
    np.testing.assert_allclose(P.sum(0), b, atol=1e-10)


def test_sinkhorn_pot_doc_example_and_uniform_default():
    P = mo.sinkhorn([0.5, 0.5], [0.5, 0.5], [[0.0, 1.0], [1.0, 0.0]], 1.0)
    np.testing.assert_allclose(P, [[0.36552929, 0.13447071], [0.13447071, 0.36552929]], atol=1e-8)
    np.testing.assert_allclose(mo.sinkhorn([], [], [[0.0, 1.0], [1.0, 0.0]], 1.0), P, atol=1e-12)


def test_sinkhorn_log_small_reg_where_scaling_breaks():
    a, b, M = problem()
    reg = 2e-3  # exp(-M/reg) underflows to 0 for many entries
    P = mo.sinkhorn(a, b, M, reg, method="sinkhorn_log", stopThr=1e-9, numItermax=20000)
    np.testing.assert_allclose(P.sum(1), a, atol=1e-8)
    np.testing.assert_allclose(P.sum(0), b, atol=1e-8)
    P_ref = pot.sinkhorn(a, b, M, reg, method="sinkhorn_log", stopThr=1e-9, numItermax=20000)
    np.testing.assert_allclose(P, P_ref, atol=1e-6)
    with pytest.warns(UserWarning, match="sinkhorn_log"):
        mo.sinkhorn(a, b, M, 1e-4, method="sinkhorn", numItermax=1000)


@pytest.mark.parametrize("method", ["sinkhorn", "sinkhorn_log"])
def test_sinkhorn_warns_at_iteration_cap(method):
    a, b, M = problem()
    with pytest.warns(UserWarning, match="numItermax=3.*increase numItermax or reg"):
        mo.sinkhorn(a, b, M, 0.01, method=method, numItermax=3, stopThr=0.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        mo.sinkhorn(a, b, M, 0.5, method=method, numItermax=10000, stopThr=1e-9)
        mo.sinkhorn(a, b, M, 0.01, method=method, numItermax=3, stopThr=0.0, warn=False)


def test_sinkhorn_log_dict():
    a, b, M = problem()
    P, log = mo.sinkhorn(a, b, M, 0.1, log=True)
    assert log["err"][-1] < 1e-9 and log["niter"] >= 1
    np.testing.assert_allclose(log["u"][:, None] * np.exp(-M / 0.1) * log["v"][None], P)


@pytest.mark.parametrize(
    "kwargs, exc, match",
    [
        (dict(reg=0.0), ValueError, "reg.*0.0"),
        (dict(reg=-1.0), ValueError, "reg.*-1.0"),
        (dict(reg=float("nan")), ValueError, "reg"),
        (dict(reg="1"), TypeError, "reg.*'1'"),
        (dict(reg=True), TypeError, "reg"),
        (dict(method="greenkhorn"), ValueError, "greenkhorn"),
        (dict(numItermax=0), ValueError, "numItermax.*0"),
        (dict(numItermax=2.5), TypeError, "numItermax.*2.5"),
        (dict(stopThr=-1e-3), ValueError, "stopThr"),
        (dict(a=[-0.5, 1.5]), ValueError, "negative"),
        (dict(a=[0.3, 0.3]), ValueError, "same total mass"),
        (dict(a=[0.2, 0.3, 0.5]), ValueError, r"shapes do not match"),
        (dict(M=[[0.0, np.inf], [1.0, 0.0]]), ValueError, "non-finite"),
        (dict(M=[0.0, 1.0]), ValueError, "dimension"),
    ],
)
def test_sinkhorn_bad_inputs(kwargs, exc, match):
    args = dict(a=[0.5, 0.5], b=[0.5, 0.5], M=[[0.0, 1.0], [1.0, 0.0]], reg=1.0)
    args.update(kwargs)
    with pytest.raises(exc, match=match):
        mo.sinkhorn(**args)


# --------------------------------------------------------------------------
# barycenters
# --------------------------------------------------------------------------
def test_barycenter_matches_pot_uniform_weights():
    A, M = hist1d()
    ref = pot.bregman.barycenter(A, M, 5e-3, stopThr=1e-14, numItermax=100000)
    p = mo.barycenter(A, M, 5e-3, stopThr=1e-14, numItermax=100000)
    np.testing.assert_allclose(p, ref, atol=1e-6, rtol=0)
    assert abs(p.sum() - 1) < 1e-8


def test_barycenter_matches_pot_weighted():
    # POT's scaling barycenter initialises u with an unweighted geometric mean, so for
    # non-uniform weights it converges elsewhere; its log-domain version is the reference.
    A, M = hist1d()
    ref = pot.bregman.barycenter(A, M, 5e-3, W3, method="sinkhorn_log", stopThr=1e-14, numItermax=100000)
    p = mo.barycenter(A, M, 5e-3, W3, stopThr=1e-14, numItermax=100000)
    np.testing.assert_allclose(p, ref, atol=1e-6, rtol=0)


def test_barycenter_one_hot_weight_and_warn():
    A, M = hist1d()
    # weights (1, 0, 0): the barycenter is the entropic "projection" of A[:, 0], with the
    # same mean as A[:, 0] for this symmetric kernel away from the borders
    t = np.linspace(0, 1, 60)
    p = mo.barycenter(A, M, 1e-3, [1.0, 0.0, 0.0], stopThr=1e-12, numItermax=100000)
    assert abs(p @ t - A[:, 0] @ t) < 1e-3
    with pytest.warns(UserWarning, match="numItermax=10"):
        mo.barycenter(A, M, 1e-3, numItermax=10, stopThr=0.0)


@pytest.mark.parametrize(
    "kwargs, exc, match",
    [
        (dict(weights=[0.5, 0.6, -0.1]), ValueError, "weights"),
        (dict(weights=[0.5, 0.5]), ValueError, r"weights must have shape \(3,\)"),
        (dict(weights=[0.5, 0.5, 0.5]), ValueError, "sum to 1"),
        (dict(reg=0), ValueError, "reg"),
        (dict(M=np.zeros((5, 5))), ValueError, r"M must have shape \(60, 60\)"),
    ],
)
def test_barycenter_bad_inputs(kwargs, exc, match):
    A, M = hist1d()
    args = dict(A=A, M=M, reg=1e-2)
    args.update(kwargs)
    with pytest.raises(exc, match=match):
        mo.barycenter(**args)


@pytest.mark.parametrize("method", ["sinkhorn", "sinkhorn_log"])
def test_convolutional_barycenter2d_matches_pot(method):
    I = images()
    ref = pot.bregman.convolutional_barycenter2d(I, 2e-2, method=method, stopThr=1e-13, numItermax=20000)
    p = mo.convolutional_barycenter2d(I, 2e-2, stopThr=1e-13, numItermax=20000)
    assert p.shape == (30, 40)
    np.testing.assert_allclose(p, ref, atol=1e-6, rtol=0)


@pytest.mark.parametrize("method", ["sinkhorn", "sinkhorn_log"])
def test_convolutional_barycenter2d_weighted_small_reg_matches_pot_log(method):
    # at reg=4e-3 POT's scaling version is off by its stabThr=1e-30 inside the log; its log one is the reference
    I = images()[:, ::2, ::2]  # 15 x 20 keeps the log-domain runs short
    I = I / I.sum((1, 2), keepdims=True)
    ref = pot.bregman.convolutional_barycenter2d(
        I, 4e-3, W3, method="sinkhorn_log", stopThr=1e-11, numItermax=20000
    )
    p = mo.convolutional_barycenter2d(I, 4e-3, W3, method=method, stopThr=1e-11, numItermax=20000)
    np.testing.assert_allclose(p, ref, atol=1e-6, rtol=0)


def test_convolutional_barycenter2d_log_domain_survives_tiny_reg():
    # reg=1e-3 on a 20 x 24 grid: the scalings under/overflow in the plain method; the log method works
    I = np.zeros((2, 20, 24))
    I[0, 3:6, 3:6] = 1
    I[1, 13:16, 17:20] = 1
    I /= I.sum((1, 2), keepdims=True)
    ref = pot.bregman.convolutional_barycenter2d(I, 1e-3, method="sinkhorn_log", stopThr=1e-10, numItermax=5000)
    p = mo.convolutional_barycenter2d(I, 1e-3, method="sinkhorn_log", stopThr=1e-10, numItermax=5000)
    assert np.all(np.isfinite(p))
    np.testing.assert_allclose(p, ref, atol=1e-6, rtol=0)
    with pytest.warns(UserWarning, match="overflow.*sinkhorn_log"):
        q = mo.convolutional_barycenter2d(I, 1e-3, method="sinkhorn", stopThr=1e-10, numItermax=5000)
    assert np.all(np.isfinite(q))
    with pytest.raises(ValueError, match="'sinkhorn_stabilized'"):
        mo.convolutional_barycenter2d(I, 1e-2, method="sinkhorn_stabilized")


def test_convolutional_barycenter_equals_dense_barycenter():
    # an operator kernel and the dense matrix it represents give the same barycenter
    A, M = hist1d(40)
    reg = 1e-2
    K = np.exp(-M / reg)
    p_dense = mo.barycenter(A, M, reg, W3, stopThr=1e-13, numItermax=100000)
    p_op = mo.convolutional_barycenter(A, lambda X: K @ X, W3, stopThr=1e-13, numItermax=100000)
    np.testing.assert_allclose(p_op, p_dense, atol=1e-10)


def test_convolutional_barycenter_bad_inputs():
    A, M = hist1d(10)
    with pytest.raises(TypeError, match="callable"):
        mo.convolutional_barycenter(A, np.eye(10))
    with pytest.raises(ValueError, match="area must be positive"):
        mo.convolutional_barycenter(A, lambda X: X, area=np.zeros(10))
    with pytest.raises(ValueError, match=r"area must have shape \(10,\)"):
        mo.convolutional_barycenter(A, lambda X: X, area=np.ones(3))
    with pytest.raises(ValueError, match="kernel must map shape"):
        mo.convolutional_barycenter(A, lambda X: X[:5])
    with pytest.raises(ValueError, match="negative"):
        mo.convolutional_barycenter(-A, lambda X: X)


# --------------------------------------------------------------------------
# mesh heat kernel
# --------------------------------------------------------------------------
def test_heat_kernel_constants_mass_symmetry(sphere3):
    V, F = sphere3
    rng = np.random.default_rng(1)
    for lap, steps in [("cotangent", 1), ("graph", 1), ("cotangent", 4)]:
        K = mo.MeshHeatKernel(V, F, 0.05, laplacian=lap, steps=steps)
        m = K.mass
        np.testing.assert_allclose(K(np.ones(len(V))), 1.0, atol=1e-10)
        u = rng.random(len(V))
        assert abs(m @ K(u) - m @ u) < 1e-10 * (m @ u)
        x, y = rng.random(len(V)), rng.random(len(V))
        assert abs(x @ K.solve(y) - y @ K.solve(x)) < 1e-10
        # a heat step strictly contracts a non-constant function (maximum principle)
        assert np.ptp(K(u)) < np.ptp(u)
    assert 4 * np.pi - 0.1 < m.sum() < 4 * np.pi  # inscribed polyhedron


@pytest.mark.parametrize("steps", [1, 5])
def test_heat_kernel_spherical_harmonics(sphere4, steps):
    # cotangent Laplacian on a fine unit sphere: L Y_l ~ l(l+1) M Y_l, so
    # K Y_l ~ Y_l / (1 + t l(l+1) / s)^s
    V, F = sphere4
    t = 0.02
    K = mo.MeshHeatKernel(V, F, t, laplacian="cotangent", steps=steps)
    x, y, z = V.T
    for ell, Y in [(1, z), (1, x + 2 * y), (2, 3 * z**2 - 1), (2, x * y), (3, z * (5 * z**2 - 3))]:
        KY = K(Y)
        expected = (1 + t * ell * (ell + 1) / steps) ** -steps
        ratio = (KY @ (K.mass * Y)) / (Y @ (K.mass * Y))
        assert abs(ratio - expected) < 0.01, (ell, ratio, expected)
        np.testing.assert_allclose(KY, Y * expected, atol=0.01 * np.abs(Y).max())


def test_heat_kernel_factorises_once(sphere3, monkeypatch):
    import cholespy

    calls = []
    real = cholespy.CholeskySolverD

    class Counting(real):
        def __init__(self, *args):
            calls.append(1)
            super().__init__(*args)

    import meshdenoise.solvers.factor

    monkeypatch.setattr(meshdenoise.solvers.factor, "CholeskySolverD", Counting)  # the two places factorisations are made
    real_cholmod = meshdenoise.solvers.factor._cholmod_factor

    def cholmod_counted(A, *args):
        factor = real_cholmod(A, *args)
        calls.append(1)
        return factor

    monkeypatch.setattr(meshdenoise.solvers.factor, "_cholmod_factor", cholmod_counted)
    V, F = sphere3
    K = mo.MeshHeatKernel(V, F, 0.1)
    for _ in range(5):
        K(np.ones(len(V)))
        K.solve(np.ones((len(V), 3)))
    assert len(calls) == 1


def test_heat_kernel_bad_inputs(sphere3):
    V, F = sphere3
    with pytest.raises(ValueError, match="t must be"):
        mo.MeshHeatKernel(V, F, 0.0)
    with pytest.raises(ValueError, match="laplacian must be.*'umbrella'"):
        mo.MeshHeatKernel(V, F, 0.1, laplacian="umbrella")
    with pytest.raises(ValueError, match=r"V must have shape \(n, 3\)"):
        mo.MeshHeatKernel(V[:, :2], F, 0.1)
    with pytest.raises(ValueError, match="outside"):
        mo.MeshHeatKernel(V, F + 1000, 0.1)
    with pytest.raises(TypeError, match="integer"):
        mo.MeshHeatKernel(V, F.astype(float), 0.1)
    Vx = np.vstack([V, [[5.0, 5.0, 5.0]]])  # an unreferenced vertex has no area
    with pytest.raises(ValueError, match=f"vertex {len(V)} has zero area"):
        mo.MeshHeatKernel(Vx, F, 0.1)
    K = mo.MeshHeatKernel(V, F, 0.1)
    with pytest.raises(ValueError, match="expected shape"):
        K(np.ones(3))


def bump(V, c, width=0.1):
    c = np.asarray(c, float) / np.linalg.norm(c)
    return np.exp(-np.sum((V - c) ** 2, axis=1) / width)


def test_mesh_barycenter_matches_dense_and_is_symmetric(sphere3):
    V, F = sphere3
    # several backward-Euler substeps: one step has exponential (not Gaussian) tails and
    # its barycenter does not move the mass to the geodesic midpoint
    K = mo.MeshHeatKernel(V, F, 0.005, steps=10)
    m = K.mass
    # two bumps mirror images under x -> -x (the icosphere is symmetric under it)
    A = np.stack([bump(V, [0.8, 0.3, 0.5], 0.05), bump(V, [-0.8, 0.3, 0.5], 0.05)], 1) * m[:, None]
    A /= A.sum(0)
    p = mo.convolutional_barycenter(A, K, area=m, stopThr=1e-11)
    # mirror permutation
    mirror = np.array([np.argmin(np.sum((V - v * [-1, 1, 1]) ** 2, 1)) for v in V])
    assert np.allclose(V[mirror], V * [-1, 1, 1], atol=1e-12)
    np.testing.assert_allclose(p[mirror], p, atol=1e-10)
    # the mass sits between the bumps, around x = 0, not at the bumps (it is not the mixture)
    assert abs(p @ V[:, 0]) < 1e-8
    assert abs(V[np.argmax(p), 0]) < 0.15
    band = np.abs(V[:, 0]) < 0.3
    assert p[band].sum() > 0.3
    assert 0.5 * (A[:, 0] + A[:, 1])[band].sum() < 0.01
    # the operator barycenter equals the dense one with Gibbs matrix G = (M + tL)^-1
    G = K.solve(np.eye(len(V)))
    assert G.min() > 0
    p_dense = mo.barycenter(A, -np.log(G), 1.0, stopThr=1e-11, numItermax=10000)
    np.testing.assert_allclose(p, p_dense, atol=1e-9)
    # a single step puts the peak on a bump instead
    K1 = mo.MeshHeatKernel(V, F, 0.005)
    p1 = mo.convolutional_barycenter(A, K1, area=m, stopThr=1e-11)
    assert abs(V[np.argmax(p1), 0]) > 0.5


def test_mesh_barycenter_of_identical_histograms(sphere3):
    V, F = sphere3
    K = mo.MeshHeatKernel(V, F, 0.02)
    a = bump(V, [0.1, 0.2, 1.0]) * K.mass
    a /= a.sum()
    p1 = mo.convolutional_barycenter(a[:, None], K, area=K.mass, stopThr=1e-12)
    p2 = mo.convolutional_barycenter(np.stack([a, a], 1), K, [0.3, 0.7], area=K.mass, stopThr=1e-12)
    np.testing.assert_allclose(p1, p2, atol=1e-12)
    assert abs(p1.sum() - 1) < 1e-8
    # same center of mass (up to the sphere's curvature pulling inwards)
    c1, c0 = p1 @ V, a @ V
    assert np.dot(c1, c0) / np.linalg.norm(c1) / np.linalg.norm(c0) > 0.999


# --------------------------------------------------------------------------
# symmetric Sinkhorn and the denoiser
# --------------------------------------------------------------------------
def test_symmetric_sinkhorn_marginals(sphere3):
    V, F = sphere3
    K = mo.MeshHeatKernel(V, F, 2.0, laplacian="graph", mass="uniform")
    rng = np.random.default_rng(0)
    m = 0.5 + rng.random(len(V))
    u, info = mo.symmetric_sinkhorn(K.solve, m, stopThr=1e-12)
    np.testing.assert_allclose(u * K.solve(u), m, rtol=1e-10)
    with pytest.warns(UserWarning, match="numItermax=2"):
        mo.symmetric_sinkhorn(K.solve, m, numItermax=2, stopThr=0.0)
    with pytest.raises(ValueError, match="non-negative"):
        mo.symmetric_sinkhorn(K.solve, -m)
    # zero-mass entries get u = 0; the rest still matches its marginal
    m0 = m.copy()
    m0[:10] = 0
    u0, _ = mo.symmetric_sinkhorn(K.solve, m0, stopThr=1e-12)
    assert np.all(u0[:10] == 0)
    np.testing.assert_allclose(u0 * K.solve(u0), m0, atol=1e-10)
    with pytest.raises(ValueError, match="not positive"):
        mo.symmetric_sinkhorn(lambda x: -x, m)


@pytest.mark.parametrize("kw", [dict(), dict(measure="area"), dict(debias=False), dict(laplacian="cotangent")])
def test_ot_denoise_translation_equivariant(sphere3, kw):
    V, F = sphere3
    X = add_noise(V, F, 0.02)
    c = np.array([3.0, -1.0, 0.5])
    Y1 = mo.ot_denoise(X, F, t=3.0, **kw) + c
    Y2 = mo.ot_denoise(X + c, F, t=3.0, **kw)
    np.testing.assert_allclose(Y1, Y2, atol=1e-8)


def test_ot_denoise_linear_with_uniform_measure(sphere3):
    V, F = sphere3
    X1, X2 = add_noise(V, F, 0.02, 1), add_noise(V, F, 0.02, 2)
    Y = mo.ot_denoise(2 * X1 - 0.5 * X2, F)
    np.testing.assert_allclose(Y, 2 * mo.ot_denoise(X1, F) - 0.5 * mo.ot_denoise(X2, F), atol=1e-10)


@pytest.mark.parametrize("kw", [dict(), dict(measure="area"), dict(debias=False)])
def test_ot_denoise_improves_snr_on_noisy_sphere(sphere4, kw):
    V, F = sphere4
    X = add_noise(V, F, 0.1)  # 20 dB
    Y = mo.ot_denoise(X, F, t=1.0, iterations=1, **kw)
    assert snr(Y, V) > snr(X, V) + 8, (snr(X, V), snr(Y, V))


def test_ot_denoise_plane(sphere3):
    # a flat grid: in-plane positions are kept in the plane exactly, out-of-plane noise shrinks
    n = 30
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    V = np.stack([i.ravel(), j.ravel(), np.zeros(n * n)], 1).astype(float)
    idx = (i * n + j)[:-1, :-1].ravel()
    F = np.concatenate([np.stack([idx, idx + n, idx + 1], 1), np.stack([idx + 1, idx + n, idx + n + 1], 1)])
    Y = mo.ot_denoise(V, F, measure="area")
    assert np.abs(Y[:, 2]).max() < 1e-12
    rng = np.random.default_rng(0)
    X = V.copy()
    X[:, 2] = 0.3 * rng.standard_normal(n * n)
    Y = mo.ot_denoise(X, F)
    interior = (i.ravel() > 3) & (i.ravel() < n - 4) & (j.ravel() > 3) & (j.ravel() < n - 4)
    assert np.std(Y[interior, 2]) < 0.3 * np.std(X[interior, 2])


def test_ot_denoise_fixed_and_identity(sphere3):
    V, F = sphere3
    X = add_noise(V, F, 0.05)
    fixed = np.zeros(len(V), bool)
    fixed[::7] = True
    Y = mo.ot_denoise(X, F, pinned=fixed)
    np.testing.assert_array_equal(Y[fixed], X[fixed])
    assert np.abs(Y[~fixed] - X[~fixed]).max() > 1e-3
    np.testing.assert_array_equal(mo.ot_denoise(X, F, iterations=0), X)


def test_ot_denoise_caches_graph_kernel(sphere3):
    V, F = sphere3
    cache = {}
    Y1 = mo.ot_denoise(V, F, t=2.0, cache=cache)
    (key,) = cache
    K = cache[key]
    Y2 = mo.ot_denoise(V, F, t=2.0, cache=cache)
    assert cache[key] is K and len(cache) == 1
    np.testing.assert_array_equal(Y1, Y2)


@pytest.mark.parametrize(
    "kwargs, exc, match",
    [
        (dict(t=-1.0), ValueError, "t must be.*-1.0"),
        (dict(iterations=-2), ValueError, "iterations.*-2"),
        (dict(laplacian="uniform"), ValueError, "laplacian.*'uniform'"),
        (dict(measure="volume"), ValueError, "measure.*'volume'"),
        (dict(debias=1), TypeError, "debias"),
        (dict(pinned=np.zeros(5, bool)), ValueError, "pinned"),
    ],
)
def test_ot_denoise_bad_inputs(sphere3, kwargs, exc, match):
    V, F = sphere3
    with pytest.raises(exc, match=match):
        mo.ot_denoise(V, F, **kwargs)


def test_ot_denoise_elephant_fast_no_dense_matrix(elephant):
    V, F = elephant
    n = len(V)
    assert n == 24955
    X = add_noise(V, F, 0.2)
    t0 = time.perf_counter()
    Y = mo.ot_denoise(X, F)  # no cache: builds the Laplacian and factorises
    elapsed = time.perf_counter() - t0
    tracemalloc.start()
    mo.ot_denoise(X, F, measure="area")
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert elapsed < 5.0, elapsed
    assert peak < n * n * 8 / 100, peak  # a dense n x n float64 matrix would be 5 GB
    assert snr(Y, V) > snr(X, V) + 20, (snr(X, V), snr(Y, V))


def test_sinkhorn_filter_registered_and_equal_to_ot_denoise(sphere3):
    import meshdenoise as md

    spec = md.get_filter("sinkhorn")
    assert spec.translation_equivariant and not spec.linear
    V, F = sphere3
    X = add_noise(V, F, 0.05)
    for kw in [dict(), dict(t=2.0, measure="area", debias=False, iterations=2, steps=3)]:
        np.testing.assert_allclose(md.sinkhorn((X, F), **kw)[0], mo.ot_denoise(X, F, **kw), atol=1e-12)
    with pytest.raises(ValueError, match="'t' = -1.0"):
        md.sinkhorn((X, F), t=-1.0)
    with pytest.raises(ValueError, match="'measure' = 'areas'.*did you mean 'area'"):
        md.sinkhorn((X, F), measure="areas")
    # an isolated vertex stays put
    V2 = np.vstack([X, [[5.0, 5, 5]]])
    for measure in ("uniform", "area"):
        out = md.sinkhorn((V2, F), measure=measure)[0]
        np.testing.assert_array_equal(out[-1], V2[-1])
        np.testing.assert_allclose(out[:-1], md.sinkhorn((X, F), measure=measure)[0], atol=1e-10)


def test_image_benchmark_reproduces_naive_gibbs_finding(tmp_path):
    import importlib.util

    path = Path(__file__).resolve().parents[1] / "benchmarks" / "ot_image.py"
    spec = importlib.util.spec_from_file_location("ot_image", path)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    s = bench.main(["--out", str(tmp_path), "--size", "64"])
    assert (tmp_path / "ot_image.png").stat().st_size > 1000
    assert json.loads((tmp_path / "ot_image.json").read_text())["best_gibbs"] == s["best_gibbs"]
    noisy = s["rows"][0]["psnr"]
    assert s["best_gibbs"]["psnr"] > noisy + 3  # it does denoise ...
    assert s["best_gibbs"]["psnr"] < s["best_gaussian"]["psnr"]  # ... but never beats a Gaussian blur
    usual = [r for r in s["rows"] if r["method"] == "gibbs" and r["param"] == "reg=0.01"]
    assert usual[0]["psnr"] < s["best_gaussian"]["psnr"] - 3

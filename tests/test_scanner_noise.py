"""The scanner noise model and the correlation-length estimator, against statistics computed here."""

from __future__ import annotations

import numpy as np
import pytest

import meshdenoise as md
from meshdenoise.geometry import vertex_normals
from meshdenoise.noise import add_scanner_noise, autocorrelation, correlation_length, mean_edge_length
from meshdenoise.shapes import grid, icosphere

from .conftest import make_mesh, vertices_of

GRID = grid(110, 110)  # 12,100 vertices, open
SPHERE = icosphere(5)  # 10,242 vertices, closed


def edge_length_by_loop(V, F):
    """Mean length of the unique undirected edges, with a Python set (written for the test)."""
    edges = {tuple(sorted((int(f[a]), int(f[b])))) for f in F for a, b in ((0, 1), (1, 2), (2, 0))}
    return float(np.mean([np.linalg.norm(V[i] - V[j]) for i, j in edges]))


def along(V0, V1, D):
    """Signed displacement along unit directions D (n, 3) or (3,)."""
    return np.einsum("ij,ij->i", V1 - V0, np.broadcast_to(D, V0.shape))


def random_fourier_field(V, h, ell, rng, modes=1500):
    """A Gaussian field with correlation exp(-(r / (ell h))^2), by random Fourier features (Rahimi and Recht).

    exp(-r^2 / l^2) is the characteristic function of N(0, 2 / l^2 I): frequencies drawn from it with
    uniform phases give sqrt(2 / M) sum cos(w . x + phi) a covariance of exactly that kernel. It shares
    nothing with the heat filter, so it checks the estimator alone.
    """
    omega = rng.normal(0.0, np.sqrt(2.0) / (ell * h), size=(modes, 3))
    phase = rng.uniform(0, 2 * np.pi, modes)
    return np.sqrt(2.0 / modes) * np.cos(V @ omega.T + phase).sum(axis=1)


def test_mean_edge_length_matches_a_loop():
    V, F = icosphere(2)
    assert mean_edge_length(V, F) == pytest.approx(edge_length_by_loop(V, F), rel=1e-12)


@pytest.mark.parametrize("ell", [1.0, 2.0, 4.0])
def test_estimator_recovers_the_length_of_a_field_made_without_the_heat_filter(ell):
    V, F = GRID
    h = mean_edge_length(V, F)
    z = random_fourier_field(V, h, ell, np.random.default_rng(7))
    assert correlation_length(z, (V, F)) == pytest.approx(ell, rel=0.1)


def test_estimator_curve_follows_the_gaussian_of_a_fourier_field():
    V, F = GRID
    h = mean_edge_length(V, F)
    z = random_fourier_field(V, h, 3.0, np.random.default_rng(1))
    r, rho, pairs = autocorrelation(z, (V, F), max_distance=6)
    assert r[0] == 0 and rho[0] == 1
    near = (r > 0.5) & (r < 5) & (pairs > 200)
    np.testing.assert_allclose(rho[near], np.exp(-(r[near] / 3.0) ** 2), atol=0.08)


@pytest.mark.parametrize("mesh", [GRID, SPHERE], ids=["grid", "sphere"])
@pytest.mark.parametrize("ell", [0.0, 1.0, 2.0, 4.0])
def test_correlation_length_and_sigma_recovered_from_samples(mesh, ell):
    """Tolerance: the mean of two seeds within 12 % (0 exactly for independent noise)."""
    V, F = mesh
    N = vertex_normals(V, F)
    estimates = []
    for seed in (0, 1):
        Vn, _ = add_scanner_noise((V, F), 0.01, correlation_length=ell, seed=seed)
        d = along(V, Vn, N)
        np.testing.assert_allclose(Vn - V, d[:, None] * N, atol=1e-15)  # along the normals only
        assert np.sqrt(np.mean(d**2)) == pytest.approx(0.01, rel=1e-12)  # rescaled to sigma exactly
        estimates.append(correlation_length(d, (V, F)))
    if ell == 0:
        assert estimates == [0.0, 0.0]
    else:
        assert np.mean(estimates) == pytest.approx(ell, rel=0.12), estimates


def test_noise_is_gaussian_and_the_field_is_smooth_when_correlated():
    V, F = GRID
    z = along(V, add_scanner_noise((V, F), 1.0, direction=(0, 0, 1), seed=3)[0], [0, 0, 1])
    assert abs(np.mean(np.abs(z)) - np.sqrt(2 / np.pi)) < 0.02  # E|z| of a standard normal
    assert abs(np.mean(z**4) - 3.0) < 0.25  # kurtosis of a normal
    c = along(V, add_scanner_noise((V, F), 1.0, correlation_length=3, direction=(0, 0, 1), seed=3)[0], [0, 0, 1])
    e = md.get_operators(F, len(V)).edges
    # neighbours differ far less when the noise is correlated (differences of white noise: variance 2)
    assert np.mean((z[e[:, 0]] - z[e[:, 1]]) ** 2) == pytest.approx(2.0, rel=0.05)
    assert np.mean((c[e[:, 0]] - c[e[:, 1]]) ** 2) < 0.3


def test_seeded_reproducible():
    V, F = SPHERE
    a = add_scanner_noise((V, F), 0.02, correlation_length=2, outlier_fraction=0.01, seed=5)[0]
    b = add_scanner_noise((V, F), 0.02, correlation_length=2, outlier_fraction=0.01, seed=5)[0]
    c = add_scanner_noise((V, F), 0.02, correlation_length=2, outlier_fraction=0.01, seed=6)[0]
    g = add_scanner_noise((V, F), 0.02, correlation_length=2, outlier_fraction=0.01, seed=np.random.default_rng(5))[0]
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(a, g)
    assert not np.array_equal(a, c)


def test_outlier_fraction_recovered():
    V, F = GRID
    n = len(V)
    view = np.array([0.0, 0.0, -1.0])
    clean = along(V, add_scanner_noise((V, F), 1.0, correlation_length=2, direction=view, seed=9)[0], view)
    noisy = along(V, add_scanner_noise((V, F), 1.0, correlation_length=2, direction=view, seed=9,
                                       outlier_fraction=0.05, outlier_scale=10)[0], view)
    extra = noisy - clean  # the correlated part is drawn first, so it is the same field
    moved = np.flatnonzero(np.abs(extra) > 1e-12)
    assert moved.size == round(0.05 * n)
    assert (np.abs(extra[moved]) >= 5 - 1e-9).all() and (np.abs(extra[moved]) <= 10 + 1e-9).all()
    assert 0.4 < np.mean(extra[moved] > 0) < 0.6  # both signs
    # recovered from the sample alone, as from a scan: the share of points beyond 3 sigma
    assert np.mean(np.abs(noisy) > 3) == pytest.approx(0.05, abs=0.006)


def test_depth_dependence_near_and_far():
    V, F = grid(100, 100)
    V = V.copy()
    V[:, 2] = V[:, 0]  # a plane tilted 45 degrees: depth along -z grows as x falls
    view = np.array([0.0, 0.0, -1.0])
    d = along(V, add_scanner_noise((V, F), 0.01, direction=view, depth_sigma=0.03, seed=2)[0], view)
    depth = V @ view
    t = (depth - depth.min()) / np.ptp(depth)
    near, far = t < 0.1, t > 0.9
    expected = np.sqrt(np.mean((0.01 + 0.02 * t[far]) ** 2)) / np.sqrt(np.mean((0.01 + 0.02 * t[near]) ** 2))
    ratio = np.sqrt(np.mean(d[far] ** 2)) / np.sqrt(np.mean(d[near] ** 2))
    assert ratio == pytest.approx(expected, rel=0.1)
    assert ratio > 2.2


def test_displacement_parallel_to_the_view_direction():
    V, F = SPHERE
    view = np.array([1.0, -2.0, 0.5])
    Vn, _ = add_scanner_noise((V, F), 0.01, correlation_length=1, direction=view, outlier_fraction=0.02, seed=0)
    D = Vn - V
    u = view / np.linalg.norm(view)
    np.testing.assert_allclose(np.cross(D, u), 0.0, atol=1e-15)
    assert np.abs(D @ u).max() > 0.01


def test_on_every_mesh_type(mesh_kind):
    V, F = icosphere(2)
    kw = dict(correlation_length=1.5, direction=(0, 1, 0), outlier_fraction=0.1, seed=4)
    out = md.add_scanner_noise(make_mesh(mesh_kind, V, F), 0.01, **kw)
    np.testing.assert_allclose(vertices_of(out), add_scanner_noise((V, F), 0.01, **kw)[0], atol=1e-12)


def test_isolated_vertices_do_not_move():
    V, F = grid(10, 10)
    V = np.vstack([V, [[5.0, 5.0, 5.0]]])
    Vn, _ = add_scanner_noise((V, F), 0.1, correlation_length=2, direction=(0, 0, 1), seed=0)
    assert np.array_equal(Vn[-1], V[-1]) and not np.array_equal(Vn[:-1], V[:-1])


def test_bad_parameters_name_the_value():
    V, F = icosphere(1)
    with pytest.raises(ValueError, match="'sigma' = -1"):
        add_scanner_noise((V, F), -1)
    with pytest.raises(TypeError, match="'sigma' must be a number"):
        add_scanner_noise((V, F), "big")
    with pytest.raises(ValueError, match="'outlier_fraction' = 1.5"):
        add_scanner_noise((V, F), 0.1, outlier_fraction=1.5)
    with pytest.raises(ValueError, match="direction must be 'normals' or a non-zero"):
        add_scanner_noise((V, F), 0.1, direction=(0, 0, 0))
    with pytest.raises(ValueError, match="direction must be 'normals' or a vector"):
        add_scanner_noise((V, F), 0.1, direction="view")
    with pytest.raises(ValueError, match="depth_sigma needs a view direction"):
        add_scanner_noise((V, F), 0.1, depth_sigma=0.2)
    with pytest.raises(ValueError, match=r"shape \(42,\) or \(42, k\)"):
        correlation_length(np.ones(5), (V, F))
    with pytest.raises(ValueError, match="constant"):
        correlation_length(np.ones(len(V)), (V, F))


def test_too_long_a_correlation_warns_and_gives_inf():
    V, F = grid(40, 40)
    z = V[:, 0] + 0.01 * np.random.default_rng(0).standard_normal(len(V))  # a ramp: correlated at every range
    with pytest.warns(UserWarning, match="stays above 1/e up to 3 mean edge lengths"):
        assert correlation_length(z, (V, F), max_distance=3) == np.inf

"""Correlated noise: the coloured trace probes, SURE with a covariance, and the (rho, ell) estimate,
against dense computations written here."""

from __future__ import annotations

import numpy as np
import pytest

from meshdenoise.geometry import cotangent_laplacian, lumped_mass, vertex_normals
from meshdenoise.noise import HEAT_STEPS, add_normal_noise, add_scanner_noise, diffusion_length, mean_edge_length
from meshdenoise.operators import get_operators
from meshdenoise.shapes import grid, icosphere, torus
from meshdenoise.tuning import auto_filters, choose_parameters, estimate_noise
from meshdenoise.tuning.covariance import NoiseModel, estimate_noise_model
from meshdenoise.tuning.risk import N_PROBES, colour_probes, noise_colouring, probe_block, sure
from meshdenoise.metrics import snr
from meshdenoise.registry import apply_filter


def dense_covariance(V, F, ell):
    """Sigma of the model by dense linear algebra: C = [(M + tau/k L)^-1 M]^k diag(sqrt(mean m / m)),
    Sigma = C C^T scaled to trace n (add_scanner_noise's rescaling)."""
    n = V.shape[0]
    h = mean_edge_length(V, F)
    m = lumped_mass(V, F)
    L = cotangent_laplacian(V, F).toarray()
    tau = (diffusion_length(ell) * h) ** 2 / 8.0
    step = np.linalg.solve(np.diag(m) + tau / HEAT_STEPS * L, np.diag(m))
    C = np.linalg.matrix_power(step, HEAT_STEPS) @ np.diag(np.sqrt(m.mean() / m))
    S = C @ C.T
    return S * n / np.trace(S)


def dense_sobolev(F, n, mu):
    L = get_operators(F, n).L.toarray()
    return np.linalg.inv(np.eye(n) + mu * L)


SMALL = icosphere(2)  # 162 vertices


def test_exact_coloured_probes_give_the_dense_trace_of_h_sigma():
    V, F = SMALL
    n = V.shape[0]
    Sigma = dense_covariance(V, F, 2.0)
    H = dense_sobolev(F, n, 3.0)
    Z, s = probe_block(n, exact=True, colour=NoiseModel(0.1, 2.0, V, F))
    assert s * np.sum(Z * (H @ Z)) == pytest.approx(np.trace(H @ Sigma), rel=1e-6)
    assert s * np.sum(Z * Z) == pytest.approx(n, rel=1e-12)  # tr(Sigma) = n
    # and not tr(H): the test can fail (the correlated noise passes the smoother far more)
    assert np.trace(H @ Sigma) > 1.5 * np.trace(H)


def test_colour_from_several_threads_colours_each_probe_block_once():
    """NoiseModel.colour called at once from threads (the default's rules side by side): the same probes are coloured
    once (the other callers wait for that colouring), different probes at the same time, every result the serial
    one; a pickled model colours alike."""
    import pickle
    import threading
    import time

    V, F = SMALL
    n = V.shape[0]
    serial = NoiseModel(0.1, 2.0, V, F)
    rng = np.random.default_rng(4)
    blocks = [rng.choice([-1.0, 1.0], size=(n, 5)) for _ in range(2)]
    expected = [serial.colour(Z, 0.2) for Z in blocks]

    model = NoiseModel(0.1, 2.0, V, F)
    computed = []
    inside = threading.Barrier(2, timeout=10)  # both blocks' colourings under way at once
    plain = model._coloured_probes

    def slow(Z, s):
        computed.append(Z[0, 0])
        if len(computed) <= 2:
            inside.wait()
        time.sleep(0.05)  # callers of the same block arrive while it is computed
        return plain(Z, s)

    model._coloured_probes = slow
    got = {}

    def call(i, j):
        got[i] = model.colour(blocks[j], 0.2)

    threads = [threading.Thread(target=call, args=(i, i % 2)) for i in range(6)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(computed) == 2  # one colouring per block, both at once (the barrier)
    for i in range(6):
        np.testing.assert_array_equal(got[i], expected[i % 2])
    assert model._pending == {}
    again = pickle.loads(pickle.dumps(serial))
    np.testing.assert_array_equal(again.colour(blocks[0], 0.2), expected[0])


def test_a_failed_colouring_leaves_the_next_caller_to_colour():
    V, F = SMALL
    model = NoiseModel(0.1, 2.0, V, F)
    Z = np.random.default_rng(6).choice([-1.0, 1.0], size=(V.shape[0], 3))
    plain, calls = model._coloured_probes, []

    def fails_once(Z, s):
        calls.append(1)
        if len(calls) == 1:
            raise MemoryError("no room")
        return plain(Z, s)

    model._coloured_probes = fails_once
    with pytest.raises(MemoryError):
        model.colour(Z, 1 / 3)
    np.testing.assert_array_equal(model.colour(Z, 1 / 3), NoiseModel(0.1, 2.0, V, F).colour(Z, 1 / 3))
    assert len(calls) == 2 and model._pending == {}


def test_hutchinson_with_coloured_probes_is_unbiased_for_the_trace():
    V, F = SMALL
    n = V.shape[0]
    exact = np.trace(dense_sobolev(F, n, 3.0) @ dense_covariance(V, F, 2.0))
    H = dense_sobolev(F, n, 3.0)
    model = NoiseModel(0.1, 2.0, V, F)
    est = []
    for seed in range(40):
        Z, s = probe_block(n, exact=False, seed=seed, colour=model)
        est.append(s * np.sum(Z * (H @ Z)))
    est = np.array(est)
    assert abs(est.mean() - exact) < 3 * est.std() / np.sqrt(est.size) + 1e-3 * exact
    assert np.all(np.abs(est / exact - 1) < 0.25)  # one block of N_PROBES: within 25 %
    assert Z.shape == (n, N_PROBES)


@pytest.mark.parametrize("ell", [1.0, 3.0])
def test_sure_with_the_covariance_is_unbiased_and_the_independent_one_is_not(ell):
    """On a flat grid with noise along z (all normals equal, so tr(H Sigma) is the exact noise term):
    the mean of SURE over many draws equals the mean true error; SURE with tr(H) misses it."""
    V, F = grid(12, 12)
    n = V.shape[0]
    rho, mu = 0.02, 2.0
    Sigma = dense_covariance(V, F, ell)
    H = dense_sobolev(F, n, mu)
    Z, s = probe_block(n, exact=True, colour=NoiseModel(rho, ell, V, F))
    trace = s * float(np.sum(Z * (H @ Z)))
    rng = np.random.default_rng(0)
    draws = 4000
    E = np.linalg.cholesky(Sigma + 1e-12 * np.eye(n)) @ rng.standard_normal((n, draws)) * rho  # (n, draws) along z
    X0 = V
    true_err, sure_c, sure_w = [], [], []
    HX0 = H @ X0
    HE = H @ E
    for k in range(draws):
        X = X0.copy()
        X[:, 2] += E[:, k]
        HX = HX0.copy()
        HX[:, 2] += HE[:, k]
        res = float(np.sum((HX - X) ** 2))
        true_err.append(float(np.sum((HX - X0) ** 2)))
        sure_c.append(sure(res, trace, n, rho))
        sure_w.append(sure(res, float(np.trace(H)), n, rho))
    true_err, sure_c, sure_w = map(np.array, (true_err, sure_c, sure_w))
    se = np.std(sure_c - true_err) / np.sqrt(draws)
    assert abs(sure_c.mean() - true_err.mean()) < 3 * se
    assert abs(sure_w.mean() - true_err.mean()) > 20 * se


TORUS = torus(160, 64)  # 10,240 vertices, closed, smooth


@pytest.mark.parametrize("ell", [0.0, 1.0, 2.0, 4.0])
def test_estimate_recovers_level_and_length_of_scanner_noise(ell):
    V, F = TORUS
    h = mean_edge_length(V, F)
    sigma = 0.3 * h
    Vn, _ = add_scanner_noise((V, F), sigma, correlation_length=ell, seed=0)
    model = estimate_noise_model((Vn, F))
    if ell == 0:
        assert model.correlation_length == 0.0
        assert model.rho == estimate_noise((Vn, F))  # bit for bit: the independent estimate unchanged
        assert model.rho == pytest.approx(sigma, rel=0.05)
    else:
        assert model.correlation_length == pytest.approx(ell, rel=0.1)
        assert model.rho == pytest.approx(sigma, rel=0.15)
        # the independent estimate reads only the high-frequency share of it
        assert estimate_noise((Vn, F)) < 0.75 * sigma


def test_estimate_reads_independent_noise_on_a_coarse_curved_mesh_as_independent():
    V, F = icosphere(3)
    Vn, _ = add_normal_noise((V, F), rho=0.01, seed=0)
    model = estimate_noise_model((Vn, F))
    assert model.correlation_length == 0.0 and model.rho == estimate_noise((Vn, F))


SPHERE2 = icosphere(2)
SPHERE2_NOISY = add_normal_noise(SPHERE2, rho=0.03, seed=1)[0]


@pytest.mark.parametrize("method", auto_filters())
def test_independent_noise_gives_bit_identical_choices(method):
    """With ell read as 0 every rule chooses exactly what it chose with the independent estimate."""
    mesh = (SPHERE2_NOISY, SPHERE2[1])
    rho = estimate_noise(mesh)
    today = choose_parameters(mesh, method, noise=rho, exact_trace=False)  # Hutchinson probes: the coloured path
    assert choose_parameters(mesh, method, exact_trace=False) == today
    assert choose_parameters(mesh, method, noise=rho, correlation_length=0, exact_trace=False) == today


def test_independent_model_leaves_the_probes_alone():
    Z, s = probe_block(1000, exact=False)
    with noise_colouring(NoiseModel(0.5)):
        Z2, s2 = probe_block(1000, exact=False)
    assert s2 == s and np.array_equal(Z2, Z)
    assert colour_probes(Z, s, NoiseModel(0.5)) is Z


def test_coloured_sure_chooses_better_under_correlated_noise():
    V, F = TORUS
    h = mean_edge_length(V, F)
    Vn, _ = add_scanner_noise((V, F), 0.3 * h, correlation_length=2, seed=3)
    mesh = (Vn, F)
    auto = choose_parameters(mesh, "sobolev")
    white = choose_parameters(mesh, "sobolev", noise=estimate_noise(mesh))
    oracle = choose_parameters(mesh, "sobolev", criterion="oracle", reference=V)
    got = {k: snr(V, apply_filter("sobolev", mesh, **p)[0]) for k, p in (("auto", auto), ("white", white), ("oracle", oracle))}
    assert got["auto"] > got["white"] + 1.0
    assert got["oracle"] - got["auto"] < 1.0


def test_given_length_colours_the_probes_of_the_rule():
    V, F = TORUS
    h = mean_edge_length(V, F)
    Vn, _ = add_scanner_noise((V, F), 0.3 * h, correlation_length=2, seed=3)
    white = choose_parameters((Vn, F), "sobolev", noise=0.3 * h)
    coloured = choose_parameters((Vn, F), "sobolev", noise=0.3 * h, correlation_length=2.0)
    assert coloured["mu"] != white["mu"]  # the rule's SURE got tr(H Sigma), not tr(H)
    oracle = choose_parameters((Vn, F), "sobolev", criterion="oracle", reference=V)
    got = {k: snr(V, apply_filter("sobolev", (Vn, F), **p)[0]) for k, p in (("c", coloured), ("o", oracle))}
    assert got["o"] - got["c"] < 0.2


def test_bad_noise_models_are_refused():
    V, F = SMALL
    with pytest.raises(ValueError, match="correlation_length"):
        NoiseModel(0.1, -1.0)
    with pytest.raises(ValueError, match="needs the mesh"):
        NoiseModel(0.1, 2.0)
    with pytest.raises(TypeError, match="rho"):
        NoiseModel("0.1")
    with pytest.raises(ValueError, match="correlation_length"):
        choose_parameters((V, F), "sobolev", noise=0.01, correlation_length=-2)
    with pytest.raises(ValueError, match="162 vertices"):
        colour_probes(np.ones((10, 2)), 0.5, NoiseModel(0.1, 2.0, V, F))
    with pytest.raises(ValueError, match="refine"):
        estimate_noise_model((V, F), refine=0)


@pytest.mark.parametrize("method", ["sobolev_normal", "sobolev_gls"])
def test_monte_carlo_sure_rules_draw_coloured_probes(method, monkeypatch):
    """The nonlinear rules' own probes (b = z N) go through the model's colouring when it is correlated."""
    calls = []
    original = NoiseModel.colour

    def spy(self, Z, s):
        calls.append(Z.shape)
        return original(self, Z, s)

    monkeypatch.setattr(NoiseModel, "colour", spy)
    mesh = (SPHERE2_NOISY, SPHERE2[1])
    choose_parameters(mesh, method, noise=0.03, correlation_length=1.5, exact_trace=False)
    assert calls


def test_details_say_why():
    V, F = TORUS
    h = mean_edge_length(V, F)
    Vn, _ = add_scanner_noise((V, F), 0.3 * h, correlation_length=2, seed=0)
    model, info = estimate_noise_model((Vn, F), details=True)
    assert info["reason"].startswith("correlated") and info["ell_fit"] == model.correlation_length
    assert info["rho_white"] == estimate_noise((Vn, F))
    model, info = estimate_noise_model(grid(20, 20), details=True)  # a plane: no noise at all
    assert model.rho == estimate_noise(grid(20, 20)) < 1e-12 and info["reason"].startswith("independent")


def test_a_noise_model_can_be_given_once_for_several_choices():
    V, F = TORUS
    h = mean_edge_length(V, F)
    Vn, _ = add_scanner_noise((V, F), 0.3 * h, correlation_length=2, seed=3)
    model = estimate_noise_model((Vn, F))
    assert model.correlation_length > 0
    assert choose_parameters((Vn, F), "sobolev", noise=model) == choose_parameters((Vn, F), "sobolev")
    with pytest.raises(ValueError, match="holds its correlation length"):
        choose_parameters((Vn, F), "sobolev", noise=model, correlation_length=1.0)


def test_unreferenced_vertices_change_neither_the_coloured_noise_nor_the_estimate():
    # range scans ship vertices on no face (face000.ply: 667 of them); their floored mass once amplified their
    # coloured noise 30,000 times, and the estimate read rho 880 where the surface's is 0.07
    from meshdenoise.noise import HeatFilter, add_scanner_noise, diffusion_length
    from meshdenoise.shapes import torus
    from meshdenoise.tuning import estimate_noise_model

    V, F = torus(60, 30)
    Vn = add_scanner_noise((V, F), 0.02, correlation_length=2.0, seed=0)[0]
    extra = np.vstack([Vn, [[50.0, 50.0, 50.0], [-3.0, 0.0, 9.0]]])  # two vertices on no face
    Z = np.random.default_rng(0).standard_normal((extra.shape[0], 2))
    out = HeatFilter(extra, F, diffusion_length(2.0))(Z)
    np.testing.assert_array_equal(out[-2:], 0.0)
    np.testing.assert_allclose(out[:-2], HeatFilter(Vn, F, diffusion_length(2.0))(Z[:-2]), rtol=1e-6, atol=1e-9)
    a, b = estimate_noise_model((Vn, F)), estimate_noise_model((extra, F))
    assert b.correlation_length == pytest.approx(a.correlation_length, abs=0.1)
    assert b.rho == pytest.approx(a.rho, rel=0.05)

"""Surface detail or correlated noise (meshdenoise.tuning.detail): the band spectrum, its fit, the verdict.

Checked against independent computations: a dense-matrix band spectrum, the lattice closed form of
white noise's finest band, brute-force non-negative least squares, synthetic spectra with a known
answer, and a sphere with a known detail field (no noise) with and without known noise.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.optimize import nnls

from meshdenoise.geometry import vertex_normals
from meshdenoise.noise import add_scanner_noise, mean_edge_length
from meshdenoise.shapes import grid, icosphere
from meshdenoise.tuning.covariance import estimate_noise_model
from meshdenoise.tuning.detail import (
    BANDS,
    BETA_GRID,
    band_spectrum,
    fit_spectrum,
    misfit_profile,
    probe_spectra,
    separate_detail,
)

CHI2_1_MEDIAN = 0.45493642311957  # median of a squared standard normal (scipy.stats.chi2(1).median())


def dense_P(F, n):
    W = np.zeros((n, n))
    for a, b in ((0, 1), (1, 2), (2, 0)):
        W[F[:, a], F[:, b]] = 1.0
        W[F[:, b], F[:, a]] = 1.0
    return W / W.sum(axis=1, keepdims=True)


def test_band_spectrum_matches_dense_matrices():
    V, F = icosphere(2)
    rng = np.random.default_rng(0)
    V = V + 0.02 * rng.standard_normal(V.shape)
    N = vertex_normals(V, F)
    P = dense_P(F, V.shape[0])
    I = np.eye(V.shape[0])
    bands = (0, 1, 2, 4, 8)
    expected = []
    for s in bands:
        R = (I - P) @ (I - P) @ np.linalg.matrix_power(P, s) @ V
        expected.append(np.median(np.sum(R * N, axis=1) ** 2))
    np.testing.assert_allclose(band_spectrum(V, F, N, bands), expected, rtol=1e-10)


def test_white_probes_finest_band_matches_the_six_regular_lattice():
    """On a 6-regular triangulation (I - P)^2 has the stencil 7/6 (centre), -5/18 (6 neighbours), 1/36 and 2/36
    (6 + 6 at distance 2): variance 1.8472 per unit white noise, median square 0.4549 times that."""
    stencil = (7 / 6) ** 2 + 6 * (5 / 18) ** 2 + 6 * (1 / 36) ** 2 + 6 * (2 / 36) ** 2
    V, F = icosphere(5)  # 10,242 vertices, all but 12 of valence 6; normals nearly parallel over two rings
    N = vertex_normals(V, F)
    p = probe_spectra(V, F, N, ells=(0.0,), bands=(0,), probes=4, seed=0)
    assert p[0, 0] == pytest.approx(CHI2_1_MEDIAN * stencil, rel=0.03)


def test_probe_spectra_match_heat_solves_and_dense_band_pass():
    """probe_spectra colours every length from one Krylov space and reads the bands through one chain of powers of P:
    against each length's heat filter solved tightly (HeatFilter, tol 1e-11) and the dense (I - P)^2 P^s."""
    from meshdenoise.noise import HeatFilter, diffusion_length, heat_geometry

    V, F = icosphere(3)  # 642 vertices
    rng = np.random.default_rng(3)
    V = V + 0.01 * rng.standard_normal(V.shape)
    N = vertex_normals(V, F)
    n, probes, ells, bands = V.shape[0], 4, (0.0, 1.0, 2.5), (0, 1, 4, 16)
    P = sp.csr_matrix(dense_P(F, n))  # scipy's own product (not meshdenoise's threaded spmm)
    xi = np.random.default_rng(7).standard_normal((n, probes))  # probe_spectra's own white probes (seed 7)
    geometry = heat_geometry(V, F)
    expected = np.empty((len(ells), len(bands)))
    for j, ell in enumerate(ells):
        Z = xi if ell == 0 else HeatFilter(V, F, diffusion_length(ell), geometry)(xi, tol=1e-11)
        Z = Z * np.sqrt(Z.size / np.sum(Z * Z))
        for b, s in enumerate(bands):
            r = np.empty((n, probes))
            for k in range(probes):
                X = Z[:, [k]] * N
                for _ in range(s):
                    X = P @ X
                X = X - P @ X
                X = X - P @ X
                r[:, k] = np.sum(X * N, axis=1)
            expected[j, b] = np.median(r * r)
    got = probe_spectra(V, F, N, ells, bands, probes=probes, seed=7)
    np.testing.assert_allclose(got, expected, rtol=1e-4)


def test_spectrum_medians_do_not_depend_on_how_many_blocks_share_a_chain():
    """_spectrum_medians pushes ``group`` probe blocks through one chain of powers of P: every grouping (odd counts,
    a last short group, weighted medians) gives each block's own chain's medians, and those equal the dense band
    pass's weighted medians."""
    from meshdenoise.operators import get_operators
    from meshdenoise.tuning import covariance as cov

    V, F = icosphere(2)
    n = V.shape[0]
    N = vertex_normals(V, F)
    ops = get_operators(F, n)
    rng = np.random.default_rng(5)
    Zs = [rng.standard_normal((n, 3)) for _ in range(5)]
    ok = rng.random(n) > 0.2
    w = rng.uniform(0.5, 2.0, n)
    bands = (0, 2, 5)
    P = dense_P(F, n)
    I = np.eye(n)
    expected = np.empty((len(Zs), len(bands)))
    for j, Z in enumerate(Zs):
        for b, s in enumerate(bands):
            B = (I - P) @ (I - P) @ np.linalg.matrix_power(P, s)
            r = np.stack([np.sum((B @ (Z[:, [k]] * N)) * N, axis=1) for k in range(Z.shape[1])], axis=1)[ok] ** 2
            x, wk = r.ravel(), np.repeat(w[ok], Z.shape[1])
            order = np.argsort(x, kind="stable")
            c = np.cumsum(wk[order])
            expected[j, b] = x[order][np.searchsorted(c, 0.5 * c[-1])]
    runs = {g: cov._spectrum_medians(ops, N, Zs, ok, w, bands, group=g) for g in (1, 2, 3, 5)}
    for g, got in runs.items():
        np.testing.assert_array_equal(got, runs[1], err_msg=f"group={g}")
    np.testing.assert_allclose(runs[2], expected, rtol=1e-9)


def test_misfit_profile_matches_brute_force_nnls():
    rng = np.random.default_rng(1)
    bands = (0, 1, 2, 4, 8, 16)
    o = np.exp(rng.uniform(-8, -2, len(bands)))
    p = np.exp(rng.uniform(-8, 0, (3, len(bands))))
    betas = (0.5, 1.3, 2.2, 3.0)
    rho2 = np.array([0.0, 1e-4, 3e-3, 0.05])
    got, g_idx, k_idx = misfit_profile(o, p, rho2, bands, betas)
    s = np.asarray(bands, float) + 1
    for r, value in enumerate(rho2):
        best = np.inf
        for g in range(p.shape[0]):
            for beta in betas:
                target = 1 - value * p[g] / o
                _, res = nnls((s ** -beta / o)[:, None], target)  # A >= 0
                best = min(best, res)
        assert got[r] == pytest.approx(best, rel=1e-9, abs=1e-12)


def synthetic_probes(ells, bands):
    """Unit-variance heat-like noise spectra: tau (tau + s + 1)^-5, tau = 1 + ell^2 (a bump over the fine bands)."""
    s = np.asarray(bands, float)
    tau = 1.0 + np.asarray(ells, float) ** 2
    return tau[:, None] * (tau[:, None] + s[None, :] + 1.0) ** -5.0


def test_fit_recovers_a_known_mixture_and_reads_a_pure_power_law_as_surface():
    ells = (0.0, 1.0, 2.0, 3.0, 4.0)
    p = synthetic_probes(ells, BANDS)
    s = np.asarray(BANDS, float) + 1
    beta = BETA_GRID[30]
    o = 1e-4 * s ** -beta + 0.04 * p[3]  # surface plus noise of rho 0.2 at ell 3
    fit = fit_spectrum(o, p, ells)
    assert fit["misfit"] < 1e-2  # the level is refined between grid points, not hit exactly
    assert fit["rho2"] == pytest.approx(0.04, rel=0.05) and fit["ell"] == 3.0 and fit["beta"] == pytest.approx(beta)
    assert 0.03 < fit["rho2_low"] <= 0.04 <= fit["rho2_high"] < 0.05
    pure = fit_spectrum(1e-4 * s ** -beta, p, ells, rho2_scale=0.04)
    assert pure["rho2"] == 0.0 and pure["rho2_low"] == 0.0 and pure["rho2_high"] < 0.04 * 0.5


def detailed_sphere(amplitude, gamma=1.5, waves=400, seed=0):
    """icosphere(5) displaced along its normals by a sum of plane waves of wavelengths 3 to 40 edge lengths, amplitudes
    growing as wavelength^gamma: a smooth surface with detail down to 3 edge lengths and no noise."""
    V, F = icosphere(5)
    h = mean_edge_length(V, F)
    rng = np.random.default_rng(seed)
    lam = np.exp(rng.uniform(np.log(3 * h), np.log(40 * h), waves))
    d = rng.standard_normal((waves, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    f = np.cos((V @ d.T) * (2 * np.pi / lam) + rng.uniform(0, 2 * np.pi, waves)) @ (lam / (3 * h)) ** gamma
    f *= amplitude * h / np.sqrt(np.mean(f ** 2))
    return V + f[:, None] * (V / np.linalg.norm(V, axis=1)[:, None]), F, h


@pytest.fixture(scope="module")
def detail_mesh():
    return detailed_sphere(2.0)


def test_detail_without_noise_is_not_read_as_correlated_noise(detail_mesh):
    V, F, h = detail_mesh
    band = estimate_noise_model((V, F))  # the fine bands alone read the detail as noise: the problem
    assert band.correlation_length > 2 and band.rho > 0.15 * h
    v = separate_detail((V, F))
    assert v.verdict in ("detail", "ambiguous")
    assert v.model.rho < 0.05 * h  # no noise was added
    assert v.rho_band > 0.15 * h and v.model.rho < v.rho_band / 5


def test_correlated_noise_on_the_detailed_surface_is_found(detail_mesh):
    V, F, h = detail_mesh
    Vn, _ = add_scanner_noise((V, F), 0.25 * h, correlation_length=2.0, seed=3)
    v = separate_detail((Vn, F))
    assert v.verdict == "noise"
    assert v.model.rho == pytest.approx(0.25 * h, rel=0.15)
    assert v.model.correlation_length == pytest.approx(2.0, abs=0.5)


def test_independent_noise_keeps_estimate_noise_level():
    V, F = icosphere(4)
    h = mean_edge_length(V, F)
    Vn, _ = add_scanner_noise((V, F), 0.2 * h, seed=0)
    v = separate_detail((Vn, F))
    assert v.model.correlation_length == 0.0 and v.model.rho == v.rho_white
    assert v.model.rho == pytest.approx(0.2 * h, rel=0.1)


def test_a_plane_reads_no_noise():
    V, F = grid(20, 20)
    v = separate_detail((V, F))
    assert v.model.rho < 1e-12 and v.model.correlation_length == 0.0 and v.verdict == "detail"
    assert "residual is zero" in v.reason


@pytest.mark.parametrize("refine", [0, 1.5, True, "2"])
def test_bad_refine_is_refused(refine):
    with pytest.raises(ValueError, match="refine"):
        separate_detail(icosphere(1), refine=refine)


@pytest.fixture(scope="module")
def correlated_sphere():
    V, F = icosphere(4)  # 2,562 vertices
    h = mean_edge_length(V, F)
    Vn, _ = add_scanner_noise((V, F), 0.3 * h, correlation_length=1.5, seed=2)
    return Vn, F, h


def test_the_spectrum_read_with_the_noise_models_probes_is_the_detail_fits_own(correlated_sphere):
    """estimate_noise_model(spectrum=...) colours the probes once for both fits: on a whole mesh its spectrum is the one
    band_spectrum and probe_spectra read (the same white probes, coloured to 1e-8 there and 1e-5 here)."""
    from meshdenoise.tuning.detail import ELL_GRID
    from meshdenoise.tuning.noise_level import estimate_noise_and_smooth

    Vn, F, h = correlated_sphere
    model, info = estimate_noise_model((Vn, F), details=True, spectrum=(BANDS, ELL_GRID))
    assert model.correlated
    rho_white, smooth = estimate_noise_and_smooth(Vn, F, 2)
    np.testing.assert_array_equal(info["smooth"], smooth)
    N = vertex_normals(smooth, F)
    np.testing.assert_allclose(info["spectrum"]["observed"], band_spectrum(Vn, F, N, BANDS), rtol=1e-10)
    np.testing.assert_allclose(info["spectrum"]["probes"], probe_spectra(smooth, F, N, ELL_GRID, BANDS), rtol=1e-3)
    a = separate_detail((Vn, F), smooth=smooth, rho_white=rho_white, spectrum=info["spectrum"])
    b = separate_detail((Vn, F))
    assert a.verdict == b.verdict == "noise"
    assert a.model.rho == pytest.approx(b.model.rho, rel=1e-2) and a.rho_range == pytest.approx(b.rho_range, rel=2e-2)
    assert a.model.rho == pytest.approx(0.3 * h, rel=0.15) and a.model.correlation_length == pytest.approx(1.5, abs=0.5)


def test_on_a_sampled_region_the_probe_spectrum_is_the_whole_meshs_within_sampling(correlated_sphere):
    from meshdenoise.tuning.detail import ELL_GRID

    Vn, F, h = correlated_sphere
    _, whole = estimate_noise_model((Vn, F), details=True, spectrum=(BANDS, ELL_GRID))
    _, part = estimate_noise_model((Vn, F), details=True, spectrum=(BANDS, ELL_GRID), sample=2400)
    assert part["fit_vertices"] < 2000  # read on a region (8 balls, 8 rings of margin)
    np.testing.assert_array_equal(part["spectrum"]["observed"], whole["spectrum"]["observed"])  # the whole mesh's
    # the probes' median squares over ~1,300 vertices x 4 probes (balls of ~10 rings, cut) against ~2,500 x 4: within
    # 0.15 decades (0.13 here at s = 32; on face000's region of 30,000 vertices within 0.07 of the whole mesh's)
    assert np.max(np.abs(np.log10(part["spectrum"]["probes"] / whole["spectrum"]["probes"]))) < 0.15


def test_a_bad_spectrum_request_is_refused():
    from meshdenoise.tuning.detail import ELL_GRID

    with pytest.raises(ValueError, match="spectrum"):
        estimate_noise_model(icosphere(2), spectrum=((4, 2), ELL_GRID))
    V, F = icosphere(3)
    with pytest.raises(ValueError, match="lengths"):
        separate_detail((V, F), smooth=V, rho_white=0.01, spectrum={"bands": BANDS, "lengths": (0.0, 1.0),
                                                                    "observed": np.ones(len(BANDS)),
                                                                    "probes": np.ones((2, len(BANDS)))})

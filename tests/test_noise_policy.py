"""The default's noise policy where the fine bands read independent noise: the detail fit's correlation test.

Noise correlated over about one mean edge length is read as independent by the fine bands
(``estimate_noise_model``'s significance test rejects the correlation, and its level is then
``estimate_noise``'s, 0.66 of the truth on icosphere(5) with 0.25 h at l = 1). The detail fit has a
test of its own (``correlation_test``: its misfit with independent noise against its misfit with
correlated noise), which the default's ``noise_policy`` uses there. Checked against brute-force
least squares, the rule written out, and meshes with known noise: correlated over 1 (found),
independent (kept as it was), and the benchmark's own independent noise (kept). Clean meshes: the
benchmark (benchmarks/noise_model_grid.py) and tests/test_detail.py.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import nnls

import meshdenoise.default as default
from meshdenoise.noise import add_scanner_noise, mean_edge_length
from meshdenoise.shapes import icosphere
from meshdenoise.tuning.covariance import NoiseModel, estimate_noise_model
from meshdenoise.tuning.detail import (
    BANDS,
    BETA_GRID,
    CORRELATION_GAIN,
    CORRELATION_PATCHES,
    CORRELATION_RATIO,
    ELL_MIN,
    DetailVerdict,
    correlation_test,
    fit_spectrum,
    separate_detail,
)


def synthetic_probes(ells, bands):
    """Unit-variance heat-like noise spectra: tau (tau + s + 1)^-5, tau = 1 + ell^2 (a bump over the fine bands)."""
    s = np.asarray(bands, float)
    tau = 1.0 + np.asarray(ells, float) ** 2
    return tau[:, None] * (tau[:, None] + s[None, :] + 1.0) ** -5.0


def brute_best(o, p_rows, levels, bands, betas):
    """min over levels, rows and betas of the relative misfit, A >= 0 by scipy's non-negative least squares."""
    s = np.asarray(bands, float) + 1
    best = np.inf
    for value in levels:
        for row in p_rows:
            for beta in betas:
                _, res = nnls((s ** -beta / o)[:, None], 1 - value * row / o)
                best = min(best, res)
    return best


def test_the_independent_misfit_is_the_best_fit_over_the_lengths_read_as_independent():
    ells = (0.0, 0.5, 1.0, 2.0, 3.0)
    p = synthetic_probes(ells, BANDS)
    s = np.asarray(BANDS, float) + 1
    betas = BETA_GRID[::8]  # 1.0, 1.4, ..., 3.0
    assert 2.2 in betas
    o = 1e-4 * s ** -2.2 + 0.04 * p[2]  # surface plus noise of rho 0.2 at ell 1
    fit = fit_spectrum(o, p, ells, BANDS, betas)
    short = [p[g] for g, e in enumerate(ells) if e < ELL_MIN]  # ell 0 and 0.5
    assert len(short) == 2
    # the best level refined as the fit's is: no coarser than the level grid, no finer than 40 steps between neighbours
    coarse = brute_best(o, short, fit["levels"], BANDS, betas)
    j = int(np.argmin([brute_best(o, short, [x], BANDS, betas) for x in fit["levels"]]))
    near = np.linspace(fit["levels"][j - 1], fit["levels"][j + 1], 41)
    assert fit["misfit_white"] == pytest.approx(min(coarse, brute_best(o, short, near, BANDS, betas)), rel=1e-9)
    assert fit["ell"] == 1.0 and fit["misfit"] < 1e-2 and fit["misfit_white"] > 0.3
    assert correlation_test(fit["misfit"], fit["misfit_white"], fit["ell"], 10_000)
    # noise at ell 0: the best fit is among the short lengths, the two misfits are the same, no correlation
    white = fit_spectrum(1e-4 * s ** -2.2 + 0.04 * p[0], p, ells, BANDS, betas)
    assert white["ell"] < ELL_MIN and white["misfit_white"] == white["misfit"]
    assert not correlation_test(white["misfit"], white["misfit_white"], white["ell"], 10_000)
    # no length under ELL_MIN: nothing to compare with
    assert math.isnan(fit_spectrum(o, p[2:], ells[2:], BANDS, betas)["misfit_white"])


@pytest.mark.parametrize("misfit, white, ell, vertices, expected", [
    (0.20, 0.35, 1.0, 10_000, True),  # ratio 1.75, gain 0.15
    (0.30, 0.41, 1.0, 10_000, False),  # ratio 1.37 < 1.4 (gain 0.11)
    (0.02, 0.10, 1.0, 10_000, False),  # ratio 5, gain 0.08 < 0.1
    (0.20, 0.35, 0.7, 10_000, False),  # the best length is read as independent
    (0.20, 0.35, 1.0, 314, False),  # 100 pi ell^2 = 314.16 correlation areas needed
    (0.20, 0.35, 1.0, 315, True),
    (0.20, 0.35, 2.0, 1_256, False),  # 1,256.6 needed at ell 2
    (float("nan"), float("nan"), 0.0, 10_000, False),  # not fitted
])
def test_the_correlation_test_is_its_documented_rule(misfit, white, ell, vertices, expected):
    assert (CORRELATION_RATIO, CORRELATION_GAIN, CORRELATION_PATCHES, ELL_MIN) == (1.4, 0.1, 100, 0.75)
    assert correlation_test(misfit, white, ell, vertices) is expected


def _verdict(kind, model, correlated, h=1.0):
    return DetailVerdict(kind, model, 0.3, 1.0, 0.25, 1.0, 2.0, (0.22, 0.27), 1.0, 0.17, h, f"{kind}: (test)",
                         np.zeros(0), 0.1, 0.5, correlated)


def test_the_policy_takes_the_detail_fits_model_over_an_independent_reading_only_when_its_test_finds_correlation():
    V, F = icosphere(1)
    band = NoiseModel(0.17)  # the fine bands' reading: independent
    joint = NoiseModel(0.25, 1.0, V, F)
    model, reason, caveats = default.noise_policy(band, _verdict("noise", joint, True), 1.0, "independent: (why)")
    assert model is joint
    assert reason.startswith("the noise is correlated over 1 edge lengths (0.25 mean edge lengths)")
    assert "read independent noise ((why))" in reason and "misfit 0.5 independent, 0.1 correlated" in reason
    (note,) = caveats
    assert "independent noise of 0.17 mean edge lengths" in note and "--noise RHO[h][,L]" in note
    for kind, test in (("noise", False), ("ambiguous", True), ("detail", True)):  # otherwise the reading is kept
        model, reason, caveats = default.noise_policy(band, _verdict(kind, joint, test), 1.0, "independent: (why)")
        assert model is band and caveats == [] and reason.startswith("the noise is independent (0.17 mean")
    white = NoiseModel(0.2)  # a verdict whose model is independent noise changes nothing either
    assert default.noise_policy(band, _verdict("noise", white, True), 1.0)[0] is band


@pytest.fixture(scope="module")
def sphere():
    V, F = icosphere(5)  # 10,242 vertices: 100 pi correlation areas of l = 1 many times over
    return V, F, mean_edge_length(V, F)


def test_noise_correlated_over_one_edge_is_found_where_the_fine_bands_read_it_independent(sphere):
    V0, F, h = sphere
    V = add_scanner_noise((V0, F), 0.25 * h, correlation_length=1.0, seed=0)[0]
    band = estimate_noise_model((V, F))
    assert not band.correlated and band.rho < 0.75 * 0.25 * h  # the problem: read independent, at 0.66 of the level
    v = separate_detail((V, F))
    assert v.correlated and v.verdict == "noise" and v.misfit_white > 2 * v.misfit
    model, reason, caveats, decided, rho_range = default.default_noise(V, F, h)
    assert decided == "noise" and model.correlation_length == pytest.approx(1.0, abs=0.25)
    assert model.rho == pytest.approx(0.25 * h, rel=0.1)
    assert rho_range[0] <= model.rho <= rho_range[1] and len(caveats) == 1
    assert "the fine bands read independent noise" in reason


def test_independent_noise_is_read_as_before(sphere):
    V0, F, h = sphere
    V = add_scanner_noise((V0, F), 0.25 * h, correlation_length=0.0, seed=0)[0]
    assert not separate_detail((V, F)).correlated  # the test itself, on the whole mesh
    model, reason, caveats, decided, rho_range = default.default_noise(V, F, h)
    band = estimate_noise_model((V, F))
    assert decided == "independent" and model.correlation_length == 0.0 and model.rho == band.rho
    assert caveats == [] and np.all(np.isnan(rho_range))


@pytest.mark.data
def test_the_benchmarks_own_independent_noise_stays_as_it_was():
    """Fandisk0.3/Noisy: the fine bands' fit reaches 1.1 edge lengths (rejected) and the detail fit's best is at 0.8;
    its misfit is 0.047 there and 0.052 at the lengths read as independent (ratio 1.1, a gain of 0.005), so the
    reading is kept."""
    from meshdenoise.io import load_arrays

    from .conftest import data_mesh_path

    V, F = load_arrays(data_mesh_path("benchmark/Fandisk0.3/Noisy.obj"))
    h = mean_edge_length(V, F)
    band, info = estimate_noise_model((V, F), details=True)
    assert not band.correlated and info["ell_fit"] >= 0.75
    v = separate_detail((V, F), smooth=info["smooth"], rho_white=info["rho_white"])
    assert not v.correlated and v.misfit_white < 1.2 * v.misfit and v.misfit_white - v.misfit < CORRELATION_GAIN / 4
    model, _, _, decided, _ = default.default_noise(V, F, h)
    assert decided == "independent" and model.rho == band.rho and model.correlation_length == 0.0


def test_a_small_box_with_independent_noise_is_kept_by_the_count_of_correlation_areas():
    """box(10), 488 vertices, 0.3 h of independent noise: the fine bands' fit reaches 1.7 edge lengths (rejected); the
    detail fit's best is 0.95 h at 1.6 with a misfit 1.7 times smaller than independent noise's (its power-law surface
    does not fit a box's flat faces and sharp edges), but 488 vertices hold fewer than 100 areas pi 1.6^2 (804)."""
    from meshdenoise.shapes import box

    V, F = box(10)
    h = mean_edge_length(V, F)
    Vn = add_scanner_noise((V, F), 0.3 * h, seed=0)[0]
    band, info = estimate_noise_model((Vn, F), details=True)
    assert not band.correlated and info["ell_fit"] >= 0.75
    v = separate_detail((Vn, F), smooth=info["smooth"], rho_white=info["rho_white"])
    assert V.shape[0] < CORRELATION_PATCHES * math.pi * v.ell_joint ** 2
    assert correlation_test(v.misfit, v.misfit_white, v.ell_joint, 10 ** 6) and not v.correlated  # the count decides
    model, _, caveats, decided, _ = default.default_noise(Vn, F, h)
    assert decided == "independent" and model.rho == band.rho and caveats == []


def test_the_probe_spectra_read_on_a_sampled_region_are_the_whole_meshs_within_sampling():
    """region_probe_spectra (the default's detail fit above 30,000 vertices) against probe_spectra on the whole mesh,
    and the detail fit's test with it."""
    from meshdenoise.geometry import vertex_normals
    from meshdenoise.operators import get_operators
    from meshdenoise.tuning.detail import ELL_GRID, probe_spectra, region_probe_spectra
    from meshdenoise.tuning.noise_level import estimate_noise_and_smooth

    V, F = icosphere(4)  # 2,562 vertices
    h = mean_edge_length(V, F)
    Vn = add_scanner_noise((V, F), 0.3 * h, correlation_length=1.5, seed=2)[0]
    rho_white, smooth = estimate_noise_and_smooth(Vn, F, 2)
    N = vertex_normals(smooth, F)
    ok = ~get_operators(F, V.shape[0]).isolated
    assert region_probe_spectra(smooth, F, N, ok, 3000) is None  # small enough: read whole
    part = region_probe_spectra(smooth, F, N, ok, 2400)
    whole = probe_spectra(smooth, F, N, ELL_GRID, BANDS, ok)
    assert part.shape == whole.shape == (len(ELL_GRID), len(BANDS))
    assert np.max(np.abs(np.log10(part / whole))) < 0.15  # as the noise model's own region (tests/test_detail.py)
    a = separate_detail((Vn, F), smooth=smooth, rho_white=rho_white, sample=2400)
    b = separate_detail((Vn, F), smooth=smooth, rho_white=rho_white)
    assert a.model.rho == pytest.approx(b.model.rho, rel=0.1) and a.correlated == b.correlated
    with pytest.raises(ValueError, match="sample"):
        separate_detail((Vn, F), sample=0)

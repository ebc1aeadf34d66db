"""The detail fit's correlation test, where the fine bands read independent noise.

Noise correlated over about one mean edge length is read as independent by the fine bands
(``estimate_noise_model``'s significance test rejects the correlation, and its level is then
``estimate_noise``'s, 0.66 of the truth on icosphere(5) with 0.25 h at l = 1). The detail fit has a
test of its own (``correlation_test``: its misfit with independent noise against its misfit with
correlated noise). Checked against brute-force least squares, the rule written out, and probe spectra read
on a sampled region against the whole mesh's. Clean meshes: tests/test_detail.py.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import nnls

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

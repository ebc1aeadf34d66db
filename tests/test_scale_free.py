"""Scale-free filters commute with scaling, even at 1e200 and 1e-200."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import meshdenoise as md
from meshdenoise.registry import power_of_two_scale
from meshdenoise.shapes import icosphere

CASES = [("sobolev_normal", {"mu": 0.5}), ("sobolev_gls", {"mu": 0.5, "beta": 5.0}), ("two_stage", {})]


@pytest.mark.parametrize("method, params", CASES, ids=[c[0] for c in CASES])
@pytest.mark.parametrize("scale", [1e80, 1e-80, 1e200, 1e-200, 3.7])
def test_scale_free_filters_commute_with_scaling(method, params, scale):
    V, F = icosphere(3)
    Vn, _ = md.add_normal_noise((V, F), rho=0.02, seed=0)
    base = md.apply_filter(method, (Vn, F), **params)[0]
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no overflow / underflow warning
        out = md.apply_filter(method, (Vn * scale, F), **params)[0]
    np.testing.assert_allclose(out / scale, base, rtol=0, atol=1e-12 * np.abs(base).max())


def test_scale_free_filters_are_declared():
    assert {s.name for s in md.list_filters() if s.scale_free} >= {m for m, _ in CASES}


def test_power_of_two_scaling_is_exact():
    rng = np.random.default_rng(1)
    V = rng.standard_normal((50, 3)) * 123.4
    s = power_of_two_scale(V)
    assert s == 2.0 ** round(np.log2(np.ptp(V, axis=0).max()))
    assert np.array_equal((V / s) * s, V)

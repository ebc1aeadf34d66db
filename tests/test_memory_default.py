"""Memory work on the default (issue 17): the copy-free paths give the public adapter's results bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

import meshdenoise as md
from meshdenoise import default
from meshdenoise.geometry import vertex_normals
from meshdenoise.operators import get_operators
from meshdenoise.registry import get_filter
from meshdenoise.shapes import box, icosphere
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

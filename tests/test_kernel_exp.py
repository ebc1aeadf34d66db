"""The pair kernels' cheaper arithmetic against exact numpy: one exponential a pair, FMA, half the spacings.

``bilateral_spatial_pass`` takes one exponential of the summed exponents where it took two, the pair
kernels multiply by reciprocals and contract products and sums into FMAs, and
``centroid_spacing_sums`` visits each unordered pair once. Each must agree with numpy's ``np.exp``
and full sums to a few ulps, a weight deep in the tail must be 0 (not garbage), and ``two_stage``'s
result must stay within 1e-11 of the extent of the numpy code's (the issue's bound is 1e-9).
"""

from __future__ import annotations

import numpy as np
import pytest

from meshdenoise import add_normal_noise, kernels
from meshdenoise.geometry import face_areas, face_normals
from meshdenoise.normal_filter import face_neighbourhood
from meshdenoise.operators import Operators
from meshdenoise.plugins.two_stage import two_stage
from meshdenoise.shapes import box, icosphere

from . import reference_two_stage as ref
from .test_two_stage_kernel import MESHES


def pair_arrays(V, F):
    nb = face_neighbourhood(Operators(F, len(V)))
    N, A, C = face_normals(V, F), face_areas(V, F), V[F].mean(1)
    return nb, N, A, C


@pytest.fixture(params=sorted(MESHES))
def mesh(request):
    return MESHES[request.param]()


def test_the_face_pairs_are_symmetric_with_sorted_rows(mesh):
    """What centroid_spacing_sums relies on to visit each unordered pair once (from the row of its smaller face)."""
    V, F = mesh
    nb = face_neighbourhood(Operators(F, len(V)))
    rows = np.repeat(np.arange(len(F)), np.diff(nb.indptr))
    assert np.all((np.diff(nb.indices) > 0) | (np.diff(rows) > 0))  # strictly increasing within each row
    forward = set(zip(rows.tolist(), nb.indices.tolist()))
    assert forward == {(j, i) for i, j in forward}


def test_spacing_sums_visit_each_pair_once_and_give_the_full_mean(mesh):
    V, F = mesh
    nb, _, _, C = pair_arrays(V, F)
    rows = np.repeat(np.arange(len(F)), np.diff(nb.indptr))
    off = rows != nb.indices
    full = np.linalg.norm(C[rows[off]] - C[nb.indices[off]], axis=1)
    sums = np.empty(len(F))
    count = kernels.centroid_spacing_sums(C, nb.indptr, nb.indices, sums)
    assert count == off.sum()
    assert sums.sum() / count == pytest.approx(full.mean(), rel=1e-14, abs=0)
    # each face's value: twice its distances to the neighbours of larger index
    upper = rows < nb.indices
    twice = 2.0 * np.bincount(rows[upper], weights=full[upper[off]], minlength=len(F))
    np.testing.assert_allclose(sums, twice, rtol=1e-14, atol=0)


def numpy_pass(N, C, A, nb, denom_s, denom_r):
    """The fused pass in numpy: two exact exponentials a pair, as the reference code weights."""
    rows = np.repeat(np.arange(len(N)), np.diff(nb.indptr))
    cols = nb.indices
    d2 = ((C[rows] - C[cols]) ** 2).sum(1)
    e2 = ((N[rows] - N[cols]) ** 2).sum(1)
    w = A[cols] * np.exp(-d2 / denom_s) * np.exp(-e2 / denom_r)
    out = np.zeros_like(N)
    for d in range(3):
        out[:, d] = np.bincount(rows, weights=w * N[cols, d], minlength=len(N))
    norm = np.linalg.norm(out, axis=1, keepdims=True)
    return np.divide(out, norm, out=np.zeros_like(out), where=norm > 0)


@pytest.mark.parametrize("sigma_r", [0.2, 0.35, 2.0])
@pytest.mark.parametrize("sigma_s", [0.3, 1.0, 4.0])
def test_the_fused_pass_with_one_exponential_matches_two_exact_ones(mesh, sigma_r, sigma_s):
    V, F = mesh
    nb, N, A, C = pair_arrays(V, F)
    rows = np.repeat(np.arange(len(F)), np.diff(nb.indptr))
    spacing = np.linalg.norm(C[rows] - C[nb.indices], axis=1).mean()
    ds, dr = 2.0 * (sigma_s * spacing) ** 2, 2.0 * sigma_r**2
    out = np.empty_like(N)
    kernels.bilateral_spatial_pass(N, N, C, A, nb.indptr, nb.indices, ds, dr, out)
    np.testing.assert_allclose(out, numpy_pass(N, C, A, nb, ds, dr), rtol=0, atol=1e-14)


def test_the_exponential_with_fma_is_within_one_ulp_of_numpys_and_zero_below_its_floor():
    """exp_nonpositive as the pair kernels compile it (FMA contraction, ``PAIR_MATH``)."""
    from meshdenoise.kernels import EXP_FLOOR, exp_nonpositive, njit

    @njit(fastmath=kernels.PAIR_MATH)
    def contracted(buf):
        exp_nonpositive(buf, buf.size)

    rng = np.random.default_rng(3)
    x = -np.concatenate([rng.random(200_000) * 30, rng.random(20_000) * -EXP_FLOOR, np.logspace(-300, 2.8, 2_000),
                         [0.0, 5e-324, 1e-17, 0.5 * np.log(2), np.log(2), 699.99]])
    y = x.copy()
    contracted(y)
    exact = np.exp(x)
    assert np.all(np.abs(y - exact) <= np.spacing(exact)), np.max(np.abs(y - exact) / np.spacing(exact))
    below = np.array([EXP_FLOOR - 1e-9, -745.0, -1e300, -np.inf])
    contracted(below)
    np.testing.assert_array_equal(below, 0.0)


def test_a_weight_deep_in_the_tail_is_zero_not_garbage():
    """With a spatial scale far below the spacing every exponent but a face's own is under -700: weight 0, so each
    face keeps its own normal (and the guided kernel's spatial weights are exactly 0 off the diagonal)."""
    V, F = icosphere(2)
    V = add_normal_noise((V, F), 0.02, seed=1)[0]
    nb, N, A, C = pair_arrays(V, F)
    out = np.empty_like(N)
    for ds, dr in ((1e-12, 0.245), (1e-300, 8.0), (0.1, 1e-9)):
        kernels.bilateral_spatial_pass(N, N, C, A, nb.indptr, nb.indices, ds, dr, out)
        same = np.ones(len(F), bool) if dr > 1e-6 else np.zeros(len(F), bool)
        if dr < 1e-6:  # the range tail: the faces whose neighbours all turn by more than a hair keep their own normal
            rows = np.repeat(np.arange(len(F)), np.diff(nb.indptr))
            e2 = ((N[rows] - N[nb.indices]) ** 2).sum(1)
            same = np.bincount(rows, weights=(e2 / dr < 700) & (rows != nb.indices), minlength=len(F)) == 0
        # unit(A_i n_i): n_i to rounding, where a garbage weight of a neighbour would turn it
        np.testing.assert_allclose(out[same], N[same], rtol=0, atol=4e-16)
        assert same.any()
    S = np.empty(nb.indices.size)
    kernels.spatial_weights(C, A, nb.indptr, nb.indices, 1e-12, S)
    rows = np.repeat(np.arange(len(F)), np.diff(nb.indptr))
    np.testing.assert_array_equal(S[rows != nb.indices], 0.0)
    np.testing.assert_array_equal(S[rows == nb.indices], A)


def test_the_guided_kernels_match_exact_exponentials():
    V, F = MESHES["box"]()
    nb, N, A, C = pair_arrays(V, F)
    rows = np.repeat(np.arange(len(F)), np.diff(nb.indptr))
    S = np.empty(nb.indices.size)
    kernels.spatial_weights(C, A, nb.indptr, nb.indices, 0.01, S)
    exact = A[nb.indices] * np.exp(-((C[rows] - C[nb.indices]) ** 2).sum(1) / 0.01)
    np.testing.assert_allclose(S, exact, rtol=4e-16 * 700, atol=0)  # an ulp of the exponent, at most 700
    assert np.abs(S - exact).max() <= 2e-15 * exact.max()
    out = np.empty_like(N)
    kernels.bilateral_pass(N, N, S, nb.indptr, nb.indices, 0.245, out)
    w = S * np.exp(-((N[rows] - N[nb.indices]) ** 2).sum(1) / 0.245)
    expected = np.stack([np.bincount(rows, weights=w * N[nb.indices, d]) for d in range(3)], 1)
    expected /= np.linalg.norm(expected, axis=1, keepdims=True)
    np.testing.assert_allclose(out, expected, rtol=0, atol=1e-14)


@pytest.mark.parametrize("shape", ["sphere", "elephant"])
def test_two_stage_stays_within_1e_11_of_the_extent_of_the_exact_exponentials(shape, request):
    """The default's run (one fused pass an outer iteration) against the numpy code with numpy's ``np.exp``."""
    if shape == "sphere":
        V, F = icosphere(4)
        V = add_normal_noise((V, F), 0.01, seed=2)[0]
    else:
        V, F = request.getfixturevalue("elephant")
        V = add_normal_noise((V, F), 0.004, seed=0)[0]  # about half the mean edge length (0.0077)
    params = dict(iterations=4, normal_iterations=1, vertex_iterations=5, sigma_r=2.0, sigma_s=1.0,
                  guidance="bilateral")
    got = two_stage((V, F), **params)[0]
    expected = ref.reference_two_stage(V, F, **params)
    extent = float(np.max(V.max(0) - V.min(0)))
    assert np.abs(got - V).max() > 1e-4 * extent  # it moved
    assert np.abs(got - expected).max() <= 1e-11 * extent


def test_box_faces_meeting_at_right_angles_weigh_exp_minus_one_over_sigma_r_squared():
    """An exact case: the range weight of two unit normals at 90 degrees is exp(-2 / (2 sigma_r^2))."""
    V, F = box(2)
    nb, N, A, C = pair_arrays(V, F)
    out = np.empty_like(N)
    kernels.bilateral_spatial_pass(N, N, C, A, nb.indptr, nb.indices, 1e300, 1.0, out)
    np.testing.assert_allclose(out, numpy_pass(N, C, A, nb, 1e300, 1.0), rtol=0, atol=1e-15)

"""The cheaper noise estimates against the computations they replace.

- ``_normal_residual_scale`` / ``_residual_energy_scale`` without per-entry gathers: equal to the
  old COO-and-gather computation (kept here as the reference) to rounding;
- ``estimate_noise_model`` on a sampled region: the whole mesh when it is small (bit-identical
  to ``sample`` >= n), and close to the whole-mesh fit when a region is used;
- :class:`~meshdenoise.tuning.region.SampledRegion`: its balls, faces and inner vertices
  against a breadth-first search written out here.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.sparse as sp

import meshdenoise as md
from meshdenoise import add_normal_noise
from meshdenoise.geometry import vertex_normals
from meshdenoise.noise import add_scanner_noise, mean_edge_length
from meshdenoise.operators import Operators, get_operators
from meshdenoise.shapes import grid, icosphere, torus
from meshdenoise.tuning import noise_level as nl
from meshdenoise.tuning.covariance import estimate_noise_model
from meshdenoise.tuning.region import SampledRegion, ring_distance


def _old_normal_residual_scale(V, ops, N):
    """The computation before: B as COO, normals gathered per entry, row sums by bincount."""
    n = ops.n
    B = nl.fourth_difference(ops).tocoo()
    g = np.einsum("ij,ij->i", N[B.row], N[B.col])
    c = np.sqrt(np.bincount(B.row, weights=(B.data * g) ** 2, minlength=n))
    r = np.einsum("ij,ij->i", np.asarray(B.tocsr() @ V), N)
    ok = (c > 1e-12) & ~ops.isolated & (np.linalg.norm(N, axis=1) > 0)
    t = r[ok] / c[ok]
    mad = float(np.median(np.abs(t)) / nl.MAD)
    m2, m4 = nl._gauss_winsor_moments(nl.WINSOR_K)
    w = np.minimum(t**2, (nl.WINSOR_K * mad) ** 2)
    winsor = float(np.sqrt(np.mean(w) / m2))
    excess = (float(np.mean(w**2) / np.mean(w) ** 2) - m4 / m2**2) / math.sqrt(24.0 / t.size)
    return c, (mad, winsor, excess)


def _meshes():
    V, F = icosphere(4)
    yield "sphere", add_normal_noise((V, F), 0.01, seed=1)[0], F
    V, F = grid(30, 20)  # open borders
    V = V + 0.002 * np.random.default_rng(2).standard_normal(V.shape)
    yield "grid", V, F
    V, F = torus(40, 16)
    V = np.vstack([V, [[9.0, 9.0, 9.0]]])  # an isolated vertex
    yield "torus+isolated", add_normal_noise((V, F), 0.02, seed=3)[0], F


@pytest.mark.parametrize("case", list(_meshes()), ids=lambda c: c[0])
def test_normal_residual_scale_equals_the_gathered_computation(case):
    _, V, F = case
    ops = Operators(F, V.shape[0])
    N = vertex_normals(V, F)
    c_old, old = _old_normal_residual_scale(V, ops, N)
    B = nl.fourth_difference(ops)
    c_new = np.sqrt(nl._normal_weight_sums(B, N))
    np.testing.assert_allclose(c_new, c_old, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(nl._normal_residual_scale(V, ops, N, B), old, rtol=1e-10)
    c2 = np.asarray(B.multiply(B).sum(axis=1)).ravel()
    ok = (c2 > 1e-24) & ~ops.isolated
    R = np.asarray(B @ V)
    old_energy = float(np.sqrt(np.mean(np.sum(R[ok] ** 2, axis=1) / c2[ok])))
    assert nl._residual_energy_scale(V, ops, B) == pytest.approx(old_energy, rel=1e-12)


def test_fourth_difference_is_the_squared_averaging_difference_and_the_estimate_keeps_nothing_on_the_operators():
    V, F = icosphere(3)
    Vn = md.add_normal_noise((V, F), 0.01, seed=0)[0]
    ops = get_operators(F, V.shape[0])
    A = np.eye(ops.n) - ops.P.toarray()
    np.testing.assert_allclose(nl.fourth_difference(ops).toarray(), A @ A, atol=1e-14)
    before = set(ops.cache)
    md.estimate_noise((Vn, F))
    assert set(ops.cache) == before  # 220 bytes per vertex not kept after the call


def _bfs(W, sources, n):
    """Ring distances by a plain breadth-first search over adjacency lists."""
    W = sp.csr_matrix(W)
    dist = np.full(n, np.inf)
    frontier = list(sources)
    for s in frontier:
        dist[s] = 0
    d = 0
    while frontier:
        d += 1
        nxt = []
        for v in frontier:
            for u in W.indices[W.indptr[v]:W.indptr[v + 1]]:
                if dist[u] == np.inf:
                    dist[u] = d
                    nxt.append(u)
        frontier = nxt
    return dist


def test_sampled_region_against_breadth_first_search():
    V, F = icosphere(4)
    ops = get_operators(F, V.shape[0])
    region = SampledRegion(F, ops, 700, 3, 2, seed=5)
    assert not region.whole and region.vertices.size >= 700
    inside = np.zeros(ops.n, dtype=bool)
    inside[region.vertices] = True
    # balls: the vertices within the common radius of a seed, the smallest radius holding 700
    dist = _bfs(ops.W, region.seeds, ops.n)
    assert region.seeds.size == 3 and region.radius > 0
    ball = dist <= region.radius
    np.testing.assert_array_equal(inside, np.isin(np.arange(ops.n), F[ball[F].all(axis=1)]))
    assert np.count_nonzero(dist <= region.radius - 1) < 700
    faces = F[inside[F].all(axis=1)]
    np.testing.assert_array_equal(region.vertices[region.F], faces)
    # inner: more than `margin` rings (inside the region) from a vertex with a neighbour outside
    cut = np.flatnonzero(inside & (ops.W @ (~inside).astype(float) > 0))
    sub = sp.csr_matrix(ops.W)[region.vertices][:, region.vertices]
    number = np.full(ops.n, -1)
    number[region.vertices] = np.arange(region.vertices.size)
    d = _bfs(sub, number[cut], region.vertices.size)
    np.testing.assert_array_equal(region.inner, d > 2)
    np.testing.assert_array_equal(region.scored, region.inner[region.F].all(axis=1))
    small = SampledRegion(F, ops, ops.n, 3, 2)
    assert small.whole and small.inner.all() and small.vertices.size == ops.n


def test_ring_distance_equals_breadth_first_search():
    V, F = grid(12, 9)
    ops = get_operators(F, V.shape[0])
    np.testing.assert_array_equal(ring_distance(ops.W, [0, 50]), _bfs(ops.W, [0, 50], ops.n))
    limited = ring_distance(ops.W, [0], 3)
    full = _bfs(ops.W, [0], ops.n)
    np.testing.assert_array_equal(limited[full <= 3], full[full <= 3])
    assert np.all(np.isinf(limited[full > 3]))


def _scanner(ell, seed=0, shape="sphere"):
    if shape == "sphere":
        V, F = icosphere(5)  # 10,242 vertices
    else:  # an open, curved sheet of 10,000 vertices: a border, where the model's noise is stronger
        V, F = grid(100, 100)
        V[:, 2] = 0.3 * np.sin(3.0 * V[:, 0]) * np.cos(2.0 * V[:, 1])
    h = mean_edge_length(V, F)
    return add_scanner_noise((V, F), 0.3 * h, correlation_length=ell, seed=seed)[0], F


def test_noise_model_whole_mesh_when_small_is_the_full_fit():
    Vn, F = _scanner(2.0)
    a, ia = estimate_noise_model((Vn, F), details=True, sample=Vn.shape[0])
    b, ib = estimate_noise_model((Vn, F), details=True, sample=10**9)
    assert (a.rho, a.correlation_length) == (b.rho, b.correlation_length)
    np.testing.assert_array_equal(ia["log_rho"], ib["log_rho"])
    assert ia["fit_vertices"] == Vn.shape[0]


@pytest.mark.parametrize("ell, shape", [(0.0, "sphere"), (2.0, "sphere"), (2.0, "sheet")])
def test_noise_model_on_a_sampled_region_keeps_the_full_fit(ell, shape):
    """A region of 6,000 of the 10,242 vertices (about 4,000 counted): the same reading (independent or
    correlated), the correlation length and the level within 5 % of the whole-mesh fit (whose own spread
    over probe seeds is 1.7 % on this mesh)."""
    Vn, F = _scanner(ell, shape=shape)
    full, info_full = estimate_noise_model((Vn, F), details=True, sample=10**9)
    part, info_part = estimate_noise_model((Vn, F), details=True, sample=6000)
    assert info_part["fit_vertices"] < 6000 < info_full["fit_vertices"]
    assert (full.correlation_length > 0) == (part.correlation_length > 0) == (ell > 0)
    assert part.rho == pytest.approx(full.rho, rel=0.05)
    if ell > 0:
        assert part.correlation_length == pytest.approx(full.correlation_length, rel=0.05)
    else:
        assert part.rho == full.rho  # independent: the white-noise level, read on the whole mesh


def test_noise_model_rejects_a_bad_sample():
    V, F = icosphere(2)
    with pytest.raises(ValueError, match="sample"):
        estimate_noise_model((V, F), sample=0)


def test_noise_model_keeps_coloured_probes_equal_to_a_fresh_colouring():
    from meshdenoise.tuning.covariance import NoiseModel

    V, F = icosphere(3)
    model = NoiseModel(0.01, 2.0, V, F)
    Z = np.random.default_rng(0).choice([-1.0, 1.0], size=(V.shape[0], 5))
    first = model.colour(Z, 0.2)
    first[0, 0] = 1e9  # the caller's copy: changing it does not change what is kept
    again = model.colour(Z, 0.2)
    fresh = NoiseModel(0.01, 2.0, V, F).colour(Z, 0.2)
    np.testing.assert_array_equal(again, fresh)
    assert len(model._coloured) == 1
    np.testing.assert_array_equal(model.colour(Z, 0.1), NoiseModel(0.01, 2.0, V, F).colour(Z, 0.1))  # s is in the key
    assert len(model._coloured) == 2
    model.clear()
    assert not model._coloured


def test_weighted_median_and_nearest_stratum():
    from meshdenoise.tuning.covariance import _nearest_present, _weighted_median

    x = np.random.default_rng(0).standard_normal(101)
    assert _weighted_median(x, np.ones(101)) == np.median(x)
    w = np.random.default_rng(1).integers(1, 5, size=101)
    w[0] += 1 - w.sum() % 2  # an odd total weight: np.median's middle value, no average of two
    assert _weighted_median(x, w.astype(float)) == np.median(np.repeat(x, w))  # odd total weight: the middle value
    present = np.array([False, True, False, False, True, False, False])
    np.testing.assert_array_equal(_nearest_present(present), [1, 1, 1, 4, 4, 4, 4])  # ties to the lower
    np.testing.assert_array_equal(_nearest_present(np.array([False, True, False])), [1, 1, 1])


# --- the noise model's probes of every correlation length from one Krylov space ------------------------------
def _dense_heat(V, F, length, Z):
    """HeatFilter written out densely: diag(s) Z, then HEAT_STEPS implicit steps (M + tau/k L) u' = M u."""
    from meshdenoise.noise import HEAT_STEPS, heat_geometry

    h, mass, L = heat_geometry(V, F)
    surface = mass > 2e-9 * mass[mass > 0].mean()
    s = np.where(surface, np.sqrt(mass[surface].mean() / mass), 0.0)
    A = np.diag(mass) + ((length * h) ** 2 / 8.0 / HEAT_STEPS) * L.toarray()
    u = s[:, None] * Z
    for _ in range(HEAT_STEPS):
        u = np.linalg.solve(A, mass[:, None] * u)
    return u


def test_heat_krylov_equals_the_dense_heat_filter_for_every_length_in_any_order():
    from meshdenoise.noise import HeatKrylov

    V, F = grid(12, 10)  # open borders, and a vertex on no face (a range map's unreferenced sample)
    V = np.vstack([V + 0.01 * np.random.default_rng(0).standard_normal(V.shape), [[5.0, 5.0, 1.0]]])
    Z = np.random.default_rng(1).standard_normal((V.shape[0], 3))
    family = HeatKrylov(V, F, Z, tol=1e-10)
    for length in (6.0, 0.5, 2.3, 0.5, 4.0):  # longest first: the shorter ones read the same space
        Y = family(length)
        ref = _dense_heat(V, F, length, Z)
        np.testing.assert_allclose(Y, ref, rtol=0, atol=1e-8 * np.abs(ref).max())
        assert np.all(Y[-1] == 0)  # the unreferenced vertex gets no noise
    assert family.fallbacks == 0


@pytest.mark.parametrize("tol", [1e-5, 1e-8])
def test_heat_krylov_is_within_its_tolerance_of_a_tightly_solved_heat_filter(tol):
    """icosphere(4) (2,562 vertices, a Krylov space far from exhausted): every column within tol of HeatFilter
    solved to 1e-12, for the noise model's lengths; the basis is float32 from tol 1e-6 up."""
    from meshdenoise.noise import HeatFilter, HeatKrylov, diffusion_length

    V, F = icosphere(4)
    Z = np.random.default_rng(2).standard_normal((V.shape[0], 4))
    family = HeatKrylov(V, F, Z, tol=tol)
    for ell in (0.5, 2.0, 6.0, 1.0):
        d = diffusion_length(ell)
        ref = HeatFilter(V, F, d)(Z, tol=1e-12)
        err = np.linalg.norm(family(d) - ref, axis=0) / np.linalg.norm(ref, axis=0)
        assert err.max() < tol, (ell, err)
    assert family.fallbacks == 0 and family.steps < 128


def test_heat_krylov_falls_back_to_cg_for_lengths_it_cannot_settle():
    from meshdenoise.noise import HeatFilter, HeatKrylov

    V, F = icosphere(3)
    Z = np.random.default_rng(3).standard_normal((V.shape[0], 2))
    family = HeatKrylov(V, F, Z, tol=1e-5, max_steps=8)  # far too few steps for a length of 6 edges
    np.testing.assert_array_equal(family(6.0), HeatFilter(V, F, 6.0)(Z, tol=1e-5))
    assert family.fallbacks == 1 and family.steps == 8
    with pytest.raises(ValueError, match="tol"):
        HeatKrylov(V, F, Z, tol=0.0)
    with pytest.raises(ValueError, match="length"):
        family(-1.0)


class _PerLengthHeatFilters:
    """The fit's colouring by a HeatFilter per length (CG solves), as a drop-in for HeatKrylov, to FIT_TOL."""

    def __init__(self, V, F, Z, *, geometry=None, tol=1e-5):
        self.args = (V, F, Z, geometry, tol)

    def __call__(self, length):
        from meshdenoise.noise import HeatFilter

        V, F, Z, geometry, tol = self.args
        return HeatFilter(V, F, length, geometry)(Z, tol=tol)


@pytest.mark.parametrize("sample", [None, 6000])
def test_noise_model_from_one_krylov_space_keeps_the_per_length_estimate(sample, monkeypatch):
    """The same chosen length, level and band spectrum as the per-length heat filters (whose own CG error,
    4e-5 relative, is the larger one), on the whole mesh and on a sampled region."""
    from meshdenoise.tuning import covariance

    # the bands (s of (I - P)^2 P^s) and the correlation lengths (edge lengths) of the spectrum this test reads
    BANDS = (0, 1, 2, 4, 8, 16, 32, 64)
    ELL_GRID = (0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0, 5.0)

    Vn, F = _scanner(2.0)
    kw = dict(details=True, spectrum=(BANDS, ELL_GRID), **({} if sample is None else {"sample": sample}))
    new, info_new = estimate_noise_model((Vn, F), **kw)
    monkeypatch.setattr(covariance, "HeatKrylov", _PerLengthHeatFilters)
    old, info_old = estimate_noise_model((Vn, F), **kw)
    assert new.correlated and old.correlated
    assert (info_new["fit_vertices"] < Vn.shape[0]) == (sample is not None)
    assert info_new["grid"].size == info_old["grid"].size
    assert new.correlation_length == pytest.approx(old.correlation_length, abs=1e-3)
    assert new.rho == pytest.approx(old.rho, rel=1e-4)
    # a median of squares moves to a neighbouring sample when the probes move by the old CG error (4e-5 relative)
    np.testing.assert_allclose(info_new["log_rho"], info_old["log_rho"], rtol=0, atol=5e-4)
    np.testing.assert_allclose(info_new["spectrum"]["probes"], info_old["spectrum"]["probes"], rtol=1e-3)


def test_noise_model_with_a_sample_too_small_for_its_margin_fits_the_whole_mesh():
    # 8 balls of ~190 vertices each lie within 8 rings of a cut: no vertex to read (an IndexError before)
    Vn, F = _scanner(2.0)
    small, info = estimate_noise_model((Vn, F), details=True, sample=1500)
    whole, info_whole = estimate_noise_model((Vn, F), details=True, sample=10**9)
    assert info["fit_vertices"] == info_whole["fit_vertices"] == Vn.shape[0]
    assert (small.rho, small.correlation_length) == (whole.rho, whole.correlation_length)


@pytest.mark.parametrize("ell", [0.0, 2.0])
def test_noise_model_under_correlated_noise_leaves_no_averaging_run_behind(ell):
    """tracemalloc: after estimate_noise_model returns (the model kept, the topology's matrices built before),
    a correlated reading holds nothing of estimate_noise's averaging runs (white probes, which no rule under the
    correlated model reads): only the model's smoothed mesh (n, 3); with release=False the memo keeps the run's
    (n, 7) state, (n, 4) probes and copy of V, so the check can fail. Independent noise keeps them (the rules read them)."""
    import gc
    import tracemalloc

    from meshdenoise.operators import clear_cache
    from meshdenoise.tuning.memo import MEMO

    Vn, F = _scanner(ell)
    n = Vn.shape[0]
    held, paths = {}, {}
    for release in (True, False):
        clear_cache()
        MEMO.clear()
        ops = get_operators(F, n)
        ops.P, ops.edges, ops.boundary_vertices  # the topology's matrices, as a caller holds them
        gc.collect()
        tracemalloc.start()
        before = tracemalloc.get_traced_memory()[0]
        model = estimate_noise_model((Vn, F), release=release)
        gc.collect()
        held[release] = tracemalloc.get_traced_memory()[0] - before
        tracemalloc.stop()
        paths[release] = sum(1 for key in MEMO if key[:1] == ("path",))
        assert model.correlated == (ell > 0)
    curve = (7 + 4 + 3) * 8 * n  # an averaging run in the memo: state, probes, V
    if ell > 0:
        assert paths == {True: 0, False: 1}
        assert held[True] < 24 * n + 16 * n + 65536, held  # the smoothed mesh; degrees and masks of the topology
        assert held[False] > held[True] + curve, held
    else:
        assert paths == {True: 1, False: 1}
        assert abs(held[True] - held[False]) < 65536, held
    with pytest.raises(TypeError, match="release"):
        estimate_noise_model((Vn, F), release="yes")


def test_heat_krylov_on_a_tiny_mesh_exhausts_its_space_exactly_and_keeps_zero_columns_zero():
    from meshdenoise.noise import HeatKrylov

    V, F = icosphere(0)  # 12 vertices: the Krylov space of a column is at most 12-dimensional
    Z = np.random.default_rng(4).standard_normal((12, 3))
    Z[:, 1] = 0.0
    family = HeatKrylov(V, F, Z, tol=1e-8)  # a float64 basis (float32 from tol 1e-6: 6e-8 of rounding)
    for length in (3.0, 0.7):
        Y = family(length)
        ref = _dense_heat(V, F, length, Z)
        np.testing.assert_allclose(Y, ref, rtol=0, atol=1e-11 * np.abs(ref).max())
        assert np.all(Y[:, 1] == 0)
    assert family.exhausted and family.steps <= 12 and family.fallbacks == 0

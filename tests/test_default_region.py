"""The default's estimates on a sampled region of a large mesh (default.RiskRegion, REGION_FROM)."""

from __future__ import annotations

import numpy as np
import pytest

import meshdenoise as md
from meshdenoise import default
from meshdenoise.geometry import vertex_normals
from meshdenoise.operators import get_operators
from meshdenoise.shapes import box, icosphere, torus
from meshdenoise.tuning.covariance import NoiseModel
from meshdenoise.tuning.region import ring_distance


def _mask(n: int, seed: int) -> np.ndarray:
    rows = np.random.default_rng(seed).random(n) < 0.6
    rows[0] = True
    return rows


def test_feature_risk_on_rows_is_monte_carlo_sure_summed_over_those_rows_written_out():
    V, F = box(5)
    rho = 0.02
    Vn = md.add_normal_noise((V, F), rho, seed=1)[0]
    N = vertex_normals(V, F)
    rows = _mask(len(V), 0)
    params = {"iterations": 2, "sigma_r": 0.3, "keep_tangential": True}
    risk, out = default.feature_risk(Vn, F, params, NoiseModel(rho), N, probes=3, seed=7, rows=rows)
    f = lambda X: md.apply_filter("two_stage", (X, F), **params)[0]  # noqa: E731
    np.testing.assert_array_equal(out, f(Vn))  # the whole result, whatever is scored
    rng = np.random.default_rng(7)
    Z = np.stack([rng.choice([-1.0, 1.0], size=len(V)) for _ in range(3)], axis=1)
    d = 0.1 * rho
    div = [float(np.sum((b * (f(Vn + d * b) - f(Vn)))[rows])) / d for b in (Z[:, k, None] * N for k in range(3))]
    expected = np.sum((f(Vn) - Vn)[rows] ** 2) - rows.sum() * rho**2 + 2 * rho**2 * np.mean(div)
    assert risk == pytest.approx(expected, rel=1e-12)
    # the default probe count follows the rows scored, not the mesh: 30,000 / 130 rows -> the upper bound 16
    with pytest.raises(ValueError, match="boolean mask"):
        default.feature_risk(Vn, F, params, NoiseModel(rho), N, rows=np.ones(len(V) - 1, dtype=bool))
    with pytest.raises(ValueError, match="boolean mask"):
        default.feature_risk(Vn, F, params, NoiseModel(rho), N, rows=np.ones(len(V)))


def test_post_step_estimates_on_rows_are_the_stein_sums_over_those_vertices_and_their_faces():
    V, F = icosphere(2)
    rho = 0.03
    Vn = md.add_normal_noise((V, F), rho, seed=3)[0]
    N = vertex_normals(V, F)
    rows = _mask(len(V), 1)
    faces = rows[F].all(axis=1)
    est = default.post_step_estimates(Vn, F, "sobolev_bilaplacian", {"mu": 0.01}, NoiseModel(rho), normals=N,
                                      scales=(1.5,), steps=(2,), probes=3, seed=5, rows=rows)
    G, S = est[(1.5, 2)]

    def f(X):
        Y = md.apply_filter("sobolev_bilaplacian", (X, F), mu=0.015)
        return md.apply_filter("taubin", Y, iterations=2, lam=0.5, mu=-0.53)[0]

    J = default.NormalJacobian(md.apply_filter("sobolev_bilaplacian", (Vn, F), mu=0.01)[0], F)
    Z = np.random.default_rng(5).choice([-1.0, 1.0], size=(3, len(V))).T
    Y, n, m = f(Vn), rows.sum(), faces.sum()
    for p in range(3):
        b = Z[:, p, None] * N
        d = f(b)  # linear: the finite difference is exact
        s = np.sum((Y - Vn)[rows] ** 2) - n * rho**2 + 2 * rho**2 * np.sum((b * d)[rows])
        Jb, Jd, JR = J(b)[faces], J(d)[faces], J(Y - Vn)[faces]
        g = (np.sum(JR**2) - rho**2 * np.sum(Jb**2) + 2 * rho**2 * np.sum(Jb * Jd)) / m
        assert S[p] == pytest.approx(s, rel=1e-8) and G[p] == pytest.approx(g, rel=1e-8)


def test_a_risk_region_is_a_submesh_scored_away_from_its_cuts():
    V, F = icosphere(5)  # 10,242 vertices
    ops = get_operators(F, len(V))
    r = default.RiskRegion.cut(V, F, ops, 3, size=2000, patches=4)
    assert 2000 <= r.V.shape[0] < len(V) and r.n == len(V)
    np.testing.assert_array_equal(r.V, V[r.vertices])
    original = {tuple(sorted(f)) for f in F.tolist()}
    assert all(tuple(sorted(f)) in original for f in r.vertices[r.F].tolist())  # faces of the mesh, renumbered
    # scored vertices are more than 3 rings (over the region's edges) from a cut (a region vertex with a
    # neighbour outside it)
    inside = np.zeros(len(V), dtype=bool)
    inside[r.vertices] = True
    cut = np.flatnonzero((inside & (ops.W @ (~inside).astype(float) > 0))[r.vertices])
    dist = ring_distance(r.ops.W, cut)
    assert np.all(dist[r.rows] > 3) and np.all(dist[~r.rows] <= 3) and r.rows.any()
    assert r.scale == pytest.approx(len(V) / r.rows.sum())
    # the noise model follows: a correlated one is rebuilt on the region's part of its geometry
    model = NoiseModel(0.01, 1.5, V, F)
    sub = r.noise_model(model)
    assert sub.correlated and sub.V.shape == r.V.shape and sub.F is r.F and sub.rho == model.rho
    assert r.noise_model(NoiseModel(0.01)) == NoiseModel(0.01)
    # a mesh no larger than the size wanted is its own region, all scored
    whole = default.RiskRegion.cut(V, F, ops, 3, size=len(V), patches=4)
    assert whole.V.shape == V.shape and whole.rows.all() and whole.ops is ops
    # the balls grow with the margin so that some of each is scored
    assert default.RiskRegion.cut(V, F, ops, 8, size=100, patches=4).V.shape[0] >= 4 * 12 * 64


def test_the_margin_grows_with_the_smooth_priors_reach_within_its_bounds():
    assert default.risk_margin(0.0) == default.RISK_MARGIN
    assert default.risk_margin(0.1) == default.RISK_MARGIN  # 4 + 5 rings: under two_stage's 10
    assert default.risk_margin(1.0) == 12  # the reach of mu x 2 (7 rings) and 5 Taubin steps
    assert default.RISK_MARGIN < default.risk_margin(50.0) <= default.RISK_MAX_MARGIN
    assert default.risk_margin(1e6) == default.RISK_MAX_MARGIN


def test_above_region_from_the_post_step_is_chosen_on_a_risk_region_with_its_normals_and_noise_model(monkeypatch):
    # the delegation, exactly: the region's vertices, faces, scored rows, the caller's normals at those vertices
    # and the noise model rebuilt on the region (benchmarks/default_region.py measures its choices against the
    # whole mesh's and the truth at 400k and 1.6M vertices)
    V, F = icosphere(4)  # 2,562 vertices
    rho = 0.05
    Vn = md.add_normal_noise((V, F), rho, seed=0)[0]
    ops = get_operators(F, len(V))
    params = md.choose_parameters((Vn, F), "sobolev_bilaplacian", noise=rho)
    N = vertex_normals(V, F)
    monkeypatch.setattr(default, "REGION_FROM", 2000)
    monkeypatch.setattr(default, "RISK_REGION", 1000)
    monkeypatch.setattr(default, "RISK_MARGIN", 3)
    monkeypatch.setattr(default, "RISK_MAX_MARGIN", 3)
    monkeypatch.setattr(default, "RISK_PATCHES", 4)
    seen = []
    estimates = default.post_step_estimates
    monkeypatch.setattr(default, "post_step_estimates", lambda *a, **k: seen.append((a, k)) or estimates(*a, **k))
    post = default.choose_post_step(Vn, F, "sobolev_bilaplacian", params, NoiseModel(rho), ops=ops, normals=N, seed=3)
    region = default.RiskRegion.cut(Vn, F, ops, 3, seed=3)
    (args, kw), = seen
    np.testing.assert_array_equal(args[0], region.V)
    np.testing.assert_array_equal(args[1], region.F)
    np.testing.assert_array_equal(kw["rows"], region.rows)
    np.testing.assert_array_equal(kw["normals"], N[region.vertices])
    assert region.V.shape[0] < len(V) and 0 < region.rows.sum() < region.V.shape[0]
    direct = default.choose_post_step(region.V, region.F, "sobolev_bilaplacian", params, NoiseModel(rho), ops=region.ops,
                                      normals=N[region.vertices], seed=3, rows=region.rows)
    assert (post.scale, post.steps, post.candidates) == (direct.scale, direct.steps, direct.candidates)
    assert len(post.candidates) == len(default.POST_SCALES) * len(default.POST_STEPS)


def test_above_region_from_the_default_scores_both_candidates_on_one_region_and_picks_as_on_the_whole_mesh(monkeypatch):
    # a CAD box (two_stage by 2.5x on the whole mesh) and a torus with strong noise (the smooth prior): the same
    # picks, with the candidates' risks on the region's scored vertices, scaled to the mesh
    monkeypatch.setattr(default, "SMALL_MESH", 0)  # two candidates
    cases = [(box(16), 0.02), (torus(50, 24), 0.04)]  # 1,352 and 1,200 vertices
    whole = []
    for (V, F), rho in cases:
        Vn = md.add_normal_noise((V, F), rho, seed=2)[0]
        whole.append(default.choose_default((Vn, F), noise=rho).method)
    assert whole == ["two_stage", "sobolev_bilaplacian"]
    calls = []
    runs = default.feature_runs
    monkeypatch.setattr(default, "feature_runs", lambda V, *a, **k: calls.append((V.shape[0], k["method"])) or runs(V, *a, **k))
    monkeypatch.setattr(default, "REGION_FROM", 1000)
    monkeypatch.setattr(default, "RISK_REGION", 600)
    monkeypatch.setattr(default, "RISK_PATCHES", 4)
    monkeypatch.setattr(default, "RISK_MARGIN", 3)
    monkeypatch.setattr(default, "RISK_MAX_MARGIN", 3)
    monkeypatch.setattr(default, "FEATURE_REGION", 600)
    monkeypatch.setattr(default, "FEATURE_PATCHES", 8)
    monkeypatch.setattr(default, "FEATURE_MARGIN", 3)
    for ((V, F), rho), method in zip(cases, whole):
        Vn = md.add_normal_noise((V, F), rho, seed=2)[0]
        calls.clear()
        choice = default.choose_default((Vn, F), noise=rho)
        assert choice.method == method
        assert sorted(m for _, m in calls) == ["sobolev_bilaplacian", "two_stage"]  # both, by Monte-Carlo SURE
        assert all(k < len(V) for k, _ in calls)  # on the region
        assert any(f"on {choice.region[1]:,} vertices of a sampled region" in r for r in choice.reasons)
        assert 0 < choice.region[1] < choice.region[0] < len(V)
        assert (choice.as_dict()["region_vertices"], choice.as_dict()["region_scored"]) == choice.region


def test_on_the_region_path_the_whole_meshs_vertex_matrices_are_dropped_and_the_region_keeps_nothing(monkeypatch):
    # what the whole-mesh path does (issue 17: about 260 bytes per vertex at the peak of the two_stage runs);
    # the region's operators are its own, not in the shared cache, so nothing of the region outlives the choice
    from meshdenoise import operators as operators_module

    V, F = box(16)
    Vn = md.add_normal_noise((V, F), 0.02, seed=2)[0]
    ops = get_operators(F, len(V))
    for name, value in (("SMALL_MESH", 0), ("REGION_FROM", 1000), ("RISK_REGION", 600), ("RISK_PATCHES", 4),
                        ("RISK_MARGIN", 3), ("RISK_MAX_MARGIN", 3), ("FEATURE_REGION", 600), ("FEATURE_PATCHES", 8),
                        ("FEATURE_MARGIN", 3)):
        monkeypatch.setattr(default, name, value)
    cached = []
    real = operators_module.get_operators
    monkeypatch.setattr(default, "get_operators", lambda F, n: cached.append(n) or real(F, n))
    choice = default.choose_default((Vn, F), noise=0.02)
    assert choice.method == "two_stage"
    assert "L" not in ops.__dict__ and "W" not in ops.__dict__  # dropped, rebuilt lazily if needed
    assert set(cached) == {len(V)}  # only the whole mesh's operators come from the shared cache

"""sobolev_normal's region search without a reach loop: one cut, its outer rings held at the whole
mesh's result, against the whole-mesh rule on a torus whose best weight is large (where a free border loses dB)."""

import numpy as np
import pytest

from meshdenoise import add_normal_noise, apply_filter, choose_parameters, get_filter, snr
from meshdenoise.operators import get_operators
from meshdenoise.plugins.sobolev_normal import SobolevNormalConfig
from meshdenoise.shapes import torus
from meshdenoise.tuning.config import SearchConfig, SpectralConfig


def _torus_case():
    V, F = torus(100, 60)  # 6,000 vertices; at 0.4 edge lengths of noise the whole mesh's best weight is about 80 (order 3)
    rho = 0.4 * float(np.linalg.norm(V[F[:, 0]] - V[F[:, 1]], axis=1).mean())
    Vn, _ = add_normal_noise((V, F), rho, seed=0)
    return V, Vn, F, rho


def _forced_region(monkeypatch, pin=None):
    """The rule's settings that cut a region of this 6,000-vertex torus, and the list of the regions cut."""
    import meshdenoise.tuning.region as region

    # the region grown by region_shape to 2 x 19 x 8^2 = 2432 vertices
    rule = SobolevNormalConfig(region=2000, patches=2, **({} if pin is None else {"pin": pin}))
    cuts = []
    real = region.SampledRegion
    monkeypatch.setattr(region, "SampledRegion", lambda *a, **k: cuts.append(real(*a, **k)) or cuts[-1])
    return (SearchConfig(region_min_vertices=1000), rule), cuts


def _filtered(V, F, config, pinned=None, **params):
    """sobolev_normal's array core with ``config`` (a filter's public call takes none), held rows kept as the
    registry keeps them."""
    spec = get_filter("sobolev_normal")
    V = np.asarray(V, dtype=np.float64)
    out = spec.core(V, F, ops=get_operators(F, len(V)), pinned=pinned, config=config, **spec.resolve(params))
    if pinned is not None:
        out[pinned] = V[pinned]
    return out


def test_region_choice_is_within_0_2_db_of_the_whole_mesh_rule_and_a_free_border_is_not(monkeypatch):
    """One cut (no second, wider one), held on its outer rings: within 0.2 dB of the whole-mesh rule's SNR. The same
    region with a free border (nothing held) loses several dB: the comparison can fail."""
    V, Vn, F, rho = _torus_case()
    whole = choose_parameters((Vn, F), "sobolev_normal", noise=rho)  # 6,000 < SearchConfig.region_min_vertices: the whole mesh
    whole_snr = snr(V, apply_filter("sobolev_normal", (Vn, F), **whole)[0])
    assert whole["order"] == 3 and whole["mu"] > 30  # strong smoothing: where a cut pulls the choice down

    config, cuts = _forced_region(monkeypatch)
    held = choose_parameters((Vn, F), "sobolev_normal", noise=rho, config=config)
    assert len(cuts) == 1 and not cuts[0].whole and cuts[0].vertices.size < 0.5 * len(V)
    held_snr = snr(V, apply_filter("sobolev_normal", (Vn, F), **held)[0])
    assert held_snr >= whole_snr - 0.2

    monkeypatch.undo()
    config, cuts = _forced_region(monkeypatch, pin=0)  # pin = 0: the cut left a free border
    free = choose_parameters((Vn, F), "sobolev_normal", noise=rho, config=config)
    assert len(cuts) == 1
    free_snr = snr(V, apply_filter("sobolev_normal", (Vn, F), **free)[0])
    assert free_snr < whole_snr - 1.0


def test_lanczos_shifted_with_spaced_tests_converges_where_the_old_schedule_costs_more(monkeypatch):
    """growth > 0 tests convergence at geometrically spaced sizes: the same result within the tolerance, the tests'
    eigenproblems less than half the cost."""
    from meshdenoise.operators import get_operators
    from meshdenoise.solvers import LanczosQuadrature, lanczos_shifted

    V, Vn, F, rho = _torus_case()
    ops = get_operators(F, len(V))
    tests = []
    real = LanczosQuadrature._coefficients

    def count(self, g, j, k):
        tests.append(k)
        return real(self, g, j, k)

    monkeypatch.setattr(LanczosQuadrature, "_coefficients", count)
    every = lanczos_shifted(ops, Vn, 1e4, 3, tol=1e-10)  # a strong weight: a couple of hundred steps
    cost_every = sum(k * k for k in tests)  # each test's tridiagonal eigenproblems take time ~ k^2
    tests.clear()
    spaced = lanczos_shifted(ops, Vn, 1e4, 3, tol=1e-10, growth=0.25)
    assert sum(k * k for k in tests) < 0.5 * cost_every
    np.testing.assert_allclose(spaced, every, atol=1e-9 * rho)
    with pytest.raises(ValueError, match="mu"):
        lanczos_shifted(ops, Vn, "strong", 3)


def test_region_rule_under_a_correlated_noise_model_colours_the_regions_probes_by_the_regions_model(monkeypatch):
    # the region's noise model is built on a smoothed region (sure_smoothed), which ran inside the whole mesh's
    # colouring: "colour_probes: the noise model has n vertices, the probes k rows" (face000 scanner, 85k vertices,
    # with method="sobolev_normal" or "sobolev_gls"; the default's own path was not affected)
    from meshdenoise.tuning.covariance import NoiseModel

    V, Vn, F, rho = _torus_case()
    model = NoiseModel(rho, 2.0, Vn, F)
    config, cuts = _forced_region(monkeypatch)
    params = choose_parameters((Vn, F), "sobolev_normal", noise=model, config=config)
    assert cuts and cuts[0].vertices.size < len(V)  # on a region
    assert snr(V, apply_filter("sobolev_normal", (Vn, F), **params)[0]) > snr(V, Vn)


def test_the_filter_with_held_vertices_on_a_large_mesh_solves_by_cg_within_its_bound_the_factors_result(monkeypatch):
    # from SobolevNormalConfig.lanczos_min_vertices (here lowered) a held border (the border option's second run) is solved
    # by CG while shifted_cg_bound allows it, a factorisation beyond: the same result to the solve's tolerance
    import meshdenoise.plugins.sobolev_normal as sn
    import meshdenoise.solvers as solvers
    from meshdenoise.operators import clear_cache, get_operators

    V, F = torus(40, 20)
    F = F[F.max(axis=1) < 700]  # an open strip: a border to hold
    V = V[:700]
    Vn, _ = add_normal_noise((V, F), 0.02, seed=1)
    pinned = get_operators(F, len(V)).boundary_vertices
    assert pinned.any()
    factor = apply_filter("sobolev_normal", (Vn, F), mu=3.0, order=2, tangential=0.2, pinned=pinned)[0]
    clear_cache()  # the factor just made would be used again
    methods = []
    real = solvers.shifted_solver
    monkeypatch.setattr(sn, "shifted_solver", lambda *a, **k: methods.append(a[4] if len(a) > 4 else "cholesky") or real(*a, **k))
    cg = _filtered(Vn, F, SobolevNormalConfig(lanczos_min_vertices=500), pinned, mu=3.0, order=2, tangential=0.2)
    assert methods == ["cg"]
    np.testing.assert_allclose(cg, factor, rtol=0, atol=1e-8 * np.abs(factor).max())
    np.testing.assert_array_equal(cg[pinned], Vn[pinned])
    methods.clear()
    clear_cache()
    beyond = SobolevNormalConfig(lanczos_min_vertices=500, pinned_cg_bound=1.0)  # beyond the bound: the factor
    np.testing.assert_array_equal(_filtered(Vn, F, beyond, pinned, mu=3.0, order=2, tangential=0.2), factor)
    assert methods == ["cholesky"]


def test_whole_mesh_rule_by_one_lanczos_run_chooses_as_by_factors(monkeypatch):
    """From SobolevNormalConfig.rule_lanczos_min_vertices the whole-mesh rule's candidates (both orders) come from one Lanczos
    run (the first grid in one second pass, LogSearch's evaluate_many) where d_max mu^(1/p) is at most the reach: the
    same order and mu (to the search's rounding) as with a factor per candidate."""
    import meshdenoise.plugins.sobolev_normal_rule as sn
    from meshdenoise.shapes import icosphere
    from meshdenoise.geometry import vertex_normals as vn
    from meshdenoise.solvers import CompiledLanczos
    from meshdenoise.tuning.choose import choose_parameters

    V0, F = icosphere(4)
    X = V0 + 0.01 * np.random.default_rng(2).standard_normal(len(V0))[:, None] * vn(V0, F)
    direct = choose_parameters((X, F), "sobolev_normal", noise=0.01,
                               config=SobolevNormalConfig(rule_lanczos_min_vertices=10**9))
    runs = []
    monkeypatch.setattr(sn, "CompiledLanczos", lambda *a, **k: runs.append(a[1].shape) or CompiledLanczos(*a, **k))
    every = SobolevNormalConfig(rule_lanczos_min_vertices=0)
    fast = choose_parameters((X, F), "sobolev_normal", noise=0.01, config=every)
    assert runs == [(len(X), 3 + 3 * sn.SOBOLEV_NORMAL_PROBES)]  # one run: coordinates and the probes
    assert fast["order"] == direct["order"] and fast["mu"] == pytest.approx(direct["mu"], rel=1e-6)
    assert fast["tangential"] == direct["tangential"]

    # both orders' first grids in one second pass; in passes of one candidate (the byte bound) the same choice
    passes = []
    real = CompiledLanczos.apply_many
    monkeypatch.setattr(CompiledLanczos, "apply_many", lambda self, gs, **k: passes.append(len(gs)) or real(self, gs, **k))
    again = choose_parameters((X, F), "sobolev_normal", noise=0.01, config=every)
    assert passes[0] == 10 and again == fast
    passes.clear()
    single = choose_parameters((X, F), "sobolev_normal", noise=0.01,
                               config=SobolevNormalConfig(rule_lanczos_min_vertices=0, batch_bytes=1))
    assert passes[:10] == [1] * 10
    assert single["order"] == fast["order"] and single["mu"] == pytest.approx(fast["mu"], rel=1e-6)


def test_log_search_evaluate_many_gives_the_points_one_at_a_time_would():
    from meshdenoise.tuning.risk import Point
    from meshdenoise.tuning.search import LogSearch

    f = lambda mu: Point(mu, 0.0, 0.0, None, (np.log10(mu) - 0.3) ** 2)  # noqa: E731
    calls = []
    many = LogSearch(f, 1.0, evaluate_many=lambda mus: calls.append(len(mus)) or [f(mu) for mu in mus])
    one = LogSearch(f, 1.0)
    assert many.bracket().value == one.bracket().value and many.refine_parabolic().value == one.refine_parabolic().value
    assert sorted(many.cache) == sorted(one.cache) and calls == [5]  # the first grid in one call, the rest one by one


def test_log_search_first_grid_points_added_are_not_evaluated_again():
    from meshdenoise.tuning.risk import Point
    from meshdenoise.tuning.search import LogSearch

    f = lambda mu: Point(mu, 0.0, 0.0, None, (np.log10(mu) - 0.3) ** 2)  # noqa: E731
    seen = []
    s = LogSearch(lambda mu: seen.append(mu) or f(mu), 1.0)
    grid = s.first_grid()
    assert np.allclose(np.log10(grid), [-1.5, -0.75, 0.0, 0.75, 1.5])
    for mu in grid[:3]:
        s.add(mu, f(mu))
    assert np.allclose(s.first_grid(), grid[3:])
    assert s.bracket().value == LogSearch(f, 1.0).bracket().value and np.allclose(seen, grid[3:])


def test_past_an_edge_length_of_noise_the_rule_scores_by_quadrature_as_by_its_solves(monkeypatch):
    """Tangential 1 (noise past an edge length): the update is H X, so SURE's residual and divergence are Gauss
    quadratures of L from one Lanczos run (no solve per candidate): the same order and mu as the solves give."""
    import meshdenoise.plugins.sobolev_normal_rule as sn
    from meshdenoise.geometry import vertex_normals as vn
    from meshdenoise.shapes import icosphere
    from meshdenoise.solvers import CompiledLanczos
    from meshdenoise.tuning.choose import choose_parameters

    V0, F = icosphere(4)  # 2,562 vertices: at least SpectralConfig.min_vertices
    h = float(np.linalg.norm(V0[F[:, 0]] - V0[F[:, 1]], axis=1).mean())
    rho = 1.5 * h
    X = V0 + rho * np.random.default_rng(4).standard_normal(len(V0))[:, None] * vn(V0, F)
    runs = []
    monkeypatch.setattr(sn, "CompiledLanczos", lambda *a, **k: runs.append(a[1].shape) or CompiledLanczos(*a, **k))
    fast = choose_parameters((X, F), "sobolev_normal", noise=rho)
    assert fast["tangential"] == 1.0
    assert runs == [(len(X), 3 * len(sn.SOBOLEV_NORMAL_ORDERS) + 3 * sn.SOBOLEV_NORMAL_PROBES)]
    direct = choose_parameters((X, F), "sobolev_normal", noise=rho,
                               config=SpectralConfig(min_vertices=10**9))  # every candidate by its solve
    assert fast["order"] == direct["order"] and fast["mu"] == pytest.approx(direct["mu"], rel=1e-6)

"""The face-normal risk of linear smoothers (meshdenoise.tuning.normal_risk) and the "normals" criterion."""

import numpy as np
import pytest
import scipy.sparse as sp

import meshdenoise as md
from meshdenoise.geometry import face_normals, vertex_normals
from meshdenoise.operators import get_operators
from meshdenoise.shapes import icosphere
from meshdenoise.tuning.choose import choose_parameters, normal_candidates, normal_filters, rule_criterion
from meshdenoise.tuning.normal_risk import NormalJacobian, normal_risk, refine_for_normals


def _dense_jacobian(J: NormalJacobian, n: int) -> np.ndarray:
    """J as a (3m, 3n) matrix, column 3i + a the turn for a unit move of vertex i along axis a."""
    cols = []
    for i in range(n):
        for a in range(3):
            D = np.zeros((n, 3))
            D[i, a] = 1.0
            cols.append(J(D).ravel())
    return np.array(cols).T


def test_jacobian_matches_finite_differences_of_the_face_normals():
    V, F = icosphere(1)
    rng = np.random.default_rng(0)
    V = V + 0.05 * rng.standard_normal(V.shape)
    D = rng.standard_normal(V.shape)
    eps = 1e-6
    fd = (face_normals(V + eps * D, F) - face_normals(V - eps * D, F)) / (2 * eps)
    np.testing.assert_allclose(NormalJacobian(V, F)(D), fd, atol=1e-6)


def test_jacobian_of_many_displacements_is_each_ones_product_and_the_risk_takes_either_form():
    V, F = icosphere(1)
    rng = np.random.default_rng(3)
    J = NormalJacobian(V + 0.05 * rng.standard_normal(V.shape), F, min_height=0.2)
    D = rng.standard_normal((len(V), 5, 3))
    many = J.many(D)
    assert many.shape == (len(F), 5, 3)
    for k in range(5):
        np.testing.assert_array_equal(many[:, k], J(D[:, k]))  # the same products and sums: bit for bit
    H = rng.standard_normal((len(V), 5, 3))
    as_lists = normal_risk(J, V, 0.9 * V, [J(D[:, k]) for k in range(5)], [H[:, k] for k in range(5)], 0.1)
    assert normal_risk(J, V, 0.9 * V, many, H, 0.1) == pytest.approx(as_lists, rel=1e-13)


def test_risk_against_a_dense_computation_of_its_expectation():
    """E[G] over the noise equals (1/m) E||J(HX - X0)||^2: the estimator written out densely with exact traces."""
    V0, F = icosphere(1)
    n, m = V0.shape[0], F.shape[0]
    R = V0 + 0.03 * np.random.default_rng(1).standard_normal(V0.shape)  # J and N at some other mesh, held fixed
    J, N = NormalJacobian(R, F), vertex_normals(R, F)
    L = get_operators(F, n).L.toarray()
    H = np.linalg.inv(np.eye(n) + 0.7 * L)
    rho = 0.05
    Jd = _dense_jacobian(J, n)
    M = Jd.T @ Jd
    Hk = np.kron(H, np.eye(3))  # vertex-major layout: index 3i + a
    D = np.zeros((3 * n, n))
    for i in range(n):
        D[3 * i:3 * i + 3, i] = N[i]
    # probes sqrt(n) e_i N_i: the mean over them is the exact trace
    B = [np.sqrt(n) * np.outer(np.eye(n)[i], N[i]) for i in range(n)]
    G0 = normal_risk(J, V0, H @ V0, [J(b) for b in B], [H @ b for b in B], rho)  # at X = X0
    I3n = np.eye(3 * n)
    # E||J(HX - X)||^2 = ||J(H - I)X0||^2 + rho^2 tr(D^T (H-I)^T M (H-I) D): add the noise part G0 lacks
    expected_G = G0 + rho**2 * np.trace(D.T @ (Hk - I3n).T @ M @ (Hk - I3n) @ D) / m
    x0 = V0.ravel()
    truth = (np.sum((Jd @ (Hk @ x0 - x0)) ** 2) + rho**2 * np.trace(D.T @ Hk.T @ M @ Hk @ D)) / m
    assert expected_G == pytest.approx(truth, rel=1e-10)


def test_risk_is_unbiased_over_noise_realisations():
    V0, F = icosphere(2)
    n = V0.shape[0]
    J, N = NormalJacobian(V0, F), vertex_normals(V0, F)
    L = get_operators(F, n).L
    solve = sp.linalg.factorized((sp.identity(n) + 0.5 * L).tocsc())
    H = lambda X: np.column_stack([solve(X[:, a]) for a in range(3)])  # noqa: E731
    rho, rng = 0.02, np.random.default_rng(2)
    est, truth = [], []
    for _ in range(300):
        X = V0 + rho * rng.standard_normal(n)[:, None] * N
        Z = rng.choice([-1.0, 1.0], size=(n, 4))
        B = [Z[:, [p]] * N for p in range(4)]
        Y = H(X)
        est.append(normal_risk(J, X, Y, [J(b) for b in B], [H(b) for b in B], rho))
        truth.append(np.sum(J(Y - V0) ** 2) / F.shape[0])
    diff = np.array(est) - np.array(truth)
    assert abs(diff.mean()) < 3 * diff.std() / np.sqrt(len(diff)) + 1e-12
    assert np.mean(truth) > 0 and abs(diff.mean()) < 0.05 * np.mean(truth)


def test_dirichlet_sure_is_unbiased_for_the_errors_dirichlet_energy_with_a_non_symmetric_smoother():
    """E D = E (HX - X0)^T L (HX - X0), the error's energy over the edges, for H = P^3 (P = D^-1 W, not symmetric);
    the estimate with exact probes (sqrt(n) e_i N_i) equals its closed form for each draw."""
    from meshdenoise.tuning.normal_risk import dirichlet_sure

    V0, F = icosphere(2)
    n = V0.shape[0]
    N = vertex_normals(V0, F)
    ops = get_operators(F, n)
    L, Pd = ops.L, ops.P.toarray()
    H = np.linalg.matrix_power(Pd, 3)
    rho, rng = 0.02, np.random.default_rng(4)
    Bx = np.hstack([np.sqrt(n) * np.outer(np.eye(n)[i], N[i]) for i in range(n)])  # exact probes, (n, 3n)
    Sigma = rho**2 * np.einsum("ia,ib->iab", N, N)  # per vertex, across coordinates: block-diagonal covariance
    Ld = L.toarray()
    est, truth = [], []
    for _ in range(300):
        X = V0 + rho * rng.standard_normal(n)[:, None] * N
        Z = rng.choice([-1.0, 1.0], size=(n, 4))
        B = (Z[:, :, None] * N[:, None, :]).reshape(n, 12)
        out = np.hstack([H @ X, H @ B])
        est.append(dirichlet_sure(L, X, out, B, L @ B, rho))
        E = H @ X - V0
        truth.append(float(np.sum(E * (Ld @ E))))
    exact = dirichlet_sure(L, X, np.hstack([H @ X, H @ Bx]), Bx, L @ Bx, rho)
    R = H @ X - X
    # the closed form with Sigma's 3 x 3 blocks: tr(L S) = sum_i L_ii tr(S_i), tr(L H S) = sum_ij L_ij H_ji tr(S_i)
    trS = np.einsum("iaa->i", Sigma)
    closed = np.sum(R * (Ld @ R)) - np.sum(np.diag(Ld) * trS) + 2 * np.sum((Ld @ H).diagonal() * trS)
    assert exact == pytest.approx(closed, rel=1e-10)
    diff = np.array(est) - np.array(truth)
    assert abs(diff.mean()) < 3 * diff.std() / np.sqrt(len(diff)) + 1e-12
    assert abs(diff.mean()) < 0.05 * np.mean(truth)


def test_noise_past_an_edge_length_ranks_the_candidates_by_the_dirichlet_sure_below_it_by_the_linearised_risk():
    """From NORMAL_LINEAR_MAX edge lengths of noise the first order of the face normals does not hold: the search
    descends the Dirichlet energy's SURE from the start (its choice the least of it over every candidate here, a
    convex curve); below, the linearised risk is used as before."""
    from meshdenoise.tuning.normal_risk import dirichlet_sure

    V0, F = icosphere(3)
    n = len(V0)
    P = get_operators(F, n).P
    h = np.mean([np.linalg.norm(V0[a] - V0[b]) for a, b, c in F])

    def steps(k, block):
        for _ in range(int(k)):
            block = P @ block
        return block

    values = normal_candidates(4, True)
    for rho, expect in ((1.5 * h, "dirichlet"), (0.2 * h, "normals")):
        X = V0 + rho * np.random.default_rng(1).standard_normal(n)[:, None] * vertex_normals(V0, F)
        got = refine_for_normals(X, F, steps, 4, values, rho, first=12, exact=False, probes=8)
        assert got.criterion == expect
    Z = np.random.default_rng(0).choice([-1.0, 1.0], size=(n, 8))  # refine_for_normals' probes (seed 0)
    B = (Z[:, :, None] * vertex_normals(steps(4, X := V0 + 1.5 * h * np.random.default_rng(1).standard_normal(n)[:, None]
                                                    * vertex_normals(V0, F)), F)[:, None, :]).reshape(n, 24)
    L = get_operators(F, n).L
    every = [dirichlet_sure(L, X, steps(v, np.hstack([X, B])), B, L @ B, 1.5 * h) / n for v in values]
    got = refine_for_normals(X, F, steps, 4, values, 1.5 * h, first=12, exact=False, probes=8)
    assert got.value == values[int(np.argmin(every))] and got.risk == pytest.approx(min(every), rel=1e-9)
    assert np.isnan(got.rms_degrees)


def test_choose_parameters_says_when_it_ranked_by_the_dirichlet_energy(caplog):
    import logging

    V0, F = icosphere(3)
    h = np.mean([np.linalg.norm(V0[a] - V0[b]) for a, b, c in F])
    X = V0 + 1.5 * h * np.random.default_rng(2).standard_normal(len(V0))[:, None] * vertex_normals(V0, F)
    with caplog.at_level(logging.INFO, logger="meshdenoise.auto"):
        choose_parameters((X, F), "sobolev_bilaplacian", noise=1.5 * h, criterion="normals")
    assert "ranked by SURE of the error's Dirichlet energy" in caplog.text and "nan" not in caplog.text


def _sphere_case(seed=0, rho=0.012):
    V0, F = icosphere(4)
    X = V0 + rho * np.random.default_rng(seed).standard_normal(len(V0))[:, None] * vertex_normals(V0, F)
    return V0, F, X


# the filters whose normals choice is SURE's moved by the normal risk (the others read held-out vertices:
# tests/test_held_out_rules.py)
@pytest.mark.parametrize("method", ["sobolev_axes"])  # sobolev_bilaplacian, the other on that search, is farther here
def test_normals_criterion_reaches_the_normal_oracle_on_a_noisy_sphere(method):
    V0, F, X = _sphere_case()
    spec = md.registry.get_filter(method)
    names = (spec.auto.normals,) if isinstance(spec.auto.normals, str) else spec.auto.normals
    chosen = choose_parameters((X, F), method, criterion="normals")
    sure = choose_parameters((X, F), method, criterion="sure")
    err = lambda p: md.normal_error_deg((V0, F), md.apply_filter(method, (X, F), **p))  # noqa: E731
    if len(names) == 1:
        name, start = names[0], float(sure[names[0]])
        grid = normal_candidates(max(start, 1.0) if spec.auto.integer else start, spec.auto.integer)
        oracle = min(err({**sure, name: (int(v) if spec.auto.integer else v)}) for v in grid)
    else:  # one factor on the named weights
        oracle = min(err({**sure, **{k: sure[k] * s for k in names}}) for s in normal_candidates(1.0, False))
    assert err(chosen) <= 1.1 * oracle
    assert err(chosen) < err(sure)  # position SURE stops early for the normals


def test_linear_maps_against_dense_matrices():
    """``AutoRule.linear_map``: the filter on ``V`` itself, and on a block of triples the dense matrices' product."""
    V0, F = icosphere(2)
    X = V0 + 0.02 * np.random.default_rng(0).standard_normal(V0.shape)
    n = len(X)
    ops = get_operators(F, n)
    L = ops.L.toarray()
    eye = np.eye(n)
    B = np.random.default_rng(1).standard_normal((n, 6))
    block = np.hstack([X, B])

    from meshdenoise.plugins.sobolev_axes import normal_frame

    spec = md.registry.get_filter("sobolev_axes")
    p = spec.resolve({"mu1": 0.0, "mu2": 0.3, "mu3": 2.0, "order": 2, "frame_steps": 1})
    out = spec.auto.linear_map(X, F, ops, p)(block)
    E, _ = normal_frame(X, F, ops, 1)
    want = np.hstack([sum(np.outer(np.linalg.solve(eye + mu * L @ L, T @ E[:, d]), E[:, d])
                          for d, mu in enumerate((0.0, 0.3, 2.0))) for T in np.split(block, 3, axis=1)])
    np.testing.assert_allclose(out, want, atol=1e-10)
    np.testing.assert_allclose(out[:, :3], spec.core(X, F, ops=ops, pinned=None, **p), atol=1e-10)


def test_guard_keeps_the_search_from_shrinking_the_mesh_away():
    """A map that only shrinks the mesh turns no face, so the linearised risk falls without end (each face's noise
    is scaled away); past ``guard_above`` a candidate must also keep the positions better than the input's."""
    V0, F, X = _sphere_case(seed=7)
    shrink = lambda v, B: B / (1.0 + v)  # noqa: E731  a uniform scaling: the face normals stay as they are
    values = [0.001 * 2.0**k for k in range(12)]
    free = refine_for_normals(X, F, shrink, values[0], values, 0.012, first=values[0])
    assert free.value == values[-1]  # the estimate alone asks for the mesh to vanish
    guarded = refine_for_normals(X, F, shrink, values[0], values, 0.012, first=values[0], guard_above=values[3])
    # SURE of Y = c X, c = 1 / (1 + v), with probes z_i N_i (trace c n): ||(c - 1) X||^2 - n rho^2 + 2 rho^2 c n, below
    # the input's n rho^2 only for 1 - c < 2 rho^2 / mean |X_i|^2 = 2.9e-4 on the unit sphere: no candidate past the guard
    assert guarded.value == values[3] and np.isfinite(guarded.risk)


def test_choice_is_scale_invariant():
    V0, F, X = _sphere_case(seed=4)
    a = choose_parameters((X, F), "sobolev_bilaplacian", criterion="normals", noise=0.012)
    b = choose_parameters((1000.0 * X, F), "sobolev_bilaplacian", criterion="normals", noise=12.0)
    assert a["mu"] == pytest.approx(b["mu"], rel=1e-6)


def test_criterion_errors_and_defaults():
    V, F = icosphere(2)
    assert set(normal_filters()) == {"filtering", "heat", "sinkhorn", "sobolev", "sobolev_axes", "sobolev_bilaplacian",
                                     "sobolev_gls", "taubin", "two_stage"}
    assert rule_criterion("taubin") == "normals" and rule_criterion("sobolev_normal") == "sure"
    with pytest.raises(ValueError, match="criterion 'normals' is for the filters with a rule .* not 'sobolev_normal'"):
        choose_parameters((V, F), "sobolev_normal", criterion="normals")
    with pytest.raises(ValueError, match="criterion must be one of"):
        choose_parameters((V, F), "sobolev", criterion="angles")
    with pytest.raises(TypeError, match="criterion='sure' needs method="):
        md.denoise((V, F), criterion="sure")
    with pytest.raises(ValueError, match="rho must be finite and > 0"):
        refine_for_normals(V, F, lambda v, b: b, 1.0, [1.0], 0.0)


def test_denoise_with_a_method_uses_the_normals_criterion():
    V0, F, X = _sphere_case(seed=5)
    _, used = md.denoise((X, F), method="sobolev", return_params=True)
    assert used == choose_parameters((X, F), "sobolev", criterion="normals")
    _, kept = md.denoise((X, F), method="sobolev", criterion="sure", return_params=True)
    assert kept == choose_parameters((X, F), "sobolev")


def test_command_line_and_pipeline_criterion(tmp_path):
    from click.testing import CliRunner

    from meshdenoise.cli import cli
    from meshdenoise.io import load_mesh, save_mesh

    V0, F, X = _sphere_case(seed=6)
    src = save_mesh(tmp_path / "n [1].ply", X, F)
    for extra, criterion in (([], "normals"), (["--criterion", "sure"], "sure")):
        out = tmp_path / f"o-{criterion}.ply"
        result = CliRunner().invoke(cli, ["denoise", str(src), str(out), "--method", "sobolev", *extra])
        assert result.exit_code == 0, result.output
        assert f"(criterion {criterion})" in result.output  # the user is told what the choice minimised
        mu = choose_parameters((X, F), "sobolev", criterion=criterion)["mu"]
        np.testing.assert_allclose(load_mesh(out).V, md.apply_filter("sobolev", (X, F), mu=mu)[0], atol=1e-9)
    result = CliRunner().invoke(cli, ["denoise", str(src), str(tmp_path / "x.ply"), "--criterion", "sure"])
    assert result.exit_code == 2 and "--criterion sure: it says how --method M chooses" in result.output
    result = CliRunner().invoke(cli, ["denoise", str(src), str(tmp_path / "x.ply"), "--method", "sobolev_normal",
                                      "--criterion", "normals"])
    assert result.exit_code == 2 and "criterion 'normals' is for the filters with a rule for it" in result.output
    assert not (tmp_path / "x.ply").exists()
    # a pipeline step: sure unless told
    p = tmp_path / "p.yaml"
    for line, criterion in (("{parameters: auto}", "sure"), ("{parameters: auto, criterion: normals}", "normals")):
        p.write_text(f"inputs: '{src.name}'\noutput_dir: {tmp_path / criterion}\nsteps:\n"
                     f"  - sobolev: {line}\n  - save: {{path: a.ply}}\n")
        result = CliRunner().invoke(cli, ["run", str(p), "--serial"])
        assert result.exit_code == 0, result.output
        mu = choose_parameters((X, F), "sobolev", criterion=criterion)["mu"]
        got = load_mesh(tmp_path / criterion / "a.ply").V
        np.testing.assert_allclose(got, md.apply_filter("sobolev", (X, F), mu=mu)[0], atol=1e-9)
    p.write_text(f"inputs: '{src.name}'\nsteps:\n  - sobolev: {{criterion: normals}}\n")
    result = CliRunner().invoke(cli, ["run", str(p), "--serial"])
    assert result.exit_code == 2 and "criterion: it says how parameters are chosen" in result.output


def test_warning_when_the_normals_choice_is_worse_than_the_input_in_positions(monkeypatch):
    """A cube's faces are flat: first-order smoothing for the normals rounds it and shrinks it, which SURE sees.

    The warning is the normal-risk search's (sobolev_bilaplacian's and sobolev_axes' normals choice); sobolev's rule
    without its held-out sweep is that search, and the first-order filter the one that rounds the cube."""
    import dataclasses

    from meshdenoise.shapes import box

    spec = md.registry.REGISTRY["sobolev"]
    monkeypatch.setitem(md.registry.REGISTRY, "sobolev",
                        dataclasses.replace(spec, auto=dataclasses.replace(spec.auto, held_out=None)))

    V0, F = box(12)
    X = V0 + 0.01 * np.random.default_rng(7).standard_normal(len(V0))[:, None] * vertex_normals(V0, F)
    with pytest.warns(UserWarning, match=r"dB worse than the input's .* criterion='sure'"):
        chosen = choose_parameters((X, F), "sobolev", criterion="normals")
    gain = md.snr(V0, md.apply_filter("sobolev", (X, F), **chosen)[0]) - md.snr(V0, X)
    assert gain < 0.5  # the estimate said worse than the input: measured, no better than about the input


def test_a_rules_normals_region_reaches_the_region_search(monkeypatch):
    """``AutoRule.normals_region``: the normals search runs on a region of that size from twice as many vertices."""
    import meshdenoise.tuning.choose as choose
    from meshdenoise.plugins.sobolev_axes_rule import AXES_NORMAL_REGION
    from meshdenoise.tuning.config import SearchConfig

    calls, real = [], choose.region_rule

    def spy(ctx, rule, size, patches, margin=0, **kw):
        calls.append((size, kw.get("min_vertices")))
        return real(ctx, rule, size, patches, margin, **kw)

    monkeypatch.setattr(choose, "region_rule", spy)
    V0, F, X = _sphere_case(seed=7)
    choose_parameters((X, F), "sobolev_axes", criterion="normals")
    assert calls == [(AXES_NORMAL_REGION, 2 * AXES_NORMAL_REGION)]
    choose_parameters((X, F), "sobolev_bilaplacian", criterion="normals")
    assert calls[-1] == (choose.NORMAL_REGION, SearchConfig().region_min_vertices)


def _walk(f, size, start, passes=6):
    """FixedPointBracket's walk on the map f of indices: the points linearised at and how it ended."""
    from meshdenoise.tuning.normal_risk import FixedPointBracket

    walk, at, seen = FixedPointBracket(size), start, []
    for _ in range(passes):
        seen.append(at)
        nxt = walk.next(at, f(at))
        if not isinstance(nxt, int):
            return seen, nxt
        assert walk.lo < nxt < walk.hi, (walk.lo, nxt, walk.hi)  # strictly inside what is known
        at = nxt
    return seen, "passes"


def _bisection_passes(f, size, start, passes=6):
    """The walk by bisection once bracketed: its pass count, the reference."""
    lo, hi, at = -1, size, start
    for k in range(1, passes + 1):
        best = f(at)
        if abs(best - at) <= 1:
            return k
        lo, hi = (at, hi) if best > at else (lo, at)
        if lo >= 0 and hi < size:
            if hi - lo <= 1:
                return k
            at = (lo + hi) // 2
        else:
            at = best
    return passes


@pytest.mark.parametrize("c", [3.4, 10.0, 15.6, 20.2])
@pytest.mark.parametrize("slope", [0.0, -0.3, -0.6, -1.0, -2.0, -5.0])
@pytest.mark.parametrize("start", [0, 8, 23])
def test_fixed_point_walk_ends_at_the_crossing_inside_its_bracket(c, slope, start):
    """Decreasing maps (the normal risk's passes: linearised at a rougher mesh the choice is larger), whose gap
    f(i) - i falls through zero at c: the walk ends at a point within one index of its own choice, or between
    adjacent ends whose gaps have opposite signs; where the fixed point attracts (slope 0 to -1) in no more passes than
    the bisection it replaced."""
    size = 24

    def f(i):
        return int(min(max(round(c + slope * (i - c)), 0), size - 1))

    seen, end = _walk(f, size, start, passes=size)
    assert end != "passes"
    if end is None:
        assert abs(f(seen[-1]) - seen[-1]) <= 1
    else:
        lo, hi = end
        assert hi == lo + 1 and f(lo) > lo and f(hi) < hi
    assert abs((seen[-1] if end is None else end[0]) - c) <= 2
    if slope >= -1:
        assert len(seen) <= _bisection_passes(f, size, start, passes=size)

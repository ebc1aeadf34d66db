"""sobolev_gls: the filter against dense 3n x 3n solves, its SURE against a dense risk, its choice against the oracle."""

from __future__ import annotations

import numpy as np
import pytest

from meshdenoise import add_normal_noise, snr
from meshdenoise.tuning import choose_parameters
from meshdenoise.plugins.sobolev_gls_rule import SOBOLEV_GLS_BETAS, SOBOLEV_GLS_SPREAD_SAMPLES, choose_sobolev_gls
from meshdenoise.tuning import TuningContext
from meshdenoise.tuning.noise_level import normal_spread
from meshdenoise.geometry import vertex_normals
from meshdenoise.operators import get_operators
from meshdenoise.plugins.sobolev_gls import GlsConfig, coherent_normals
from meshdenoise.registry import apply_filter, get_filter
from meshdenoise.shapes import grid, icosphere, torus


def _dense_L(F, n):
    W = np.zeros((n, n))
    for a, b, c in F:  # a loop written for the test, independent of operators.py
        for i, j in ((a, b), (b, c), (c, a)):
            W[i, j] = W[j, i] = 1.0
    return np.diag(W.sum(1)) - W


def _unit_normals(X, F):
    """Unit vertex normals written again: unit face normals summed per vertex (a loop), normalised."""
    N = np.zeros_like(X)
    for a, b, c in F:
        fn = np.cross(X[b] - X[a], X[c] - X[a])
        for i in (a, b, c):
            N[i] += fn / np.linalg.norm(fn)
    return N / np.linalg.norm(N, axis=1, keepdims=True)


def _dense_system(N, beta, mu, Lp):
    """W (3n x 3n, index 3i + d) and A = W + mu L^p (x) I_3."""
    n = len(N)
    W = np.zeros((3 * n, 3 * n))
    for i in range(n):
        W[3 * i:3 * i + 3, 3 * i:3 * i + 3] = beta * np.eye(3) - (beta - 1) * np.outer(N[i], N[i])
    return W, W + mu * np.kron(Lp, np.eye(3))


def _dense_gls(x, F, L3, mu, beta):
    """The filter written densely: isotropic pass, its coherent normals, the 3n x 3n weighted solve."""
    n = L3.shape[0]
    X = x.reshape(n, 3)
    N = coherent_normals(np.linalg.solve(np.eye(n) + mu * L3, X), F)
    W, A = _dense_system(N, beta, mu, L3)
    return np.linalg.solve(A, W @ x)


def _reduced_dense_gls(Vn, F, Lp, mu, beta, pinned, draft=None):
    """The filter with ``pinned`` rows held, written densely: the isotropic pass's reduced system, its coherent
    normals, the reduced 3n x 3n weighted solve; (3n,) in the index 3i + d. With ``draft`` (the border option's
    free isotropic pass) the normals are the draft's."""
    n = len(Vn)
    pinned = np.asarray(pinned, dtype=int)
    free = np.setdiff1d(np.arange(n), pinned)
    Ai = np.eye(n) + mu * Lp
    X0 = Vn.copy()
    X0[free] = np.linalg.solve(Ai[np.ix_(free, free)], Vn[free] - Ai[np.ix_(free, pinned)] @ Vn[pinned])
    N = coherent_normals(X0 if draft is None else draft, F)
    W, A = _dense_system(N, beta, mu, Lp)
    f3 = (3 * free[:, None] + np.arange(3)).ravel()
    p3 = (3 * pinned[:, None] + np.arange(3)).ravel()
    x = Vn.ravel()
    y = x.copy()
    y[f3] = np.linalg.solve(A[np.ix_(f3, f3)], (W @ x)[f3] - A[np.ix_(f3, p3)] @ x[p3])
    return y


def _gls(mesh, config=None, pinned=None, **params):
    """sobolev_gls on ``mesh`` as its public function runs it (``config`` None), or its array core with ``config``
    (a filter's public call takes none), held rows kept as the registry keeps them."""
    if config is None:
        return apply_filter("sobolev_gls", mesh, pinned=pinned, **params)[0]
    V, F = mesh
    spec = get_filter("sobolev_gls")
    mask = None
    if pinned is not None:
        mask = np.zeros(len(V), dtype=bool)
        mask[pinned] = True
    out = spec.core(V, F, ops=get_operators(F, len(V)), pinned=mask, config=config, **spec.resolve(params))
    if mask is not None:
        out[mask] = V[mask]
    return out


@pytest.fixture(params=["direct", "cg"])
def solve_path(request):
    """Both ways normal_weighted_solve solves: the small mesh's dense Cholesky (None: the default config) and the
    conjugate gradients it takes above GlsConfig.dense_max_vertices (forced here by a limit of 0)."""
    if request.param == "cg":
        return GlsConfig(dense_max_vertices=0, filter_tol=1e-12)  # its own tolerance's bound: the test below
    return None


def test_sobolev_gls_filter_tolerance_bounds_its_error_against_the_dense_solve():
    """At the filter's CG tolerance (GlsConfig.filter_tol) the correction D solves A D = b with A >= I, so the error is
    at most tol ||b|| <= tol (beta - 1) ||X - X0||; and it is not exact (the tolerance is what the filter runs at)."""
    config = GlsConfig(dense_max_vertices=0)
    V, F = torus(12, 6)
    Vn, _ = add_normal_noise((V, F), 0.03, seed=1)
    n = len(V)
    L3 = np.linalg.matrix_power(_dense_L(F, n), 3)
    mu, beta = 0.4, 12.0
    expected = _dense_gls(Vn.ravel(), F, L3, mu, beta).reshape(n, 3)
    X0 = np.linalg.solve(np.eye(n) + mu * L3, Vn)
    got = _gls((Vn, F), config, mu=mu, beta=beta, order=3)
    error = np.linalg.norm(got - expected)
    assert error <= config.filter_tol * (beta - 1.0) * np.linalg.norm(Vn - X0)
    assert error > 1e-13


def test_sobolev_gls_matches_a_dense_generalised_least_squares_solve(solve_path):
    V, F = torus(12, 6)
    Vn, _ = add_normal_noise((V, F), 0.03, seed=1)
    n = len(V)
    L3 = np.linalg.matrix_power(_dense_L(F, n), 3)
    mu, beta = 0.4, 4.0
    expected = _dense_gls(Vn.ravel(), F, L3, mu, beta).reshape(n, 3)
    got = _gls((Vn, F), solve_path, mu=mu, beta=beta, order=3)
    np.testing.assert_allclose(got, expected, atol=1e-8)
    # beta = 1 is the isotropic polyharmonic filter
    iso = _gls((Vn, F), solve_path, mu=mu, beta=1.0)
    np.testing.assert_allclose(iso, np.linalg.solve(np.eye(n) + mu * L3, Vn), atol=1e-10)
    # rotation and translation equivariant
    R = np.linalg.qr(np.random.default_rng(2).standard_normal((3, 3)))[0]
    moved = _gls((Vn @ R.T + 5.0, F), solve_path, mu=mu, beta=beta)
    np.testing.assert_allclose(moved, got @ R.T + 5.0, atol=1e-7)


def test_sobolev_gls_pinned_vertices_solve_the_reduced_dense_system(solve_path):
    V, F = icosphere(2)
    Vn, _ = add_normal_noise((V, F), 0.03, seed=3)
    n = len(V)
    L2 = np.linalg.matrix_power(_dense_L(F, n), 2)
    mu, beta, pinned = 0.7, 6.0, np.arange(7)
    y = _reduced_dense_gls(Vn, F, L2, mu, beta, pinned)  # isotropic pass and weighted solve, pinned rows kept
    got = _gls((Vn, F), solve_path, pinned, mu=mu, beta=beta, order=2)
    assert np.array_equal(got[pinned], Vn[pinned])
    np.testing.assert_allclose(got, y.reshape(n, 3), atol=1e-8)


@pytest.mark.parametrize("held", [False, True])
@pytest.mark.parametrize("order", [2, 3])
def test_sobolev_gls_one_ring_pcg_path_solves_the_dense_system(monkeypatch, order, held):
    """From GlsConfig.factor_free_min_vertices (0 here) with no factor stored and CG's bound past
    GlsConfig.factor_free_cg_bound (0 here): both solves by CG preconditioned by the one-ring factor's (L + aI)^-p (ShiftedPCG), no factor of
    I + mu L^p; against the (reduced) dense system."""
    import meshdenoise.plugins._gls_solve as gls_solve
    import meshdenoise.plugins.sobolev_gls as sg
    from meshdenoise.operators import clear_cache

    V, F = icosphere(2)
    Vn, _ = add_normal_noise((V, F), 0.03, seed=3)
    n = len(V)
    Lp = np.linalg.matrix_power(_dense_L(F, n), order)
    mu, beta = 40.0, 6.0
    pinned = np.arange(7) if held else np.zeros(0, dtype=int)
    y = _reduced_dense_gls(Vn, F, Lp, mu, beta, pinned)
    config = GlsConfig(factor_free_min_vertices=0, factor_free_cg_bound=0.0, dense_max_vertices=0, filter_tol=1e-12)
    clear_cache()
    real = sg.shifted_solver
    for module in (sg, gls_solve):
        monkeypatch.setattr(module, "shifted_solver", lambda *a, **k: real(*a, **k) if a[4:] == ("pcg",)
                            else pytest.fail("a factor was built"))
    got = _gls((Vn, F), config, pinned if held else None, mu=mu, beta=beta, order=order)
    assert np.array_equal(got[pinned], Vn[pinned])
    np.testing.assert_allclose(got, y.reshape(n, 3), atol=1e-8)
    # given the border option's draft (the free isotropic pass): held rows, one correction solve from it, the normals
    # the draft's; without held rows the draft is the isotropic pass's start, the same answer
    mask = np.zeros(n, dtype=bool)
    mask[pinned] = True
    draft = np.linalg.solve(np.eye(n) + mu * Lp, Vn)
    warm = get_filter("sobolev_gls").core(Vn, F, ops=get_operators(F, n), pinned=mask if held else None, mu=mu,
                                          beta=beta, order=order, draft=draft, config=config)
    assert np.array_equal(warm[pinned], Vn[pinned])
    np.testing.assert_allclose(warm, _reduced_dense_gls(Vn, F, Lp, mu, beta, pinned, draft).reshape(n, 3), atol=1e-8)


@pytest.mark.parametrize("order", [2, 3])
def test_sobolev_gls_factor_free_path_with_held_rows_solves_the_reduced_dense_system(monkeypatch, order):
    """With held rows (the border option's second run) and CG's bound under GlsConfig.factor_free_cg_bound the filter
    factorises nothing either: Jacobi CG for the isotropic pass, block-Jacobi CG on the free rows for the correction.
    The reference is the reduced dense system, as in the test above."""
    import meshdenoise.plugins._gls_solve as gls_solve
    import meshdenoise.plugins.sobolev_gls as sg
    from meshdenoise.operators import clear_cache

    V, F = icosphere(2)
    Vn, _ = add_normal_noise((V, F), 0.03, seed=3)
    n = len(V)
    Lp = np.linalg.matrix_power(_dense_L(F, n), order)
    mu, beta, pinned = 0.3, 6.0, np.arange(7)
    y = _reduced_dense_gls(Vn, F, Lp, mu, beta, pinned)
    config = GlsConfig(factor_free_min_vertices=0, factor_free_cg_bound=np.inf, filter_tol=1e-12)
    clear_cache()
    real = sg.shifted_solver
    for module in (sg, gls_solve):
        monkeypatch.setattr(module, "shifted_solver", lambda *a, **k: real(*a, **k) if a[4:] == ("cg",)
                            else pytest.fail("a factor was built"))
    got = _gls((Vn, F), config, pinned, mu=mu, beta=beta, order=order)
    assert np.array_equal(got[pinned], Vn[pinned])
    np.testing.assert_allclose(got, y.reshape(n, 3), atol=1e-8)
    mask = np.zeros(n, dtype=bool)
    mask[pinned] = True
    draft = np.linalg.solve(np.eye(n) + mu * Lp, Vn)  # the border option's draft: the free isotropic pass
    warm = get_filter("sobolev_gls").core(Vn, F, ops=get_operators(F, n), pinned=mask, mu=mu, beta=beta, order=order,
                                          draft=draft, config=config)
    assert np.array_equal(warm[pinned], Vn[pinned])
    np.testing.assert_allclose(warm, _reduced_dense_gls(Vn, F, Lp, mu, beta, pinned, draft).reshape(n, 3), atol=1e-8)
    # a draft with beta = 1: the held isotropic pass alone, started from it
    iso = get_filter("sobolev_gls").core(Vn, F, ops=get_operators(F, n), pinned=mask, mu=mu, beta=1.0, order=order,
                                         draft=draft, config=config)
    np.testing.assert_allclose(iso, _reduced_dense_gls(Vn, F, Lp, mu, 1.0, pinned).reshape(n, 3), atol=1e-8)
    # the gate: a stored factor, or a bound above the limit, keeps the factor path (here: the test fails on a factor)
    with pytest.raises(pytest.fail.Exception, match="a factor was built"):
        _gls((Vn, F), GlsConfig(factor_free_min_vertices=0, factor_free_cg_bound=0.0, filter_tol=1e-12), pinned,
             mu=mu, beta=beta, order=order)


def test_normal_weighted_cg_with_held_rows_solves_the_reduced_system():
    from meshdenoise.plugins.sobolev_gls import normal_weighted_cg

    V, F = icosphere(2)
    n = len(V)
    ops = get_operators(F, n)
    N = _unit_normals(V + 0.05 * np.random.default_rng(0).standard_normal(V.shape), F)
    B = np.random.default_rng(1).standard_normal((n, 3))
    held = np.zeros(n, dtype=bool)
    held[[0, 5, 9, 30]] = True
    x0 = np.where(held[:, None], np.random.default_rng(2).standard_normal((n, 3)), 0.0)  # Dirichlet data
    _, A = _dense_system(N, 8.0, 0.5, np.linalg.matrix_power(_dense_L(F, n), 3))
    f3 = np.repeat(~held, 3)
    y = x0.ravel().copy()
    y[f3] = np.linalg.solve(A[np.ix_(f3, f3)], B.ravel()[f3] - A[np.ix_(f3, ~f3)] @ y[~f3])
    Y, ok = normal_weighted_cg(ops, N, 8.0, 0.5, 3, B, tol=1e-12, x0=x0, pinned=held)
    assert ok and np.array_equal(Y[held], x0[held])
    np.testing.assert_allclose(Y.ravel(), y, atol=1e-9)


@pytest.mark.parametrize("rho, gcv_regime, mu, beta", [(0.03, True, 0.3, 5.0), (0.4, False, 2.0, 3.0)])
def test_sobolev_gls_risk_equals_the_dense_estimate_with_the_normals_jacobian(rho, gcv_regime, mu, beta, solve_path):
    """With exact traces the rule's score is built from the full Jacobian J of the filter (normals included).

    J is taken by central differences of a dense re-implementation (3n solves of the 3n x 3n system):
    SURE = ||f(x) - x||^2 - tr S + 2 tr(S J) above half an edge length of noise, and
    GCV = n ||f(x) - x||^2 / (n - tr(S J) / rho^2)^2 below it (the normal-only regime).
    """
    V, F = icosphere(1)  # 42 vertices: 252 dense 126 x 126 solves for J
    Vn, _ = add_normal_noise((V, F), rho, seed=4)
    n = len(V)
    h = np.mean([np.linalg.norm(V[a] - V[b]) for f in F for a, b in ((f[0], f[1]), (f[1], f[2]), (f[2], f[0]))])
    assert (rho < h / 2) == gcv_regime  # 0.03 is 0.05 edge lengths; 0.4 is 0.7
    L = _dense_L(F, n)
    L3 = np.linalg.matrix_power(L, 3)
    # noise directions: normals of the SURE-best bi-Laplacian estimate (chosen by its own rule, solved densely)
    mu2 = choose_parameters((Vn, F), "sobolev_bilaplacian", noise=rho, exact_trace=True)["mu"]
    Xs = np.linalg.solve(np.eye(n) + mu2 * L @ L, Vn)
    Nn = vertex_normals(Xs, F)
    # the normals' spread tau: the parametric bootstrap written again densely, with the test's own face-normal sums
    H2 = np.linalg.inv(np.eye(n) + mu2 * L @ L)
    eps = np.random.default_rng(0).standard_normal((n, SOBOLEV_GLS_SPREAD_SAMPLES))
    tau = np.mean([np.mean(1 - np.sum(_unit_normals(H2 @ (Xs + rho * eps[:, [k]] * Nn), F) * Nn, 1) ** 2)
                   for k in range(SOBOLEV_GLS_SPREAD_SAMPLES)])
    assert 0 < tau < (0.1 if gcv_regime else 0.5)
    S = np.zeros((3 * n, 3 * n))
    for i in range(n):
        P = np.outer(Nn[i], Nn[i])
        S[3 * i:3 * i + 3, 3 * i:3 * i + 3] = rho**2 * ((1 - tau) * P + tau / 2 * (np.eye(3) - P))
    ops = get_operators(F, n)
    x = Vn.ravel()
    for beta in (1.0, beta):  # beta = 1: the isotropic filter, linear (J = its matrix)
        fx = _dense_gls(x, F, L3, mu, beta)
        if beta == 1.0:
            J = np.kron(np.linalg.inv(np.eye(n) + mu * L3), np.eye(3))
        else:
            step = 1e-6
            J = np.empty((3 * n, 3 * n))
            for j in range(3 * n):  # central differences, one coordinate at a time
                e = np.zeros(3 * n)
                e[j] = step
                J[:, j] = (_dense_gls(x + e, F, L3, mu, beta) - _dense_gls(x - e, F, L3, mu, beta)) / (2 * step)
        resid = np.sum((fx - x) ** 2)
        tr = np.trace(S @ J)
        expected = n * resid / (n - tr / rho**2) ** 2 if gcv_regime else resid - np.trace(S) + 2 * tr
        ctx = TuningContext(Vn, F, ops, rho, "sure", True, {"mu": mu, "beta": beta})
        chosen, point = choose_sobolev_gls(ctx)
        assert chosen == {"mu": mu, "beta": beta}
        assert point.score == pytest.approx(expected, rel=1e-6)
        if beta > 1:  # the normals' part of the Jacobian is there and matters at this precision
            W, A = _dense_system(coherent_normals(np.linalg.solve(np.eye(n) + mu * L3, Vn), F), beta, mu, L3)
            fixed = np.trace(S @ np.linalg.solve(A, W))
            assert abs(fixed - tr) > 1e-4 * abs(tr)


def _plane(m=12, z=1.0):
    V, F = grid(m, m)
    V = np.array(V, dtype=float)
    V[:, 2] = z
    return V, F


def test_normal_spread_of_noise_smoothed_to_a_tilted_plane_matches_the_regression_closed_form():
    """Known spread: H projects each column on span{1, x, y} (a least-squares plane fit).

    On a flat grid at height 1, H Xs = Xs, and the smoothed noise rho H(eps N) = (0, 0, a x + b y + c)
    tilts the whole plane by the regression slopes (a, b) of rho eps on (x, y): every vertex normal
    is (-a, -b, 1) / sqrt(1 + a^2 + b^2), sin^2 = (a^2 + b^2) / (1 + a^2 + b^2) ~ a^2 + b^2, and
    E[a^2 + b^2] = rho^2 ((A^T A)^{-1}_{xx} + (A^T A)^{-1}_{yy}), A = [1, x, y] (ordinary least squares).
    """
    V, F = _plane()
    A = np.column_stack([np.ones(len(V)), V[:, 0], V[:, 1]])
    Q, _ = np.linalg.qr(A)
    rho = 0.02
    expected = rho**2 * (np.linalg.inv(A.T @ A)[1, 1] + np.linalg.inv(A.T @ A)[2, 2])
    got = normal_spread(V, F, lambda Y: Q @ (Q.T @ Y), rho, samples=4000, seed=5)
    assert got == pytest.approx(expected, rel=0.08)  # Monte-Carlo error of 4000 draws: ~2 %
    assert normal_spread(V, F, lambda Y: Y, 0.0, samples=3) == 0.0  # no noise, no smoothing: no spread


def test_normal_spread_counts_the_smoothing_bias_of_the_normals():
    """rho = 0: only the bias. H = I + c x 1^T / n turns the plane z = 1 into z = 1 + c x (x centred), sin^2 = c^2 / (1 + c^2)."""
    V, F = _plane()
    V[:, :2] -= V[:, :2].mean(axis=0)
    n, c = len(V), 0.3
    H = np.eye(n) + c * np.outer(V[:, 0], np.ones(n)) / n
    assert np.allclose(H @ V[:, :2], V[:, :2])  # x and y stay (centred grid), z tilts
    got = normal_spread(V, F, lambda Y: H @ Y, 0.0, samples=2)
    assert got == pytest.approx(c**2 / (1 + c**2), rel=1e-9)


def test_normal_spread_ignores_the_tangential_irregularity_of_the_sampling():
    """The old estimate (tangential residual X - Xs) read in-plane sampling jitter as normal spread; this one does not.

    A jittered flat grid, no noise: the in-plane drift of a smoother moves no normal, so tau = 0
    (the tangential residual of a Laplacian step is large).
    """
    V, F = _plane(16)
    rng = np.random.default_rng(3)
    V[:, :2] += 0.2 * (V[1, 0] - V[0, 0]) * rng.uniform(-1, 1, (len(V), 2))
    L = _dense_L(F, len(V))
    H = np.linalg.inv(np.eye(len(V)) + 0.5 * L @ L)
    drift = H @ V - V
    assert np.sum(drift[:, :2] ** 2) > 100 * np.sum(drift[:, 2] ** 2)  # the residual is tangential, and not small
    assert np.sum(drift[:, :2] ** 2) / len(V) > 1e-3 * (V[1, 0] - V[0, 0]) ** 2
    assert normal_spread(V, F, lambda Y: H @ Y, 0.0, samples=2) == pytest.approx(0.0, abs=1e-20)


def test_sobolev_gls_automatic_choice_is_close_to_the_oracle():
    V, F = icosphere(3)  # 642 vertices: auto 37.79 dB, oracle 38.17, noisy 26.03 (icosphere(4): 17 s, 41.76 / 41.77)
    Vn, _ = add_normal_noise((V, F), 0.05, seed=0)
    auto = choose_parameters((Vn, F), "sobolev_gls")
    oracle = choose_parameters((Vn, F), "sobolev_gls", criterion="oracle", reference=V)
    assert set(auto) == {"mu", "beta"} and auto["beta"] in SOBOLEV_GLS_BETAS
    got = snr(V, apply_filter("sobolev_gls", (Vn, F), **auto)[0])
    best = snr(V, apply_filter("sobolev_gls", (Vn, F), **oracle)[0])
    assert got > snr(V, Vn) + 10
    assert got > best - 0.5
    with pytest.raises(ValueError, match="not a linear smoother"):
        choose_parameters((Vn, F), "sobolev_gls", criterion="gcv")


def test_coherent_normals_are_the_unit_normals_on_a_smooth_mesh_and_shrink_on_folds():
    V, F = icosphere(2)
    np.testing.assert_allclose(coherent_normals(V, F), vertex_normals(V, F), atol=1e-12)
    # a vertex with 3 faces, two of them folded back: |s| = 1 < 3/2, N = s / 1.5
    V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [-1, -1, 0]])
    F = np.array([[0, 1, 2], [0, 2, 3], [0, 1, 3]])  # normals +z, +z, -z... (loop: check by hand below)
    n_f = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    n_f /= np.linalg.norm(n_f, axis=1, keepdims=True)
    s0 = n_f.sum(0)
    np.testing.assert_allclose(coherent_normals(V, F)[0], s0 / max(np.linalg.norm(s0), 1.5), atol=1e-12)


def test_coherent_normals_derivative_matches_central_differences_on_both_branches():
    """The analytic derivative against central differences of coherent_normals itself.

    A noisy sphere (every vertex on the unit branch) and a folded pair of faces (the k/2 branch,
    where the faces disagree), plus a zero-area face whose vertex keeps a zero derivative.
    """
    from meshdenoise.geometry import coherent_normals_derivative

    rng = np.random.default_rng(5)
    V, F = icosphere(2)
    V = V + 0.05 * rng.standard_normal(V.shape)
    folded = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0.2, 0.1, 0.3]])
    Ff = np.array([[0, 1, 2], [0, 2, 3]])
    for X, FF in ((V, F), (folded, Ff)):
        Y = rng.standard_normal((len(X), 3, 4))
        got = coherent_normals_derivative(X, FF, Y, chunk=3)
        e = 1e-6
        fd = np.stack([(coherent_normals(X + e * Y[:, :, j], FF) - coherent_normals(X - e * Y[:, :, j], FF)) / (2 * e)
                       for j in range(4)], axis=2)
        np.testing.assert_allclose(got, fd, atol=1e-6)
        assert np.abs(got).max() > 0.1
    k_half = np.linalg.norm(coherent_normals(folded, Ff), axis=1) < 1 - 1e-9
    assert k_half[0]  # vertex 0 is on the k/2 branch: its two faces are 60+ degrees apart
    flat = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0]])  # a zero-area face
    assert not coherent_normals_derivative(flat, np.array([[0, 1, 2]]), rng.standard_normal((3, 3, 2))).any()


# ----------------------------------------------------------------------------- scan-sized path
@pytest.mark.parametrize("gate", ["size", "bound"])
@pytest.mark.parametrize("mu, beta, order, jacobi_cap", [(0.4, 4.0, 3, 3000), (5.0, 12.0, 2, 3000), (0.4, 4.0, 3, 3)])
def test_sobolev_gls_factor_free_path_matches_the_dense_solve(monkeypatch, mu, beta, order, jacobi_cap, gate):
    """From GlsConfig.iterative_min_vertices (0 here: gate "size"), or from GlsConfig.factor_free_min_vertices under
    CG's bound (0 and none here: gate "bound") nothing is factorised: Lanczos passes and block-Jacobi CG (a cap of 3 iterations
    forces the Lanczos-preconditioned fallback); the dense 3n x 3n solve is the reference."""
    import meshdenoise.plugins._gls_solve as gls_solve
    import meshdenoise.plugins.sobolev_gls as sg
    from meshdenoise.operators import clear_cache

    V, F = torus(12, 6)
    Vn, _ = add_normal_noise((V, F), 0.03, seed=1)
    n = len(V)
    Lp = np.linalg.matrix_power(_dense_L(F, n), order)
    expected = _dense_gls(Vn.ravel(), F, Lp, mu, beta).reshape(n, 3)
    if gate == "size":
        paths = dict(iterative_min_vertices=0, factor_free_cg_bound=0.0)  # the size alone decides
    else:
        paths = dict(factor_free_min_vertices=0, factor_free_cg_bound=np.inf)
    config = GlsConfig(jacobi_max_iterations=jacobi_cap, **paths)
    clear_cache()
    built = []
    for module in (sg, gls_solve):
        monkeypatch.setattr(module, "shifted_solver", lambda *a, **k: built.append(a) or pytest.fail("a factor was built"))
    # at the filter's tolerance: the correction D solves A D = b with A >= I (W >= I, L^p >= 0), so a relative
    # residual tol bounds its error by tol ||b||, ||b|| <= (beta - 1) ||X - X0|| (b a projection of (beta - 1)(X - X0))
    X0 = np.linalg.solve(np.eye(n) + mu * Lp, Vn)
    got = _gls((Vn, F), config, mu=mu, beta=beta, order=order)
    assert np.linalg.norm(got - expected) <= config.filter_tol * (beta - 1.0) * np.linalg.norm(Vn - X0) + 1e-10
    config = GlsConfig(jacobi_max_iterations=jacobi_cap, filter_tol=1e-12, **paths)
    got = _gls((Vn, F), config, mu=mu, beta=beta, order=order)
    np.testing.assert_allclose(got, expected, atol=1e-8)
    iso = _gls((Vn, F), config, mu=mu, beta=1.0, order=order)
    np.testing.assert_allclose(iso, np.linalg.solve(np.eye(n) + mu * Lp, Vn), atol=1e-10)


def test_normal_weighted_cg_solves_the_dense_system_and_reports_non_convergence():
    from meshdenoise.plugins.sobolev_gls import normal_weighted_cg

    V, F = icosphere(2)
    n = len(V)
    ops = get_operators(F, n)
    N = _unit_normals(V + 0.05 * np.random.default_rng(0).standard_normal(V.shape), F)
    B = np.random.default_rng(1).standard_normal((n, 3))
    for order, mu, beta in ((1, 3.0, 2.0), (2, 0.5, 8.0), (3, 0.2, 12.0)):
        _, A = _dense_system(N, beta, mu, np.linalg.matrix_power(_dense_L(F, n), order))
        Y, ok = normal_weighted_cg(ops, N, beta, mu, order, B, tol=1e-12)
        assert ok
        np.testing.assert_allclose(Y.ravel(), np.linalg.solve(A, B.ravel()), atol=1e-9)
    _, ok = normal_weighted_cg(ops, N, 12.0, 100.0, 3, B, tol=1e-12, maxiter=2)
    assert not ok
    # a starting guess: from the solution itself it stops at once; from a perturbed one it converges to the same
    _, A = _dense_system(N, 12.0, 0.2, np.linalg.matrix_power(_dense_L(F, n), 3))
    exact = np.linalg.solve(A, B.ravel()).reshape(n, 3)
    Y, ok = normal_weighted_cg(ops, N, 12.0, 0.2, 3, B, tol=1e-8, maxiter=0, x0=exact)
    assert ok and np.array_equal(Y, exact)
    Y, ok = normal_weighted_cg(ops, N, 12.0, 0.2, 3, B, tol=1e-12, x0=exact + 0.1)
    assert ok
    np.testing.assert_allclose(Y, exact, atol=1e-9)


def test_sobolev_gls_scored_rule_with_every_vertex_scored_is_the_whole_rule():
    """region_rule's scored mask: all True must give the whole-mesh rule's choice and score exactly."""
    from meshdenoise.plugins.sobolev_gls_rule import choose_sobolev_gls_whole
    from meshdenoise.tuning.risk import Criterion

    V, F = torus(16, 8)
    Vn, _ = add_normal_noise((V, F), 0.05, seed=2)
    ops = get_operators(F, len(V))

    def run(scored):
        return choose_sobolev_gls_whole(TuningContext(Vn, F, ops, 0.05, Criterion("sure"), False, {}), scored)

    (c0, p0), (c1, p1) = run(None), run(np.ones(len(V), dtype=bool))
    assert c0 == c1 and p0.score == pytest.approx(p1.score, rel=1e-12)


def test_sobolev_gls_region_mode_choice_and_refinement_against_the_whole_rule(monkeypatch):
    """loose=True (looser CG, warm starts) chooses what the whole rule chooses up to a golden step; with a previous
    choice beta is held and mu refined in a few candidates, landing near the whole rule's mu."""
    import meshdenoise.plugins.sobolev_gls_rule as sg
    from meshdenoise.plugins.sobolev_gls_rule import choose_sobolev_gls_whole
    from meshdenoise.tuning.risk import Criterion

    V, F = torus(16, 8)
    Vn, _ = add_normal_noise((V, F), 0.05, seed=2)
    ops = get_operators(F, len(V))

    def run(**kw):
        return choose_sobolev_gls_whole(TuningContext(Vn, F, ops, 0.05, Criterion("sure"), False, {}), None, **kw)

    (c0, p0), (c1, p1) = run(), run(loose=True)
    assert c1["beta"] == c0["beta"] and abs(np.log10(c1["mu"] / c0["mu"])) < 0.06
    assert p1.score == pytest.approx(p0.score, rel=1e-3)
    solves = []
    real = sg.normal_weighted_solve
    monkeypatch.setattr(sg, "normal_weighted_solve", lambda *a, **k: solves.append(1) or real(*a, **k))
    c2, _ = run(loose=True, previous={"mu": c0["mu"] * 10**0.15, "beta": 5.0})
    assert c2["beta"] == 5.0 and len(solves) <= 9  # the full rule: about 27
    c3, _ = run(loose=True, previous={"mu": c0["mu"] * 10**0.15, "beta": c0["beta"]})
    assert abs(np.log10(c3["mu"] / c0["mu"])) < 0.06


def test_a_loose_sweep_over_beta_alone_stops_at_the_sweep_tolerance_and_chooses_the_tight_sweeps_beta(monkeypatch):
    """With mu held (the sweep before the normals search) a loose sweep's CG stops at SOBOLEV_GLS_SWEEP_TOL, a loose
    mu search at SOBOLEV_GLS_LOOSE_TOL; the loose sweep chooses the beta of the sweep to 1e-9 (CG_TOL), every
    candidate's score within 1e-3 of it (relative)."""
    import logging

    import meshdenoise.plugins.sobolev_gls_rule as sg
    from meshdenoise.shapes import torus
    from meshdenoise.tuning.risk import Criterion

    assert sg.SOBOLEV_GLS_SWEEP_TOL == 1e-2 and sg.SOBOLEV_GLS_LOOSE_TOL == 1e-3
    V, F = torus(40, 20)  # 800 vertices: the CG path
    Vn, _ = add_normal_noise((V, F), 0.04, seed=3)
    ops = get_operators(F, len(V))
    tols = []
    real = sg.shifted_family_cg
    monkeypatch.setattr(sg, "shifted_family_cg", lambda *a, **k: tols.append(k["tol"]) or real(*a, **k))
    scores = {}

    def run(loose, given):
        ctx = TuningContext(Vn, F, ops, 0.04, Criterion("sure"), False, given)
        chosen, _ = sg.choose_sobolev_gls_whole(ctx, None, loose=loose)
        return chosen

    class Scores(logging.Handler):
        def emit(self, record):
            msg = record.getMessage()
            if msg.startswith("sobolev_gls: mu"):
                parts = msg.split()
                scores.setdefault(self.key, {})[float(parts[4])] = float(parts[6])

    handler = Scores()
    log = logging.getLogger("meshdenoise.auto")
    old_level = log.level
    log.addHandler(handler)
    log.setLevel(logging.DEBUG)
    try:
        handler.key = "tight"
        tight = run(False, {"mu": 0.05})
        handler.key = "loose"
        loose = run(True, {"mu": 0.05})
    finally:
        log.removeHandler(handler)
        log.setLevel(old_level)
    assert tols == [sg.CG_TOL, sg.SOBOLEV_GLS_SWEEP_TOL]
    assert loose["beta"] == tight["beta"]
    for beta, score in scores["tight"].items():
        assert scores["loose"][beta] == pytest.approx(score, rel=1e-3)
    tols.clear()
    run(True, {"beta": 3.0})  # mu searched, beta held: no sweep, each candidate's CG at the loose tolerance
    assert tols == []
    solves = []
    real_solve = sg.normal_weighted_solve
    monkeypatch.setattr(sg, "normal_weighted_solve", lambda *a, **k: solves.append(k.get("tol")) or real_solve(*a, **k))
    run(True, {"beta": 3.0})
    assert solves and set(solves) == {sg.SOBOLEV_GLS_LOOSE_TOL}

"""The scan-size search paths against the direct computations they replace.

- :class:`LanczosQuadrature` against dense ``b^T g(M) b`` (eigendecomposition / inverse);
- ``best_shifted(search="quadrature")`` against ``search="factor"`` (one Cholesky factor per
  candidate, the old search): same candidates, same chosen weight, same score;
- :func:`shifted_coordinates` (CG) against a dense solve;
- the memoised :class:`PathCurve` against :func:`iterative_path` (the old walk), and the rules
  reading it against the old walk's choice;
- the taubin rule's pruning of finer steps on large meshes.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from meshdenoise import add_normal_noise, apply_filter, choose_parameters, get_filter
from meshdenoise.operators import clear_cache, get_operators
from meshdenoise.operators import Operators
from meshdenoise.shapes import grid, icosphere, torus
from meshdenoise.solvers import LanczosQuadrature, shifted_cg_bound
from meshdenoise.tuning.config import SearchConfig, SpectralConfig
from meshdenoise.tuning.memo import MEMO
from meshdenoise.tuning import TuningContext
from meshdenoise.tuning.risk import Criterion, Point, probe_block
from meshdenoise.tuning.search import (
    PathCurve,
    averaging_step,
    best_on_path,
    best_shifted,
    iterative_path,
    path_curve,
    probe_count,
    shifted_coordinates,
    shifted_quadrature,
    solve_point,
    sure_smoothed,
)


def _noisy(shape, rho, seed=0):
    V, F = shape
    Vn, _ = add_normal_noise((V, F), rho, seed=seed)
    return V, Vn, F


# --------------------------------------------------------------------------- Lanczos quadrature
@pytest.mark.parametrize("order", [1, 2, 3])
def test_lanczos_quadrature_matches_dense_quadratic_forms(order):
    _, Vn, F = _noisy(icosphere(3), 0.02)
    ops = Operators(F, len(Vn))
    L = ops.L.toarray()
    lam, U = np.linalg.eigh(L)
    Z = np.random.default_rng(1).choice([-1.0, 1.0], size=(ops.n, 5))
    c = Vn.copy()
    for _ in range(order):
        c = L @ c
    q = LanczosQuadrature(ops.L, np.hstack([c, Z]))
    for mu in (0.01, 0.5, 8.0, 60.0):
        g_res = lambda t: mu**2 / (1.0 + mu * np.maximum(t, 0) ** order) ** 2  # noqa: E731
        g_tr = lambda t: 1.0 / (1.0 + mu * np.maximum(t, 0) ** order)  # noqa: E731
        H = (U * g_tr(lam)) @ U.T  # (I + mu L^p)^-1 from the eigendecomposition
        res = q.evaluate(g_res, range(3))
        tr = q.evaluate(g_tr, range(3, 8))
        np.testing.assert_allclose(res.sum(), np.sum((H @ Vn - Vn) ** 2), rtol=1e-9)
        np.testing.assert_allclose(tr, np.einsum("ij,ij->j", Z, H @ Z), rtol=1e-9)


@pytest.mark.parametrize("order", [1, 2, 3, 4])
def test_shifted_forms_by_tridiagonal_solves_equal_the_dense_forms_and_the_gauss_rules(order):
    """evaluate of a ShiftedInverse (p tridiagonal solves per column and size, no eigenproblem) against the dense forms
    b^T (I + mu L^p)^-power b, and shifted_forms against the eigenvalue route (quadrature) at every size, both classes."""
    from meshdenoise.solvers import CompiledLanczos, ShiftedInverse

    _, Vn, F = _noisy(icosphere(3), 0.02)
    ops = Operators(F, len(Vn))
    lam, U = np.linalg.eigh(ops.L.toarray())
    B = np.hstack([Vn, np.random.default_rng(1).choice([-1.0, 1.0], size=(ops.n, 4)), np.zeros((ops.n, 1))])
    for cls in (LanczosQuadrature, CompiledLanczos):
        q = cls(ops.L, B, max_steps=800)
        for mu in (0.01, 0.5, 60.0, 1e4):
            for power in (1, 2):
                g = lambda t: (1.0 / (1.0 + mu * np.maximum(t, 0) ** order)) ** power  # noqa: E731
                dense = np.einsum("ij,ij->j", B, (U * g(lam)) @ (U.T @ B))
                got = q.evaluate(ShiftedInverse(mu, order, power), growth=0.25)
                np.testing.assert_allclose(got, dense, rtol=1e-9, atol=1e-14 * np.abs(dense).max())
                assert got[-1] == 0.0  # a zero column
                for k in (1, 2, 7, q.steps // 2, q.steps):
                    np.testing.assert_allclose(q.shifted_forms(mu, order, power, k=k), q.quadrature(g, k=k),
                                               rtol=1e-9, atol=1e-15)  # both rounded: 1e-10 at p 1, mu 1e4
    with pytest.raises(ValueError, match="power must be 1 or 2"):
        q.shifted_forms(1.0, 3, 3)


@pytest.mark.parametrize("order", [1, 3])
def test_apply_of_a_shifted_inverse_takes_tridiagonal_solves_and_equals_the_eigenvalue_route(order, monkeypatch):
    """apply(ShiftedInverse(mu, p)): its coefficients by kernels.shifted_tridiagonal_solves (no eigenproblem), the same
    result as the same function given as a plain callable (eigh_tridiagonal), and the dense (I + mu L^p)^-1 B."""
    import scipy.linalg

    from meshdenoise.solvers import CompiledLanczos, ShiftedInverse

    _, Vn, F = _noisy(icosphere(3), 0.02)
    ops = Operators(F, len(Vn))
    lam, U = np.linalg.eigh(ops.L.toarray())
    B = np.hstack([ops.L @ Vn, np.random.default_rng(2).standard_normal((ops.n, 2))])
    for mu in (0.3, 500.0):
        g = ShiftedInverse(mu, order)
        dense = (U * g(lam)) @ (U.T @ B)
        plain = [LanczosQuadrature(ops.L, B).apply(lambda t: g(t), rtol=1e-12),
                 CompiledLanczos(ops.L, B).apply_many([[lambda t: g(t)]], rtol=1e-12)[0]]
        with monkeypatch.context() as m:
            m.setattr(scipy.linalg, "eigh_tridiagonal", lambda *a, **k: pytest.fail("an eigenproblem was solved"))
            fast = [LanczosQuadrature(ops.L, B).apply(g, rtol=1e-12), CompiledLanczos(ops.L, B).apply_many([[g]], rtol=1e-12)[0]]
        for a, b in zip(fast, plain):
            np.testing.assert_allclose(a, b, rtol=0, atol=1e-11 * np.abs(B).max())
            np.testing.assert_allclose(a, dense, rtol=0, atol=1e-10 * np.abs(B).max())


def test_lanczos_quadrature_exhausted_space_and_zero_column_are_exact():
    M = sp.csr_matrix(np.diag([0.0, 1.0, 1.0, 3.0, 3.0, 3.0]))  # 3 distinct eigenvalues: exact after 3 steps
    B = np.column_stack([np.ones(6), np.zeros(6)])
    q = LanczosQuadrature(M, B)
    out = q.evaluate(lambda t: np.exp(-t))
    assert q.lengths[0] <= 4 and q.lengths[1] == 0
    np.testing.assert_allclose(out, [1 + 2 * np.exp(-1) + 3 * np.exp(-3), 0.0], rtol=1e-12)


@pytest.mark.parametrize("lift", [1, 2, 3])
def test_shifted_inverse_with_a_lift_against_dense_forms_and_coefficients(lift):
    """ShiftedInverse(mu, p, power, lift) = x^lift (1 + mu x^p)^-power: its Gauss rules (shifted_forms, tridiagonal
    solves and products) and apply's coefficients against the dense b^T g(L) b and g(L) B, and against the same
    function as a plain callable (the eigenvalue route); LanczosDots' estimates with a lift too."""
    from meshdenoise.solvers import CompiledLanczos, LanczosDots, ShiftedInverse

    _, Vn, F = _noisy(icosphere(3), 0.02)
    ops = Operators(F, len(Vn))
    lam, U = np.linalg.eigh(ops.L.toarray())
    B = np.hstack([ops.L @ (ops.L @ Vn), np.random.default_rng(4).choice([-1.0, 1.0], size=(ops.n, 3))])
    for order, mu in ((3, 0.05), (3, 40.0), (2, 3.0)):
        for power in (1, 2):
            f = ShiftedInverse(mu, order, power, lift)
            g = np.maximum(lam, 0) ** lift / (1.0 + mu * np.maximum(lam, 0) ** order) ** power
            np.testing.assert_allclose(f(lam), g, rtol=1e-13, atol=1e-300)
            dense = np.einsum("ij,ij->j", B, (U * g) @ (U.T @ B))
            q = CompiledLanczos(ops.L, B, max_steps=800)
            got = q.evaluate(f, growth=0.25)
            np.testing.assert_allclose(got, dense, rtol=1e-9, atol=1e-12 * np.abs(dense).max())
            for k in (1, 2, 5, q.steps):
                np.testing.assert_allclose(q.shifted_forms(mu, order, power, k=k, lift=lift),
                                           q.quadrature(lambda t: f(t), k=k), rtol=1e-9, atol=1e-13 * np.abs(dense).max())
        f = ShiftedInverse(mu, order, lift=lift)
        g = np.maximum(lam, 0) ** lift / (1.0 + mu * np.maximum(lam, 0) ** order)
        Y = CompiledLanczos(ops.L, B, max_steps=800).apply(f, rtol=1e-12)
        np.testing.assert_allclose(Y, (U * g) @ (U.T @ B), rtol=0, atol=1e-9 * np.abs((U * g) @ (U.T @ B)).max())
        Duals = np.random.default_rng(5).standard_normal((1,) + B.shape)
        dots = LanczosDots(ops.L, B, Duals, max_steps=800).dots(f, rtol=1e-12)
        np.testing.assert_allclose(dots[0], np.einsum("ij,ij->j", Duals[0], (U * g) @ (U.T @ B)), rtol=1e-8,
                                   atol=1e-10 * np.abs(dots).max())
    for bad in (-1, 1.5, True):
        with pytest.raises(ValueError, match="lift must be an int >= 0"):
            ShiftedInverse(1.0, 3, lift=bad)
        with pytest.raises(ValueError, match="lift must be an int >= 0"):
            CompiledLanczos(ops.L, B).shifted_forms(1.0, 3, 1, lift=bad)


def test_one_quadrature_run_serves_the_orders_2_and_3_against_factor_points_and_dense_coordinates():
    """shifted_quadrature of order 3 runs on the columns L^2 V (QUADRATURE_BASE_ORDER), lifted: its points equal
    the factor's (solve_point), an order-2 search on the same coordinates and probes goes on with the same run
    (the tuning memo: no new run, its steps kept), and quadrature_coordinates with the run's base equals the dense
    solve of either order."""
    from meshdenoise.tuning.search import QUADRATURE_BASE_ORDER, quadrature_coordinates

    assert QUADRATURE_BASE_ORDER == 2
    _, Vn, F = _noisy(torus(40, 20), 0.01)
    ops = Operators(F, len(Vn))
    Z, s = probe_block(ops.n, False, n_probes=6)
    MEMO.clear()
    third = shifted_quadrature(Vn, ops, 3, Z, s)
    assert third.base == 2
    for mu in (0.01, 0.4, 30.0):
        p, ref = third(mu), solve_point(Vn, ops, 3, mu, Z, s)
        np.testing.assert_allclose([p.residual_sq, p.trace], [ref.residual_sq, ref.trace], rtol=1e-9)
    steps = third.quadrature.steps
    second = shifted_quadrature(Vn, ops, 2, Z, s)
    assert second.quadrature is third.quadrature and second.quadrature.steps == steps  # the same run, not a new one
    for mu in (0.01, 0.4, 30.0):
        p, ref = second(mu), solve_point(Vn, ops, 2, mu, Z, s)
        np.testing.assert_allclose([p.residual_sq, p.trace], [ref.residual_sq, ref.trace], rtol=1e-9)
    first = shifted_quadrature(Vn, ops, 1, Z, s)
    assert first.base == 1 and first.quadrature is not third.quadrature  # order 1: columns L V, a run of its own
    L = ops.L.toarray()
    for order, mu in ((3, 2.0), (2, 2.0)):
        X = quadrature_coordinates(Vn, third.quadrature, order, mu, base=third.base)
        dense = np.linalg.solve(np.eye(ops.n) + mu * np.linalg.matrix_power(L, order), Vn)
        np.testing.assert_allclose(X, dense, rtol=0, atol=1e-8 * np.abs(Vn).max())
    with pytest.raises(ValueError, match="base must be between 0 and order 2"):
        quadrature_coordinates(Vn, third.quadrature, 2, 1.0, base=3)
    MEMO.clear()


def test_shifted_quadrature_at_its_default_tolerance_stops_sooner_within_it_of_the_factor_points():
    """QUADRATURE_TOL (1e-6 relative change over 10 steps): fewer Lanczos steps than the rules to 1e-10, each point's
    residual and trace within 1e-5 of the factor's (solve_point), and those to 1e-10 within 1e-9."""
    from meshdenoise.tuning.search import QUADRATURE_TOL

    assert QUADRATURE_TOL == 1e-6
    _, Vn, F = _noisy(torus(60, 30), 0.01)  # 1,800 vertices: the rules converge long before the space is exhausted
    ops = Operators(F, len(Vn))
    Z, s = probe_block(ops.n, False, n_probes=6)
    steps = {}
    for tol, accuracy in ((QUADRATURE_TOL, 1e-5), (1e-10, 1e-9)):
        MEMO.clear()
        at = shifted_quadrature(Vn, ops, 2, Z, s, tol=tol)
        for mu in (0.05, 3.0):
            p, ref = at(mu), solve_point(Vn, ops, 2, mu, Z, s)
            np.testing.assert_allclose([p.residual_sq, p.trace], [ref.residual_sq, ref.trace], rtol=accuracy)
        steps[tol] = at.quadrature.steps
    assert steps[QUADRATURE_TOL] < steps[1e-10]  # 40 against 50 here
    MEMO.clear()


def test_a_quadrature_run_above_the_shared_bound_is_not_kept():
    """Above SearchConfig.shared_run_max_bytes (the run's columns and two basis vectors) the run is the search's own:
    a second search of another order starts its own, and the memo holds nothing of it."""
    _, Vn, F = _noisy(torus(40, 20), 0.01)
    ops = Operators(F, len(Vn))
    Z, s = probe_block(ops.n, False, n_probes=6)
    MEMO.clear()
    size = 8 * 3 * ops.n * (3 + Z.shape[1])
    below = SearchConfig(shared_run_max_bytes=size - 1)
    third = shifted_quadrature(Vn, ops, 3, Z, s, config=below)
    assert shifted_quadrature(Vn, ops, 2, Z, s, config=below).quadrature is not third.quadrature and len(MEMO) == 0
    at = SearchConfig(shared_run_max_bytes=size)
    third = shifted_quadrature(Vn, ops, 3, Z, s, config=at)
    assert shifted_quadrature(Vn, ops, 2, Z, s, config=at).quadrature is third.quadrature and len(MEMO) == 1
    third(1.0)  # the run grows: the memo counts its arrays as they are now (columns, two basis vectors, recurrence)
    run = third.quadrature
    assert MEMO.total_bytes() == run.nbytes == size + 8 * 2 * run.steps * (3 + Z.shape[1])
    MEMO.clear()


def test_lanczos_quadrature_gives_up_after_max_steps():
    _, Vn, F = _noisy(icosphere(3), 0.02)
    ops = Operators(F, len(Vn))
    q = LanczosQuadrature(ops.L, Vn, max_steps=10)
    assert q.evaluate(lambda t: 1.0 / (1.0 + 1e6 * t**2)) is None
    Z, s = probe_block(ops.n, False, n_probes=4)
    assert shifted_quadrature(Vn, ops, 2, Z, s, max_steps=10)(1e6) is None


def test_lanczos_apply_equals_the_dense_matrix_function():
    _, Vn, F = _noisy(icosphere(3), 0.02)
    ops = Operators(F, len(Vn))
    lam, U = np.linalg.eigh(ops.L.toarray())
    B = np.hstack([ops.L @ Vn, np.random.default_rng(2).standard_normal((ops.n, 2))])
    for g in (lambda t: 1.0 / (1.0 + 3.0 * t**2), lambda t: np.exp(-0.5 * t)):
        Y = LanczosQuadrature(ops.L, B).apply(g, rtol=1e-12)
        np.testing.assert_allclose(Y, (U * g(lam)) @ (U.T @ B), rtol=0, atol=1e-10 * np.abs(B).max())
    assert LanczosQuadrature(ops.L, B, max_steps=5).apply(lambda t: 1.0 / (1.0 + 1e8 * t**2)) is None


def test_lanczos_quadrature_rejects_mismatched_shapes():
    with pytest.raises(ValueError, match="do not match"):
        LanczosQuadrature(sp.identity(3, format="csr"), np.ones((4, 1)))


# --------------------------------------------------------------------------- the Sobolev searches
@pytest.mark.parametrize(
    "shape, rho, order, exact",
    [
        (icosphere(3), 0.02, 1, None),  # 642 vertices: exact traces (identity probes)
        (icosphere(3), 0.02, 2, None),
        (torus(40, 20), 0.01, 2, False),  # 800 vertices, Hutchinson probes
        (grid(30, 30), 0.01, 1, False),  # open: boundary rows of L
    ],
)
def test_quadrature_search_chooses_the_factor_search_weight(shape, rho, order, exact):
    _, Vn, F = _noisy(shape, rho)
    ops = Operators(F, len(Vn))
    MEMO.clear()
    old = best_shifted(Vn, ops, order, rho, "sure", exact, center=0.3, search="factor")
    new = best_shifted(Vn, ops, order, rho, "sure", exact, center=0.3, search="quadrature")
    assert new.value == pytest.approx(old.value, rel=1e-9)
    np.testing.assert_allclose([new.residual_sq, new.trace, new.score], [old.residual_sq, old.trace, old.score], rtol=1e-8)
    np.testing.assert_allclose(new.X, old.X, rtol=0, atol=1e-8 * np.abs(old.X).max())


def test_quadrature_points_equal_factor_points_and_oracle_keeps_factor():
    V, Vn, F = _noisy(icosphere(3), 0.02)
    ops = Operators(F, len(Vn))
    Z, s = probe_block(ops.n, False, n_probes=6)
    at = shifted_quadrature(Vn, ops, 2, Z, s)
    for mu in (0.003, 0.2, 5.0):
        p, ref = at(mu), solve_point(Vn, ops, 2, mu, Z, s)
        assert p.X is None
        np.testing.assert_allclose([p.residual_sq, p.trace], [ref.residual_sq, ref.trace], rtol=1e-10)
    oracle = best_shifted(Vn, ops, 1, None, Criterion("oracle", V), None, center=0.3, search="quadrature")
    assert oracle.X is not None and oracle.score == pytest.approx(np.sum((oracle.X - V) ** 2), rel=1e-12)
    with pytest.raises(ValueError, match="search must be one of"):
        best_shifted(Vn, ops, 1, 0.02, "sure", search="lanczos")


def test_best_shifted_without_coordinates_and_shifted_coordinates_against_dense():
    _, Vn, F = _noisy(torus(30, 15), 0.01)
    ops = Operators(F, len(Vn))
    p = best_shifted(Vn, ops, 2, 0.01, "sure", False, center=0.3, search="quadrature", coordinates=False)
    assert p.X is None
    for order, mu in ((1, 0.7), (2, 2.5)):
        A = np.eye(ops.n) + mu * np.linalg.matrix_power(ops.L.toarray(), order)
        X = shifted_coordinates(Vn, ops, order, mu)
        np.testing.assert_allclose(X, np.linalg.solve(A, Vn), rtol=0, atol=1e-9 * np.abs(Vn).max())


def test_best_shifted_strong_weight_coordinates_by_its_lanczos_run_not_cg(monkeypatch):
    """Past SearchConfig.coordinates_cg_bound the best point's coordinates come from the search's Lanczos run (no CG), as the
    dense solve gives them; below it by CG."""
    import meshdenoise.tuning.search as search

    _, Vn, F = _noisy(torus(30, 15), 0.3)  # strong noise: a large weight
    ops = Operators(F, len(Vn))
    calls = []
    real = search.shifted_coordinates
    monkeypatch.setattr(search, "shifted_coordinates", lambda *a, **k: calls.append(a[3]) or real(*a, **k))
    low = SearchConfig(coordinates_cg_bound=50)  # this small mesh's choice: a bound near 116
    p = best_shifted(Vn, ops, 2, 0.3, "sure", False, center=30.0, search="quadrature", config=low)
    assert shifted_cg_bound(ops, p.value, 2, 1e-10) > low.coordinates_cg_bound and not calls
    A = np.eye(ops.n) + p.value * np.linalg.matrix_power(ops.L.toarray(), 2)
    np.testing.assert_allclose(p.X, np.linalg.solve(A, Vn), rtol=0, atol=1e-9 * np.abs(Vn).max())
    q = best_shifted(Vn, ops, 2, 0.3, "sure", False, center=30.0, search="quadrature",
                     config=SearchConfig(coordinates_cg_bound=1e12))
    assert calls == [q.value] and q.value == p.value
    np.testing.assert_allclose(q.X, p.X, rtol=0, atol=1e-9 * np.abs(Vn).max())


# --------------------------------------------------------------------------- probes
def test_probe_count_by_size():
    assert [probe_count(n) for n in (10, 50_000, 60_000, 100_000, 300_000, 5_000_000)] == [24, 24, 20, 12, 4, 4]
    # a rule's own count (sobolev_gls: 8 up to 10,000 scored vertices, m x scored >= 80,000 above, at least 4)
    assert [probe_count(n, 8, 10_000) for n in (3_371, 10_000, 10_001, 16_000, 24_955, 90_000)] == [8, 8, 8, 5, 4, 4]
    for bad in ({"n": -1}, {"n": 2.5}, {"n": True}, {"n": 10, "most": 3}, {"n": 10, "reference": 0}):
        with pytest.raises(ValueError, match="probe_count"):
            probe_count(**bad)


# --------------------------------------------------------------------------- memoised curves
def test_path_curve_terms_and_coordinates_equal_the_walk():
    _, Vn, F = _noisy(icosphere(3), 0.03)
    ops = Operators(F, len(Vn))
    step = averaging_step(ops.P, 0.5)
    curve = PathCurve(Vn, ops, step, exact=False)
    walk = iterative_path(Vn, ops, step, exact=False)
    for p, q in zip(curve.points(), walk):
        np.testing.assert_allclose([p.residual_sq, p.trace], [q.residual_sq, q.trace], rtol=1e-12)
        if p.value in (0, 3, 11):
            np.testing.assert_array_equal(curve.coordinates(p.value), q.X)
        if p.value == 15:
            break


@pytest.mark.parametrize("rho", [0.005, 0.03, 0.1])
def test_sure_smoothed_on_the_memo_equals_the_old_walk(rho):
    _, Vn, F = _noisy(icosphere(3), rho)
    ops = Operators(F, len(Vn))
    MEMO.clear()
    for r in (rho, 0.5 * rho, 2 * rho):  # several rhos on one memoised run
        new = sure_smoothed(Vn, ops, r)
        old = best_on_path(iterative_path(Vn, ops, averaging_step(ops.P, 1.0), None), ops.n, r, "sure")
        assert new.value == old.value and new.score == pytest.approx(old.score, rel=1e-12)
        np.testing.assert_array_equal(new.X, old.X)
    assert any(k[0] == "path" for k in MEMO)


@pytest.mark.parametrize("method, given", [("filtering", {}), ("filtering", {"weights": "meshlab", "lam": 0.5}),
                                           ("heat", {}), ("taubin", {})])
def test_rules_on_the_memo_choose_what_the_old_walk_chose(method, given, monkeypatch):
    # taubin on 288 vertices: it walks the same three step sizes (0.5, 0.25, 0.125) as on 800, in 1 s instead of 15
    V, Vn, F = _noisy(torus(24, 12) if method == "taubin" else torus(40, 20), 0.02)
    MEMO.clear()
    new = choose_parameters((Vn, F), method, noise=0.02, **given)
    import meshdenoise.plugins.filtering_rule as filtering_mod
    import meshdenoise.plugins.heat_rule as heat_mod
    import meshdenoise.plugins.taubin_rule as taubin_mod

    def old_curve(V_, ops, step, name, exact=None):  # the old walk: a fresh run, every step's coordinates
        return _OldWalk(V_, ops, step, exact)

    for mod in (filtering_mod, heat_mod, taubin_mod):
        monkeypatch.setattr(mod, "path_curve", old_curve)
    old = choose_parameters((Vn, F), method, noise=0.02, **given)
    assert new == old


class _OldWalk:
    """:func:`iterative_path` dressed as a curve (what the rules walked before the memo)."""

    def __init__(self, V, ops, step, exact):
        self.path = iterative_path(V, ops, step, exact)

    def points(self):
        return self.path

    def coordinates(self, k):  # pragma: no cover - the rules ask for none
        raise AssertionError


def test_taubin_tries_finer_steps_only_while_the_count_is_small():
    import meshdenoise.plugins.taubin_rule as taubin_mod

    _, Vn, F = _noisy(torus(40, 20), 0.04)
    full = choose_parameters((Vn, F), "taubin", noise=0.04)
    pruned = choose_parameters((Vn, F), "taubin", noise=0.04, config=taubin_mod.TaubinConfig(fine_min_vertices=0))
    at_half = choose_parameters((Vn, F), "taubin", noise=0.04, lam=0.5, mu=-0.53)
    assert at_half["iterations"] >= taubin_mod.TaubinConfig().fine_max_iterations  # this mesh's count: pruning applies
    assert pruned == {**at_half, "lam": 0.5, "mu": -0.53}
    assert full["lam"] in taubin_mod.TAUBIN_LAMBDAS


# --------------------------------------------------------------------------- sobolev_bilaplacian's CG solver
def test_bilaplacian_cg_equals_dense_solve_and_auto_picks_cg_only_when_large():
    import meshdenoise.plugins.sobolev_bilaplacian as bl
    from meshdenoise.plugins.sobolev import SobolevConfig
    from meshdenoise.operators import get_operators

    _, Vn, F = _noisy(torus(30, 15), 0.01)
    ops = Operators(F, len(Vn))
    pinned = np.zeros(ops.n, dtype=bool)
    pinned[::17] = True
    for mu, pin in ((0.3, None), (4.0, pinned)):
        L2 = np.linalg.matrix_power(ops.L.toarray(), 2)
        A = np.eye(ops.n) + mu * L2
        if pin is None:
            expected = np.linalg.solve(A, Vn)
        else:  # Dirichlet rows: free rows solved with the pinned values moved to the right-hand side
            f, q = ~pin, pin
            expected = Vn.copy()
            expected[f] = np.linalg.solve(A[np.ix_(f, f)], Vn[f] - mu * L2[np.ix_(f, q)] @ Vn[q])
        for solver in ("cg", "lanczos"):  # lanczos with pinned vertices: CG
            Y, _ = bl.sobolev_bilaplacian((Vn, F), mu=mu, solver=solver, tol=1e-12, pinned=pin)
            np.testing.assert_allclose(Y, expected, rtol=0, atol=1e-9 * np.abs(Vn).max())
        if pin is None:
            Y = bl.lanczos_bilaplacian(ops, Vn, mu, 1e-10)
            np.testing.assert_allclose(Y, expected, rtol=0, atol=1e-10 * np.abs(Vn).max())
    ops = get_operators(F, len(Vn))
    assert bl._choose_solver(ops, 1.0, None, 1e-10) == "cholesky"  # small mesh: the factor is cheap and kept
    config = bl.BilaplacianConfig(lanczos_min_vertices=0)
    assert bl._choose_solver(ops, 1.0, None, 1e-10, config) == "lanczos"
    assert bl.bilaplacian_cg_bound(ops, 1.0, 1e-10) == pytest.approx(0.5 * np.sqrt(1 + 12.0**2) * np.log(2e10))  # 143
    assert bl._choose_solver(ops, 1.0, pinned, 1e-10, config) == "cholesky"  # pinned: a factor below its size
    config = bl.BilaplacianConfig(lanczos_min_vertices=0, pinned_cg_min_vertices=0)
    assert bl._choose_solver(ops, 1.0, pinned, 1e-10, config) == "cg"  # ... then CG while under pinned_cg_bound
    config = bl.BilaplacianConfig(lanczos_min_vertices=0, pinned_cg_min_vertices=0, pinned_cg_bound=100)
    assert bl._choose_solver(ops, 1.0, pinned, 1e-10, config) == "cholesky"
    large = SobolevConfig(cg_min_vertices=0)
    assert bl._choose_solver(ops, 1.0, pinned, 1e-10, config, large) == "cg"  # from there sobolev's bound (300)
    assert bl._choose_solver(ops, 1e4, None, 1e-10, config, large) == "lanczos"  # its steps grow like mu^(1/4)
    assert bl._choose_solver(ops, 1e4, pinned, 1e-10, config, large) == "cholesky"  # CG's bound too large
    bl.sobolev_bilaplacian((Vn, F), mu=1.0, solver="cholesky")  # the factor stored: reused
    assert bl._choose_solver(ops, 1.0, None, 1e-10, config, large) == "cholesky"


def test_path_curve_memo_is_keyed_by_the_probes(monkeypatch):
    import meshdenoise.tuning.search as search

    _, Vn, F = _noisy(icosphere(3), 0.02)
    ops = Operators(F, len(Vn))
    MEMO.clear()
    step = averaging_step(ops.P, 1.0)
    a = path_curve(Vn, ops, step, ("P", 1.0), exact=False)
    assert path_curve(Vn, ops, step, ("P", 1.0), exact=False) is a
    plain = search.probe_block
    monkeypatch.setattr(search, "probe_block", lambda *args, **kw: (2.0 * plain(*args, **kw)[0], plain(*args, **kw)[1]))
    b = path_curve(Vn, ops, step, ("P", 1.0), exact=False)  # other probes (a coloured noise model): another run
    assert b is not a and np.array_equal(b.Z, 2.0 * a.Z)


# ----------------------------------------------------------------------------- sobolev_normal / sobolev_gls at scale
@pytest.mark.parametrize("order, mu", [(1, 0.3), (2, 4.0), (3, 0.5), (3, 60.0)])
def test_lanczos_shifted_equals_a_dense_solve(order, mu):
    from meshdenoise.solvers import lanczos_shifted
    from meshdenoise.shapes import grid

    V, F = grid(9, 7)  # open: a border, and a zero eigenvalue
    V = V + 0.05 * np.random.default_rng(0).standard_normal(V.shape)
    ops = get_operators(F, len(V))
    L = ops.L.toarray()
    expected = np.linalg.solve(np.eye(len(V)) + mu * np.linalg.matrix_power(L, order), V)
    np.testing.assert_allclose(lanczos_shifted(ops, V, mu, order, tol=1e-13), expected, atol=1e-10)
    np.testing.assert_allclose(lanczos_shifted(ops, V[:, 0], mu, order, tol=1e-13), expected[:, 0], atol=1e-10)
    assert lanczos_shifted(ops, V, 1e6, order, max_steps=3) is None
    with pytest.raises(ValueError, match="mu"):
        lanczos_shifted(ops, V, -1.0, order)
    with pytest.raises(ValueError, match="order"):
        lanczos_shifted(ops, V, 1.0, 0)


def test_sobolev_normal_factor_free_path_equals_the_factor_path(monkeypatch):
    import meshdenoise.plugins.sobolev_normal as sn

    V, F = icosphere(3)
    Vn, _ = add_normal_noise((V, F), 0.02, seed=0)
    for order, mu, t in ((2, 3.0, 0.0), (3, 0.7, 0.4)):
        clear_cache()
        before = apply_filter("sobolev_normal", (Vn, F), mu=mu, order=order, tangential=t)[0]
        clear_cache()
        monkeypatch.setattr(sn, "shifted_solver", lambda *a, **k: pytest.fail("a factor was built"))
        after = get_filter("sobolev_normal").core(Vn, F, ops=get_operators(F, len(Vn)), pinned=None, mu=mu, order=order,
                                                  tangential=t, config=sn.SobolevNormalConfig(lanczos_min_vertices=0))
        monkeypatch.undo()
        np.testing.assert_allclose(after, before, atol=1e-11)


@pytest.mark.parametrize("method", ["sobolev_normal", "sobolev_gls", "sinkhorn"])
def test_region_rule_is_not_used_below_its_size(monkeypatch, method):
    """Every quality-table mesh is below SearchConfig.region_min_vertices: the rule runs on the whole mesh, as before."""
    import meshdenoise.tuning.region as region

    monkeypatch.setattr(region, "SampledRegion", lambda *a, **k: pytest.fail("a region was cut"))
    V, F = icosphere(2)
    Vn, _ = add_normal_noise((V, F), 0.02, seed=0)
    params = choose_parameters((Vn, F), method, noise=0.02)
    assert params["t" if method == "sinkhorn" else "mu"] > 0


def test_sinkhorn_rule_scores_a_regions_inner_vertices_and_cuts_again_while_its_choice_reaches_further(monkeypatch):
    """From SearchConfig.region_min_vertices the rule runs on a sampled region; a free border pulls its choice low,
    and while the choice's reach (sinkhorn_reach) is wider than the margin used the region is cut again with that
    margin (here the second region would be the whole mesh, so the whole-mesh rule decides). The first cut's margin is
    the reach of the search's start (first_margin), here narrowed to see the second cut. On a 24,000-vertex torus the third
    cut's choice is within 0.4 % of the whole mesh's t."""
    import meshdenoise.plugins.sinkhorn_rule as sk
    import meshdenoise.tuning.search as search

    V, F = torus(100, 60)
    rho = 0.3 * float(np.linalg.norm(V[F[:, 0]] - V[F[:, 1]], axis=1).mean())
    Vn, _ = add_normal_noise((V, F), rho, seed=0)
    whole = choose_parameters((Vn, F), "sinkhorn", noise=rho)
    MEMO.clear()
    config = (SearchConfig(region_min_vertices=1000), sk.SinkhornConfig(region=3000, patches=2))
    start = sk.first_margin(TuningContext(Vn, F, get_operators(F, len(V)), rho, Criterion("sure"), None, {}))
    assert sk.SINKHORN_MARGIN < start <= search.REGION_MAX_MARGIN
    monkeypatch.setattr(sk, "first_margin", lambda ctx: sk.SINKHORN_MARGIN)  # (the start's margin: the whole torus)
    calls = []
    real = sk.choose_sinkhorn_whole
    monkeypatch.setattr(sk, "choose_sinkhorn_whole",
                        lambda ctx, scored=None: calls.append((ctx.n, scored)) or real(ctx, scored))
    params = choose_parameters((Vn, F), "sinkhorn", noise=rho, config=config)
    (n_region, scored), (n_last, last) = calls
    assert n_region < len(V) and 0 < scored.sum() < n_region
    assert (n_last, last) == (len(V), None) and params == whole
    first = real(TuningContext(Vn, F, get_operators(F, len(V)), rho, Criterion("sure"), None, {}), None)[0]
    assert first == whole and sk.sinkhorn_reach(whole) > sk.SINKHORN_MARGIN


def test_sinkhorn_rule_scoring_every_vertex_is_the_whole_mesh_rule():
    V, F = icosphere(3)
    Vn, _ = add_normal_noise((V, F), 0.02, seed=1)
    import meshdenoise.plugins.sinkhorn_rule as sk

    ctx = TuningContext(Vn, F, get_operators(F, len(V)), 0.02, Criterion("sure"), False, {})
    a, pa = sk.choose_sinkhorn_whole(ctx, None)
    MEMO.clear()
    b, pb = sk.choose_sinkhorn_whole(ctx, np.ones(len(V), dtype=bool))
    assert a == b and pa.score == pytest.approx(pb.score, rel=1e-12)
    # two-thirds of the vertices scored: the score counts those only (residual, probes and n)
    half = np.arange(len(V)) % 3 > 0
    _, pc = sk.choose_sinkhorn_whole(ctx, half)
    assert pc.residual_sq < pa.residual_sq


def test_sinkhorn_rule_on_scored_vertices_traces_the_scored_diagonal_of_the_dense_smoother():
    import meshdenoise.plugins.sinkhorn_rule as sk
    from meshdenoise.registry import get_filter

    V, F = icosphere(2)
    Vn, _ = add_normal_noise((V, F), 0.03, seed=2)
    ops = get_operators(F, len(V))
    scored = np.arange(len(V)) % 4 > 0
    ctx = TuningContext(Vn, F, ops, 0.03, Criterion("sure"), True, {})  # exact traces: identity probes
    params, point = sk.choose_sinkhorn_whole(ctx, scored)
    p = get_filter("sinkhorn").resolve(params)  # the rule's configuration: graph Laplacian, uniform measure
    L = ops.L.toarray()
    G = np.linalg.matrix_power(np.linalg.inv(np.eye(len(V)) + p["t"] / p["steps"] * L), p["steps"])
    H = np.linalg.matrix_power(2 * G - G @ G, p["iterations"])  # the dense smoother (2G - G^2)^k
    assert point.trace == pytest.approx(float(np.trace(H[np.ix_(scored, scored)])), rel=1e-9)
    Y = H @ Vn
    assert point.residual_sq == pytest.approx(float(np.sum((Y - Vn)[scored] ** 2)), rel=1e-9)


def test_sobolev_normal_region_search_runs_on_a_cut_region_with_the_whole_mesh_tangential(monkeypatch):
    """The wiring of region_rule: a region is cut (grown to patches x 19 x margin^2 vertices), the rule scores its
    inner vertices with the whole mesh's tangential share held, and the risk is scaled to the whole mesh. Its
    quality against the whole-mesh search is measured in docs/scale.md (elephant at 100k; a torus where it fails)."""
    import meshdenoise.plugins.sobolev_normal_rule as sn
    import meshdenoise.tuning.region as region
    from meshdenoise.plugins.sobolev_normal import SobolevNormalConfig

    V, F = torus(100, 60)
    rho = 0.4 * float(np.linalg.norm(V[F[:, 0]] - V[F[:, 1]], axis=1).mean())
    Vn, _ = add_normal_noise((V, F), rho, seed=0)
    config = (SearchConfig(region_min_vertices=1000),
              SobolevNormalConfig(region=3000, patches=4))  # grown by region_shape to 4 x 19 x 8^2 = 4864
    cut, scored = [], []
    real_region, real_rule = region.SampledRegion, sn.choose_sobolev_normal_whole
    monkeypatch.setattr(region, "SampledRegion", lambda *a, **k: cut.append(real_region(*a, **k)) or cut[-1])

    def spy(ctx, mask, **kw):
        scored.append((ctx, mask, kw))
        return real_rule(ctx, mask, **kw)

    monkeypatch.setattr(sn, "choose_sobolev_normal_whole", spy)
    params, risk = choose_parameters((Vn, F), "sobolev_normal", noise=rho, return_risk=True, config=config)
    assert len(cut) == 1 and not cut[0].whole and 4864 <= cut[0].vertices.size < len(V)
    (ctx, mask, kw), = scored
    pinned, _ = kw["boundary"]  # the region's outer SobolevNormalConfig.pin rings, held at the whole mesh's result
    assert pinned.any() and not (pinned & mask).any()
    assert ctx.n == cut[0].vertices.size and np.array_equal(mask, cut[0].inner) and 0 < mask.sum() < ctx.n
    np.testing.assert_array_equal(ctx.V, Vn[cut[0].vertices])
    whole_t = sn.normal_trust(rho, sn.mean_edge_length(
        real_rule.__globals__["TuningContext"](Vn, F, get_operators(F, len(V)), rho, Criterion("sure"), None, {})
        .smoothed("sure").X, get_operators(F, len(V))))
    assert ctx.given == {"tangential": whole_t} and params["tangential"] == whole_t
    assert set(params) == {"mu", "order", "tangential"}
    sub_params, sub_point = real_rule(ctx, mask, **kw)
    # the same rule again: the held border's Lanczos run has been extended meanwhile (values moved by about 1e-9),
    # and the parabolic refinement's candidates follow the scores continuously
    assert {k: v for k, v in sub_params.items() if k != "mu"} == {k: v for k, v in params.items() if k != "mu"}
    assert sub_params["mu"] == pytest.approx(params["mu"], rel=1e-6)
    assert risk == pytest.approx(sub_point.score * len(V) / mask.sum(), rel=1e-6)


def test_region_rule_cuts_again_with_the_margin_the_choice_needs(monkeypatch):
    """A choice that needs a wider margin than the region had: cut again with it; the whole mesh once too large."""
    import meshdenoise.tuning.region as region
    import meshdenoise.tuning.search as search

    V, F = torus(100, 60)
    Vn, _ = add_normal_noise((V, F), 0.01, seed=0)
    ctx = TuningContext(Vn, F, get_operators(F, len(V)), 0.01, Criterion("sure"), None, {})
    cut, calls = [], []
    real_region = region.SampledRegion
    monkeypatch.setattr(region, "SampledRegion", lambda *a, **k: cut.append(real_region(*a, **k)) or cut[-1])

    def rule(c, mask):
        calls.append((c.n, None if mask is None else int(mask.sum())))
        return {"mu": 1.0}, Point(1.0, 1.0, 1.0, None, 1.0)

    needs = iter([9, 9])
    search.region_rule(ctx, rule, 1000, 2, 4, min_vertices=10, reach=lambda chosen: next(needs))
    assert [c.radius > 0 for c in cut] == [True, True] and len(calls) == 2
    assert cut[1].vertices.size >= 2 * 19 * 81 > cut[0].vertices.size  # grown for a 9-ring margin
    assert calls[1][1] < calls[1][0]
    calls.clear()
    search.region_rule(ctx, rule, 1000, 2, 4, min_vertices=10, reach=lambda chosen: 16)  # 2 x 19 x 256 > n
    assert calls[-1] == (len(V), None)


def test_sobolev_normal_scored_rule_with_every_vertex_scored_is_the_whole_rule():
    from meshdenoise.plugins.sobolev_normal_rule import choose_sobolev_normal_whole
    from meshdenoise.tuning import TuningContext

    V, F = torus(16, 8)
    Vn, _ = add_normal_noise((V, F), 0.05, seed=2)
    ops = get_operators(F, len(V))
    for given in ({}, {"tangential": 0.5}):
        ctx = TuningContext(Vn, F, ops, 0.05, Criterion("sure"), None, dict(given))
        (c0, p0), (c1, p1) = choose_sobolev_normal_whole(ctx, None), choose_sobolev_normal_whole(ctx, np.ones(len(V), bool))
        assert c0 == c1 and p0.score == pytest.approx(p1.score, rel=1e-12)


def test_sobolev_axes_quadrature_search_chooses_the_factor_search_weights(monkeypatch):
    """Same candidates scored by quadrature and by a factor per mu (the independent path): same mu1..mu3, same risk."""
    import meshdenoise.plugins.sobolev_axes_rule as ax

    V, F = torus(40, 20)
    Vn, _ = add_normal_noise((V, F), 0.03, seed=0)
    monkeypatch.setattr(ax, "probe_count", lambda n: 24)
    old, old_risk = choose_parameters((Vn, F), "sobolev_axes", noise=0.03, exact_trace=False, return_risk=True,
                                      config=SearchConfig(quadrature_min_vertices=10**9))
    monkeypatch.setattr(ax, "solve_shifted", lambda *a, **k: pytest.fail("a factor was used"))
    new, new_risk = choose_parameters((Vn, F), "sobolev_axes", noise=0.03, exact_trace=False, return_risk=True,
                                      config=SearchConfig(quadrature_min_vertices=100))
    for name in ("mu1", "mu2", "mu3"):
        assert new[name] == pytest.approx(old[name], rel=1e-9)
    assert new["frame_steps"] == old["frame_steps"]
    assert new_risk == pytest.approx(old_risk, rel=1e-8)


def test_sobolev_axes_quadrature_by_one_run_per_column_chooses_as_one_run(monkeypatch):
    """Past AxesConfig.one_run_max_vertices the quadrature is one run per column (the probes' LanczosDots with their three
    weighted duals): the same weights and risk as the one compiled run of every column."""
    import meshdenoise.plugins.sobolev_axes_rule as ax
    from meshdenoise.plugins.sobolev_axes import AxesConfig

    V, F = torus(40, 20)
    Vn, _ = add_normal_noise((V, F), 0.03, seed=0)
    quadrature = SearchConfig(quadrature_min_vertices=100)
    monkeypatch.setattr(ax, "solve_shifted", lambda *a, **k: pytest.fail("a factor was used"))
    one, one_risk = choose_parameters((Vn, F), "sobolev_axes", noise=0.03, exact_trace=False, return_risk=True,
                                      config=quadrature)
    each, each_risk = choose_parameters((Vn, F), "sobolev_axes", noise=0.03, exact_trace=False, return_risk=True,
                                        config=(quadrature, AxesConfig(one_run_max_vertices=100)))
    assert each == pytest.approx(one, rel=1e-9)
    assert each_risk == pytest.approx(one_risk, rel=1e-5)


def test_sobolev_axes_factor_free_filter_equals_the_factor_filter(monkeypatch):
    import meshdenoise.plugins.sobolev_axes as ax

    V, F = icosphere(3)
    Vn, _ = add_normal_noise((V, F), 0.02, seed=0)
    params = dict(mu1=0.3, mu2=0.0, mu3=4.0, order=3, frame_steps=2)
    clear_cache()
    before = apply_filter("sobolev_axes", (Vn, F), **params)[0]
    monkeypatch.setattr(ax, "shifted_solver", lambda *a, **k: pytest.fail("a factor was built"))
    clear_cache()
    spec = get_filter("sobolev_axes")
    after = spec.core(Vn, F, ops=get_operators(F, len(Vn)), pinned=None, config=ax.AxesConfig(lanczos_min_vertices=0),
                      **spec.resolve(params))
    np.testing.assert_allclose(after, before, atol=1e-11)


# --------------------------------------------------------------------------- cheaper region searches
def test_search_log_narrow_grid_finds_the_minimum_with_few_evaluations():
    """A quadratic in log10 mu with its minimum at 0.3: the default grid and the narrow refining grid both find it;
    the narrow one (three points 0.2 decades apart, 4 golden steps) from a start 0.15 decades off in at most 9."""
    from meshdenoise.tuning.search import search_log

    seen = []

    def evaluate(mu):
        seen.append(mu)
        t = np.log10(mu)
        return Point(mu, 0.0, 0.0, None, (t - 0.3) ** 2)

    assert abs(np.log10(search_log(evaluate, 1.0, golden_steps=8).value) - 0.3) < 0.05
    seen.clear()
    best = search_log(evaluate, 10**0.45, golden_steps=4, spacing=0.2, half_width=1)
    assert abs(np.log10(best.value) - 0.3) < 0.05 and len(seen) <= 9
    seen.clear()  # a start far off: the grid is extended while the minimum sits at its end
    assert abs(np.log10(search_log(evaluate, 10**-1.0, golden_steps=4, spacing=0.2, half_width=1).value) - 0.3) < 0.1
    with pytest.raises(ValueError, match="spacing"):
        search_log(evaluate, 1.0, spacing=0.0)


def test_region_rule_restart_hands_the_previous_choice_to_the_next_run(monkeypatch):
    """restart=True: a run after the first gets the choice of the run before as its third argument."""
    import meshdenoise.tuning.search as search

    V, F = torus(100, 60)
    Vn, _ = add_normal_noise((V, F), 0.01, seed=0)
    ctx = TuningContext(Vn, F, get_operators(F, len(V)), 0.01, Criterion("sure"), None, {})
    calls = []

    def rule(c, mask, previous=None):
        calls.append(previous)
        return {"mu": 1.0 + len(calls)}, Point(1.0, 1.0, 1.0, None, 1.0)

    needs = iter([9, 9])
    chosen, _ = search.region_rule(ctx, rule, 1000, 2, 4, min_vertices=10, reach=lambda c: next(needs), restart=True)
    assert calls == [None, {"mu": 2.0}] and chosen == {"mu": 3.0}
    calls.clear()
    search.region_rule(ctx, rule, 1000, 2, 4, min_vertices=10, reach=lambda c: 4, restart=True)  # one run
    assert calls == [None]


def test_solve_shifted_without_memo_equals_a_dense_solve_and_keeps_nothing():
    """memo=False (the region searches): the same solve, no factor stored on the operators, nothing in the memo."""
    from meshdenoise.tuning.search import solve_shifted

    V, F = icosphere(2)
    ops = Operators(F, len(V))
    rhs = np.random.default_rng(0).standard_normal((len(V), 5))
    MEMO.clear()
    before = len(MEMO)
    for order, mu in ((2, 0.7), (3, 2.0)):
        A = np.eye(len(V)) + mu * np.linalg.matrix_power(ops.L.toarray(), order)
        np.testing.assert_allclose(solve_shifted(ops, order, mu, rhs, memo=False), np.linalg.solve(A, rhs), atol=1e-10)
    assert not any(k.startswith("shifted-") for k in ops.cache) and len(MEMO) == before


def test_lanczos_rows_equals_a_dense_matrix_function_at_the_rows():
    from meshdenoise.solvers import LanczosRows

    V, F = icosphere(2)
    L = Operators(F, len(V)).L
    lam, U = np.linalg.eigh(L.toarray())
    B = np.random.default_rng(0).standard_normal((len(V), 3))
    rows = np.array([0, 5, 17, 100])
    run = LanczosRows(L, B, rows)
    for g in (lambda t: 1.0 / (1.0 + 2.0 * t**3), lambda t: np.maximum(t, 0) / (1.0 + 0.3 * np.maximum(t, 0) ** 2)):
        np.testing.assert_allclose(run.rows_apply(g, rtol=1e-12), ((U * g(lam)) @ U.T @ B)[rows], atol=1e-9)
    assert LanczosRows(L, B, rows, max_steps=3).rows_apply(lambda t: 1.0 / (1.0 + 50.0 * t**3)) is None


def test_region_held_at_the_whole_result_on_its_cut_rings_reproduces_the_whole_mesh():
    """The cause of the region's low choice (docs/scale.md): with a free cut the region's result at strong smoothing
    (torus, mu = 80, order 3) differs from the whole mesh's by a sizable fraction of rho on the scored vertices,
    however deep; held on its outer 3 rings at the whole mesh's result (whole_result_at, checked against a factor
    solve) its free rows are the whole mesh's result."""
    from meshdenoise.plugins.sobolev_normal_rule import whole_result_at
    from meshdenoise.solvers import SPDSolver, shifted_matrix
    from meshdenoise.tuning.region import SampledRegion

    V, F = torus(60, 36)
    rho = 0.4 * float(np.linalg.norm(V[F[:, 0]] - V[F[:, 1]], axis=1).mean())
    Vn, _ = add_normal_noise((V, F), rho, seed=0)
    ops = get_operators(F, len(V))
    region = SampledRegion(F, ops, 800, 2, 8, 0)
    sub = Operators(region.F, region.vertices.size)
    pinned = region.cut_rings(2) <= 2
    ctx = TuningContext(Vn, F, ops, rho, Criterion("sure"), None, {})
    values = whole_result_at(ctx, region.vertices[pinned])
    for mu, order in ((80.0, 3), (5.0, 2)):
        whole = SPDSolver(shifted_matrix(ops, mu, order)).solve(Vn)[region.vertices]
        np.testing.assert_allclose(values(mu, order), whole[pinned], atol=1e-8 * rho)
        rhs = Vn[region.vertices].copy()
        rhs[pinned] = values(mu, order)
        held = SPDSolver(shifted_matrix(sub, mu, order), pinned).solve(rhs)
        np.testing.assert_allclose(held[~pinned], whole[~pinned], atol=1e-6 * rho)
    free = SPDSolver(shifted_matrix(sub, 80.0, 3)).solve(Vn[region.vertices])
    whole80 = SPDSolver(shifted_matrix(ops, 80.0, 3)).solve(Vn)[region.vertices]
    drift = np.sqrt(np.mean(np.sum((free - whole80)[region.inner] ** 2, axis=1)))
    assert region.inner.any() and drift > 0.1 * rho


def test_curve_terms_are_the_records_sums_on_any_thread_count(monkeypatch):
    """kernels.curve_terms against numpy's sums; PathCurve takes it from SearchConfig.curve_kernel_min_vertices on."""
    import numba

    from meshdenoise import kernels
    from meshdenoise.tuning import search

    rng = np.random.default_rng(3)
    n = 3 * kernels.CURVE_CHUNK + 17
    V, Z = rng.standard_normal((n, 3)), rng.choice([-1.0, 1.0], size=(n, 4))
    Y = np.hstack([V + 0.01 * rng.standard_normal((n, 3)), 0.5 * Z + rng.standard_normal((n, 4))])
    r, t = kernels.curve_terms(Y, V, Z)
    assert r == pytest.approx(float(np.sum((Y[:, :3] - V) ** 2)), rel=1e-12)
    assert t == pytest.approx(float(np.sum(Z * Y[:, 3:])), rel=1e-12)
    monkeypatch.setattr(kernels, "set_threads", lambda: numba.set_num_threads(1) or 1)
    assert kernels.curve_terms(Y, V, Z) == (r, t)  # the same bits on one thread
    with pytest.raises(ValueError, match="do not match"):
        kernels.curve_terms(Y[:, :6], V, Z)
    Vs, Fs = icosphere(3)
    ops = Operators(Fs, len(Vs))
    step = search.averaging_step(ops.P, 0.5)
    Zs = probe_block(len(Vs), False, n_probes=4)
    old = search.PathCurve(Vs, ops, step, probes=Zs)
    new = search.PathCurve(Vs, ops, step, probes=Zs, config=SearchConfig(curve_kernel_min_vertices=len(Vs)))
    for a, b in zip(new.points(), old.points()):
        assert a.residual_sq == pytest.approx(b.residual_sq, rel=1e-12, abs=1e-300)
        assert a.trace == pytest.approx(b.trace, rel=1e-12)
        if a.value == 12:
            break


# --------------------------------------------------------------------------- LogSearch's two phases
def _reference_search_log(evaluate, center, golden_steps=8, lo_limit=-8.0, hi_limit=10.0, spacing=0.75, half_width=2):
    """The log search written out in one function (grid extended at its ends, then golden section), for comparison."""
    import math

    cache = {}

    def at(t):
        t = round(t, 12)
        if t not in cache:
            cache[t] = evaluate(10.0**t)
        return cache[t]

    grid = [math.log10(center) + spacing * j for j in range(-half_width, half_width + 1)]
    while True:
        scores = [at(t).score for t in grid]
        i = int(np.argmin(scores))
        if i == 0 and grid[0] > lo_limit:
            grid.insert(0, grid[0] - spacing)
        elif i == len(grid) - 1 and grid[-1] < hi_limit:
            grid.append(grid[-1] + spacing)
        else:
            break
    a, b = grid[max(i - 1, 0)], grid[min(i + 1, len(grid) - 1)]
    g = (math.sqrt(5) - 1) / 2
    c, d = b - g * (b - a), a + g * (b - a)
    for _ in range(golden_steps):
        if at(c).score < at(d).score:
            b, d = d, c
            c = b - g * (b - a)
        else:
            a, c = c, d
            d = a + g * (b - a)
    return min(cache.values(), key=lambda p: p.score)


@pytest.mark.parametrize("center, minimum, kwargs", [
    (1.0, 0.3, {}), (1e-3, 1.7, {}), (50.0, -2.2, {"golden_steps": 5}),
    (10**0.45, 0.3, {"golden_steps": 4, "spacing": 0.2, "half_width": 1}),
])
def test_search_log_evaluates_the_same_points_in_the_same_order_as_the_reference(center, minimum, kwargs):
    from meshdenoise.tuning.search import search_log

    def recorder(seen):
        def evaluate(mu):
            seen.append(mu)
            t = np.log10(mu)
            return Point(mu, 0.0, 0.0, None, abs(t - minimum) ** 1.5 + 0.1 * np.sin(3 * t))
        return evaluate

    ours, ref = [], []
    assert search_log(recorder(ours), center, **kwargs).value == _reference_search_log(recorder(ref), center, **kwargs).value
    assert ours == ref


def test_log_search_predicts_a_parabolas_minimum_and_its_grid_score_at_an_end():
    from meshdenoise.tuning.search import LogSearch

    f = lambda mu: Point(mu, 0.0, 0.0, None, 2.0 * (np.log10(mu) - 0.3) ** 2 + 1.0)  # noqa: E731
    s = LogSearch(f, 1.0)
    assert s.bracket().value == 1.0  # the grid point nearest 0.3 decades
    assert s.predicted() == pytest.approx(1.0, abs=1e-12)  # exact for a parabola in t
    before = len(s.cache)
    assert abs(np.log10(s.refine().value) - 0.3) < 0.03 and len(s.cache) > before
    edge = LogSearch(f, 1e-3, hi_limit=-2.0)  # the minimum beyond hi_limit: the grid stops at its end
    assert edge.predicted() == edge.bracket().score
    with pytest.raises(ValueError, match="center"):
        LogSearch(f, 0.0)


def test_sobolev_normal_refines_only_an_order_that_can_still_win_and_chooses_as_with_both(monkeypatch):
    """The rule's grid for both orders, the golden section only for an order whose grid parabola comes within
    SobolevNormalConfig.order_margin of the least grid score: on a noisy plane (order 2's grid 0.0504, order 3's 0.0543,
    its parabola 0.0527) one order is refined, fewer evaluations, and the choice equals the one with both refined."""
    import meshdenoise.plugins.sobolev_normal_rule as sn
    from meshdenoise.plugins.sobolev_normal import SobolevNormalConfig
    from meshdenoise.tuning.search import LogSearch

    V, F = grid(40, 40)
    Vn = add_normal_noise((V, F), 0.02, seed=1)[0]
    counts = []

    class Counting(LogSearch):
        def __init__(self, evaluate, *args, **kwargs):
            counts.append(0)
            i = len(counts) - 1

            def counted(mu):
                counts[i] += 1
                return evaluate(mu)
            super().__init__(counted, *args, **kwargs)

    monkeypatch.setattr(sn, "LogSearch", Counting)
    chosen = choose_parameters((Vn, F), "sobolev_normal", noise=0.02)
    some = sum(counts)
    counts.clear()
    clear_cache()
    MEMO.clear()
    both = choose_parameters((Vn, F), "sobolev_normal", noise=0.02,
                             config=SobolevNormalConfig(order_margin=np.inf))  # every order refined
    assert chosen == both
    assert some < sum(counts)


def test_parabolic_refinement_is_exact_on_a_parabola_and_close_with_fewer_evaluations_on_smooth_scores():
    from scipy.optimize import minimize_scalar

    from meshdenoise.tuning.search import LogSearch

    parabola = lambda mu: Point(mu, 0.0, 0.0, None, 2.0 * (np.log10(mu) - 0.3) ** 2 + 1.0)  # noqa: E731
    s = LogSearch(parabola, 1.0)
    grid = len(s.cache) if s.bracket() else 0
    assert np.log10(s.refine_parabolic().value) == pytest.approx(0.3, abs=1e-9)
    assert len(s.cache) - grid == 1

    for minimum, shape in [(0.3, lambda x: np.cosh(2.0 * x)), (-1.37, lambda x: x**2 + 0.3 * x**3 + x**4),
                           (2.2, lambda x: np.log1p(4.0 * x * x))]:
        f = lambda mu, m=minimum, g=shape: Point(mu, 0.0, 0.0, None, float(g(np.log10(mu) - m)))  # noqa: E731
        truth = minimize_scalar(lambda t, m=minimum, g=shape: g(t - m), bracket=(minimum - 1, minimum + 1), tol=1e-10).x
        parabolic, golden = LogSearch(f, 1.0), LogSearch(f, 1.0)
        t_p, t_g = (float(np.log10(x.value)) for x in (parabolic.refine_parabolic(), golden.refine()))
        assert abs(t_p - truth) < 0.02 and abs(t_g - truth) < 0.03
        assert len(parabolic.cache) < len(golden.cache)

    flat = LogSearch(lambda mu: Point(mu, 0.0, 0.0, None, 1.0), 1.0)  # no parabola: golden steps, at most max_steps
    flat.bracket()
    before = len(flat.cache)
    flat.refine_parabolic(max_steps=5)
    assert len(flat.cache) - before <= 5
    with pytest.raises(ValueError, match="tol"):
        LogSearch(parabola, 1.0).refine_parabolic(tol=0.0)


def test_retain_factors_keeps_more_factorisations_within_the_block_and_trims_back_on_leaving(monkeypatch):
    """cached_solver keeps FACTORS_PER_FAMILY (4) per family, least recently used out; inside retain_factors(9) the
    last 9, so a search that comes back to an earlier weight reuses its factor; on leaving the family is trimmed back."""
    import meshdenoise.solvers as solvers

    assert solvers.FACTORS_PER_FAMILY == 4  # the sequences below are written for it
    V, F = icosphere(2)
    ops = Operators(F, len(V))
    built = []
    real = solvers.shifted_factor
    monkeypatch.setattr(solvers.shifted, "shifted_factor", lambda *a, **k: built.append(a[1]) or real(*a, **k))
    mus = [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7]
    L3 = np.linalg.matrix_power(ops.L.toarray(), 3)
    with solvers.retain_factors(9):
        for mu in mus + mus[:2]:  # seven weights, then back to the first two: no new factor
            X = solvers.shifted_solver(ops, mu, 3).solve(V)
            np.testing.assert_allclose(X + mu * L3 @ X, V, atol=1e-9)
        assert built == mus
    family = ops.cache["shifted-p3-cholesky"]
    assert [key[0] for key in family] == [0.6, 0.7, 0.1, 0.2]  # the four most recently used
    built.clear()
    for mu in mus + mus[:1]:  # outside the block: four kept, so coming back to 0.1 factorises it again
        solvers.shifted_solver(ops, mu, 3)
    assert built == [0.3, 0.4, 0.5, 0.6, 0.7, 0.1]
    with pytest.raises(ValueError, match="count"):
        with solvers.retain_factors(0):
            pass


@pytest.mark.parametrize("columns", [None, [2, 0]])
def test_apply_many_from_the_kept_basis_equals_the_regenerated_one(columns):
    """A run that keeps its first pass's basis (CompiledLanczos(keep_basis=...)) sums it in apply_many; one that keeps
    none regenerates it by a second pass: the same numbers to the bit, one function or several; a run outgrowing its
    budget drops the basis and regenerates, the same numbers again."""
    from meshdenoise.solvers import CompiledLanczos, ShiftedInverse

    V, F = icosphere(3)
    L = get_operators(F, len(V)).L
    B = np.random.default_rng(7).standard_normal((len(V), 3))
    gs = [ShiftedInverse(0.3, 2), lambda t: np.exp(-0.7 * t), (ShiftedInverse(2.0, 3), ShiftedInverse(0.1, 3), lambda t: np.sqrt(np.maximum(t, 0.0)))]
    kept, regenerated = CompiledLanczos(L, B, keep_basis=2**24), CompiledLanczos(L, B)
    small = CompiledLanczos(L, B, keep_basis=5 * 8 * B.size)  # five vectors: outgrown
    for many in (gs[:1], gs):
        want = regenerated.apply_many(many, rtol=1e-12, columns=columns)
        for got in (kept.apply_many(many, rtol=1e-12, columns=columns), small.apply_many(many, rtol=1e-12, columns=columns)):
            for a, b in zip(got, want):
                np.testing.assert_array_equal(a, b)
        assert kept._basis is not None and kept._kept == kept.steps + 1  # summed from the kept vectors
    assert small._basis is None and regenerated._basis is None
    for bad in (-1, 1.5, True):
        with pytest.raises(ValueError, match="keep_basis must be an int >= 0"):
            CompiledLanczos(L, B, keep_basis=bad)


def test_a_spectral_search_keeps_its_coordinates_basis_within_its_budget():
    """SpectralSearch's coordinates run keeps its basis (SpectralConfig.basis_bytes): every candidate's coordinates
    summed from it, the same as with none kept (a second pass per call)."""
    from meshdenoise.tuning.spectral import SpectralSearch, shifted_spectral

    V, F = icosphere(3)
    ops = get_operators(F, len(V))
    got = {}
    for budget in (SpectralConfig().basis_bytes, 0):
        search = SpectralSearch(V, lambda mu: shifted_spectral(ops, mu, 2), candidates=[0.1, 0.3, 1.0],
                                config=SpectralConfig(basis_bytes=budget))
        got[budget] = [search.coordinates(mu) for mu in (0.3, 1.0, 0.1)]
        assert (search._coords._basis is not None) == (budget > 0)
    for a, b in zip(*got.values()):
        np.testing.assert_array_equal(a, b)


def test_evaluate_tests_convergence_against_a_given_scale():
    """LanczosQuadrature.evaluate(scale=...): the change over the last steps is compared with scale(k) instead of the
    rule: a large scale stops at the first test, a tiny one runs on until the rule itself has converged."""
    from meshdenoise.solvers import CompiledLanczos, ShiftedInverse

    _, Vn, F = _noisy(torus(60, 30), 0.01)
    ops = Operators(F, len(Vn))
    B = np.random.default_rng(3).choice([-1.0, 1.0], size=(ops.n, 4))
    g = ShiftedInverse(50.0, 2)
    plain = CompiledLanczos(ops.L, B)
    ref = plain.evaluate(g, rtol=1e-8)
    loose = CompiledLanczos(ops.L, B)
    loose.evaluate(g, rtol=1e-8, scale=lambda k: np.full(4, 1e12))
    assert loose.steps == 10 < plain.steps
    tight = CompiledLanczos(ops.L, B)
    got = tight.evaluate(g, rtol=1e-8, scale=lambda k: np.abs(tight.quadrature(g, k=k)))
    assert tight.steps == plain.steps and np.array_equal(got, ref)

"""The paper's three filters against dense reference computations, and their invariants."""

import math

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as sla

import meshdenoise as md
from meshdenoise.operators import Operators, get_operators
from meshdenoise import solvers
from meshdenoise.plugins import sobolev as sobolev_module
from meshdenoise.shapes import grid, icosphere

from .conftest import noisy_sphere


def dense_P(F, n):
    W = np.zeros((n, n))
    for a, b in np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]):
        if a != b:
            W[a, b] = W[b, a] = 1
    return W / W.sum(1, keepdims=True)


def test_filtering_matches_dense_powers():
    V, Vn, F = noisy_sphere(subdivisions=2)
    P = dense_P(F, len(V))
    Y, F2 = md.filtering((Vn, F), iterations=7)
    np.testing.assert_allclose(Y, np.linalg.matrix_power(P, 7) @ Vn, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(F2, F)


def test_filtering_zero_iterations_is_identity_and_lam_relaxes():
    V, Vn, F = noisy_sphere(subdivisions=2)
    np.testing.assert_array_equal(md.filtering((Vn, F), iterations=0)[0], Vn)
    P = dense_P(F, len(V))
    Y, _ = md.filtering((Vn, F), iterations=3, lam=0.3)
    step = 0.7 * np.eye(len(V)) + 0.3 * P
    np.testing.assert_allclose(Y, np.linalg.matrix_power(step, 3) @ Vn, atol=1e-12)


def test_heat_matches_dense_euler_and_step_count():
    V, Vn, F = noisy_sphere(subdivisions=2)
    P = dense_P(F, len(V))
    A = np.eye(len(V)) - P
    tau, T = 0.3, 2.0
    X = Vn.copy()
    for _ in range(math.ceil(T / tau)):  # 7 steps, ending at t = 2.1
        X = X - tau * A @ X
    np.testing.assert_allclose(md.heat((Vn, F), tau=tau, time=T)[0], X, atol=1e-12)
    # T an exact multiple of tau: exactly T / tau steps, not one more from rounding
    X = Vn.copy()
    for _ in range(10):
        X = X - 0.1 * A @ X
    np.testing.assert_allclose(md.heat((Vn, F), tau=0.1, time=1.0)[0], X, atol=1e-12)


def test_heat_with_tau_one_equals_filtering():
    V, Vn, F = noisy_sphere(subdivisions=2)
    np.testing.assert_allclose(md.heat((Vn, F), tau=1.0, time=5)[0], md.filtering((Vn, F), iterations=5)[0], atol=1e-14)


def test_unstable_tau_raises_and_really_diverges(elephant):
    V, F = elephant
    with pytest.raises(ValueError, match=r"'tau' = 1.42 is out of the stable range 0 < tau <= 2 / lambda_max"):
        md.heat((V, F), tau=1.42, time=40)
    # the refusal is right: the Euler iteration itself blows up at tau = 1.42 ...
    ops = get_operators(F, len(V))
    rng = np.random.default_rng(0)
    x = rng.standard_normal(len(V))
    for _ in range(300):
        x = x - 1.42 * (x - ops.P @ x)
    assert np.abs(x).max() > 1e3
    # ... and a tau just inside the bound is accepted and stays bounded
    limit = 2.0 / ops.lambda_max()
    Y, _ = md.heat((V, F), tau=0.999 * limit, time=20)
    assert np.isfinite(Y).all() and np.abs(Y).max() < 2 * np.abs(V).max()


def test_lambda_max_bound_is_the_dense_one_on_a_small_mesh():
    V, F = icosphere(1)
    lam = np.linalg.eigvals(np.eye(len(V)) - dense_P(F, len(V))).real.max()
    limit = 2 / lam
    md.heat((V, F), tau=min(limit * 0.999, 2.0), time=1.0)
    if limit < 2.0:
        with pytest.raises(ValueError, match="stable range"):
            md.heat((V, F), tau=min(limit * 1.01, 2.0), time=1.0)


def test_sobolev_matches_dense_solve():
    V, Vn, F = noisy_sphere(subdivisions=2)
    n = len(V)
    W = (dense_P(F, n) > 0).astype(float)
    L = np.diag(W.sum(1)) - W
    for mu in (0.1, 2.0, 30.0):
        expected = np.linalg.solve(np.eye(n) + mu * L, Vn)
        np.testing.assert_allclose(md.sobolev((Vn, F), mu=mu)[0], expected, rtol=0, atol=1e-10)
    np.testing.assert_array_equal(md.sobolev((Vn, F), mu=0.0)[0], Vn)


def test_sobolev_on_elephant_matches_spsolve(elephant):
    V, F = elephant
    Vn, _ = md.add_normal_noise((V, F), rho=0.2, seed=1)
    ops = get_operators(F, len(V))
    expected = sla.spsolve((sp.identity(len(V)) + 3.0 * ops.L).tocsc(), Vn)
    np.testing.assert_allclose(md.sobolev((Vn, F), mu=3.0)[0], expected, rtol=0, atol=1e-9)


def test_sobolev_factorisation_is_cached_and_reused(monkeypatch):
    V, Vn, F = noisy_sphere(subdivisions=3)
    from meshdenoise import solvers

    built = []
    original = solvers.SPDSolver.__init__

    def counting_init(self, *args, **kwargs):
        built.append(1)
        original(self, *args, **kwargs)

    monkeypatch.setattr(solvers.SPDSolver, "__init__", counting_init)
    mu = 1.2345  # a value no other test uses, so the cache starts without it
    a = md.sobolev((Vn, F), mu=mu)[0]
    b = md.sobolev((V, F), mu=mu)[0]  # other coordinates, same faces: only the triangular solves
    assert len(built) == 1
    md.sobolev((V, F), mu=2 * mu)
    assert len(built) == 2
    assert not np.allclose(a, b)
    solver = solvers.shifted_solver(get_operators(F, len(V)), mu)
    np.testing.assert_allclose(solver.solve(Vn), a, atol=1e-14)


@pytest.mark.parametrize("order", [3, 4])
@pytest.mark.parametrize("mu", [1e-3, 1.0, 300.0, 1e5])
def test_higher_order_shifted_solver_by_real_factors_equals_the_spectral_solution(order, mu):
    # the exact (I + mu L^p)^-1 from L's eigenvectors: an independent computation of what the factors solve
    V, Vn, F = noisy_sphere(subdivisions=2)
    ops = Operators(F, len(V))  # not the cached topology: its factors are this test's own
    lam, Q = np.linalg.eigh(ops.L.toarray())
    lam = np.maximum(lam, 0.0)
    X = np.hstack([Vn, np.random.default_rng(1).standard_normal((len(V), 5))])
    exact = Q @ ((Q.T @ X) / (1.0 + mu * lam**order)[:, None])
    solver = solvers.shifted_solver(ops, mu, order)
    assert isinstance(solver, solvers.ShiftedProduct) and len(solver.factors) == 2
    # the factors' condition numbers are about the p-th root of I + mu L^p's (up to 6e8 here): measured 2e-12 at
    # most, where one factor of the matrix itself is off by 2e-9
    atol = 1e-11 * np.abs(X).max()
    np.testing.assert_allclose(solver.solve(X), exact, rtol=0, atol=atol)
    np.testing.assert_allclose(solver.solve(X[:, 0]), exact[:, 0], rtol=0, atol=atol)


def test_pinned_higher_order_shifted_solver_keeps_one_factor_of_the_matrix():
    V, Vn, F = noisy_sphere(subdivisions=2)
    ops = Operators(F, len(V))
    pinned = np.zeros(len(V), dtype=bool)
    pinned[:7] = True
    solver = solvers.shifted_solver(ops, 2.0, 3, pinned)
    assert isinstance(solver, solvers.SPDSolver)  # the free rows of a product are not the product of free rows
    A = np.eye(len(V)) + 2.0 * np.linalg.matrix_power(ops.L.toarray(), 3)
    free = ~pinned
    Y = solver.solve(Vn)
    np.testing.assert_array_equal(Y[pinned], Vn[pinned])
    np.testing.assert_allclose((A @ Y)[free], Vn[free], atol=1e-10)


def test_linear_filters_preserve_constants_and_commute_with_rotations():
    V, Vn, F = noisy_sphere(subdivisions=2)
    const = np.tile([[1.5, -2.0, 0.25]], (len(V), 1))
    theta = 0.7
    R = np.array([[np.cos(theta), -np.sin(theta), 0], [np.sin(theta), np.cos(theta), 0], [0, 0, 1]])
    for name, params in [("filtering", {"iterations": 5}), ("heat", {"tau": 0.4, "time": 3}), ("sobolev", {"mu": 2})]:
        np.testing.assert_allclose(md.apply_filter(name, (const, F), **params)[0], const, atol=1e-12)
        rotated_then = md.apply_filter(name, (Vn @ R.T, F), **params)[0]
        then_rotated = md.apply_filter(name, (Vn, F), **params)[0] @ R.T
        np.testing.assert_allclose(rotated_then, then_rotated, atol=1e-12)


def test_a_plane_stays_planar():
    V, F = grid(10, 10)
    rng = np.random.default_rng(3)
    V = V.copy()
    V[:, :2] += 0.01 * rng.standard_normal((len(V), 2))  # jitter within the plane
    for name, params in [("filtering", {"iterations": 5}), ("heat", {"tau": 0.5, "time": 3}), ("sobolev", {"mu": 2})]:
        Y = md.apply_filter(name, (V, F), **params)[0]
        np.testing.assert_array_equal(Y[:, 2], 0.0)


def test_denoising_improves_snr_on_a_noisy_sphere():
    V, Vn, F = noisy_sphere(rho=0.03, subdivisions=4)
    noisy = md.snr(V, Vn)
    for name, params in [("filtering", {"iterations": 2}), ("heat", {"tau": 0.5, "time": 1}), ("sobolev", {"mu": 0.5})]:
        assert md.snr(V, md.apply_filter(name, (Vn, F), **params)[0]) > noisy + 3


def test_every_filter_on_every_mesh_type(mesh_kind):
    """One fixture runs each registered filter on each mesh type; results agree with the array path."""
    from .conftest import make_mesh, vertices_of

    V, Vn, F = noisy_sphere(subdivisions=2)
    for spec in md.list_filters():
        expected = spec.public((Vn, F))[0]
        mesh = make_mesh(mesh_kind, Vn, F)
        out = spec.public(mesh)
        assert type(out) is type(mesh)
        np.testing.assert_allclose(vertices_of(out), expected, atol=1e-12, err_msg=spec.name)


def test_operators_argument_is_used_and_checked():
    V, Vn, F = noisy_sphere(subdivisions=2)
    ops = Operators(F, len(V))
    np.testing.assert_allclose(md.filtering((Vn, F), iterations=2, operators=ops)[0], md.filtering((Vn, F), iterations=2)[0])
    with pytest.raises(ValueError, match="another topology"):
        md.filtering((Vn, F), operators=Operators(F[:-1], len(V)))

"""solvers.ShiftedPCG: (I + mu L^p) Y = X by CG preconditioned by one factor of the one-ring matrix L + a I."""

from __future__ import annotations

import numpy as np
import pytest

from meshdenoise import solvers
from meshdenoise.operators import Operators
from meshdenoise.shapes import grid, icosphere


def _dense(ops, mu, order):
    return np.eye(ops.n) + mu * np.linalg.matrix_power(ops.L.toarray(), order)


@pytest.mark.parametrize("order", [1, 2, 3, 4])
@pytest.mark.parametrize("mu", [1e-3, 1.0, 300.0, 1e5])
def test_free_system_matches_the_dense_solve_within_the_condition_bound(order, mu):
    """Without held rows the preconditioned matrix's condition number is at most 2^(p-1): CG's steps stay within
    the bound 0.5 sqrt(kappa) ln(2 / tol) whatever mu (a weight of 1e5 included)."""
    V, F = icosphere(3)
    ops = Operators(F, len(V))
    X = np.hstack([V, np.random.default_rng(0).standard_normal((len(V), 2))])
    S = solvers.ShiftedPCG(ops, mu, order)
    Y = S.solve(X, tol=1e-12)
    lam, Q = np.linalg.eigh(ops.L.toarray())  # the exact inverse from L's eigenvectors (a dense solve of I + mu L^4
    exact = Q @ ((Q.T @ X) / (1.0 + mu * np.maximum(lam, 0.0) ** order)[:, None])  # at 1e5 is off by 1e-7 itself)
    # CG's attainable accuracy is about eps ||A|| (measured 3.5e-10 at p 4, mu 1e5, where eps ||A|| is 1.4e-7)
    atol = (1e-12 + 1e-16 * (1.0 + mu * lam.max() ** order)) * np.abs(X).max()
    np.testing.assert_allclose(Y, exact, rtol=0, atol=atol)
    assert S.iterations <= 0.5 * np.sqrt(2.0 ** (order - 1)) * np.log(2.0 / 1e-12) + 1
    np.testing.assert_allclose(S.solve(X[:, 0], tol=1e-12), Y[:, 0], atol=atol)  # a vector keeps its shape


def test_held_rows_are_kept_and_the_free_rows_solve_the_reduced_system():
    V, F = grid(12, 12)  # an open border, held as the border option holds it
    ops = Operators(F, len(V))
    held = ops.boundary_vertices.copy()
    X = np.random.default_rng(1).standard_normal((len(V), 3))
    S = solvers.ShiftedPCG(ops, 25.0, 3, held)
    Y = S.solve(X, tol=1e-12)
    assert np.array_equal(Y[held], X[held])
    A = _dense(ops, 25.0, 3)
    free = ~held
    np.testing.assert_allclose((A @ Y)[free], X[free], atol=1e-9 * np.abs(X).max())
    assert 0 < S.iterations < solvers.SHIFTED_PCG_MAXITER
    # the preconditioner alone: mu^-1 (L_ff + a I + (2/3) H)^-3 on the free rows, H the free rows' held neighbours
    Z = S.precondition(X[free])
    Ld = ops.L.toarray()
    Lf = Ld[np.ix_(free, free)]
    H = np.diag(-Ld[np.ix_(free, held)].sum(axis=1))  # W is 0/1: minus the coupling counts the held neighbours
    assert H.max() > 0 and solvers.held_row_share(3) == pytest.approx(2.0 / 3.0) and solvers.held_row_share(1) == 0
    M = 25.0 * np.linalg.matrix_power(Lf + 25.0 ** (-1 / 3) * np.eye(Lf.shape[0]) + 2.0 / 3.0 * H, 3)
    np.testing.assert_allclose(Z, np.linalg.solve(M, X[free]), atol=1e-10)
    # one_ring_solve, the same preconditioner with a weight per column: each column's own mu_j^-1 (...)^-3 at one shift
    mus = np.array([25.0, 5.0, 125.0])
    W = solvers.one_ring_solve(S.factor, X[free], 3, mus)
    Ms = [m * np.linalg.matrix_power(Lf + 25.0 ** (-1 / 3) * np.eye(Lf.shape[0]) + 2.0 / 3.0 * H, 3) for m in mus]
    np.testing.assert_allclose(W, np.column_stack([np.linalg.solve(Ms[j], X[free][:, j]) for j in range(3)]), atol=1e-10)
    # started from a nearby answer (x0, the border option's free run): the same solution, fewer steps; held rows kept
    cold = S.iterations
    near = Y + 1e-6 * np.random.default_rng(3).standard_normal(Y.shape)
    near[held] = 123.0  # x0's held rows are not read
    Y2 = S.solve(X, tol=1e-12, x0=near)
    assert np.array_equal(Y2[held], X[held]) and S.iterations < cold
    np.testing.assert_allclose(Y2, Y, atol=1e-9 * np.abs(X).max())
    with pytest.raises(ValueError, match="x0 has shape"):
        S.solve(X, x0=near[:, :2])


def test_past_its_step_limit_the_held_system_is_factorised(monkeypatch):
    V, F = grid(10, 10)
    ops = Operators(F, len(V))
    held = ops.boundary_vertices.copy()
    X = np.random.default_rng(2).standard_normal((len(V), 3))
    S = solvers.ShiftedPCG(ops, 50.0, 3, held)
    Y = S.solve(X, maxiter=1)
    assert S._fallback is not None  # the factor, kept for the next solves
    free = ~held
    np.testing.assert_allclose((_dense(ops, 50.0, 3) @ Y)[free], X[free], atol=1e-9 * np.abs(X).max())
    np.testing.assert_array_equal(S.solve(X), Y)


def test_shifted_solver_builds_and_keeps_it_and_rejects_bad_arguments():
    V, F = icosphere(1)
    ops = Operators(F, len(V))
    S = solvers.shifted_solver(ops, 2.0, 3, None, "pcg")
    assert isinstance(S, solvers.ShiftedPCG) and solvers.shifted_solver(ops, 2.0, 3, None, "pcg") is S
    assert S.nbytes > 0
    with pytest.raises(ValueError, match="mu must be"):
        solvers.ShiftedPCG(ops, 0.0, 3)
    with pytest.raises(ValueError, match="order must be"):
        solvers.ShiftedPCG(ops, 1.0, 0)


@pytest.mark.parametrize("held_border", [True, False])
def test_family_solves_each_columns_own_system_with_one_factor(held_border):
    """ShiftedPCGFamily: column j solves (I + mu_j L^p) y_j = x_j (held rows kept), one one-ring factor at the
    geometric mean of the mu_j^(-1/p) for them all; against dense solves, and a single weight against ShiftedPCG."""
    V, F = grid(12, 12)
    ops = Operators(F, len(V))
    held = ops.boundary_vertices.copy() if held_border else None
    mus = [0.5, 25.0, 400.0]
    X = np.random.default_rng(4).standard_normal((len(V), 3))
    S = solvers.ShiftedPCGFamily(ops, mus, 3, held)
    Y = S.solve(X, tol=1e-12)
    free = np.ones(len(V), dtype=bool) if held is None else ~held
    for j, mu in enumerate(mus):
        A = _dense(ops, mu, 3)
        expected = X[:, j].copy()
        expected[free] = np.linalg.solve(A[np.ix_(free, free)], X[free, j] - A[np.ix_(free, ~free)] @ X[~free, j])
        np.testing.assert_allclose(Y[:, j], expected, rtol=0, atol=1e-9 * np.abs(X).max())
    assert held is None or np.array_equal(Y[held], X[held])
    assert 0 < S.iterations < solvers.SHIFTED_PCG_MAXITER and S.nbytes > 0
    a = np.exp(np.mean(np.log(np.array(mus) ** (-1 / 3))))  # the shared shift: the factor's diagonal minus L's
    Lf = ops.L.toarray()[np.ix_(free, free)]
    share = np.diag(S.factor.A.toarray()) - np.diag(Lf) - a
    assert np.all(share >= -1e-12) and (np.any(share > 0) == held_border)
    one = solvers.ShiftedPCGFamily(ops, [25.0], 3, held).solve(X[:, [1]], tol=1e-12)
    np.testing.assert_allclose(one[:, 0], solvers.ShiftedPCG(ops, 25.0, 3, held).solve(X[:, 1], tol=1e-12),
                               atol=1e-9 * np.abs(X).max())
    # started from a nearby answer: the same solution, fewer steps
    cold = S.iterations
    Y2 = S.solve(X, tol=1e-12, x0=Y + 1e-7)
    assert S.iterations < cold
    np.testing.assert_allclose(Y2, Y, atol=1e-9 * np.abs(X).max())


def test_family_past_its_step_limit_factorises_each_column_and_rejects_bad_arguments():
    V, F = grid(10, 10)
    ops = Operators(F, len(V))
    held = ops.boundary_vertices.copy()
    X = np.random.default_rng(5).standard_normal((len(V), 2))
    Y = solvers.ShiftedPCGFamily(ops, [50.0, 5.0], 3, held).solve(X, maxiter=1)
    free = ~held
    for j, mu in enumerate([50.0, 5.0]):
        np.testing.assert_allclose((_dense(ops, mu, 3) @ Y[:, j])[free], X[free, j], atol=1e-9 * np.abs(X).max())
    assert np.array_equal(Y[held], X[held])
    for bad in ([], [1.0, 0.0], [np.inf], "ab", [[1.0, 2.0]]):
        with pytest.raises(ValueError, match="mus must be"):
            solvers.ShiftedPCGFamily(ops, bad, 3)
    with pytest.raises(ValueError, match="order must be"):
        solvers.ShiftedPCGFamily(ops, [1.0], 0)
    S = solvers.ShiftedPCGFamily(ops, [1.0, 2.0], 3)
    with pytest.raises(ValueError, match="2 weights"):
        S.solve(X[:, :1])
    with pytest.raises(ValueError, match="x0 has shape"):
        S.solve(X, x0=X[:, :1])

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

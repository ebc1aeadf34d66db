"""Block conjugate gradient (meshdenoise.solvers.block_cg / CGSolver) and sobolev(solver="cg").

Every result is checked against an independent dense solve (numpy.linalg.solve) or the
cached Cholesky path; the iteration-cap warning and the parameter messages are checked too.
"""

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.linalg import spsolve

import meshdenoise as md
from meshdenoise.noise import add_normal_noise
from meshdenoise.operators import get_operators
from meshdenoise.plugins.sobolev import cg_iteration_cap, sobolev
from meshdenoise.shapes import grid, icosphere, torus
from meshdenoise.solvers import CGSolver, block_cg


def _rel(a, b):
    return np.linalg.norm(a - b) / np.linalg.norm(b)


def _noisy(shape):
    V, F = shape
    Vn, _ = add_normal_noise((V, F), rho=0.02, seed=3)
    return Vn, F


def test_block_cg_matches_dense_solve_on_each_column():
    rng = np.random.default_rng(0)
    V, F = torus(20, 10)
    n = len(V)
    A = sp.identity(n, format="csr") + 4.0 * get_operators(F, n).L
    B = rng.normal(size=(n, 5))
    B[:, 3] *= 1e6  # columns on very different scales converge on their own relative residual
    B[:, 4] = 0.0  # a zero column has the solution 0 and must not produce NaN
    X, its, relres = block_cg(A, B, tol=1e-12)
    expected = np.linalg.solve(A.toarray(), B)
    for j in range(4):
        assert _rel(X[:, j], expected[:, j]) < 1e-10
    assert np.array_equal(X[:, 4], np.zeros(n)) and relres[4] == 0.0
    assert 0 < its < n and np.all(relres[:4] <= 1e-12)
    true_res = np.linalg.norm(B[:, :4] - A @ X[:, :4], axis=0) / np.linalg.norm(B[:, :4], axis=0)
    assert np.all(true_res < 1e-11)


def test_block_cg_gives_the_same_bits_on_one_thread_or_two_and_follows_the_recurrence():
    # the dot products are summed by fixed blocks of rows (kernels.CG_BLOCK), whatever the thread count; on a mesh of
    # several blocks the iterates are the textbook Jacobi-preconditioned recurrence written out here in numpy
    from meshdenoise import kernels

    V, F = icosphere(5)  # 10,242 rows: 6 blocks
    n = len(V)
    assert n > 4 * kernels.CG_BLOCK
    A = sp.csr_matrix(sp.identity(n) + 3.0 * get_operators(F, n).L)
    B = np.random.default_rng(1).normal(size=(n, 4))
    with kernels.single_threaded():
        one = block_cg(A, B, tol=1e-9)
    two = block_cg(A, B, tol=1e-9)
    np.testing.assert_array_equal(one[0], two[0])
    assert one[1] == two[1]
    d = 1.0 / A.diagonal()
    X, R = np.zeros((n, 4)), B.copy()
    P = R * d[:, None]
    rz = np.sum(R * P, axis=0)
    for _ in range(two[1]):
        Q = A @ P
        alpha = rz / np.sum(P * Q, axis=0)
        X += alpha * P
        R -= alpha * Q
        rz_new = np.sum(R * R * d[:, None], axis=0)
        P = R * d[:, None] + (rz_new / rz) * P
        rz = rz_new
    np.testing.assert_allclose(two[0], X, rtol=0, atol=1e-9 * np.abs(X).max())
    # a sparse LU (SuperLU) for the exact answer: the dense solve of these 10,242 rows took ~30 s of the suite
    exact = spsolve(A.tocsc(), B)
    np.testing.assert_allclose(two[0], exact, rtol=0, atol=1e-7 * np.abs(B).max())


def test_block_cg_vector_rhs_and_warm_start():
    V, F = icosphere(2)
    n = len(V)
    A = sp.identity(n, format="csr") + 2.0 * get_operators(F, n).L
    b = V[:, 0].copy()
    x, cold, _ = block_cg(A, b, tol=1e-10)
    assert x.shape == (n,)
    np.testing.assert_allclose(A @ x, b, rtol=0, atol=1e-9 * np.linalg.norm(b))
    x2, warm, _ = block_cg(A, b, tol=1e-10, x0=x + 1e-6)  # a guess close to the answer needs fewer steps
    assert warm < cold and _rel(x2, np.linalg.solve(A.toarray(), b)) < 1e-9


@pytest.mark.parametrize("shape", [icosphere(2), grid(12, 9), torus(16, 8)], ids=["sphere", "grid", "torus"])
@pytest.mark.parametrize("mu", [0.3, 5.0])
def test_sobolev_cg_equals_cholesky_and_dense(shape, mu):
    Vn, F = _noisy(shape)
    n = len(Vn)
    dense = np.linalg.solve(np.eye(n) + mu * get_operators(F, n).L.toarray(), Vn)
    cg = sobolev((Vn, F), mu=mu, solver="cg", tol=1e-12)[0]
    chol = sobolev((Vn, F), mu=mu)[0]
    assert _rel(cg, dense) < 1e-9 and _rel(cg, chol) < 1e-9


def test_sobolev_cg_error_follows_tol():
    Vn, F = _noisy(icosphere(3))
    chol = sobolev((Vn, F), mu=2.0)[0]
    errors = [_rel(sobolev((Vn, F), mu=2.0, solver="cg", tol=t)[0], chol) for t in (1e-4, 1e-7, 1e-10)]
    assert errors[0] > errors[1] > errors[2]
    assert errors[0] < 1e-3 and errors[2] < 1e-9  # about tol times a small condition factor


def test_sobolev_cg_with_pinned_vertices_matches_dense_constrained_solve():
    Vn, F = _noisy(icosphere(2))
    n = len(Vn)
    pinned = np.zeros(n, bool)
    pinned[[0, 3, 17, 40, 100]] = True
    mu = 3.0
    A = np.eye(n) + mu * get_operators(F, n).L.toarray()
    f, p = ~pinned, pinned
    expected = Vn.copy()
    expected[f] = np.linalg.solve(A[np.ix_(f, f)], Vn[f] - A[np.ix_(f, p)] @ Vn[p])
    out = md.sobolev((Vn, F), mu=mu, pinned=pinned, solver="cg", tol=1e-12)[0]
    assert np.array_equal(out[pinned], Vn[pinned])  # bit-identical, not merely close
    assert _rel(out, expected) < 1e-9
    assert _rel(out, md.sobolev((Vn, F), mu=mu, pinned=pinned)[0]) < 1e-9


def test_cg_solver_fixed_rows_direct():
    V, F = grid(8, 8)
    n = len(V)
    A = sp.identity(n, format="csr") + 1.5 * get_operators(F, n).L
    fixed = np.zeros(n, bool)
    fixed[::7] = True
    X = np.random.default_rng(1).normal(size=(n, 3))
    Y = CGSolver(A, fixed).solve(X, tol=1e-12)
    Ad = A.toarray()
    assert np.array_equal(Y[fixed], X[fixed])
    np.testing.assert_allclose((Ad @ Y)[~fixed], X[~fixed], rtol=0, atol=1e-10)
    every = CGSolver(A, np.ones(n, bool)).solve(X)  # nothing free: the input comes back
    assert np.array_equal(every, X)


def test_iteration_cap_warns_with_hint_and_returns_best_iterate():
    V, F = torus(20, 10)
    n = len(V)
    A = sp.identity(n, format="csr") + 100.0 * get_operators(F, n).L
    B = np.random.default_rng(2).normal(size=(n, 3))  # not the torus coordinates: those span 2 eigenvectors
    with pytest.warns(UserWarning, match=r"did not reach the relative residual tol = 1e-12 in maxiter = 3.*hint"):
        X, its, relres = block_cg(A, B, tol=1e-12, maxiter=3)
    assert its == 3 and np.all(relres > 1e-12)
    np.testing.assert_allclose(relres, np.linalg.norm(B - A @ X, axis=0) / np.linalg.norm(B, axis=0), rtol=1e-8)


def test_sobolev_cg_default_cap_is_not_reached(recwarn):
    Vn, F = _noisy(icosphere(3))
    ops = get_operators(F, len(Vn))
    solver_cap = cg_iteration_cap(ops, 50.0, 1e-10)
    sobolev((Vn, F), mu=50.0, solver="cg")
    used = ops.cache["shifted-p1-cg"][(50.0, None)].iterations
    assert 0 < used < solver_cap and not [w for w in recwarn if issubclass(w.category, UserWarning)]


def test_default_solver_is_cholesky_bit_identical():
    Vn, F = _noisy(icosphere(2))
    n = len(Vn)
    from meshdenoise.plugins.sobolev import SobolevSolver

    direct = SobolevSolver(get_operators(F, n), 2.0).solve(Vn)
    assert np.array_equal(sobolev((Vn, F), mu=2.0)[0], direct)
    assert np.array_equal(sobolev((Vn, F), mu=2.0, solver="cholesky", tol=1e-3)[0], direct)  # tol is cg's only


@pytest.mark.parametrize(
    "params,error,message",
    [
        ({"solver": "lu"}, ValueError, "'solver' = 'lu'.*one of 'auto', 'cholesky', 'cg'"),
        ({"solver": "cg", "tol": 0.0}, ValueError, r"'tol' = 0.0 .*1e-14 <= tol <= 0.01"),
        ({"solver": "cg", "tol": 0.5}, ValueError, r"'tol' = 0.5 .*1e-14 <= tol <= 0.01"),
        ({"solver": "cg", "tol": "small"}, TypeError, "'tol'.*float"),
    ],
)
def test_parameter_validation_messages(params, error, message):
    with pytest.raises(error, match=message):
        sobolev(icosphere(1), mu=1.0, **params)


@pytest.mark.parametrize(
    "kwargs,message",
    [
        ({"tol": 0.0}, r"tol must be a number in \(0, 1\), got 0.0"),
        ({"maxiter": 0}, "maxiter must be at least 1, got 0"),
    ],
)
def test_block_cg_argument_errors(kwargs, message):
    A = sp.identity(4, format="csr")
    with pytest.raises(ValueError, match=message):
        block_cg(A, np.ones(4), **kwargs)


def test_block_cg_rejects_non_positive_diagonal():
    A = sp.csr_matrix(np.diag([1.0, 0.0, 2.0]))
    with pytest.raises(ValueError, match="diagonal entry 1 is 0.0"):
        block_cg(A, np.ones(3))


def test_auto_solver_takes_cg_for_a_one_off_solve_on_a_large_mesh():
    from meshdenoise.plugins import sobolev as sobolev_module

    Vn, F = _noisy(icosphere(3))
    ops = get_operators(F, len(Vn))
    mu = 0.6173  # a weight no other test factorises on this topology (the factors are stored on it)
    assert sobolev_module.choose_solver(ops, mu, None, 1e-10) == "cholesky"  # small mesh: keep a factor
    large = sobolev_module.SobolevConfig(cg_min_vertices=10)
    assert sobolev_module.choose_solver(ops, mu, None, 1e-10, large) == "cg"
    assert sobolev_module.choose_solver(ops, 1e6, None, 1e-10, large) == "cholesky"  # sqrt(mu) iterations: too many
    auto = md.get_filter("sobolev").core(Vn, F, ops=ops, pinned=None, mu=0.913, config=large)
    assert (0.913, None) in ops.cache["shifted-p1-cg"] and (0.913, None) not in ops.cache.get("shifted-p1-cholesky", {})
    exact = sobolev((Vn, F), mu=0.913, solver="cholesky")[0]
    np.testing.assert_allclose(auto, exact, rtol=0, atol=1e-8 * np.abs(exact).max())
    assert sobolev_module.choose_solver(ops, 0.913, None, 1e-10) == "cholesky"  # the factor is stored now: reuse it

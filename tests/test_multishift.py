"""shifted_family_cg: one CG run for (K + s_j P) X_j = B, against dense solves; sobolev_gls' sweep by it."""

from __future__ import annotations

import numpy as np
import pytest

from meshdenoise.multishift import shifted_family_cg


def _system(n=50, rank=20, seed=0):
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((n, n))
    C = rng.standard_normal((n, rank))  # P singular: the shifted systems keep K's directions outside its range
    return A @ A.T / n + 0.5 * np.eye(n), C @ C.T / n, rng.standard_normal((n, 3))


@pytest.mark.parametrize("shifts", [[1.0, 2.0, 4.0, 7.0, 11.0], [3.0], [5.0, 5.0, 0.01]])
def test_each_system_is_the_dense_solve(shifts):
    K, P, B = _system()
    X = shifted_family_cg(lambda Y: np.linalg.solve(K, Y), lambda Y: P @ Y, B, shifts, tol=1e-12)
    assert len(X) == len(shifts)
    for s, x in zip(shifts, X):
        want = np.linalg.solve(K + s * P, B)
        np.testing.assert_allclose(x, want, atol=1e-9 * np.abs(want).max())


def test_the_tolerance_is_each_systems_relative_residual_per_column():
    K, P, B = _system(seed=1)
    B[:, 1] *= 1e6  # columns of very different sizes: each against its own norm
    X = shifted_family_cg(lambda Y: np.linalg.solve(K, Y), lambda Y: P @ Y, B, [1.0, 10.0, 100.0], tol=1e-5)
    for s, x in zip([1.0, 10.0, 100.0], X):
        res = np.linalg.norm(B - (K + s * P) @ x, axis=0) / np.linalg.norm(B, axis=0)
        assert (res <= 1e-5).all() and res.max() > 1e-12  # stopped at the tolerance, not run to rounding


def test_blocks_of_vertex_triples_with_the_tangent_projector_as_sobolev_gls_uses_it():
    """B (n, 3, k), P_T = I - N N^T per vertex, K = (I + mu L) per coordinate: the 3n x 3n dense solve."""
    from meshdenoise.operators import get_operators
    from meshdenoise.shapes import icosphere

    V, F = icosphere(2)
    n = len(V)
    L = get_operators(F, n).L.toarray()
    N = V / np.linalg.norm(V, axis=1, keepdims=True) * 0.9  # coherent normals may be shorter than 1
    Kd = np.kron(np.eye(n) + 0.3 * L, np.eye(3))
    Pd = np.zeros((3 * n, 3 * n))
    for i in range(n):
        Pd[3 * i:3 * i + 3, 3 * i:3 * i + 3] = np.eye(3) - np.outer(N[i], N[i])
    B = np.random.default_rng(2).standard_normal((n, 3, 4))
    solve = np.linalg.inv(np.eye(n) + 0.3 * L)
    X = shifted_family_cg(lambda Y: np.einsum("ij,jck->ick", solve, Y),
                          lambda Y: Y - N[:, :, None] * np.sum(N[:, :, None] * Y, axis=1, keepdims=True),
                          B, [1.0, 11.0], tol=1e-12)
    for s, x in zip([1.0, 11.0], X):
        want = np.linalg.solve(Kd + s * Pd, B.reshape(3 * n, 4)).reshape(n, 3, 4)
        np.testing.assert_allclose(x, want, atol=1e-9 * np.abs(want).max())


def test_a_column_done_leaves_the_solves_and_keeps_its_solution():
    """A column in an invariant subspace of K^-1 P (an eigenvector) is done after one step: the later solves see the
    other columns only, and every column is still the dense solve."""
    K, P, B = _system(seed=4)
    w, U = np.linalg.eigh(np.linalg.solve(np.linalg.cholesky(K), np.linalg.solve(np.linalg.cholesky(K), P).T))
    B[:, 0] = K @ np.linalg.solve(np.linalg.cholesky(K).T, U[:, -1])  # K^-1 B_0 an eigenvector of K^-1 P
    widths = []

    def solve(Y):
        widths.append(Y.shape[-1])
        return np.linalg.solve(K, Y)

    shifts = [1.0, 10.0]
    X = shifted_family_cg(solve, lambda Y: P @ Y, B, shifts, tol=1e-10)
    assert widths[0] == 3 and widths[-1] == 2 and len(widths) > 3
    for s, x in zip(shifts, X):
        want = np.linalg.solve(K + s * P, B)
        np.testing.assert_allclose(x, want, atol=1e-8 * np.abs(want).max())


def test_bad_shifts_and_non_convergence():
    K, P, B = _system(seed=3)
    solve = lambda Y: np.linalg.solve(K, Y)  # noqa: E731
    with pytest.raises(ValueError, match="shifts"):
        shifted_family_cg(solve, lambda Y: P @ Y, B, [1.0, 0.0])
    with pytest.raises(ValueError, match="shifts"):
        shifted_family_cg(solve, lambda Y: P @ Y, B, [])
    with pytest.warns(UserWarning, match="did not reach"):
        shifted_family_cg(solve, lambda Y: P @ Y, B, [1.0, 1000.0], tol=1e-14, maxiter=2)


def test_sobolev_gls_sweep_by_one_run_chooses_as_by_one_cg_per_beta(monkeypatch):
    """The rule's beta sweep by shifted_family_cg against a CG per beta (GlsConfig.family_min_betas out of reach): the
    same choice, the sweep's scores to 1e-5 (1e-3 loose: both CG runs stop at SOBOLEV_GLS_SWEEP_TOL, 1e-2), in fewer
    preconditioner solves."""
    import meshdenoise.plugins._gls_solve as gls_solve
    import meshdenoise.plugins.sobolev_gls_rule as sg
    from meshdenoise import add_normal_noise
    from meshdenoise.operators import get_operators
    from meshdenoise.shapes import torus
    from meshdenoise.tuning import TuningContext
    from meshdenoise.tuning.risk import Criterion

    V, F = torus(40, 20)  # 800 vertices: above GlsConfig.dense_max_vertices, the CG path
    Vn, _ = add_normal_noise((V, F), 0.04, seed=3)
    ops = get_operators(F, len(V))
    solves = []
    real = sg.shifted_solver

    def counting(*a, **k):
        S = real(*a, **k)
        return type("Counted", (), {"solve": lambda self, X: solves.append(1) or S.solve(X)})()

    for module in (sg, gls_solve):  # the rule's solves and those of the solve it shares with the filter
        monkeypatch.setattr(module, "shifted_solver", counting)

    def run(loose, config=()):
        solves.clear()
        ctx = TuningContext(Vn, F, ops, 0.04, Criterion("sure"), False, {"mu": 0.05},  # mu held: the sweep alone
                            config=config)
        return sg.choose_sobolev_gls_whole(ctx, None, loose=loose), len(solves)

    for loose in (False, True):
        (fast, p_fast), n_fast = run(loose)
        (slow, p_slow), n_slow = run(loose, gls_solve.GlsConfig(family_min_betas=10**9))
        assert fast == slow and p_fast.score == pytest.approx(p_slow.score, rel=1e-3 if loose else 1e-5)
        assert n_fast < 0.6 * n_slow

"""SPDSolver's two factorisation back ends (CHOLMOD with a reused symbolic analysis up to
SolverConfig.cholmod_max_rows rows, METIS's ordering up to SolverConfig.cholmod_metis_max_rows; cholespy), against
dense solves; each test hands in the SolverConfig it wants."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

import meshdenoise.solvers as solvers
from meshdenoise.solvers import SolverConfig
from meshdenoise.solvers.factor import _symbolic
from meshdenoise.operators import Operators, clear_cache
from meshdenoise.shapes import icosphere, torus


def _shifted(ops, mu, order):
    return sp.identity(ops.n, format="csr") + mu * sp.csr_matrix(np.linalg.matrix_power(ops.L.toarray(), order))


def _backend(solver):
    return "cholmod" if solver._factor is not None else "cholespy"


def test_the_project_environment_has_cholmod():
    """make installs the dev extra, which holds scikit-sparse: the CHOLMOD path is the one the suite and the
    benchmarks run up to cholmod_max_rows rows (cholespy alone is a plain pip install's, tested by switching)."""
    assert solvers.CHOLMOD and SolverConfig().cholmod


@pytest.mark.parametrize("cholmod", [True, False], ids=["cholmod", "cholespy"])
@pytest.mark.parametrize("order, mu", [(1, 0.7), (2, 3.0), (3, 40.0)])
def test_spd_solver_equals_a_dense_solve_with_and_without_pinned_rows(cholmod, order, mu):
    config = SolverConfig(cholmod=cholmod)
    V, F = torus(16, 8)
    ops = Operators(F, len(V))
    A = _shifted(ops, mu, order)
    Ad = A.toarray()
    X = np.random.default_rng(0).standard_normal((ops.n, 5))
    pinned = np.zeros(ops.n, dtype=bool)
    pinned[::7] = True
    free = ~pinned
    whole, held = solvers.SPDSolver(A, config=config), solvers.SPDSolver(A, pinned, config=config)
    assert _backend(whole) == _backend(held) == ("cholmod" if cholmod else "cholespy")
    np.testing.assert_allclose(whole.solve(X), np.linalg.solve(Ad, X), rtol=0, atol=1e-9)
    np.testing.assert_allclose(whole.solve(X[:, 0]), np.linalg.solve(Ad, X[:, 0]), rtol=0, atol=1e-9)  # (n,)
    Y = held.solve(X)
    expected = np.linalg.solve(Ad[np.ix_(free, free)], X[free] - Ad[np.ix_(free, pinned)] @ X[pinned])
    np.testing.assert_allclose(Y[free], expected, rtol=0, atol=1e-9)
    assert np.array_equal(Y[pinned], X[pinned])


def test_larger_systems_go_to_cholespy_and_a_matrix_gets_the_same_bits_whatever_came_before():
    V, F = icosphere(3)  # 642 vertices
    ops = Operators(F, len(V))
    A = _shifted(ops, 2.0, 2)
    X = np.random.default_rng(1).standard_normal((ops.n, 3))
    solvers.clear_symbolic()
    first = solvers.SPDSolver(A).solve(X)
    again = solvers.SPDSolver(A).solve(X)  # the analysis reused: the same ordering, the same bits
    assert np.array_equal(first, again)
    assert _backend(solvers.SPDSolver(A, config=SolverConfig(cholmod_max_rows=ops.n - 1))) == "cholespy"


def test_patterns_past_the_metis_bound_are_ordered_by_cholmods_default_and_solve_as_a_dense_solve(monkeypatch):
    """Between cholmod_metis_max_rows and cholmod_max_rows rows CHOLMOD orders the pattern by its default (AMD, METIS
    where AMD fills much): a cheaper analysis for the one-off factors of 50k to 200k rows."""
    import sksparse.cholmod as cholmod

    orderings = []
    real = cholmod.analyze
    monkeypatch.setattr(cholmod, "analyze", lambda *a, **k: orderings.append(k["ordering_method"]) or real(*a, **k))
    V, F = icosphere(3)
    ops = Operators(F, len(V))
    A = _shifted(ops, 2.0, 2)
    X = np.random.default_rng(2).standard_normal((ops.n, 3))
    solvers.clear_symbolic()
    solver = solvers.SPDSolver(A, config=SolverConfig(cholmod_metis_max_rows=ops.n - 1))
    assert _backend(solver) == "cholmod" and orderings == ["default"]
    np.testing.assert_allclose(solver.solve(X), np.linalg.solve(A.toarray(), X), rtol=0, atol=1e-9)
    solvers.clear_symbolic()
    solvers.SPDSolver(A, config=SolverConfig(cholmod_metis_max_rows=ops.n))
    assert orderings == ["default", "metis"]


def test_one_symbolic_analysis_per_sparsity_pattern_and_clear(monkeypatch):
    import sksparse.cholmod as cholmod

    analysed = []
    real = cholmod.analyze
    monkeypatch.setattr(cholmod, "analyze", lambda *a, **k: analysed.append(a[0].nnz) or real(*a, **k))
    clear_cache()
    V, F = icosphere(3)
    ops = Operators(F, len(V))
    for mu in (0.5, 1.0, 2.0, 4.0):  # one pattern (I + mu L), four factors
        solvers.SPDSolver(_shifted(ops, mu, 1))
    assert len(analysed) == 1
    solvers.SPDSolver(_shifted(ops, 1.0, 2))  # a second pattern
    assert len(analysed) == 2
    pinned = np.zeros(ops.n, dtype=bool)
    pinned[:10] = True
    solvers.SPDSolver(_shifted(ops, 1.0, 1), pinned)  # the free rows' pattern is another one
    assert len(analysed) == 3
    clear_cache()  # also forgets the analyses
    solvers.SPDSolver(_shifted(ops, 1.0, 1))
    assert len(analysed) == 4


def test_symbolic_analyses_are_bounded():
    solvers.clear_symbolic()
    for n in (5, 6, 7, 8):
        solvers.SPDSolver(sp.identity(n, format="csr") * 2.0, config=SolverConfig(symbolic_max=2))
    assert len(_symbolic) == 2


@pytest.mark.parametrize("cholmod", [True, False], ids=["cholmod", "cholespy"])
def test_an_indefinite_matrix_fails_as_not_positive_definite(cholmod):
    """CHOLMOD's simplicial L D L^T would factor it: a pivot D <= 0 is reported as cholespy reports it."""
    A = sp.csr_matrix(np.array([[2.0, -3.0, 0.0], [-3.0, 2.0, 0.0], [0.0, 0.0, 1.0]]))
    with pytest.raises(ValueError, match="not positive definite"):
        solvers.SPDSolver(A, config=SolverConfig(cholmod=cholmod))


def test_a_config_is_frozen_and_checked():
    with pytest.raises(AttributeError):
        SolverConfig().cholmod_max_rows = 1  # frozen: a caller hands in another one
    with pytest.raises(TypeError, match="SolverConfig"):
        solvers.SPDSolver(sp.identity(3, format="csr"), config={"cholmod": False})

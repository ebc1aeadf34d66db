"""HeldByProduct: (I + mu L^p) Y = X with held rows, by CG preconditioned by the free product's factors."""

from __future__ import annotations

import functools

import numpy as np
import pytest

import meshdenoise as md
import meshdenoise.solvers as solvers
from meshdenoise.noise import add_normal_noise
from meshdenoise.operators import get_operators
from meshdenoise.shapes import grid, icosphere
from meshdenoise.solvers import HeldByProduct, SolverConfig, SPDSolver, shifted_matrix, shifted_solver


def _border(F, n):
    E = np.sort(np.vstack([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    edges, counts = np.unique(E, axis=0, return_counts=True)
    held = np.zeros(n, dtype=bool)
    held[edges[counts == 1].ravel()] = True  # a written-again border: edges of one face
    return held


@pytest.mark.parametrize("order, mu", [(3, 0.3), (3, 20.0), (4, 2.0)])
def test_held_rows_solve_as_the_dense_constrained_system(order, mu):
    V, F = grid(14, 12)
    n = len(V)
    ops = get_operators(F, n)
    held = _border(F, n)
    X = np.random.default_rng(order).standard_normal((n, 3))
    Y = HeldByProduct(ops, mu, order, held).solve(X)
    A = np.eye(n) + mu * np.linalg.matrix_power(ops.L.toarray(), order)
    f = ~held
    want = X.copy()
    want[f] = np.linalg.solve(A[np.ix_(f, f)], X[f] - A[np.ix_(f, held)] @ X[held])
    assert np.array_equal(Y[held], X[held])
    np.testing.assert_allclose(Y, want, atol=1e-8 * np.abs(want).max())


def test_past_its_steps_the_held_system_is_factorised():
    V, F = grid(14, 12)
    n = len(V)
    ops = get_operators(F, n)
    held = _border(F, n)
    X = np.random.default_rng(5).standard_normal((n, 2))
    H = HeldByProduct(ops, 20.0, 3, held)
    Y = H.solve(X, maxiter=2)
    assert H._factor is not None
    np.testing.assert_allclose(Y, SPDSolver(shifted_matrix(ops, 20.0, 3), held).solve(X), atol=1e-12)
    with pytest.raises(ValueError, match="order"):
        HeldByProduct(ops, 1.0, 2, held)


def test_shifted_solver_takes_it_for_few_held_rows_from_its_size():
    V, F = grid(14, 12)
    n = len(V)
    ops = get_operators(F, n)
    held = _border(F, n)
    assert isinstance(shifted_solver(ops, 1.0, 3, held), SPDSolver)  # a small mesh: the factor
    any_size = SolverConfig(held_by_product_min_vertices=0)
    assert isinstance(shifted_solver(ops, 1.5, 3, held, config=any_size), HeldByProduct)
    assert isinstance(shifted_solver(ops, 1.5, 2, held, config=any_size), SPDSolver)  # no product form below p = 3
    fewer = SolverConfig(held_by_product_min_vertices=0, held_by_product_max_held=int(held.sum()) - 1)
    assert isinstance(shifted_solver(ops, 2.5, 3, held, config=fewer), SPDSolver)  # too many held rows
    assert isinstance(shifted_solver(ops, 1.0, 3, held), SPDSolver)  # the default's solver, stored apart from them


def test_sobolev_gls_and_axes_with_a_held_border_as_by_the_held_factor(monkeypatch):
    """The border option's second run of sobolev_gls (its isotropic pass by the held solve, its weighted CG
    preconditioned by the free factors) and sobolev_axes past CG's bound: the same result as the held factor's (the
    filters' shifted_solver handed a config that takes the held solver at any size)."""
    V, F = icosphere(3)
    keep = V[:, 2] < 0.6  # an open cap: a border
    idx = -np.ones(len(V), dtype=int)
    idx[keep] = np.arange(keep.sum())
    F = idx[F[keep[F].all(axis=1)]]
    V = V[keep]
    Vn, _ = add_normal_noise((V, F), 0.02, seed=1)
    from meshdenoise.operators import clear_cache
    import meshdenoise.plugins.sobolev_axes as ax
    import meshdenoise.plugins.sobolev_gls as sg

    from meshdenoise.registry import get_filter, run_core

    gls = get_filter("sobolev_gls")
    # the held solves compared, not the weighted CG's tolerance: the core's config, handed in with its parameters
    values = {**gls.resolve({"mu": 0.5, "beta": 8.0}), "config": sg.GlsConfig(filter_tol=1e-12)}
    built = []
    real = solvers.HeldByProduct.__init__
    monkeypatch.setattr(solvers.HeldByProduct, "__init__", lambda self, *a, **k: built.append(a[1:3]) or real(self, *a, **k))
    runs = {}
    for mode in ("factor", "product"):
        clear_cache()
        if mode == "product":
            any_size = functools.partial(shifted_solver, config=SolverConfig(held_by_product_min_vertices=0))
            monkeypatch.setattr(sg, "shifted_solver", any_size)
            monkeypatch.setattr(ax, "shifted_solver", any_size)
        runs[mode] = (run_core(gls, Vn, get_operators(F, len(Vn)), values, boundary_motion="normal"),
                      md.apply_filter("sobolev_axes", (Vn, F), mu1=0.5, mu2=2.0, mu3=40.0, boundary_motion="normal")[0])
    assert (0.5, 3) in built and (40.0, 3) in built  # gls' isotropic pass, the axis past CG's bound
    for a, b in zip(runs["factor"], runs["product"]):
        np.testing.assert_allclose(b, a, atol=1e-8 * np.abs(a).max())

"""sobolev_axes at scan size: one Lanczos run for the three axes, the search's own run for its coordinates,
and the Lanczos recurrences written in place (the same numbers as before)."""

import numpy as np
import pytest

from meshdenoise import add_normal_noise, apply_filter
from meshdenoise.registry import get_filter
from meshdenoise.operators import Operators, clear_cache, get_operators
from meshdenoise.shapes import grid, icosphere, torus
from meshdenoise.solvers import LanczosQuadrature, LanczosRows, lanczos_shifted
from meshdenoise.tuning.risk import probe_block
from meshdenoise.tuning.search import quadrature_coordinates, shifted_quadrature


def _axes(Vn, F, config, pinned=None, start=None, **params):
    """sobolev_axes' array core with ``config`` (a filter's public call takes none), held rows kept as the registry
    keeps them."""
    out = get_filter("sobolev_axes").core(Vn, F, ops=get_operators(F, len(Vn)), pinned=pinned, start=start,
                                          config=config, **params)
    if pinned is not None:
        out[pinned] = Vn[pinned]
    return out


def _dense_function(L: np.ndarray, g, B: np.ndarray) -> np.ndarray:
    lam, U = np.linalg.eigh(L)
    return (U * g(lam)) @ (U.T @ B)


def test_apply_on_chosen_columns_equals_the_dense_function():
    V, F = torus(16, 10)
    V = V + 0.02 * np.random.default_rng(0).standard_normal(V.shape)
    ops = Operators(F, len(V))
    L = ops.L.toarray()
    B = np.hstack([L @ V, np.random.default_rng(1).standard_normal((ops.n, 3))])
    g = lambda t: 1.0 / (1.0 + 0.5 * t**3)  # noqa: E731
    q = LanczosQuadrature(ops.L, B)
    q.extend(5)  # a run already under way (as a search's): apply extends it as needed
    Y = q.apply(g, rtol=1e-12, columns=[4, 1])  # in that order
    assert Y.shape == (ops.n, 2)
    expected = _dense_function(L, g, B[:, [4, 1]])
    np.testing.assert_allclose(Y, expected, atol=1e-10 * np.abs(B).max())
    full = q.apply(g, rtol=1e-12)  # every column: the chosen ones are the same columns of it
    np.testing.assert_allclose(Y, full[:, [4, 1]], rtol=0, atol=1e-12 * np.abs(B).max())


def test_quadrature_coordinates_are_the_solve_of_the_search_s_own_run():
    V, F = icosphere(3)
    Vn, _ = add_normal_noise((V, F), 0.02, seed=0)
    ops = Operators(F, len(Vn))
    Z, s = probe_block(ops.n, False, n_probes=4)
    evaluate = shifted_quadrature(Vn, ops, 2, Z, s)
    for mu in (0.05, 1.5):
        evaluate(mu)  # the search's candidates run the recurrence first
        X = quadrature_coordinates(Vn, evaluate.quadrature, 2, mu)
        A = np.eye(ops.n) + mu * np.linalg.matrix_power(ops.L.toarray(), 2)
        np.testing.assert_allclose(X, np.linalg.solve(A, Vn), atol=1e-10)


def _reference_extend(M, B, steps):
    """The recurrence with a new array per product, for the bit-for-bit comparison with the in-place one."""
    n, k = B.shape
    norms2 = np.einsum("ij,ij->j", B, B)
    scale = float(abs(M).sum(axis=1).max())
    q = B * np.divide(1.0, np.sqrt(norms2), out=np.zeros(k), where=norms2 > 0)
    q_prev, beta_prev, active = np.zeros_like(q), np.zeros(k), norms2 > 0
    alphas, betas = [], []
    W = np.empty_like(q)
    for _ in range(steps):
        W[:] = M @ q
        a = np.einsum("ij,ij->j", q, W)
        W -= q * a
        W -= q_prev * beta_prev
        b = np.sqrt(np.einsum("ij,ij->j", W, W))
        a[~active] = 0.0
        alphas.append(a)
        active &= b > 1e-13 * scale
        b[~active] = 0.0
        betas.append(b)
        inv = np.divide(1.0, b, out=np.zeros(k), where=active)
        q_prev, q = q, W * inv
        beta_prev = b
    return np.array(alphas), np.array(betas)


def test_lanczos_recurrence_in_place_gives_the_same_numbers_bit_for_bit():
    V, F = torus(30, 16)
    V = V + 0.01 * np.random.default_rng(0).standard_normal(V.shape)
    ops = Operators(F, len(V))
    B = np.hstack([ops.L @ V, np.random.default_rng(1).standard_normal((ops.n, 4))])
    a_ref, b_ref = _reference_extend(ops.L, B, 45)
    q = LanczosQuadrature(ops.L, B)
    q.extend(20)
    q.extend(25)  # extended in two calls: the buffers carry over
    assert np.array_equal(q._alpha, a_ref) and np.array_equal(q._beta, b_ref)
    rows = LanczosRows(ops.L, B, np.arange(0, ops.n, 5))
    rows.extend(45)
    assert np.array_equal(rows._alpha, a_ref) and np.array_equal(rows._beta, b_ref)


def test_sobolev_axes_large_path_uses_one_run_and_equals_the_factor_filter(monkeypatch):
    """The axes with a weight by one compiled Lanczos run (one function per column), no factor, equal to the factor
    path; a run past its steps falls back to a factor-free solve per axis."""
    import meshdenoise.plugins.sobolev_axes as ax
    from meshdenoise.solvers import CompiledLanczos

    V, F = icosphere(3)
    Vn, _ = add_normal_noise((V, F), 0.02, seed=0)
    params = dict(mu1=0.3, mu2=0.0, mu3=4.0, order=3, frame_steps=2)
    clear_cache()
    before = apply_filter("sobolev_axes", (Vn, F), **params)[0]
    runs, calls = [], []
    real = ax.lanczos_shifted

    def spy(ops, X, mu, order, **kw):
        calls.append((float(mu), kw["tol"]))
        return real(ops, X, mu, order, **kw)

    factor_free = ax.AxesConfig(lanczos_min_vertices=0)
    monkeypatch.setattr(ax, "lanczos_shifted", spy)
    monkeypatch.setattr(ax, "CompiledLanczos", lambda *a, **k: runs.append(a[1].shape) or CompiledLanczos(*a, **k))
    monkeypatch.setattr(ax, "shifted_solver", lambda *a, **k: pytest.fail("a factor was built"))
    clear_cache()
    after = _axes(Vn, F, factor_free, **params)
    assert runs == [(len(Vn), 2)] and not calls  # an axis with mu = 0 is not solved
    np.testing.assert_allclose(after, before, atol=1e-11)
    clear_cache()
    runs.clear()
    gives_up = ax.AxesConfig(lanczos_min_vertices=0, lanczos_max_steps=3)  # the run gives up: each axis on its own
    again = _axes(Vn, F, gives_up, **params)
    assert runs == [(len(Vn), 2)] and calls == [(0.3, 1e-10), (4.0, 1e-10)]
    np.testing.assert_allclose(again, before, atol=1e-11)


def test_sobolev_axes_with_held_vertices_by_cg_equals_its_factor(monkeypatch):
    """The border option's second run (held vertices): CG while shifted_cg_bound is at most AxesConfig.pinned_cg_bound,
    CG preconditioned by a one-ring factor past it (ShiftedPCGFamily, the axes together), the factor's Dirichlet solve
    below AxesConfig.lanczos_min_vertices; the same result to 1e-9 of the coordinates."""
    import meshdenoise.plugins.sobolev_axes as ax
    V, F = icosphere(3)
    Vn, _ = add_normal_noise((V, F), 0.02, seed=0)
    pinned = np.zeros(len(Vn), dtype=bool)
    pinned[::13] = True
    params = dict(mu1=0.3, mu2=0.0, mu3=0.05, order=3, frame_steps=2)
    clear_cache()
    before = apply_filter("sobolev_axes", (Vn, F), pinned=pinned, **params)[0]  # 642 vertices: the factor
    methods = []
    real = ax.shifted_solver
    monkeypatch.setattr(ax, "shifted_solver", lambda *a, **k: methods.append(a[4] if len(a) > 4 else "cholesky") or real(*a, **k))
    clear_cache()
    after = _axes(Vn, F, ax.AxesConfig(lanczos_min_vertices=0), pinned, **params)
    assert methods == ["cg", "cg"]  # the two weighted axes
    np.testing.assert_allclose(after, before, atol=1e-9 * np.abs(Vn).max())
    np.testing.assert_array_equal(after[pinned], Vn[pinned])
    past = ax.AxesConfig(lanczos_min_vertices=0, pinned_cg_bound=0)  # past the bound: one CG run for the two axes
    methods.clear()  # together, preconditioned by one one-ring factor (ShiftedPCGFamily)
    families = []
    real_family = ax.ShiftedPCGFamily
    monkeypatch.setattr(ax, "ShiftedPCGFamily", lambda *a, **k: families.append(list(a[1])) or real_family(*a, **k))
    clear_cache()
    pcg = _axes(Vn, F, past, pinned, **params)
    assert methods == [] and families == [[0.3, 0.05]]
    np.testing.assert_allclose(pcg, before, atol=1e-9 * np.abs(Vn).max())
    np.testing.assert_array_equal(pcg[pinned], Vn[pinned])
    # started from a nearby result (the border option's free run), both iterations: the same result, held rows exact
    free = apply_filter("sobolev_axes", (Vn, F), **params)[0]
    for bound in (0, 10**9):
        clear_cache()
        ops = get_operators(F, len(Vn))
        warm = get_filter("sobolev_axes").core(Vn, F, ops=ops, pinned=pinned, start=free, **params,
                                               config=ax.AxesConfig(lanczos_min_vertices=0, pinned_cg_bound=bound))
        np.testing.assert_allclose(warm, before, atol=1e-9 * np.abs(Vn).max())
        np.testing.assert_allclose(warm[pinned], Vn[pinned], atol=1e-15)  # the core's frame rotation back: rounding
    methods.clear()
    clear_cache()
    _axes(Vn, F, ax.AxesConfig(lanczos_min_vertices=10**9), pinned, **params)  # below the size: the factor
    assert methods == ["cholesky", "cholesky"]

"""Correctness of the fast paths (threaded kernel, fused steps, Chebyshev heat, backends, the
benchmark's Loop subdivision) against independent computations. No timings here."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg as sl
import scipy.sparse as sp
from scipy.special import iv

from meshdenoise import operators as op_module
from meshdenoise.gpu import BACKENDS, get_backend
from meshdenoise.operators import Operators, spmm
from meshdenoise.plugins.filtering import filtering
from meshdenoise.plugins.heat import chebyshev_coefficients, heat
from meshdenoise.registry import get_filter
from meshdenoise.shapes import grid, icosphere, torus


def _noisy(mesh, seed=0):
    V, F = mesh
    return V + 0.05 * np.random.default_rng(seed).standard_normal(V.shape), F


def _random_csr(n, p, density, seed):
    A = sp.random(n, p, density=density, format="csr", random_state=seed)
    A.sort_indices()
    return A


@pytest.mark.parametrize("threads", [1, 2, 3, 7])
def test_spmm_matches_dense_product(threads):
    A = _random_csr(200, 150, 0.05, 1)
    X = np.random.default_rng(2).standard_normal((150, 3))
    np.testing.assert_allclose(spmm(A, X, threads=threads), A.toarray() @ X, rtol=1e-13, atol=1e-13)
    Y0 = np.random.default_rng(3).standard_normal((200, 3))
    Y = Y0.copy()
    spmm(A, X, Y, accumulate=True, threads=threads)
    np.testing.assert_allclose(Y, Y0 + A.toarray() @ X, rtol=1e-13, atol=1e-13)
    Y = Y0.copy()  # out= without accumulate: what it held is overwritten (each thread clears its own rows)
    assert spmm(A, X, Y, threads=threads) is Y
    np.testing.assert_allclose(Y, A.toarray() @ X, rtol=1e-13, atol=1e-13)


def test_spmm_empty_rows_vectors_and_fallback(monkeypatch):
    A = sp.csr_matrix(np.array([[0.0, 0, 0], [1, 0, 2], [0, 0, 0], [0, 3, 0]]))
    x = np.array([1.0, 2.0, 3.0])
    np.testing.assert_array_equal(spmm(A, x, threads=4), A.toarray() @ x)
    monkeypatch.setattr(op_module, "_kernel_ok", False)  # a scipy without the private kernel
    np.testing.assert_array_equal(spmm(A, x), A.toarray() @ x)


def test_spmm_rejects_bad_arguments():
    A = sp.csr_matrix(np.eye(3))
    with pytest.raises(ValueError, match="accumulate=True needs out"):
        spmm(A, np.ones((3, 2)), accumulate=True)
    with pytest.raises(ValueError, match="X has 4 rows"):
        spmm(A, np.ones((4, 2)))
    with pytest.raises(ValueError, match="C-contiguous float64"):
        spmm(A, np.ones((3, 2)), out=np.ones((3, 2), dtype=np.float32))


def test_spmm_threads_env(monkeypatch):
    monkeypatch.setenv("MESHDENOISE_THREADS", "3")
    assert op_module.spmm_threads() == 3
    monkeypatch.setenv("MESHDENOISE_THREADS", "zero")
    with pytest.raises(ValueError, match="MESHDENOISE_THREADS = 'zero'"):
        op_module.spmm_threads()


def test_spmm_stays_on_the_calling_thread_inside_single_threaded(monkeypatch):
    """A product large enough to thread runs the compiled kernel on every allowed thread; inside
    kernels.single_threaded (runs going side by side) on the calling thread only, with the same bits; the cap ends
    with the block, and the caller's numba thread count is given back."""
    import numba

    from meshdenoise import kernels

    if numba.config.NUMBA_NUM_THREADS < 2:
        pytest.skip("numba has one thread here")  # pragma: no cover - CI has 2 cores
    monkeypatch.setenv("MESHDENOISE_THREADS", "2")
    A = _random_csr(4000, 4000, 0.003, 4)  # 48k non-zeros x 80 columns: above the threading threshold
    X = np.random.default_rng(5).standard_normal((4000, 80))
    assert A.nnz * X.shape[1] >= op_module._THREADED_WORK
    counts = []
    kernel = kernels.csr_matmat
    monkeypatch.setattr(kernels, "csr_matmat", lambda *a: (counts.append(numba.get_num_threads()), kernel(*a)))
    before = numba.get_num_threads()
    threaded = spmm(A, X)
    assert counts == [2] and numba.get_num_threads() == before
    counts.clear()
    with kernels.single_threaded():
        assert op_module.thread_limit() == 1
        alone = spmm(A, X)
    assert counts == [1]
    np.testing.assert_array_equal(alone, threaded)
    assert op_module.thread_limit() is None
    spmm(A, X)
    assert counts == [1, 2]


@pytest.mark.parametrize("columns", [1, 2, 3, 5, 16, 40])
@pytest.mark.parametrize("threads", [1, 2])
def test_spmm_gives_scipys_product_bit_for_bit(columns, threads):
    # each row summed over its non-zeros in storage order from 0 (or from out's value): scipy's own A @ X, exactly,
    # with unsorted indices and 64-bit indices too
    rng = np.random.default_rng(columns)
    A = _random_csr(300, 250, 0.04, columns)
    X = rng.standard_normal((250, columns)) * 10.0 ** rng.integers(-8, 8, size=(250, 1))
    for M in (A, _shuffled_rows(A, rng), sp.csr_matrix((A.data, A.indices.astype(np.int64), A.indptr.astype(np.int64)),
                                                       shape=A.shape)):
        np.testing.assert_array_equal(spmm(M, X, threads=threads), M @ X)
        Y0 = rng.standard_normal((300, columns))
        Y = Y0.copy()
        spmm(M, X, Y, accumulate=True, threads=threads)
        expected = Y0.copy()
        for i in range(300):  # Y0 + each product in turn, as the kernels add them
            for t in range(M.indptr[i], M.indptr[i + 1]):
                expected[i] += M.data[t] * X[M.indices[t]]
        np.testing.assert_array_equal(Y, expected)


def _shuffled_rows(A, rng):
    """``A`` with each row's non-zeros stored in a random order (unsorted indices)."""
    data, indices = A.data.copy(), A.indices.copy()
    for i in range(A.shape[0]):
        lo, hi = A.indptr[i], A.indptr[i + 1]
        order = lo + rng.permutation(hi - lo)
        data[lo:hi], indices[lo:hi] = data[order], indices[order]
    B = sp.csr_matrix((data, indices, A.indptr.copy()), shape=A.shape)
    B.has_sorted_indices = False
    return B


def test_every_thread_lifts_a_workers_cap_for_the_block_only():
    from meshdenoise import kernels

    assert op_module.thread_limit() is None
    with kernels.single_threaded():
        with kernels.every_thread():  # work others wait for: every thread
            assert op_module.thread_limit() is None
        assert op_module.thread_limit() == 1
    assert op_module.thread_limit() is None


@pytest.mark.parametrize("mesh", [icosphere(2), grid(9, 6), torus(12, 7)], ids=["sphere", "plane", "torus"])
def test_fast_operator_build_matches_coo_construction(mesh):
    """W and P built from sorted keys equal scipy's COO -> CSR construction with duplicates summed."""
    V, F = mesh
    n = len(V)
    ops = Operators(F, n)
    rows = np.concatenate([F[:, 0], F[:, 1], F[:, 2], F[:, 1], F[:, 2], F[:, 0]])
    cols = np.concatenate([F[:, 1], F[:, 2], F[:, 0], F[:, 0], F[:, 1], F[:, 2]])
    W = sp.coo_matrix((np.ones(rows.size), (rows, cols)), shape=(n, n)).tocsr()
    W.data[:] = 1.0
    assert (ops.W != W).nnz == 0
    assert ops.W.has_sorted_indices and ops.W.indices.dtype == np.int32
    for i in range(n):  # sorted, duplicate-free column indices in every row
        row = ops.W.indices[ops.W.indptr[i] : ops.W.indptr[i + 1]]
        assert np.all(np.diff(row) > 0)
    np.testing.assert_allclose(ops.P.toarray(), W.toarray() / W.toarray().sum(1, keepdims=True), atol=1e-15)


def test_filtering_fused_step_equals_textbook_update():
    """X <- X + lam (A X - X), written as a loop here, for every linear weights rule and pinned vertices."""
    V, F = _noisy(grid(10, 8))
    ops = Operators(F, len(V))
    pinned = np.zeros(len(V), bool)
    pinned[::7] = True
    for weights, A in [("uniform", ops.P), ("open3d", None), ("meshlab", None)]:
        from meshdenoise.plugins.filtering import averaging_operator

        A = averaging_operator(ops, weights, pinned).toarray()
        X = V.copy()
        for _ in range(4):
            X = X + 0.4 * (A @ X - X)
        Y, _ = filtering((V, F), iterations=4, lam=0.4, weights=weights, pinned=pinned)
        np.testing.assert_allclose(Y, X, rtol=0, atol=1e-13)
        np.testing.assert_array_equal(Y[pinned], V[pinned])


def test_heat_euler_equals_textbook_steps():
    V, F = _noisy(icosphere(2))
    P = Operators(F, len(V)).P.toarray()
    X = V.copy()
    for _ in range(7):  # ceil(3.4 / 0.5)
        X = X - 0.5 * (X - P @ X)
    Y, _ = heat((V, F), tau=0.5, time=3.4)
    np.testing.assert_allclose(Y, X, rtol=0, atol=1e-13)


@pytest.mark.parametrize("upper", [2.0, 1.5, 0.7])
@pytest.mark.parametrize("T, tol", [(12.5, 1e-9), (40.0, 1e-3), (3.0, 1e-5)])
def test_chebyshev_coefficients_against_bessel_series(upper, T, tol):
    """a_k = e^-T' I_k(T') (doubled for k >= 1, T' = T b / 2), and the truncated polynomial in
    y = 1 - 2x/b stays within tol of exp(-T x) on [0, b] while one term fewer does not."""
    a = chebyshev_coefficients(T, tol, upper)
    K = len(a) - 1
    Tp = T * upper / 2
    ref = 2 * np.exp(-Tp) * iv(np.arange(K + 1), Tp)
    ref[0] /= 2
    np.testing.assert_allclose(a[1:], ref[1:], rtol=1e-12)
    assert abs(a.sum() - 1.0) < 1e-15  # p(0) = 1: translations pass through
    x = np.linspace(0, upper, 4001)
    y = 1 - 2 * x / upper
    assert np.abs(np.polynomial.chebyshev.chebval(y, a) - np.exp(-T * x)).max() <= tol
    shorter = a[:-1].copy()
    shorter[0] += a[-1]  # the same construction one degree lower
    assert np.abs(np.polynomial.chebyshev.chebval(y, shorter) - np.exp(-T * x)).max() > tol / 20


def test_chebyshev_coefficients_edge_cases():
    np.testing.assert_array_equal(chebyshev_coefficients(0.0, 1e-7), [1.0])
    for bad in (0.0, -1.0, 2.5):
        with pytest.raises(ValueError, match="upper"):
            chebyshev_coefficients(1.0, 1e-3, bad)


def _meshes_for_the_bound():
    rng = np.random.default_rng(8)
    V, F = grid(6, 5)
    yield "closed icosphere", icosphere(2)[1], len(icosphere(2)[0])
    yield "closed torus", torus(9, 6)[1], len(torus(9, 6)[0])
    yield "open grid", F, len(V)
    yield "one triangle", np.array([[0, 1, 2]]), 3
    yield "two triangles sharing an edge", np.array([[0, 1, 2], [1, 3, 2]]), 4
    fan = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [0, 1, 4]])  # edge 0-1 in three faces
    yield "non-manifold fan", fan, 5
    yield "with degenerate faces and an isolated vertex", np.vstack([F, [[0, 0, 1], [3, 3, 3]]]), len(V) + 1
    for k in range(6):  # triangle soups: random faces on few vertices, duplicates and all
        n = int(rng.integers(4, 12))
        yield f"random soup {k}", rng.integers(0, n, size=(int(rng.integers(2, 25)), 3)), n


@pytest.mark.parametrize("case", list(_meshes_for_the_bound()), ids=lambda c: c[0])
def test_lambda_max_bound_holds_against_dense_eigenvalues(case):
    _, F, n = case
    ops = Operators(F, n)
    lam = float(np.max(np.linalg.eigvals(np.eye(n) - ops.P.toarray()).real))
    assert lam <= ops.lambda_max_bound + 1e-12 <= 2.0 + 1e-12


def test_lambda_max_bound_is_tight_on_closed_meshes():
    for V, F in (icosphere(3), torus(20, 12)):
        ops = Operators(F, len(V))
        assert ops.lambda_max_bound == 1.5
        assert 1.3 < ops.lambda_max() <= 1.5
    tri = Operators(np.array([[0, 1, 2]]), 3)  # eigenvalues 0, 1.5, 1.5: the bound is attained
    assert tri.lambda_max_bound == 1.5
    np.testing.assert_allclose(np.sort(np.linalg.eigvals(np.eye(3) - tri.P.toarray()).real), [0, 1.5, 1.5], atol=1e-12)
    assert Operators(np.zeros((0, 3), dtype=int), 4).lambda_max_bound == 0.0


@pytest.mark.parametrize("n", [10, 3_000_000])
def test_gather_rows_equals_fancy_indexing(n):
    """Small inputs take numpy's path, large ones the threaded sparse gather: both equal X[index]."""
    rng = np.random.default_rng(n)
    X = rng.standard_normal((n, 3))
    index = rng.permutation(n)
    got = op_module.gather_rows(X, index)
    np.testing.assert_array_equal(got, X[index])
    assert got.flags.c_contiguous and not np.shares_memory(got, X)
    index[:3] = [-1, -n, 0]  # negative indices count from the end, as in numpy
    np.testing.assert_array_equal(op_module.gather_rows(X, index), X[index])
    for bad in (n, -n - 1):
        index[5] = bad
        with pytest.raises(IndexError, match="out of range"):
            op_module.gather_rows(X, index)


@pytest.mark.parametrize("backend", ["cpu", "scipy"])
def test_chebyshev_heat_matches_dense_expm(backend):
    V, F = _noisy(torus(10, 6))
    n = len(V)
    P = Operators(F, n).P.toarray()
    E = sl.expm(-9.7 * (np.eye(n) - P)) @ V
    Y, _ = heat((V, F), time=9.7, method="chebyshev", tol=1e-10, backend=backend)
    np.testing.assert_allclose(Y, E, rtol=0, atol=1e-9)


def test_chebyshev_heat_with_pinned_vertices_is_the_dirichlet_exponential():
    V, F = _noisy(grid(9, 7))
    n = len(V)
    ops = Operators(F, n)
    pinned = ops.boundary_vertices
    Pf = ops.P.toarray()
    Pf[pinned] = np.eye(n)[pinned]  # fixed rows as identity: d/dt x_p = 0
    E = sl.expm(-6.0 * (np.eye(n) - Pf)) @ V
    Y, _ = heat((V, F), time=6.0, method="chebyshev", tol=1e-10, pinned="boundary")
    np.testing.assert_allclose(Y, E, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(Y[pinned], V[pinned])


def test_chebyshev_and_euler_converge_to_the_same_heat_flow():
    """Euler with a small step approaches exp(-T(I - P)) X; Chebyshev is that limit."""
    V, F = _noisy(icosphere(2))
    cheb, _ = heat((V, F), time=2.0, method="chebyshev", tol=1e-12)
    errs = [np.abs(heat((V, F), time=2.0, tau=tau)[0] - cheb).max() for tau in (0.1, 0.05, 0.025)]
    assert errs[0] > errs[1] > errs[2]
    assert 1.7 < errs[0] / errs[1] < 2.3 and 1.7 < errs[1] / errs[2] < 2.3  # first order in tau


def test_chebyshev_time_zero_returns_input():
    V, F = _noisy(icosphere(1))
    Y, _ = heat((V, F), time=0.0, method="chebyshev")
    np.testing.assert_array_equal(Y, V)


@pytest.mark.parametrize("name", ["scipy", "cpu"])
def test_generic_backend_path_equals_default(name):
    """The backend-generic code path (public scipy API) agrees with the default threaded kernel."""
    V, F = _noisy(icosphere(3))
    for kwargs in [{"iterations": 5}, {"iterations": 3, "lam": 0.3, "weights": "meshlab"}]:
        a, _ = filtering((V, F), **kwargs)
        b, _ = filtering((V, F), backend=name, **kwargs)
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-14)
    a, _ = heat((V, F), time=5.0, method="chebyshev")
    b, _ = heat((V, F), time=5.0, method="chebyshev", backend=name)
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-13)


def test_torch_backend_matches_cpu_or_says_what_to_install():
    """With torch installed (its CPU build runs the same calls as on CUDA) every backend-generic
    filter agrees with the default path; without it, asking for it is a clear ValueError."""
    V, F = _noisy(torus(14, 9))
    try:
        import torch  # noqa: F401
    except ImportError:
        with pytest.raises(ValueError, match="backend='torch' needs PyTorch"):
            heat((V, F), time=5.0, method="chebyshev", backend="torch")
        return
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no torch warning leaks to the user
        for kwargs in [{"time": 5.0, "method": "chebyshev"}, {"time": 5.0, "tau": 0.5}]:
            np.testing.assert_allclose(heat((V, F), backend="torch", **kwargs)[0], heat((V, F), **kwargs)[0], atol=1e-13)
        kw = {"iterations": 7, "lam": 0.4, "weights": "meshlab", "pinned": "boundary"}
        np.testing.assert_allclose(filtering((V, F), backend="torch", **kw)[0], filtering((V, F), **kw)[0], atol=1e-13)


def test_backend_errors_are_clear():
    with pytest.raises(ValueError, match="backend = 'tpu' is unknown"):
        get_backend("tpu")
    assert set(BACKENDS) == {"cpu", "scipy", "cupy", "torch"}
    V, F = icosphere(1)
    with pytest.raises(ValueError, match="inverse_distance"):
        filtering((V, F), weights="inverse_distance", backend="scipy")
    for name in ("cupy", "torch"):
        try:
            __import__(name)
        except ImportError:
            with pytest.raises(ValueError, match=f"backend='{name}' needs"):
                filtering((V, F), backend=name)


def _speed_module():
    path = Path(__file__).resolve().parent.parent / "benchmarks" / "speed.py"
    spec = importlib.util.spec_from_file_location("speed_benchmark", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_loop_subdivision_of_the_benchmark():
    """Counts n + e and 4m, closed stays closed, and a flat grid stays flat with interior points
    matching Loop's rules written out for one vertex and one edge."""
    loop = _speed_module().loop_subdivide
    V, F = icosphere(1)
    ops = Operators(F, len(V))
    V2, F2 = loop(V, F)
    assert len(V2) == len(V) + len(ops.edges) and len(F2) == 4 * len(F)
    assert len(Operators(F2, len(V2)).boundary_edges) == 0
    # vertex 0 of the icosphere has valence 5: (1 - 5 beta) v + beta sum(neighbours)
    k = 5
    beta = (5 / 8 - (3 / 8 + np.cos(2 * np.pi / k) / 4) ** 2) / k
    nb = ops.W[0].indices
    np.testing.assert_allclose(V2[0], (1 - k * beta) * V[0] + beta * V[nb].sum(0), atol=1e-14)
    # an interior edge (a, b) with opposite vertices c, d: 3/8 (a + b) + 1/8 (c + d)
    a, b = ops.edges[0]
    opp = [f[(f != a) & (f != b)][0] for f in F if a in f and b in f]
    target = 3 / 8 * (V[a] + V[b]) + 1 / 8 * (V[opp[0]] + V[opp[1]])
    assert np.min(np.linalg.norm(V2[len(V) :] - target, axis=1)) < 1e-14
    Vg, Fg = grid(5, 4)
    Vg2, Fg2 = loop(Vg, Fg)
    np.testing.assert_allclose(Vg2[:, 2], 0.0, atol=1e-15)  # planar stays planar


def test_locality_order_is_a_permutation_that_shrinks_bandwidth():
    V, F = icosphere(3)
    perm = np.random.default_rng(4).permutation(len(V))  # scramble the labels first
    inv = np.argsort(perm)
    ops = Operators(inv[F], len(V))
    order = ops.locality_order
    np.testing.assert_array_equal(np.sort(order), np.arange(len(V)))
    Pp = ops.permuted(ops.P, "P").tocoo()
    np.testing.assert_array_equal(Pp.toarray(), ops.P.toarray()[order][:, order])
    assert np.abs(Pp.row - Pp.col).max() < np.abs(ops.P.tocoo().row - ops.P.tocoo().col).max() / 4


@pytest.mark.parametrize("method", ["euler", "chebyshev"])
def test_relabelled_fast_path_gives_the_same_result(method):
    """Forcing the locality-ordered path on a small mesh (the cores' LocalityConfig) changes nothing but rounding."""
    from meshdenoise.plugins import filtering as filtering_module

    V, F = _noisy(torus(14, 9))
    pinned = np.zeros(len(V), bool)
    pinned[[3, 40, 77]] = True
    assert not filtering_module.use_locality_order(Operators(F, len(V)), 20)  # a small mesh: the plain path
    ref_heat, _ = heat((V, F), time=6.0, method=method, pinned=pinned)
    ref_filt, _ = filtering((V, F), iterations=20, lam=0.6, weights="meshlab", pinned=pinned)
    config = filtering_module.LocalityConfig(min_vertices=0)
    ops = Operators(F, len(V))
    assert filtering_module.use_locality_order(ops, 20, config)
    mask = np.asarray(pinned, dtype=bool)

    def core(name, **params):  # the filter's array core with the config, held rows kept as the registry keeps them
        spec = get_filter(name)
        out = spec.core(V, F, ops=ops, pinned=mask, config=config, **spec.resolve(params))
        out[mask] = V[mask]
        return out

    got_heat = core("heat", time=6.0, method=method)
    got_filt = core("filtering", iterations=20, lam=0.6, weights="meshlab")
    assert "locality_order" in ops.__dict__  # the relabelled path really ran
    np.testing.assert_allclose(got_heat, ref_heat, rtol=0, atol=1e-13)
    np.testing.assert_allclose(got_filt, ref_filt, rtol=0, atol=1e-13)
    np.testing.assert_array_equal(got_heat[pinned], V[pinned])


@pytest.mark.parametrize("case", list(_meshes_for_the_bound()), ids=lambda c: c[0])
def test_chebyshev_heat_on_the_bounded_interval_matches_expm(case):
    """The shrunk interval [0, lambda_max_bound] is safe on open, non-manifold and degenerate meshes."""
    _, F, n = case
    V = np.random.default_rng(n).standard_normal((n, 3))
    ops = Operators(F, n)
    E = sl.expm(-7.0 * (np.eye(n) - ops.P.toarray())) @ V
    Y, _ = heat((V, F), time=7.0, method="chebyshev", tol=1e-11)
    np.testing.assert_allclose(Y, E, rtol=0, atol=1e-9 * max(1.0, np.abs(V).max()))


def test_cached_chebyshev_matrices_follow_the_pinned_mask():
    """Two calls with different pinned sets on the same Operators each match their own exponential."""
    V, F = _noisy(grid(8, 6))
    n = len(V)
    ops = Operators(F, n)
    for pinned in (np.arange(n) < 5, ops.boundary_vertices, None):
        Pf = ops.P.toarray()
        if pinned is not None:
            Pf[pinned] = np.eye(n)[pinned]
        E = sl.expm(-4.0 * (np.eye(n) - Pf)) @ V
        Y, _ = heat((V, F), time=4.0, method="chebyshev", tol=1e-11, pinned=pinned, operators=ops)
        np.testing.assert_allclose(Y, E, rtol=0, atol=1e-9)
    assert sum(k[0] == "chebyshev_heat" for k in ops.cache) == 3


def test_default_tolerance_is_closer_to_exp_than_euler_at_tau_half():
    """The documented reason for tol=1e-3: the polynomial's response error at T = 40 is below
    the Euler scheme's (1 - tau x)^(T/tau) error, on the whole interval."""
    from meshdenoise.plugins.heat import DEFAULT_TOL

    x = np.linspace(0, 1.5, 30001)
    a = chebyshev_coefficients(40.0, DEFAULT_TOL, 1.5)
    cheb = np.abs(np.polynomial.chebyshev.chebval(1 - 2 * x / 1.5, a) - np.exp(-40 * x)).max()
    euler = np.abs((1 - 0.5 * x) ** 80 - np.exp(-40 * x)).max()
    assert cheb <= DEFAULT_TOL < euler

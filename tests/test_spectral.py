"""Linear smoothers as functions of one symmetric matrix (meshdenoise.tuning.spectral, solvers.LanczosDots) and the
normals search that scores its candidates from them (refine_for_normals(spectral=...))."""

import numpy as np
import scipy.sparse as sp
import pytest

import meshdenoise as md
import meshdenoise.tuning.normal_risk as nr
import meshdenoise.tuning.spectral as spectral_module
from meshdenoise.geometry import vertex_normals
from meshdenoise.operators import get_operators
from meshdenoise.registry import get_filter
from meshdenoise.shapes import icosphere
from meshdenoise.solvers import LanczosDots
from meshdenoise.tuning.choose import choose_parameters, normal_candidates
from meshdenoise.tuning.config import SpectralConfig
from meshdenoise.tuning.spectral import (SpectralSearch, averaging_spectral, heat_kernel_spectral, shifted_spectral)


def _noisy(level=2, rho=0.02, seed=1):
    V0, F = icosphere(level)
    X = V0 + rho * np.random.default_rng(seed).standard_normal(len(V0))[:, None] * vertex_normals(V0, F)
    return V0, F, X


def _open_noisy():
    """A sphere with a cap cut off: a border, and a vertex left on no face (isolated)."""
    V0, F, X = _noisy(2)
    keep = V0[F].mean(axis=1)[:, 2] < 0.7
    return V0, F[keep], X


@pytest.mark.parametrize("case", [_noisy, _open_noisy])
@pytest.mark.parametrize("method, params", [
    ("sobolev_bilaplacian", {"mu": 0.4}),
    ("sobolev_axes", {"mu1": 0.2, "mu2": 0.0, "mu3": 1.5, "order": 2, "frame_steps": 2}),
])
def test_each_filters_spectral_form_is_its_own_map(case, method, params):
    """``AutoRule.spectral`` (the filters whose normals choice is the normal-risk search) against the filter itself
    (its linear map, or its core on the coordinates): the dense S^-1 g(M) S from an eigendecomposition of M."""
    V0, F, X = case()
    ops = get_operators(F, len(X))
    spec = get_filter(method)
    p = spec.resolve(params)
    form = spec.auto.spectral(X, F, ops, p)
    if spec.auto.linear_map is not None:
        block = np.hstack([X, np.random.default_rng(0).standard_normal((len(X), 6))])
        want = spec.auto.linear_map(X, F, ops, p)(block)
        np.testing.assert_allclose(form.apply_dense(block), want, atol=1e-7 * np.abs(block).max())  # gls: CG's tol
    else:
        np.testing.assert_allclose(form.apply_dense(X), spec.core(X, F, ops=ops, pinned=None, **p), atol=1e-10)


@pytest.mark.parametrize("g", [lambda t: 1.0 / (1.0 + 3.0 * t), lambda t: np.exp(-0.5 * t), lambda t: (1 - 0.2 * t) ** 9])
def test_lanczos_dots_against_dense_bilinear_forms(g):
    _, F, X = _noisy(2)
    L = get_operators(F, len(X)).L
    rng = np.random.default_rng(2)
    B, U1, U2 = (rng.standard_normal((len(X), 5)) for _ in range(3))
    theta, Q = np.linalg.eigh(L.toarray())
    G = (Q * g(np.maximum(theta, 0.0))) @ Q.T
    run = LanczosDots(L, B, [U1, U2])
    got = run.dots(g)
    want = np.array([np.einsum("ij,ij->j", U, G @ B) for U in (U1, U2)])
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9 * np.abs(want).max())
    assert run.steps < len(X)  # converged long before the Krylov space is the whole space
    assert LanczosDots(L, B, [U1], max_steps=3).dots(lambda t: 1.0 / (1.0 + 1e4 * t**3), check=2) is None


@pytest.mark.parametrize("order", [1, 2, 3])
def test_lanczos_dots_of_shifted_inverses_by_tridiagonal_solves(order):
    """dots of ShiftedInverse functions (p tridiagonal solves per column and size, no eigenproblem), one function or
    one per axis, against the same functions as plain callables (the eigenvalue route) at every size, and against
    the dense bilinear forms once converged."""
    from meshdenoise.solvers import ShiftedInverse

    _, F, X = _noisy(2)
    L = get_operators(F, len(X)).L
    rng = np.random.default_rng(3)
    B, U1, U2 = (rng.standard_normal((len(X), 6)) for _ in range(3))
    theta, Q = np.linalg.eigh(L.toarray())
    for mus in [(0.7,), (0.05, 2.0, 30.0), (0.05, 0.0, 30.0)]:  # mu 0: an axis left as it is
        fs = tuple(ShiftedInverse(mu, order) for mu in mus)
        plain = tuple((lambda t, f=f: f(t)) for f in fs)  # the same values, not recognised: eigenvalue route
        g, g_plain = (fs[0], plain[0]) if len(fs) == 1 else (fs, plain)
        run = LanczosDots(L, B, [U1, U2])
        got = run.dots(g)
        for k in (1, 2, 5, run.steps):
            fast, slow = run._estimate(g, k), run._estimate(g_plain, k)
            np.testing.assert_allclose(fast[0], slow[0], rtol=1e-10, atol=1e-12 * np.abs(slow[0]).max())
            np.testing.assert_allclose(fast[1], slow[1], rtol=1e-10)
        want = np.zeros((2, B.shape[1]))
        for j in range(B.shape[1]):
            G = (Q * fs[j % len(fs)](np.maximum(theta, 0.0))) @ Q.T
            want[:, j] = [U[:, j] @ G @ B[:, j] for U in (U1, U2)]
        np.testing.assert_allclose(got, want, rtol=1e-8, atol=1e-9 * np.abs(want).max())


def test_lanczos_dots_is_exact_once_the_krylov_space_is_exhausted_and_checks_shapes():
    import scipy.sparse as sp

    M = sp.csr_matrix(np.diag([0.0, 1.0, 3.0]))
    b, u = np.array([[1.0], [1.0], [0.0]]), np.array([[2.0], [5.0], [7.0]])
    assert LanczosDots(M, b, [u]).dots(lambda t: np.exp(-t))[0, 0] == pytest.approx(2.0 + 5.0 * np.exp(-1.0), abs=1e-14)
    with pytest.raises(ValueError, match="dual has shape"):
        LanczosDots(M, b, [np.ones((3, 2))])


@pytest.mark.parametrize("family, values", [
    (lambda ops: lambda v: shifted_spectral(ops, v, 1), [0.05, 2.0, 80.0]),
    (lambda ops: lambda v: shifted_spectral(ops, v, 3), [0.01, 1.0, 30.0]),
    (lambda ops: lambda v: averaging_spectral(ops, (0.5, -0.53), int(v)), [1, 12, 250]),
    (lambda ops: lambda v: heat_kernel_spectral(ops, v, 1, 4), [0.2, 2.0, 20.0]),
])
@pytest.mark.parametrize("tol, accuracy", [(1e-10, 1e-9), (None, 1e-5)])  # None: SpectralConfig.tol, the searches' own
def test_spectral_search_coordinates_and_probe_terms_against_dense(family, values, tol, accuracy):
    """One coordinates' run and one probes' run serve every candidate: HX and u^T H b as the dense matrices give them,
    to ``accuracy`` of the smoothing's correction HX - X (the run's tolerance is relative to it, not to X)."""
    _, F, X = _open_noisy()
    ops = get_operators(F, len(X))
    fam = family(ops)
    search = SpectralSearch(X, fam, tol=tol)
    rng = np.random.default_rng(4)
    B, U = rng.choice([-1.0, 1.0], size=(len(X), 6)), rng.standard_normal((len(X), 6))
    search.coordinates(values[0])
    terms = search.probes(B, [U])
    for v in values:
        H = fam(v).dense()
        correction = np.abs(H @ X - X).max()
        np.testing.assert_allclose(search.coordinates(v), H @ X, atol=accuracy * correction)
        want = np.einsum("ij,ij->j", U, H @ B)
        np.testing.assert_allclose(terms(v)[0], want, atol=accuracy * np.abs(want).max())


def _frame_family(ops):
    """Per-axis Sobolev weights 0.1 v, 0 and v in a random frame (as sobolev_axes builds them; one axis left as it is)."""
    E = np.linalg.qr(np.random.default_rng(5).standard_normal((3, 3)))[0]

    def fam(v):
        axes = [shifted_spectral(ops, v * w, 2) for w in (0.1, 0.0, 1.0)]
        return spectral_module.Spectral(ops.L, tuple(a.g for a in axes), tuple(a.h for a in axes), frame=E)

    return fam


@pytest.mark.parametrize("tol, accuracy", [(1e-10, 1e-9), (None, 1e-5)])
def test_spectral_search_with_a_frame_against_dense(tol, accuracy):
    """Per-axis functions in a frame (sobolev_axes): the coordinates and u . H b as the dense per-axis maps give them."""
    _, F, X = _open_noisy()
    ops = get_operators(F, len(X))
    fam = _frame_family(ops)

    search = SpectralSearch(X, fam, tol=tol)
    rng = np.random.default_rng(6)
    B, U = rng.choice([-1.0, 1.0], size=(len(X), 6)), rng.standard_normal((len(X), 6))
    search.coordinates(1.0)
    terms = search.probes(B, [U])
    for v in (0.3, 1.0, 5.0):
        HX, HB = fam(v).apply_dense(X), fam(v).apply_dense(B)
        np.testing.assert_allclose(search.coordinates(v), HX, atol=accuracy * np.abs(HX - X).max())
        got = terms(v)[0].reshape(2, 3).sum(axis=1)  # per probe triple: the frame mixes its three columns
        want = np.einsum("ipc,ipc->p", U.reshape(-1, 2, 3), HB.reshape(-1, 2, 3))
        np.testing.assert_allclose(got, want, atol=accuracy * np.abs(want).max())


@pytest.mark.parametrize("family, values, direct", [
    (lambda ops: lambda v: shifted_spectral(ops, v, 1), [0.05, 2.0, 80.0], True),
    (lambda ops: lambda v: shifted_spectral(ops, v, 3), [0.01, 1.0, 30.0], True),
    (lambda ops: lambda v: averaging_spectral(ops, (0.5, -0.53), int(v)), [1, 12, 250], False),  # a scale: formed
    (lambda ops: lambda v: heat_kernel_spectral(ops, v, 1, 4), [0.2, 2.0, 20.0], True),
])
def test_start_duals_against_dense_and_read_from_the_probes_own_run(family, values, direct, monkeypatch):
    """StartDual(k, A): u = A^k B. Without a scale and with A the search's M (or k = 0) its terms are Gauss rules of
    the probes' own run (no dual recorded), else A^k B is formed and recorded: u^T H b as the dense map gives it,
    either way; another matrix than M is formed."""
    from meshdenoise.tuning.spectral import StartDual

    _, F, X = _open_noisy()
    ops = get_operators(F, len(X))
    fam = family(ops)
    recorded = []
    real = spectral_module.LanczosDots
    monkeypatch.setattr(spectral_module, "LanczosDots",
                        lambda M, B, duals, **k: recorded.append(len(duals)) or real(M, B, duals, **k))
    search = SpectralSearch(X, fam, tol=1e-10)
    rng = np.random.default_rng(7)
    B, U = rng.choice([-1.0, 1.0], size=(len(X), 6)), rng.standard_normal((len(X), 6))
    search.coordinates(values[0])
    M = fam(values[0]).M
    L_copy = sp.csr_matrix(M.copy())
    other = sp.csr_matrix(2.0 * M)
    terms = search.probes(B, [U, StartDual(), StartDual(1), StartDual(1, L_copy), StartDual(2, other)])
    assert recorded == [2 if direct else 5]  # U and the other matrix's dual; all five with a scale
    Md = M.toarray()
    for v in values:
        HB = fam(v).dense() @ B
        got = terms(v)
        for row, A in ((0, None), (1, np.eye(len(X))), (2, Md), (3, Md), (4, (2.0 * Md) @ (2.0 * Md))):
            u = U if A is None else A @ B
            want = np.einsum("ij,ij->j", u, HB)
            np.testing.assert_allclose(got[row], want, rtol=1e-8, atol=1e-9 * np.abs(want).max())
    with pytest.raises(ValueError, match="power must be an int >= 0"):
        StartDual(-1)


def test_start_dual_with_a_frame_against_dense():
    """A frame's per-axis functions (sobolev_axes): StartDual() and StartDual(1) per column as the dense maps give them."""
    from meshdenoise.tuning.spectral import StartDual

    _, F, X = _open_noisy()
    ops = get_operators(F, len(X))
    fam = _frame_family(ops)

    search = SpectralSearch(X, fam, tol=1e-10)
    B = np.random.default_rng(6).choice([-1.0, 1.0], size=(len(X), 6))
    search.coordinates(1.0)
    terms = search.probes(B, [StartDual(), StartDual(1)])
    L = ops.L.toarray()
    for v in (0.3, 1.0, 5.0):
        HB = fam(v).apply_dense(B)
        for row, u in ((0, B), (1, L @ B)):
            got = terms(v)[row].reshape(2, 3).sum(axis=1)
            want = np.einsum("ipc,ipc->p", u.reshape(-1, 2, 3), HB.reshape(-1, 2, 3))
            np.testing.assert_allclose(got, want, rtol=1e-8, atol=1e-9 * np.abs(want).max())


def test_spectral_search_refuses_candidates_on_another_matrix():
    _, F, X = _noisy(1)
    ops = get_operators(F, len(X))
    search = SpectralSearch(X, lambda v: shifted_spectral(ops, v, 1) if v < 1 else averaging_spectral(ops, (1.0,), 2))
    search.coordinates(0.5)
    with pytest.raises(ValueError, match="share the first"):
        search.coordinates(2.0)


def _sphere(seed=3, rho=0.012):
    V0, F = icosphere(4)  # 2,562 vertices: at least SpectralConfig.min_vertices
    X = V0 + rho * np.random.default_rng(seed).standard_normal(len(V0))[:, None] * vertex_normals(V0, F)
    return V0, F, X


@pytest.mark.parametrize("tol, accuracy", [(1e-10, 1e-8), (SpectralConfig().tol, 1e-5)])
@pytest.mark.parametrize("averaging", [True, False])
@pytest.mark.parametrize("rho", [0.012, 0.2])  # 0.2: past an edge length, the Dirichlet ranking
def test_refine_for_normals_scores_the_same_by_lanczos_runs_as_by_running_the_filter(averaging, rho, tol, accuracy):
    """The spectral search against the filter run on the probes: the same candidates visited, the same choice and path,
    the risks and position SURE to ``accuracy`` (at the searches' tolerance and at 1e-10)."""
    config = SpectralConfig(tol=tol)
    V0, F, X = _sphere(rho=rho)
    ops = get_operators(F, len(X))
    assert len(X) >= config.min_vertices
    if averaging:  # k steps of X <- P X, or (I + mu L)^-1
        M = ops.P

        def apply(k, block):
            for _ in range(int(k)):
                block = M @ block
            return block

        family, values, start = (lambda k: averaging_spectral(ops, (1.0,), int(k))), normal_candidates(2, True), 2
    else:
        def apply(mu, block):
            return md.apply_filter("sobolev", (block, F), mu=mu)[0] if block.shape[1] == 3 else np.hstack(
                [md.apply_filter("sobolev", (block[:, i:i + 3], F), mu=mu)[0] for i in range(0, block.shape[1], 3)])

        family, values, start = (lambda mu: shifted_spectral(ops, mu, 1)), normal_candidates(0.3, False), 0.3
    rows = np.ones(len(X), dtype=bool)
    rows[:200] = False  # a scored part, as on a region
    kw = dict(first=start * 3, rows=rows)
    direct = nr.refine_for_normals(X, F, apply, start, values, rho, **kw)
    fast = nr.refine_for_normals(X, F, apply, start, values, rho, spectral=family, config=config, **kw)
    assert direct.criterion == fast.criterion == ("dirichlet" if rho == 0.2 else "normals")
    assert (fast.value, fast.path, fast.values) == (direct.value, direct.path, direct.values)
    np.testing.assert_allclose(fast.risks, direct.risks, rtol=accuracy)
    assert fast.position_risk == pytest.approx(direct.position_risk, rel=accuracy)


def test_refine_for_normals_runs_the_filter_where_a_lanczos_run_does_not_converge():
    V0, F, X = _sphere()
    ops = get_operators(F, len(X))
    calls = []

    def apply(mu, block):
        calls.append(block.shape[1])
        return np.hstack([md.apply_filter("sobolev", (block[:, i:i + 3], F), mu=mu)[0] for i in range(0, block.shape[1], 3)])

    values = normal_candidates(0.3, False)
    direct = nr.refine_for_normals(X, F, apply, 0.3, values, 0.012)
    calls.clear()
    fallback = nr.refine_for_normals(X, F, apply, 0.3, values, 0.012, spectral=lambda mu: shifted_spectral(ops, mu, 1),
                                     config=SpectralConfig(max_steps=3))
    assert fallback == direct and any(c > 3 for c in calls)  # the filter's own runs, the same choice to the bit


@pytest.mark.filterwarnings("ignore:choose_parameters.*shrinks the mesh:UserWarning")
@pytest.mark.parametrize("method", ["sobolev_bilaplacian", "sobolev_axes"])  # the others' normals: held-out vertices
def test_normals_criterion_chooses_the_same_with_and_without_the_spectral_search(method, monkeypatch):
    V0, F, X = _sphere(seed=5)
    runs = []

    class Counted(SpectralSearch):
        def probes(self, B, duals):
            runs.append(B.shape)
            return super().probes(B, duals)

    monkeypatch.setattr(nr, "SpectralSearch", Counted)
    fast = choose_parameters((X, F), method, noise=0.012, criterion="normals")
    assert runs  # the candidates were scored by the Lanczos runs
    direct = choose_parameters((X, F), method, noise=0.012, criterion="normals", config=SpectralConfig(min_vertices=10**9))
    assert fast == direct


def test_sinkhorn_rule_reads_its_sure_curves_from_lanczos_runs_as_from_its_factors(monkeypatch):
    """choose_sinkhorn_whole's curves over (t, k) by SpectralSearch (the probes' run shared by every t) and by the heat
    kernel's factors: the same t (to the search's rounding) and iterations; strong kernels (past the CG bound) by factors."""
    import meshdenoise.plugins.sinkhorn_rule as sk

    V0, F, X = _sphere(seed=7)
    calls = []
    real = SpectralSearch.coordinates_many
    monkeypatch.setattr(SpectralSearch, "coordinates_many", lambda self, values: calls.append(values) or real(self, values))
    fast = choose_parameters((X, F), "sinkhorn", noise=0.012, criterion="sure")
    assert calls and all(len(v) == sk.SINKHORN_MAX_ITERATIONS for v in calls)  # every k of a t in one pass
    direct = choose_parameters((X, F), "sinkhorn", noise=0.012, criterion="sure", config=SpectralConfig(min_vertices=10**9))
    assert fast["iterations"] == direct["iterations"] and fast["t"] == pytest.approx(direct["t"], rel=1e-6)
    calls.clear()
    gated = choose_parameters((X, F), "sinkhorn", noise=0.012, criterion="sure",
                              config=(SpectralConfig(min_vertices=0),
                                      sk.SinkhornConfig(spectral_max_bound=0)))  # every t past the bound: the factors' runs
    assert gated == direct and not [v for v in calls if len(v) == sk.SINKHORN_MAX_ITERATIONS]


def test_compiled_lanczos_applies_as_the_numpy_recurrence_and_its_second_pass_on_any_columns():
    """CompiledLanczos against LanczosQuadrature (the same recurrence, sums in another order; both to 1e-10), several functions in
    one second pass as one at a time, and a subset of columns to the bit as the same columns of the whole run."""
    from meshdenoise.solvers import CompiledLanczos, LanczosQuadrature

    _, F, X = _noisy(3)
    L = get_operators(F, len(X)).L
    B = np.hstack([L @ X, np.random.default_rng(8).standard_normal((len(X), 4))])
    gs = [lambda t: 1.0 / (1.0 + 0.7 * t), lambda t: np.exp(-0.3 * t)]
    run = CompiledLanczos(L, B)
    many = run.apply_many(gs)
    for g, got in zip(gs, many):
        want = LanczosQuadrature(L, B).apply(g)
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-10 * np.abs(want).max())  # both converged to 1e-10
        np.testing.assert_array_equal(run.apply(g), got)
    np.testing.assert_array_equal(run.apply(gs[0], columns=[4, 1]), many[0][:, [4, 1]])
    per_axis = run.apply_many([(gs[0], gs[1])])[0]  # column j takes g[j % 2]
    np.testing.assert_array_equal(per_axis[:, 0::2], many[0][:, 0::2])
    np.testing.assert_array_equal(per_axis[:, 1::2], many[1][:, 1::2])


@pytest.mark.parametrize("depth", [2, 3, 7, 1000])  # some leave a last, partial block
def test_second_pass_for_several_functions_accumulates_by_blocks_to_the_bit(depth):
    """apply_many with several functions keeps a ring of depth + 2 basis vectors and accumulates every depth steps
    (kernels.lanczos_next, kernels.lanczos_accumulate_steps): the same numbers as one accumulation per step (the
    fused lanczos_regenerate, a ring of 0 bytes), whatever the depth against the run's length: two runs alike but for
    their SolverConfig.regenerate_ring_bytes."""
    import meshdenoise.solvers as solvers

    _, F, X = _noisy(3)
    L = get_operators(F, len(X)).L
    B = np.hstack([L @ X, np.random.default_rng(9).standard_normal((len(X), 5))])
    gs = [solvers.ShiftedInverse(mu, 3) for mu in (0.05, 2.0, 90.0)] + [lambda t: np.exp(-0.3 * t)]
    runs = [solvers.CompiledLanczos(L, B, config=solvers.SolverConfig(regenerate_ring_bytes=ring))
            for ring in (0, (depth + 2) * 8 * B.size)]
    for run in runs:
        run.apply_many(gs)  # each run extended alike: both passes below read the same coefficients
    fused, blocks = (run.apply_many(gs) for run in runs)
    run = runs[1]
    assert run.steps > depth or depth == 1000  # several blocks
    for a, b in zip(blocks, fused):
        np.testing.assert_array_equal(a, b)


def test_compiled_lanczos_second_pass_sweep_is_the_first_pass_kernels_to_the_bit():
    """The fused second pass (kernels.lanczos_regenerate) against the first pass's kernels (product, update, scale)
    and lanczos_accumulate run one after the other with the same coefficients: equal to the bit."""
    from meshdenoise import kernels
    from meshdenoise.solvers import CompiledLanczos

    _, F, X = _noisy(4)
    L = get_operators(F, len(X)).L
    B = np.hstack([L @ X, np.random.default_rng(9).standard_normal((len(X), 5))])
    run = CompiledLanczos(L, B)
    gs = [lambda t: 1.0 / (1.0 + 0.7 * t), lambda t: np.exp(-0.3 * t)]
    got = run.apply_many(gs)
    coefs = [run._converged_coefficients(g, 1e-10, 10, None, 0.0) for g in gs]  # already converged: the same sizes
    steps = max(c.size for coef in coefs for c in coef)
    Y = np.zeros((steps, 2, B.shape[1]))
    for m, coef in enumerate(coefs):
        for j, c in enumerate(coef):
            tail = np.sqrt(np.cumsum((c * c)[::-1]))[::-1]
            c = c[:max(int(np.count_nonzero(tail > 1e-11 * tail[0])), 1)]
            Y[: c.size, m, j] = c
    inv = 1.0 / np.sqrt(run.norms2)
    q_prev, q, W = np.zeros_like(run._B), np.ascontiguousarray(run._B * inv), np.empty_like(run._B)
    beta_prev, want = np.zeros(B.shape[1]), np.zeros((2,) + B.shape)
    for i in range(steps):
        kernels.lanczos_accumulate(q, np.ascontiguousarray(Y[i]), want)
        run._step(q, q_prev, W, np.ascontiguousarray(run._alpha[i]), beta_prev)
        b = np.ascontiguousarray(run._beta[i])
        kernels.lanczos_scale(W, np.divide(1.0, b, out=np.zeros_like(b), where=b > 0), q_prev)
        q_prev, q, beta_prev = q, q_prev, b
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_array_equal(got[1], want[1])

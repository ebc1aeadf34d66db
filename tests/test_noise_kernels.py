"""The noise estimate's compiled kernels and its shared intermediate results against the code they replace.

Every comparison is bit for bit (``np.array_equal``, ``==``): the kernels promise the numpy/scipy
arithmetic in the same order, and the estimate the same numbers as before.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from meshdenoise import add_normal_noise
from meshdenoise.geometry import numpy_vertex_normals
from meshdenoise.noise import add_scanner_noise
from meshdenoise.operators import Operators, get_operators, spmm
from meshdenoise.shapes import grid, icosphere, torus
from meshdenoise.tuning import noise_kernels as nk
from meshdenoise.tuning import noise_level as nl
from meshdenoise.tuning.search import sure_smoothed


def _meshes():
    V, F = icosphere(4)
    yield "sphere", add_normal_noise((V, F), 0.01, seed=1)[0], F
    V, F = grid(30, 20)  # open borders
    yield "grid", V + 0.002 * np.random.default_rng(2).standard_normal(V.shape), F
    V, F = torus(40, 16)
    V = np.vstack([V, [[9.0, 9.0, 9.0]]])  # an isolated vertex: an identity row of P
    yield "torus+isolated", add_normal_noise((V, F), 0.02, seed=3)[0], F
    V, F = icosphere(2)
    F = np.vstack([F, [[0, 0, 1]], F[:3]])  # a degenerate face and repeated faces
    yield "degenerate", V + 1e-3 * np.random.default_rng(4).standard_normal(V.shape), F
    rng = np.random.default_rng(5)  # a random vertex order (no locality) and coordinates far from the origin
    V, F = torus(30, 12)
    perm = rng.permutation(V.shape[0])
    inv = np.argsort(perm)
    yield "shuffled", V[perm] * 1e3 + 1e5, inv[F]


CASES = list(_meshes())


KERNELS = nk.NoiseKernelConfig(min_vertices=0)  # the compiled paths on these small meshes (from 65,536 vertices otherwise)


def _scipy_fourth_difference(P):
    A = sp.identity(P.shape[0], format="csr") - P
    return sp.csr_matrix(A @ A)


@pytest.mark.parametrize("case", CASES, ids=lambda c: c[0])
def test_fourth_difference_is_scipys_entry_for_entry(case):
    _, V, F = case
    ops = Operators(F, V.shape[0])
    old, new = _scipy_fourth_difference(ops.P), nk.fourth_difference_csr(ops.P, config=KERNELS)
    assert np.array_equal(new.indptr, old.indptr) and np.array_equal(new.indices, old.indices)
    assert np.array_equal(new.data, old.data)  # the same values in the same order in every row
    # what the estimate reads off it: row sums of the squares (pairwise reduceat) and products with coordinates
    assert np.array_equal(np.asarray(nl._squared(new).sum(axis=1)).ravel(), np.asarray(nl._squared(old).sum(axis=1)).ravel())
    assert np.array_equal(spmm(new, V), spmm(old, V))


@pytest.mark.parametrize("threads", [1, 2, 3, 5, 40])
def test_fourth_difference_on_any_number_of_threads_with_cancelled_entries(threads):
    V, F = icosphere(1)  # 42 rows; 40 threads: blocks of one row
    P = Operators(F, V.shape[0]).P.toarray()
    # blocks [[0, 1], [-1, 0]] (not an averaging matrix): (I - P)^2 = [[0, -2], [2, 0]] has its diagonal cancel to
    # zero, which scipy drops: a block then holds fewer entries than its bound and the blocks after it move down
    k = 6
    Q = sp.block_diag([sp.csr_matrix(np.array([[0.0, 1.0], [-1.0, 0.0]]))] * k + [sp.csr_matrix(P)], format="csr")
    Q.sort_indices()
    Q = sp.csr_matrix(sp.block_diag([Q, Q[:2 * k, :2 * k]], format="csr"))
    Q.sort_indices()
    old = _scipy_fourth_difference(Q)
    S = abs(sp.identity(Q.shape[0], format="csr") - Q)  # the structure: positive entries cannot cancel
    assert old.nnz < (S @ S).nnz
    new = nk.fourth_difference_csr(Q, threads=threads, config=KERNELS)
    assert np.array_equal(new.indptr, old.indptr) and np.array_equal(new.indices, old.indices)
    assert np.array_equal(new.data, old.data)


def test_fourth_difference_of_a_non_canonical_matrix_takes_scipys_route():
    V, F = icosphere(0)
    P = Operators(F, V.shape[0]).P
    Q = sp.csr_matrix((P.data[::-1].copy(), P.indices[::-1].copy(), P.indptr), shape=P.shape)  # rows unsorted
    Q.has_sorted_indices = False
    assert not Q.has_canonical_format
    np.testing.assert_allclose(nk.fourth_difference_csr(Q, config=KERNELS).toarray(), _scipy_fourth_difference(Q).toarray(), atol=1e-15)


@pytest.mark.parametrize("case", CASES, ids=lambda c: c[0])
def test_vertex_normals_and_edge_lengths_are_numpys(case):
    _, V, F = case
    assert np.array_equal(nk.vertex_normals(V, F, KERNELS), numpy_vertex_normals(V, F))
    e = Operators(F, V.shape[0]).edges
    assert np.array_equal(nk.edge_lengths(V, e, KERNELS), np.linalg.norm(V[e[:, 0]] - V[e[:, 1]], axis=1))
    with pytest.raises(ValueError, match="face indices"):
        nk.vertex_normals(V, F + V.shape[0], KERNELS)
    with pytest.raises(ValueError, match="edge indices"):
        nk.edge_lengths(V, e - V.shape[0] - 1, KERNELS)


def _old_estimate(V, F, refine=2):
    """estimate_noise_and_smooth as it was: B made by scipy, squared and multiplied anew in every round."""
    ops = get_operators(F, V.shape[0])
    B = _scipy_fourth_difference(ops.P)
    rho_e = nl._residual_energy_scale(V, ops, B)
    rho, smooth, N, h = rho_e, V, None, None
    for _ in range(refine):
        if rho == 0:
            return 0.0, V, None, None
        smooth = sure_smoothed(V, ops, rho).X
        N = numpy_vertex_normals(smooth, F)
        rho_n, rho_w, excess = nl._normal_residual_scale(V, ops, N, B)
        e = ops.edges
        h = float(np.linalg.norm(smooth[e[:, 0]] - smooth[e[:, 1]], axis=1).mean())
        if excess > nl.HEAVY_TAIL_SE and rho_n >= nl.HEAVY_TAIL_MIN_NOISE * h:
            rho_n = rho_w
        w = nl.normal_trust(rho_e, h)
        rho = float(np.exp((1 - w) * np.log(max(rho_n, 1e-300)) + w * np.log(rho_e)))
    return rho, smooth, N, h


def _heavy():
    """Strong noise with outliers: the winsorised level (heavy tails) and the blend with the energy estimate."""
    V, F = icosphere(4)
    return "heavy", add_scanner_noise((V, F), 0.03, outlier_fraction=0.05, seed=6)[0], F


@pytest.mark.parametrize("case", CASES + [_heavy()], ids=lambda c: c[0])
def test_smoothed_estimate_is_the_old_estimate_bit_for_bit(case):
    _, V, F = case
    rho, smooth, N, h = _old_estimate(V, F)
    found = nl.smoothed_estimate(V, F, 2)
    assert found.rho == rho and rho > 0
    assert np.array_equal(found.smooth, smooth) and np.array_equal(found.normals, N) and found.edge_length == h
    assert nl.estimate_noise_and_smooth(V, F, 2)[0] == rho


def test_smoothed_estimate_of_a_mesh_without_residual_is_zero():
    V, F = grid(10, 10)
    V = np.zeros_like(V)  # every vertex at one point: B X = 0 exactly
    found = nl.smoothed_estimate(V, F, 2)
    assert found.rho == 0.0 and found.smooth is V and found.normals is None
    assert _old_estimate(V, F)[0] == 0.0


def test_memo_digest_reads_every_value_and_the_type():
    from meshdenoise.tuning.memo import digest

    rng = np.random.default_rng(7)
    X = rng.standard_normal((1000, 7))
    key = digest(X, 0.25)
    assert digest(X.copy(), 0.25) == key and digest(np.asfortranarray(X), 0.25) == key  # content, not the object
    for i, j in [(0, 0), (500, 3), (999, 6)]:  # one value anywhere
        Y = X.copy()
        Y[i, j] = np.nextafter(Y[i, j], np.inf)
        assert digest(Y, 0.25) != key
    Y = X.copy()
    Y[[3, 700], [1, 2]] *= -1  # two sign bits (a sum of words would not see it)
    assert digest(Y, 0.25) != key
    assert digest(X[::-1], 0.25) != key and digest(X.reshape(7, 1000), 0.25) != key and digest(X, 0.5) != key
    assert digest(X.view(np.int64), 0.25) != key  # same bytes, another type
    A = sp.random(50, 50, density=0.1, format="csr", random_state=0)
    assert digest(A) == digest(A.tocoo()) != digest(A * 2.0)


def test_the_noise_model_hands_its_operators_to_the_estimate(monkeypatch):
    """estimate_noise_model passes its operators down: the faces are hashed once (get_operators), not per step."""
    from meshdenoise.tuning import covariance

    V, F = icosphere(3)
    Vn = add_normal_noise((V, F), 0.01, seed=0)[0]
    want = covariance.estimate_noise_model((Vn, F))
    calls = []
    real = covariance.smoothed_estimate
    monkeypatch.setattr(covariance, "smoothed_estimate", lambda *a, **k: calls.append(a) or real(*a, **k))
    got = covariance.estimate_noise_model((Vn, F))
    assert len(calls) == 1 and isinstance(calls[0][3], Operators) and calls[0][3] is get_operators(F, V.shape[0])
    assert got.rho == want.rho and got.correlation_length == want.correlation_length


def test_small_meshes_take_the_numpy_code_and_large_ones_the_kernels(monkeypatch):
    """Below NoiseKernelConfig.min_vertices the numpy/scipy code itself runs (no compiled code loaded for a small mesh)."""
    V, F = icosphere(3)
    e = Operators(F, V.shape[0]).edges
    P = Operators(F, V.shape[0]).P
    called = []

    class Ran(Exception):
        pass

    def stub(name):
        def run(*args):
            called.append(name)
            raise Ran(name)  # stop there: the code after a kernel expects its output
        return run

    for name in ("_unit_face_normals", "_edge_lengths", "_i_minus_counts"):
        monkeypatch.setattr(nk, name, stub(name))
    above = nk.NoiseKernelConfig(min_vertices=V.shape[0] + 1)
    for config in (above, None):  # None: the default's 65,536 vertices
        assert np.array_equal(nk.vertex_normals(V, F, config), numpy_vertex_normals(V, F))
        assert np.array_equal(nk.edge_lengths(V, e, config), np.linalg.norm(V[e[:, 0]] - V[e[:, 1]], axis=1))
        assert np.array_equal(nk.fourth_difference_csr(P, config=config).toarray(), _scipy_fourth_difference(P).toarray())
    assert called == []
    at = nk.NoiseKernelConfig(min_vertices=V.shape[0])
    for f in (lambda: nk.vertex_normals(V, F, at), lambda: nk.edge_lengths(V, e, at),
              lambda: nk.fourth_difference_csr(P, config=at)):
        with pytest.raises(Ran):
            f()
    assert called == ["_unit_face_normals", "_edge_lengths", "_i_minus_counts"]


def test_the_estimates_averaging_rounds_are_sure_smoothed_and_share_its_memoised_curve():
    from meshdenoise.tuning.memo import MEMO

    V, F = icosphere(4)
    Vn = add_normal_noise((V, F), 0.02, seed=11)[0]
    ops = get_operators(F, V.shape[0])
    MEMO.clear()
    smoother = nl._AveragingSmoother(Vn, ops)
    steps = []
    for rho in (0.01, 0.02, 0.02, 0.03):  # best step counts 0, 2, 2, 1: up, equal, then down (recomputed from V)
        X = smoother(rho)
        steps.append(smoother.k)
        keys = set(MEMO)
        want = sure_smoothed(Vn, ops, rho)
        assert set(MEMO) == keys  # sure_smoothed found the estimate's curve: one run for both
        assert want.value == smoother.k and np.array_equal(X, want.X)
    assert steps[0] < steps[1] == steps[2] > steps[3] > 0, steps


def test_geometry_vertex_normals_take_the_compiled_kernel_from_its_threshold(monkeypatch):
    """``geometry.vertex_normals`` asks the compiled kernel first (``LARGE_VERTEX_NORMALS``), which answers from
    ``NoiseKernelConfig.min_vertices`` on: the same numbers as numpy's."""
    from meshdenoise import geometry

    V, F = icosphere(3)
    V = V + 0.01 * np.random.default_rng(0).standard_normal(V.shape)
    assert nk._large_vertex_normals in geometry.LARGE_VERTEX_NORMALS
    assert np.array_equal(geometry.vertex_normals(V, F), numpy_vertex_normals(V, F))
    calls = []
    kernel = nk._unit_face_normals
    monkeypatch.setattr(nk, "_unit_face_normals", lambda *a: (calls.append(1), kernel(*a))[1])
    assert nk._large_vertex_normals(V, F, nk.NoiseKernelConfig(min_vertices=V.shape[0] + 1)) is None and calls == []
    assert nk._large_vertex_normals(V, F) is None and calls == []  # the default: from 65,536 vertices
    at = nk._large_vertex_normals(V, F, nk.NoiseKernelConfig(min_vertices=V.shape[0]))
    assert np.array_equal(at, numpy_vertex_normals(V, F)) and calls == [1]

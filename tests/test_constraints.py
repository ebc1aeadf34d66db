"""pinned=, region= and preserve_volume=, shared by every filter."""

import numpy as np
import pytest

import meshdenoise as md
from meshdenoise.geometry import signed_volume
from meshdenoise.operators import get_operators
from meshdenoise.shapes import grid, icosphere, torus

from .conftest import make_mesh, noisy_sphere


@pytest.mark.parametrize("spec", [s.name for s in md.list_filters()])
def test_pinned_vertices_are_bit_identical(spec):
    V, Vn, F = noisy_sphere(subdivisions=2)
    pinned = np.zeros(len(V), bool)
    pinned[::7] = True
    out = md.apply_filter(spec, (Vn, F), pinned=pinned)[0]
    np.testing.assert_array_equal(out[pinned], Vn[pinned])
    assert not np.allclose(out[~pinned], Vn[~pinned])
    out2 = md.apply_filter(spec, (Vn, F), pinned=np.flatnonzero(pinned))[0]
    np.testing.assert_array_equal(out, out2)


def test_constrained_sobolev_matches_dense_constrained_solve():
    V, Vn, F = noisy_sphere(subdivisions=2)
    n = len(V)
    L = get_operators(F, n).L.toarray()
    pinned = np.zeros(n, bool)
    pinned[[0, 3, 17, 40]] = True
    mu = 3.0
    A = np.eye(n) + mu * L
    f, p = ~pinned, pinned
    expected = Vn.copy()
    expected[f] = np.linalg.solve(A[np.ix_(f, f)], Vn[f] - A[np.ix_(f, p)] @ Vn[p])
    np.testing.assert_allclose(md.sobolev((Vn, F), mu=mu, pinned=pinned)[0], expected, atol=1e-11)


def test_constrained_iterations_are_dirichlet_not_reset():
    V, Vn, F = noisy_sphere(subdivisions=2)
    P = get_operators(F, len(V)).P.toarray()
    pinned = np.zeros(len(V), bool)
    pinned[:10] = True
    X = Vn.copy()
    for _ in range(4):
        X = np.where(pinned[:, None], Vn, P @ X)
    np.testing.assert_allclose(md.filtering((Vn, F), iterations=4, pinned=pinned)[0], X, atol=1e-13)


def test_pinned_boundary_on_open_mesh():
    V, F = grid(10, 10)
    Vn = V + 0.05 * np.random.default_rng(0).standard_normal(V.shape)
    border = get_operators(F, len(V)).boundary_vertices
    for spec in md.list_filters():
        out = spec.public((Vn, F), pinned="boundary")[0]
        np.testing.assert_array_equal(out[border], Vn[border])


def test_region_only_moves_inside():
    V, Vn, F = noisy_sphere(subdivisions=2)
    region = V[:, 2] > 0.3
    for spec in md.list_filters():
        out = spec.public((Vn, F), region=region)[0]
        np.testing.assert_array_equal(out[~region], Vn[~region])
        assert not np.allclose(out[region], Vn[region])


def test_region_selection_reads_meshset_selection():
    V, Vn, F = noisy_sphere(subdivisions=2)
    ms = make_mesh("meshset", Vn, F)
    ms.compute_selection_by_condition_per_vertex(condselect="z > 0.3")
    sel = ms.current_mesh().vertex_selection_array().astype(bool)
    md.sobolev(ms, mu=2.0, region="selection")
    np.testing.assert_array_equal(ms.current_mesh().vertex_matrix(), md.sobolev((Vn, F), mu=2.0, region=sel)[0])
    with pytest.raises(ValueError, match="selection is read from a pymeshlab"):
        md.sobolev((Vn, F), region="selection")


@pytest.mark.parametrize("mesh", [icosphere(3), torus(30, 12)], ids=["sphere", "torus"])
@pytest.mark.parametrize("name,params", [("sobolev", {"mu": 50.0}), ("filtering", {"iterations": 100})])
def test_preserve_volume_on_closed_mesh(mesh, name, params):
    V, F = mesh
    Vn, _ = md.add_normal_noise((V, F), rho=0.02, seed=0)
    vol0 = signed_volume(Vn, F)
    shrunk = md.apply_filter(name, (Vn, F), **params)[0]
    assert signed_volume(shrunk, F) < 0.95 * vol0  # the filter really shrinks
    kept = md.apply_filter(name, (Vn, F), preserve_volume=True, **params)[0]
    assert signed_volume(kept, F) == pytest.approx(vol0, rel=1e-9)


def test_preserve_volume_with_pinned_vertices():
    V, F = icosphere(3)
    Vn, _ = md.add_normal_noise((V, F), rho=0.02, seed=0)
    pinned = V[:, 0] > 0.8
    out = md.sobolev((Vn, F), mu=30.0, pinned=pinned, preserve_volume=True)[0]
    np.testing.assert_array_equal(out[pinned], Vn[pinned])
    assert signed_volume(out, F) == pytest.approx(signed_volume(Vn, F), rel=1e-9)


def test_bad_constraint_specs():
    V, F = icosphere(1)
    with pytest.raises(ValueError, match="one entry per vertex"):
        md.filtering((V, F), pinned=np.ones(3, bool))
    with pytest.raises(ValueError, match="out of range"):
        md.filtering((V, F), pinned=[0, 1000])
    with pytest.raises(ValueError, match="not understood"):
        md.filtering((V, F), pinned="edges")
    with pytest.raises(ValueError, match="use pinned='boundary'"):
        md.filtering((V, F), region="boundary")
    with pytest.raises(TypeError, match="preserve_volume"):
        md.filtering((V, F), preserve_volume="yes")


def test_sobolev_factor_cache_keys_on_the_mask():
    from meshdenoise.solvers import shifted_solver

    def sobolev_solver(ops, mu, fixed):
        return shifted_solver(ops, mu, 1, fixed)

    V, Vn, F = noisy_sphere(subdivisions=2)
    ops = get_operators(F, len(V))
    a = np.zeros(len(V), bool)
    a[:5] = True
    b = np.zeros(len(V), bool)
    b[5:10] = True
    sa = sobolev_solver(ops, 0.777, a)
    assert sobolev_solver(ops, 0.777, a.copy()) is sa  # same mask content: same factor
    sb = sobolev_solver(ops, 0.777, b)
    assert sb is not sa and sobolev_solver(ops, 0.777, None) not in (sa, sb)
    np.testing.assert_array_equal(md.sobolev((Vn, F), mu=0.777, pinned=b)[0][b], Vn[b])

"""``filtering(weights="meshlab_cotangent")`` against pymeshlab's default Laplacian smoothing (cotangent weights).

Every expected value is pymeshlab's own ``apply_coord_laplacian_smoothing(cotangentweight=True)``;
errors are the largest vertex distance divided by the bounding-box diagonal.
"""

import numpy as np
import pymeshlab
import pytest

import meshdenoise as md
from meshdenoise.data import sample_mesh
from meshdenoise.locality import relabelling
from meshdenoise.shapes import grid, icosphere, torus

TOL = 1e-9  # of the bounding-box diagonal


def load_sample(name):
    ms = pymeshlab.MeshSet()
    ms.load_new_mesh(str(sample_mesh(name)))
    m = ms.current_mesh()
    return m.vertex_matrix(), m.face_matrix()


@pytest.fixture(scope="module", params=["grid", "torus", "icosphere", "bunny", "face000"])
def mesh(request):
    """Open: a noisy grid and the range scan face000 (with unreferenced vertices); closed: the others."""
    name = request.param
    if name == "grid":
        V, F = grid(15, 11)
        return V + 0.02 * np.random.default_rng(0).standard_normal(V.shape), F
    if name == "torus":
        return md.add_normal_noise(torus(24, 12), rho=0.03, seed=1)
    if name == "icosphere":
        return md.add_normal_noise(icosphere(3), rho=0.05, seed=2)
    return load_sample("bunny.obj" if name == "bunny" else "rangemaps/face000.ply")


def meshlab_cotangent(V, F, steps, boundary=True, selection=None, **extra):
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=V, face_matrix=F.astype(np.int32)))
    if selection is not None:
        ms.compute_selection_by_condition_per_vertex(condselect=selection)
    ms.apply_coord_laplacian_smoothing(stepsmoothnum=steps, boundary=boundary, selected=selection is not None, **extra)
    return ms.current_mesh().vertex_matrix()


def err(a, b, V):
    return np.abs(a - b).max() / np.linalg.norm(V.max(axis=0) - V.min(axis=0))


def ours(V, F, steps, boundary=True, **kw):
    return md.filtering((V, F), iterations=steps, weights="meshlab_cotangent", boundary=boundary, **kw)[0]


def test_pymeshlab_default_is_cotangent_and_is_ours():
    V, F = md.add_normal_noise(torus(24, 12), rho=0.03, seed=1)
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=V, face_matrix=F.astype(np.int32)))
    assert ms.filter_parameter_values("apply_coord_laplacian_smoothing")["cotangentweight"] is True
    ms.apply_coord_laplacian_smoothing(stepsmoothnum=3)  # every option at pymeshlab's default
    assert err(ours(V, F, 3), ms.current_mesh().vertex_matrix(), V) < TOL


@pytest.mark.parametrize("steps", [1, 3, 10])
@pytest.mark.parametrize("boundary", [True, False])
def test_matches_pymeshlab(mesh, boundary, steps):
    V, F = mesh
    theirs = meshlab_cotangent(V, F, steps, boundary, cotangentweight=True)
    assert err(ours(V, F, steps, boundary), theirs, V) < TOL
    # the weights matter: MeshLab's own uniform form and the paper's operator land far away
    assert err(md.filtering((V, F), iterations=steps, weights="meshlab", boundary=boundary)[0], theirs, V) > 1e-4
    assert err(md.filtering((V, F), iterations=steps)[0], theirs, V) > 1e-4


@pytest.mark.parametrize("boundary", [True, False])
def test_selected_is_region_selection(mesh, boundary):
    V, F = mesh
    condition = f"x < {float(np.median(V[:, 0]))!r}"
    expected = meshlab_cotangent(V, F, 4, boundary, selection=condition, cotangentweight=True)
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=V, face_matrix=F.astype(np.int32)))
    ms.compute_selection_by_condition_per_vertex(condselect=condition)
    selected = ms.current_mesh().vertex_selection_array()
    assert 0 < selected.sum() < len(V)
    assert md.filtering(ms, iterations=4, weights="meshlab_cotangent", boundary=boundary, region="selection") is ms
    assert err(ms.current_mesh().vertex_matrix(), expected, V) < TOL
    # the same with arrays and a mask
    assert err(ours(V, F, 4, boundary, region=selected), expected, V) < TOL
    np.testing.assert_array_equal(expected[~selected], V[~selected])  # pymeshlab moved only the selection ...
    assert err(expected[selected], V[selected], V) > 1e-4  # ... and did move it


def test_one_relaxed_step_is_a_fraction_of_meshlabs_step():
    V, F = md.add_normal_noise(torus(24, 12), rho=0.03, seed=1)
    full = meshlab_cotangent(V, F, 1, cotangentweight=True)
    assert err(ours(V, F, 1, lam=0.3), V + 0.3 * (full - V), V) < TOL


def degenerate_grid(kind):
    """A noisy 6 x 6 grid with a corner face whose two other vertices coincide, a flat face, or faces
    with a repeated index."""
    V, F = grid(6, 6)
    V = V + 0.01 * np.random.default_rng(0).standard_normal(V.shape)
    if kind == "coincident":  # corner 5 has one face, (4, 5, 11): vcglib's Angle returns -1 at 4 and 11
        assert sorted(F[(F == 5).any(axis=1)].ravel()) == [4, 5, 11]
        V[11] = V[4]
    elif kind == "flat":  # a vertex on the segment of the other two: angles 0, 0 and pi, cotangents about 1e16
        f = F[10]
        V[f[0]] = 0.5 * (V[f[1]] + V[f[2]])
    else:  # vcglib counts the sides i-i too (a border side when single)
        F = np.vstack([F, [[7, 7, 14], [20, 20, 20]]])
    return V, F


@pytest.mark.parametrize("steps", [1, 4, 10])
@pytest.mark.parametrize("boundary", [True, False])
@pytest.mark.parametrize("kind", ["coincident", "flat", "repeated index"])
def test_degenerate_faces_match_pymeshlab(kind, boundary, steps):
    """Unclamped huge or negative weights: only vcglib's float32 roundings and order of sums give its result."""
    V, F = degenerate_grid(kind)
    theirs = meshlab_cotangent(V, F, steps, boundary, cotangentweight=True)
    assert np.isfinite(theirs).all()
    assert err(ours(V, F, steps, boundary), theirs, V) < TOL


def test_a_vertex_whose_weights_sum_to_zero_or_less_stays():
    """The corner's only face has two coincident vertices: weights tan(pi/2 + 1) = -0.64 each, sum < 0."""
    V, F = degenerate_grid("coincident")
    theirs = meshlab_cotangent(V, F, 1, False, cotangentweight=True)
    np.testing.assert_array_equal(theirs[5], V[5])  # pymeshlab leaves it ...
    assert err(theirs, V, V) > 1e-3  # ... while the rest moves
    np.testing.assert_array_equal(ours(V, F, 1, False)[5], V[5])


@pytest.mark.parametrize("boundary", [True, False])
def test_relabelled_large_mesh_matches_to_rounding(boundary):
    """face000 with its vertices shuffled: the registry relabels it, so the sums run in another face order.

    MeshLab's own result depends on that order: the same mesh with its faces shuffled differs after
    10 steps by 1.9e-10 (boundary) and 2.2e-8 (no boundary) of the diagonal. After 1 and 3 steps ours
    was 1.3e-15 and 4.9e-11 of the diagonal from pymeshlab's.
    """
    V, F = load_sample("rangemaps/face000.ply")
    perm = np.random.default_rng(0).permutation(len(V))
    inverse = np.empty_like(perm)
    inverse[perm] = np.arange(len(V))
    V, F = V[perm], inverse[F].astype(np.int32)
    assert relabelling(F, len(V)) is not None
    for steps in (1, 3):
        theirs = meshlab_cotangent(V, F, steps, boundary, cotangentweight=True)
        assert err(ours(V, F, steps, boundary), theirs, V) < TOL


def test_meshlab_taubin_has_no_cotangent_form():
    """vcglib's VertexCoordTaubin calls AccumulateLaplacianInfo without the cotangent flag, and pymeshlab's
    filter has no such parameter: taubin(weights="meshlab") (uniform) is all there is to reproduce."""
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=grid(4, 4)[0], face_matrix=grid(4, 4)[1].astype(np.int32)))
    params = ms.filter_parameter_values("apply_coord_taubin_smoothing")
    assert set(params) == {"lambda_", "mu", "stepsmoothnum", "selected"}


def test_bad_settings_are_refused_with_the_value():
    V, F = grid(5, 5)
    with pytest.raises(ValueError, match=r"'backend' = 'scipy' is not available with weights='meshlab_cotangent'"):
        md.filtering((V, F), weights="meshlab_cotangent", backend="scipy")
    with pytest.raises(ValueError, match=r"weights='meshlab_cotangent' is not a linear smoother"):
        md.choose_parameters((V, F), "filtering", weights="meshlab_cotangent")
    with pytest.raises(ValueError, match=r"'boundary' = False applies only to weights='meshlab' or 'meshlab_cotangent', "
                                         r"not weights='uniform'"):
        md.filtering((V, F), boundary=False)

"""Our settings that compute exactly what MeshLab's and Open3D's smoothing filters compute (to 1e-10)."""

import numpy as np
import open3d as o3d
import pymeshlab
import pytest

import meshdenoise as md
from meshdenoise.shapes import grid, torus

MESHES = ["elephant", "nefertiti", "elephant_with_holes", "grid", "torus"]


@pytest.fixture(params=MESHES)
def mesh(request):
    if request.param == "grid":
        V, F = grid(15, 11)
        V = V + 0.02 * np.random.default_rng(0).standard_normal(V.shape)
        return V, F
    if request.param == "torus":
        V, F = torus(24, 12)
        return md.add_normal_noise((V, F), rho=0.03, seed=1)
    return request.getfixturevalue(request.param)


def rel_err(a, b):
    return np.linalg.norm(a - b) / np.linalg.norm(b)


def meshlab_laplacian(V, F, steps, boundary, selected=False, selection=None):
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=V, face_matrix=F.astype(np.int32)))
    if selection is not None:
        ms.compute_selection_by_condition_per_vertex(condselect=selection)
    ms.apply_coord_laplacian_smoothing(stepsmoothnum=steps, boundary=boundary, cotangentweight=False, selected=selected)
    return ms.current_mesh().vertex_matrix()


@pytest.mark.parametrize("boundary", [True, False])
def test_meshlab_laplacian_matches(mesh, boundary):
    V, F = mesh
    theirs = meshlab_laplacian(V, F, 12, boundary)
    ours = md.filtering((V, F), iterations=12, weights="meshlab", boundary=boundary)[0]
    assert rel_err(ours, theirs) < 1e-10
    # and the difference from the paper's D^-1 W is real, not a rounding matter
    assert rel_err(md.filtering((V, F), iterations=12)[0], theirs) > 1e-6


def test_meshlab_36_steps_on_elephant_differ_from_paper_operator(elephant):
    V, F = elephant
    theirs = meshlab_laplacian(V, F, 36, True)
    assert rel_err(md.filtering((V, F), iterations=36, weights="meshlab")[0], theirs) < 1e-10
    assert rel_err(md.filtering((V, F), iterations=36)[0], theirs) > 1e-4


def test_meshlab_selected_is_region_selection():
    V, F = grid(12, 12)
    V = V + 0.02 * np.random.default_rng(1).standard_normal(V.shape)
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=V, face_matrix=F.astype(np.int32)))
    ms.compute_selection_by_condition_per_vertex(condselect="x < 0.5")
    assert 0 < ms.current_mesh().selected_vertex_number() < len(V)
    ours = md.filtering(ms, iterations=5, weights="meshlab", region="selection")  # in place on the MeshSet
    assert ours is ms
    expected = meshlab_laplacian(V, F, 5, True, selected=True, selection="x < 0.5")
    assert rel_err(ms.current_mesh().vertex_matrix(), expected) < 1e-10


def o3d_mesh(V, F):
    return o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(V), o3d.utility.Vector3iVector(F.astype(np.int32)))


def test_open3d_simple_matches(mesh):
    V, F = mesh
    theirs = np.asarray(o3d_mesh(V, F).filter_smooth_simple(number_of_iterations=7).vertices)
    ours = md.filtering((V, F), iterations=7, weights="open3d")[0]
    assert rel_err(ours, theirs) < 1e-10


@pytest.mark.parametrize("lam", [0.5, 0.9])
def test_open3d_laplacian_matches(mesh, lam):
    V, F = mesh
    theirs = np.asarray(o3d_mesh(V, F).filter_smooth_laplacian(number_of_iterations=6, lambda_filter=lam).vertices)
    ours = md.filtering((V, F), iterations=6, weights="inverse_distance", lam=lam)[0]
    assert rel_err(ours, theirs) < 1e-10


@pytest.mark.parametrize("lam, mu, steps", [(0.5, -0.53, 10), (0.33, -0.34, 3)])
def test_meshlab_taubin_matches(mesh, lam, mu, steps):
    V, F = mesh
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=V, face_matrix=F.astype(np.int32)))
    ms.apply_coord_taubin_smoothing(lambda_=lam, mu=mu, stepsmoothnum=steps)
    theirs = ms.current_mesh().vertex_matrix()
    assert rel_err(md.taubin((V, F), iterations=steps, lam=lam, mu=mu, weights="meshlab")[0], theirs) < 1e-10
    assert rel_err(V, theirs) > 1e-4  # MeshLab really moved the mesh


@pytest.mark.parametrize("lam, mu, steps", [(0.5, -0.53, 10), (0.33, -0.34, 3)])
def test_open3d_taubin_matches(mesh, lam, mu, steps):
    V, F = mesh
    theirs = np.asarray(o3d_mesh(V, F).filter_smooth_taubin(steps, lambda_filter=lam, mu=mu).vertices)
    ours = md.taubin((V, F), iterations=steps, lam=lam, mu=mu, weights="open3d")[0]
    assert rel_err(ours, theirs) < 1e-10
    assert rel_err(V, theirs) > 1e-4


def grid_with_repeated_indices():
    V, F = grid(6, 6)
    V = V + 0.01 * np.random.default_rng(0).standard_normal(V.shape)
    return V, np.vstack([F, [[7, 7, 14], [20, 20, 20]]])


@pytest.mark.parametrize("boundary", [True, False])
def test_meshlab_laplacian_faces_with_a_repeated_index(boundary):
    """vcglib counts a face's side i-i like any other (a border side when single); Operators skip it."""
    V, F = grid_with_repeated_indices()
    theirs = meshlab_laplacian(V, F, 3, boundary)
    assert rel_err(md.filtering((V, F), iterations=3, weights="meshlab", boundary=boundary)[0], theirs) < 1e-10


def test_meshlab_taubin_faces_with_a_repeated_index():
    V, F = grid_with_repeated_indices()
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=V, face_matrix=F.astype(np.int32)))
    ms.apply_coord_taubin_smoothing(lambda_=0.5, mu=-0.53, stepsmoothnum=3)
    theirs = ms.current_mesh().vertex_matrix()
    assert rel_err(md.taubin((V, F), iterations=3, lam=0.5, mu=-0.53, weights="meshlab")[0], theirs) < 1e-10

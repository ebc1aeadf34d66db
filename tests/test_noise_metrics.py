"""The paper's noise model and SNR, against loops and closed forms."""

import numpy as np
import pytest

import meshdenoise as md
from meshdenoise.geometry import area_normals, face_normals, vertex_normals
from meshdenoise.shapes import icosphere

from .conftest import make_mesh, vertices_of


def normals_by_loop(V, F):
    N = np.zeros_like(V)
    for f in F:
        n = np.cross(V[f[1]] - V[f[0]], V[f[2]] - V[f[0]])
        n /= np.linalg.norm(n)
        for i in f:
            N[i] += n
    return N / np.linalg.norm(N, axis=1, keepdims=True)


def test_vertex_normals_match_loop_and_point_outwards_on_sphere():
    V, F = icosphere(2)
    N = vertex_normals(V, F)
    np.testing.assert_allclose(N, normals_by_loop(V, F), atol=1e-14)
    assert (np.einsum("ij,ij->i", N, V) > 0.99).all()


def test_area_normals_match_a_loop_over_faces_and_ignore_collapsed_faces():
    """Area weighting against a per-face loop on an irregular mesh, Open3D's area-weighted normals,
    and a collapsed face (cross product 1e-20) that gets no vote where its unit normal would get a full one."""
    import open3d as o3d

    V, F = icosphere(2)
    V = V * np.array([1.0, 0.6, 1.7]) + 0.02 * np.random.default_rng(3).standard_normal(V.shape)
    S = np.zeros_like(V)
    for f in F:
        c = np.cross(V[f[1]] - V[f[0]], V[f[2]] - V[f[0]])  # twice the area times the unit normal
        S[f] += c
    expected = S / np.linalg.norm(S, axis=1, keepdims=True)
    np.testing.assert_allclose(area_normals(V, F), expected, atol=1e-14)
    assert np.abs(area_normals(V, F) - vertex_normals(V, F)).max() > 1e-3  # the weighting matters here
    m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(V), o3d.utility.Vector3iVector(F))
    m.compute_vertex_normals(normalized=True)  # Open3D sums the unnormalised face normals
    np.testing.assert_allclose(area_normals(V, F), np.asarray(m.vertex_normals), atol=1e-12)
    Vd = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [1, 0.5, 1e-12]])
    Fd = np.array([[0, 1, 2], [1, 3, 2], [1, 3, 4]])  # the last face is a sliver standing on its edge (normal +-x)
    np.testing.assert_allclose(area_normals(Vd, Fd)[1], [0.0, 0.0, 1.0], atol=1e-11)
    assert abs(vertex_normals(Vd, Fd)[1, 2] - 1.0) > 1e-3  # the unit-normal average is tilted by it


def test_noise_is_along_normals_with_std_rho_and_reproducible():
    V, F = icosphere(4)
    rho = 0.05
    Vn, _ = md.add_normal_noise((V, F), rho=rho, seed=42)
    D = Vn - V
    N = vertex_normals(V, F)
    eps = np.einsum("ij,ij->i", D, N)
    np.testing.assert_allclose(D, eps[:, None] * N, atol=1e-15)  # purely along the normal
    assert np.std(eps) == pytest.approx(rho, rel=0.05)
    np.testing.assert_array_equal(md.add_normal_noise((V, F), rho=rho, seed=42)[0], Vn)
    assert not np.array_equal(md.add_normal_noise((V, F), rho=rho, seed=43)[0], Vn)
    expected = V + rho * np.random.default_rng(42).standard_normal(len(V))[:, None] * N
    np.testing.assert_allclose(Vn, expected, atol=1e-15)


def test_noise_on_every_mesh_type(mesh_kind):
    V, F = icosphere(2)
    out = md.add_normal_noise(make_mesh(mesh_kind, V, F), rho=0.01, seed=0)
    np.testing.assert_allclose(vertices_of(out), md.add_normal_noise((V, F), rho=0.01, seed=0)[0], atol=1e-15)


def test_noise_rejects_bad_rho():
    V, F = icosphere(1)
    with pytest.raises(ValueError, match="'rho' = -1"):
        md.add_normal_noise((V, F), rho=-1)
    with pytest.raises(TypeError):
        md.add_normal_noise((V, F), rho="big")


def test_snr_closed_form_and_paper_convention():
    rng = np.random.default_rng(0)
    Y = rng.standard_normal((50, 3))
    E = rng.standard_normal((50, 3))
    X = Y + E
    expected = -20 * np.log10(np.sqrt((E**2).sum()) / np.sqrt((Y**2).sum()))
    assert md.snr(Y, X) == pytest.approx(expected, rel=1e-13)
    assert md.snr(X, Y) != pytest.approx(expected)  # the reference is the denominator
    assert md.snr(Y, Y) == np.inf


def test_snr_accepts_mesh_types(mesh_kind):
    V, F = icosphere(2)
    Vn, _ = md.add_normal_noise((V, F), rho=0.02, seed=0)
    assert md.snr(make_mesh(mesh_kind, V, F), make_mesh(mesh_kind, Vn, F)) == pytest.approx(md.snr(V, Vn), rel=1e-12)


def test_snr_errors():
    with pytest.raises(ValueError, match="vertices"):
        md.snr(np.ones((4, 3)), np.ones((5, 3)))
    with pytest.raises(ValueError, match="norm is 0"):
        md.snr(np.zeros((4, 3)), np.ones((4, 3)))


def test_face_normals_zero_for_degenerate_face():
    V = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0]])
    np.testing.assert_array_equal(face_normals(V, np.array([[0, 1, 2]])), [[0, 0, 0]])

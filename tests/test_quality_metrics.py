"""The quality metrics against loops written here, closed forms and MeshLab's Hausdorff filter."""

import numpy as np
import pytest

import meshdenoise as md
from meshdenoise.metrics import METRICS, compute_metrics
from meshdenoise.metrics import max_distance, mean_distance, normal_error_deg, volume_change
from meshdenoise.shapes import icosphere

from .conftest import make_mesh, noisy_sphere


def point_segment(p, a, b):
    t = np.clip(np.dot(p - a, b - a) / np.dot(b - a, b - a), 0.0, 1.0)
    return np.linalg.norm(p - (a + t * (b - a)))


def point_triangle(p, a, b, c):
    """Brute force: the plane distance if the projection falls inside, else the nearest edge."""
    n = np.cross(b - a, c - a)
    n = n / np.linalg.norm(n)
    q = p - np.dot(p - a, n) * n
    inside = all(np.dot(np.cross(v1 - v0, q - v0), n) >= 0 for v0, v1 in ((a, b), (b, c), (c, a)))
    if inside:
        return abs(np.dot(p - a, n))
    return min(point_segment(p, a, b), point_segment(p, b, c), point_segment(p, c, a))


def brute_distances(P, V, F):
    return np.array([min(point_triangle(p, *V[f]) for f in F) for p in P])


def test_metrics_are_registered():
    for name in ("snr", "normal_error_deg", "mean_distance", "max_distance", "volume_change"):
        assert name in METRICS
    V, Vn, F = noisy_sphere(subdivisions=1)
    out = compute_metrics((V, F), (Vn, F))
    assert set(out) >= {"normal_error_deg", "mean_distance", "max_distance", "volume_change"}


def test_normal_error_matches_a_loop():
    V, Vn, F = noisy_sphere(rho=0.05, subdivisions=2)
    angles = []
    for f in F:
        n0 = np.cross(V[f[1]] - V[f[0]], V[f[2]] - V[f[0]])
        n1 = np.cross(Vn[f[1]] - Vn[f[0]], Vn[f[2]] - Vn[f[0]])
        c = np.dot(n0, n1) / np.linalg.norm(n0) / np.linalg.norm(n1)
        angles.append(np.degrees(np.arccos(min(1.0, max(-1.0, c)))))
    assert normal_error_deg((V, F), (Vn, F)) == pytest.approx(np.mean(angles), rel=1e-9)
    assert normal_error_deg((V, F), Vn) == pytest.approx(np.mean(angles), rel=1e-9)
    assert normal_error_deg((V, F), (V, F)) == 0.0


@pytest.mark.parametrize("kind", ["arrays", "meshset", "open3d"])
def test_distances_match_brute_force_point_to_triangle(kind):
    V, F = icosphere(1)
    rng = np.random.default_rng(3)
    P = V * (1 + 0.1 * rng.standard_normal((len(V), 1))) + 0.05 * rng.standard_normal(V.shape)
    d = brute_distances(P, V, F)
    assert d.max() > 0.05  # not trivially small
    ref = make_mesh(kind, V, F)
    assert mean_distance(ref, P) == pytest.approx(d.mean(), rel=1e-5)
    assert max_distance(ref, P) == pytest.approx(d.max(), rel=1e-5)


def test_distances_agree_with_meshlab_hausdorff():
    import pymeshlab

    V, Vn, F = noisy_sphere(rho=0.03, subdivisions=2)
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=V, face_matrix=F.astype(np.int32)), "clean")
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=Vn, face_matrix=F.astype(np.int32)), "noisy")
    h = ms.get_hausdorff_distance(
        sampledmesh=1, targetmesh=0, samplevert=True, sampleedge=False, sampleface=False, samplenum=len(V)
    )
    assert mean_distance((V, F), Vn) == pytest.approx(h["mean"], rel=1e-5)
    assert max_distance((V, F), Vn) == pytest.approx(h["max"], rel=1e-5)


def test_volume_change_closed_form_and_convex_hull():
    from scipy.spatial import ConvexHull

    V, F = icosphere(2)
    assert volume_change((V, F), 0.9 * V) == pytest.approx(0.9**3 - 1, rel=1e-12)
    assert volume_change((V, F), V + 5.0) == pytest.approx(0.0, abs=1e-12)  # translation does not change it
    # against scipy's hull volume of a convex polyhedron
    W = V * np.array([1.0, 1.3, 0.8])
    expected = ConvexHull(W).volume / ConvexHull(V).volume - 1
    assert volume_change((V, F), W) == pytest.approx(expected, rel=1e-10)
    # plain filtering shrinks: negative
    V, Vn, F = noisy_sphere(subdivisions=2)
    assert volume_change((V, F), md.filtering((Vn, F), iterations=20)) < -0.05


def test_bad_metric_input_is_refused_with_names():
    V, F = icosphere(1)
    with pytest.raises(ValueError, match="normal_error_deg: the candidate has 3 vertices"):
        normal_error_deg((V, F), V[:3])
    with pytest.raises(TypeError, match="mean_distance: the reference must be a mesh"):
        mean_distance(V, V)
    with pytest.raises(ValueError, match="faces differ"):
        volume_change((V, F), (V, F[::-1]))

"""Properties every registered filter must have, checked with hypothesis on generated meshes.

Filters come from ``meshdenoise.list_filters()``, so a filter registered later is covered
without editing this file. Meshes are random closed and open surfaces of varied sizes and
vertex degrees: perturbed icospheres, grids and tori, random subsets of a sphere's faces
(isolated vertices included), Delaunay triangulations of random points in a plane (open)
and convex hulls of random points on a sphere (closed).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.spatial import ConvexHull, Delaunay
from scipy.spatial.transform import Rotation

import meshdenoise as md
from meshdenoise.noise import add_normal_noise
from meshdenoise.shapes import grid, icosphere, torus

from .conftest import make_mesh

FILTERS = md.list_filters()
NAMES = [s.name for s in FILTERS]
SETTINGS = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])


# ------------------------------------------------------------------------------ meshes
def _hull(n: int, rng) -> tuple[np.ndarray, np.ndarray]:
    P = rng.normal(size=(n, 3))
    P /= np.linalg.norm(P, axis=1, keepdims=True)
    F = ConvexHull(P).simplices.astype(np.int64)
    normals = np.cross(P[F[:, 1]] - P[F[:, 0]], P[F[:, 2]] - P[F[:, 0]])
    flip = (normals * P[F].mean(axis=1)).sum(axis=1) < 0  # orient every face outwards
    F[flip] = F[flip][:, ::-1]
    return P, F


def _delaunay(n: int, rng) -> tuple[np.ndarray, np.ndarray]:
    P = rng.random((n, 2))
    F = Delaunay(P).simplices.astype(np.int64)
    return np.column_stack([P, np.zeros(n)]), F


@st.composite
def meshes(draw, kinds=("icosphere", "grid", "torus", "face_subset", "delaunay", "hull")):
    """A random triangle mesh ``(V, F)`` with at most a few hundred vertices."""
    kind = draw(st.sampled_from(kinds))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    if kind == "icosphere":
        V, F = icosphere(draw(st.integers(0, 2)))
    elif kind == "grid":
        V, F = grid(draw(st.integers(2, 14)), draw(st.integers(2, 14)))
    elif kind == "torus":
        V, F = torus(draw(st.integers(3, 16)), draw(st.integers(3, 9)))
    elif kind == "face_subset":
        V, F = icosphere(2)
        keep = rng.random(len(F)) < draw(st.floats(0.2, 1.0))
        keep[rng.integers(len(F))] = True
        F = F[keep]  # holes, several components, isolated vertices
    elif kind == "delaunay":
        V, F = _delaunay(draw(st.integers(3, 150)), rng)
    else:
        V, F = _hull(draw(st.integers(4, 150)), rng)
    noise = draw(st.sampled_from([0.0, 1e-3, 0.03]))
    scale = draw(st.sampled_from([1e-3, 1.0, 1e3]))
    V = (V + noise * rng.normal(size=V.shape)) * scale
    return np.ascontiguousarray(V), np.ascontiguousarray(F)


def _extent(V: np.ndarray) -> float:
    return float(np.ptp(V, axis=0).max()) or 1.0


# ------------------------------------------------------------------------------ properties
@pytest.mark.parametrize("name", NAMES)
@SETTINGS
@given(mesh=meshes(), dtype=st.sampled_from([np.float64, np.float32]))
def test_output_has_input_shape_and_dtype_and_is_finite(name, mesh, dtype):
    V, F = mesh
    V = V.astype(dtype)
    V_out, F_out = md.apply_filter(name, (V, F))
    assert V_out.shape == V.shape and V_out.dtype == V.dtype
    assert np.isfinite(V_out).all()
    np.testing.assert_array_equal(F_out, F)


@pytest.mark.parametrize("kind", ["arrays", "open3d", "pymeshlab_mesh"])
@pytest.mark.parametrize("name", NAMES)
@settings(max_examples=8, deadline=None)
@given(mesh=meshes())
def test_input_object_is_untouched(name, kind, mesh):
    V, F = mesh
    obj = make_mesh(kind, V, F)
    if kind == "arrays":
        before = (obj[0].copy(), obj[1].copy())
        out = md.apply_filter(name, obj)
        np.testing.assert_array_equal(obj[0], before[0])
        np.testing.assert_array_equal(obj[1], before[1])
        assert obj[0].flags.writeable
        assert out[0] is not obj[0]
    elif kind == "open3d":
        obj.compute_vertex_normals()
        snap = [np.asarray(a).copy() for a in (obj.vertices, obj.triangles, obj.vertex_normals)]
        out = md.apply_filter(name, obj)
        for a, b in zip(snap, (obj.vertices, obj.triangles, obj.vertex_normals)):
            np.testing.assert_array_equal(np.asarray(b), a)
        assert out is not obj
    else:
        snap = (obj.vertex_matrix().copy(), obj.face_matrix().copy())
        out = md.apply_filter(name, obj)
        np.testing.assert_array_equal(obj.vertex_matrix(), snap[0])
        np.testing.assert_array_equal(obj.face_matrix(), snap[1])
        assert out is not obj


@pytest.mark.parametrize("name", NAMES)
def test_the_callers_face_array_stays_writeable(name):
    V, F = _delaunay(41 + NAMES.index(name), np.random.default_rng(987 + NAMES.index(name)))  # a fresh topology
    md.apply_filter(name, (V, F))
    assert F.flags.writeable


@pytest.mark.parametrize("name", NAMES)
@SETTINGS
@given(mesh=meshes(), t=st.tuples(*[st.floats(-1e3, 1e3)] * 3))
def test_translation_equivariance_or_a_documented_exception(name, mesh, t):
    spec = md.get_filter(name)
    if not spec.translation_equivariant:
        doc = (spec.core.__doc__ or "").lower()
        assert "translation" in doc, f"filter '{name}' is not translation-equivariant: its docstring must say why"
        return
    V, F = mesh
    t = np.asarray(t) * _extent(V)
    Y = md.apply_filter(name, (V, F))[0]
    Yt = md.apply_filter(name, (V + t, F))[0]
    tol = 1e-9 * (_extent(V) + np.abs(t).max())
    np.testing.assert_allclose(Yt - t, Y, rtol=0, atol=tol)


LINEAR = [s.name for s in FILTERS if s.linear]


@pytest.mark.parametrize("name", LINEAR)
@SETTINGS
@given(mesh=meshes(), c=st.tuples(*[st.floats(-1e4, 1e4)] * 3))
def test_linear_filters_keep_a_constant_signal(name, mesh, c):
    V, F = mesh
    C = np.tile(np.asarray(c, dtype=np.float64), (V.shape[0], 1))
    Y = md.apply_filter(name, (C, F))[0]
    np.testing.assert_allclose(Y, C, rtol=0, atol=1e-11 * (1 + np.abs(c).max()))


@pytest.mark.parametrize("name", LINEAR)
@SETTINGS
@given(mesh=meshes(), seed=st.integers(0, 2**32 - 1))
def test_linear_filters_commute_with_rotations(name, mesh, seed):
    V, F = mesh
    R = Rotation.random(random_state=seed).as_matrix()
    Y = md.apply_filter(name, (V, F))[0]
    YR = md.apply_filter(name, (V @ R.T, F))[0]
    np.testing.assert_allclose(YR, Y @ R.T, rtol=0, atol=1e-9 * _extent(V))


@pytest.mark.parametrize("name", LINEAR)
@SETTINGS
@given(mesh=meshes(), a=st.floats(-10, 10), b=st.floats(-10, 10), seed=st.integers(0, 2**32 - 1))
def test_linear_filters_are_linear(name, mesh, a, b, seed):
    V, F = mesh
    X2 = np.random.default_rng(seed).normal(size=V.shape) * _extent(V)
    lhs = md.apply_filter(name, (a * V + b * X2, F))[0]
    rhs = a * md.apply_filter(name, (V, F))[0] + b * md.apply_filter(name, (X2, F))[0]
    np.testing.assert_allclose(lhs, rhs, rtol=0, atol=1e-9 * (abs(a) + abs(b) + 1) * _extent(V))


# ---------------------------------------------------------- smooth surfaces barely move
def _mean_edge(V, F) -> float:
    return float(np.linalg.norm(V[F[:, 0]] - V[F[:, 1]], axis=1).mean())


def _rms(x) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


@pytest.fixture(scope="module")
def fine_sphere():
    return icosphere(5)  # 10242 vertices: Laplacian shrinkage ~ h^2 is well below noise ~ h


@pytest.mark.parametrize("name", NAMES)
def test_a_finely_sampled_sphere_moves_less_than_the_noise_it_would_remove(name, fine_sphere):
    """Distance to the true surface: after filtering the clean sphere it is smaller than the
    noise (half the mean edge length, along the normals), and filtering the noisy sphere
    brings it below the noise."""
    V, F = fine_sphere
    Vn, _ = add_normal_noise((V, F), rho=0.5 * _mean_edge(V, F), seed=0)
    distance = lambda X: np.linalg.norm(X, axis=1) - 1.0  # noqa: E731
    noise = _rms(distance(Vn))
    assert _rms(distance(md.apply_filter(name, (V, F))[0])) < noise
    assert _rms(distance(md.apply_filter(name, (Vn, F))[0])) < noise


@pytest.mark.parametrize("name", NAMES)
@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(30, 300))
def test_a_plane_moves_less_than_the_noise_it_would_remove(name, seed, n):
    """A random Delaunay triangulation of a plane in a random orientation: the filter may slide
    vertices within the plane but must not move them off it by as much as the noise."""
    rng = np.random.default_rng(seed)
    V, F = _delaunay(n, rng)
    R = Rotation.random(random_state=seed).as_matrix()
    V = V @ R.T
    normal = R[:, 2]
    rho = 0.5 * _mean_edge(V, F)
    Vn, _ = add_normal_noise((V, F), rho=rho, seed=seed)
    noise = _rms(Vn @ normal)
    assert _rms(md.apply_filter(name, (V, F))[0] @ normal) < 0.01 * noise
    assert _rms(md.apply_filter(name, (Vn, F))[0] @ normal) < noise


# -------------------------------------------------------------------- parameter validation
def _out_of_range_values(p: md.Param) -> list:
    """Values just outside and far outside ``p``'s bounds (and NaN/inf for floats)."""
    if p.choices is not None:
        return [p.choices[0] + "_not_a_choice", ""]
    if p.kind not in (int, float):
        return []
    step = 1 if p.kind is int else 0.5
    bad = []
    if p.low is not None:
        low = p.kind(p.low) if p.kind is float or float(p.low).is_integer() else math.floor(p.low)
        bad += [low - step, low - 10**6 * step] + ([low] if p.low_open else [])
    if p.high is not None:
        high = p.kind(p.high) if p.kind is float or float(p.high).is_integer() else math.ceil(p.high)
        bad += [high + step, high + 10**6 * step] + ([high] if p.high_open else [])
    if p.kind is float:
        bad += [float("nan"), float("inf"), -float("inf")]
    return bad


BAD_VALUES = [(s.name, p.name, v) for s in FILTERS for p in s.params for v in _out_of_range_values(p)]


def test_every_bounded_parameter_is_covered():
    bounded = {(s.name, p.name) for s in FILTERS for p in s.params
               if p.choices is not None or (p.kind in (int, float) and (p.low is not None or p.high is not None))}
    assert bounded and bounded <= {(f, p) for f, p, _ in BAD_VALUES}


@pytest.mark.parametrize("name,param,value", BAD_VALUES, ids=lambda x: repr(x))
def test_out_of_range_value_raises_naming_parameter_value_and_range(name, param, value):
    spec = md.get_filter(name)
    p = spec.param(param)
    with pytest.raises(ValueError) as info:
        md.apply_filter(name, icosphere(1), **{param: value})
    msg = str(info.value)
    assert f"'{param}'" in msg and repr(value) in msg and p.range_text() in msg, msg


BOUNDED = [(s.name, p) for s in FILTERS for p in s.params if p.kind in (int, float) and (p.low is not None or p.high is not None)]


@pytest.mark.parametrize("name,p", BOUNDED, ids=lambda x: getattr(x, "name", x))
@SETTINGS
@given(data=st.data())
def test_random_values_are_accepted_exactly_inside_the_range(name, p, data):
    """Param.check agrees with the bounds for random values on both sides of them."""
    if p.kind is int:
        value = data.draw(st.integers(-(10**9), 10**9))
    else:
        value = data.draw(st.floats(-1e9, 1e9))
    inside = (p.low is None or (value > p.low if p.low_open else value >= p.low)) and (
        p.high is None or (value < p.high if p.high_open else value <= p.high)
    )
    if inside:
        assert p.check(value) == value
    else:
        with pytest.raises(ValueError, match=re_escape(p.range_text())):
            p.check(value, where=f"filter '{name}'")


def re_escape(text: str) -> str:
    import re

    return re.escape(text)


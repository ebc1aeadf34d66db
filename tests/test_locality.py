"""Relabelling large meshes into a cache-friendly vertex order (meshdenoise.locality).

The filters and choices must not depend on vertex labels: a mesh whose vertices are
shuffled (so the package relabels it) gives, mapped back, what the same mesh in a good
order gives (where nothing is relabelled).
"""

import numpy as np
import pytest

import meshdenoise as md
from meshdenoise import locality
from meshdenoise.locality import FAR_ROWS, FAR_SIDES_MAX, LOCALITY_MIN_VERTICES, Relabelling, far_side_fraction, relabelling
from meshdenoise.operators import Operators, clear_cache
from meshdenoise.shapes import grid, torus
from meshdenoise.tuning.choose import relabelled_model
from meshdenoise.tuning.covariance import NoiseModel


def _wavy_grid(nx=300, ny=300, seed=0):
    """A 90,000-vertex height field listed row by row (a range scan's order), with noise along z."""
    V, F = grid(nx, ny, size=1.0)
    V = V.copy()
    V[:, 2] = 0.05 * np.sin(6 * V[:, 0]) * np.cos(5 * V[:, 1])
    V[:, 2] += 0.3 / nx * np.random.default_rng(seed).standard_normal(len(V))
    return V, F


def _shuffled(V, F, seed=1):
    """The same mesh with its vertices in a random order: ``V2[k] = V[perm[k]]``."""
    perm = np.random.default_rng(seed).permutation(len(V))
    inverse = np.empty_like(perm)
    inverse[perm] = np.arange(len(perm))
    return V[perm], inverse[F], perm


def test_far_side_fraction_against_a_loop():
    F = np.random.default_rng(0).integers(0, 50_000, size=(200, 3))
    far = 0
    for f in F:
        for a, b in ((0, 1), (1, 2), (2, 0)):
            far += abs(int(f[a]) - int(f[b])) > FAR_ROWS
    assert far_side_fraction(F) == far / (3 * len(F))
    assert far_side_fraction(np.zeros((0, 3), int)) == 0.0


def test_relabelling_round_trip_and_faces():
    F = np.array([[0, 1, 2], [2, 1, 3], [3, 4, 2]])
    order = np.array([3, 0, 4, 2, 1])
    r = Relabelling.from_order(order, F)
    V = np.random.default_rng(0).standard_normal((5, 3))
    V2 = r.vertices(V)
    np.testing.assert_array_equal(V2, V[order])
    np.testing.assert_array_equal(r.restore(V2), V)
    np.testing.assert_array_equal(r.inverse[order], np.arange(5))
    # the same triangles (as vertex positions), rows sorted by their smallest new label
    old = {tuple(map(tuple, V[f])) for f in F}
    new = {tuple(map(tuple, V2[f])) for f in r.faces}
    assert old == new
    assert (np.diff(r.faces.min(axis=1)) >= 0).all()
    mask = np.array([True, False, False, True, False])
    np.testing.assert_array_equal(r.mask(mask), mask[order])
    assert r.mask(None) is None
    with pytest.raises(ValueError, match="4 rows for a relabelling of 5"):
        r.vertices(V[:4])


def test_small_and_ordered_meshes_are_not_relabelled():
    V, F = torus(40, 20)
    assert relabelling(F, len(V)) is None  # small
    V, F = _wavy_grid()
    assert len(V) >= LOCALITY_MIN_VERTICES
    assert far_side_fraction(F) <= FAR_SIDES_MAX  # row by row
    assert relabelling(F, len(V)) is None
    ops = Operators(F, len(V))
    assert ops.in_locality_order
    np.testing.assert_array_equal(ops.locality_order, np.arange(len(V)))


def test_shuffled_mesh_is_relabelled_into_a_local_order():
    V, F = _wavy_grid()
    V2, F2, _ = _shuffled(V, F)
    assert far_side_fraction(F2) > 0.5
    r = relabelling(F2, len(V2))
    assert r is not None
    assert far_side_fraction(r.faces) <= FAR_SIDES_MAX
    assert sorted(r.order.tolist()) == list(range(len(V2)))
    assert relabelling(F2.copy(), len(V2)) is r  # kept for the filter after the choice
    clear_cache()
    assert relabelling(F2, len(V2)) is not r


@pytest.mark.parametrize("method, params", [
    ("taubin", {"iterations": 30}),
    ("sobolev", {"mu": 2.0}),
    ("filtering", {"iterations": 25, "weights": "meshlab"}),
    ("heat", {"time": 5.0}),
    ("two_stage", {"iterations": 2}),
])
def test_filters_on_a_shuffled_mesh_equal_the_ordered_mesh(monkeypatch, method, params):
    """Relabelled internally, mapped back: the ordered mesh's result (not relabelled) to rounding."""
    V, F = _wavy_grid()
    V2, F2, perm = _shuffled(V, F)
    pinned = np.zeros(len(V), bool)
    pinned[::997] = True
    ref = md.apply_filter(method, (V, F), pinned=pinned, **params)[0]
    made = []
    monkeypatch.setattr(locality, "relabelling", lambda F, n: made.append(relabelling(F, n)) or made[-1])
    got = md.apply_filter(method, (V2, F2), pinned=pinned[perm], **params)[0]
    assert len(made) == 1 and made[0] is not None  # the filter ran on relabelled vertices
    scale = np.abs(V).max()
    np.testing.assert_allclose(got, ref[perm], rtol=0, atol=1e-11 * scale)
    np.testing.assert_array_equal(got[pinned[perm]], V2[pinned[perm]])


def test_operators_given_are_used_as_they_are():
    V, F = _wavy_grid()
    V2, F2, perm = _shuffled(V, F)
    ops = Operators(F2, len(V2))
    got = md.apply_filter("taubin", (V2, F2), iterations=5, operators=ops)[0]
    assert "P" in ops.__dict__  # the caller's operators ran the filter (no relabelled copy)
    ref = md.apply_filter("taubin", (V, F), iterations=5)[0]
    np.testing.assert_allclose(got, ref[perm], rtol=0, atol=1e-12)


def test_oracle_choice_sees_the_reference_in_the_same_labels():
    """The oracle's score reads the clean mesh: it must be relabelled with the noisy one."""
    V, F = _wavy_grid()
    clean = V.copy()
    clean[:, 2] = 0.05 * np.sin(6 * V[:, 0]) * np.cos(5 * V[:, 1])
    V2, F2, perm = _shuffled(V, F)
    ref = md.choose_parameters((V, F), "filtering", criterion="oracle", reference=clean)
    got = md.choose_parameters((V2, F2), "filtering", criterion="oracle", reference=clean[perm])
    assert got == ref and ref["iterations"] >= 1


def test_a_correlated_noise_model_is_relabelled_with_its_mesh():
    V, F = _wavy_grid(120, 120)
    order = np.random.default_rng(2).permutation(len(V))
    r = Relabelling.from_order(order, F)
    ops = Operators(F, len(V))
    model = NoiseModel(0.001, 2.0, V, ops.F)
    m2 = relabelled_model(model, F, r)
    np.testing.assert_array_equal(m2.V, V[order])
    np.testing.assert_array_equal(m2.F, r.faces)
    assert (m2.rho, m2.correlation_length) == (0.001, 2.0)
    assert relabelled_model(NoiseModel(0.001), F, r).V is None
    other = NoiseModel(0.001, 2.0, V[:10], F[:3])  # another mesh's model: left as it is
    assert relabelled_model(other, F, r) is other

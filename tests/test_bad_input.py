"""Each kind of bad input gets a clear error or a defined, documented behaviour."""

import numpy as np
import pytest

import meshdenoise as md
from meshdenoise.shapes import grid, icosphere

FILTERS = [("filtering", {"iterations": 3}), ("heat", {"tau": 0.5, "time": 2}), ("sobolev", {"mu": 2.0})]


@pytest.mark.parametrize("name,params", FILTERS)
def test_isolated_and_unreferenced_vertices_stay_put(name, params):
    V, F = icosphere(2)
    V2 = np.vstack([V, [[5.0, 5, 5], [7.0, 7, 7]]])
    F2 = np.vstack([F, [[len(V) + 1] * 3]])  # last vertex only in a degenerate "point" face
    out = md.apply_filter(name, (V2, F2), **params)[0]
    np.testing.assert_array_equal(out[-2:], V2[-2:])
    np.testing.assert_allclose(out[:-2], md.apply_filter(name, (V, F), **params)[0], atol=1e-12)


@pytest.mark.parametrize("name,params", FILTERS)
def test_duplicate_and_degenerate_faces_change_nothing(name, params):
    V, F = icosphere(2)
    a, b, c = F[0]
    F2 = np.vstack([F, F[:10], [[a, a, b]], [[c, b, c]]])  # degenerate faces on existing edges
    np.testing.assert_allclose(md.apply_filter(name, (V, F2), **params)[0], md.apply_filter(name, (V, F), **params)[0], atol=1e-12)


def test_zero_area_faces_do_not_make_nan():
    V, F = grid(5, 5)
    V = V.copy()
    V[6] = V[7]  # two vertices on top of each other: zero-area faces, zero-length edges
    for name, params in FILTERS:
        assert np.isfinite(md.apply_filter(name, (V, F), **params)[0]).all()
    assert np.isfinite(md.filtering((V, F), weights="inverse_distance", iterations=3)[0]).all()
    assert np.isfinite(md.add_normal_noise((V, F), rho=0.1, seed=0)[0]).all()


@pytest.mark.parametrize(
    "V,F,exc,match",
    [
        (np.zeros((0, 3)), np.zeros((0, 3), int), ValueError, "no vertices"),
        (np.random.rand(5, 3), np.zeros((0, 3), int), ValueError, "no faces"),
        (np.random.rand(5, 2), [[0, 1, 2]], ValueError, r"shape \(n, 3\)"),
        (np.random.rand(5, 3), [[0, 1, 2, 3]], ValueError, r"shape \(m, 3\)"),
        (np.random.rand(5, 3), [[0, 1, 5]], ValueError, "outside 0..4"),
        (np.random.rand(5, 3), [[0, -1, 2]], ValueError, "outside 0..4"),
        (np.random.rand(5, 3), [[0.0, 1.0, 2.0]], TypeError, "integer"),
        (np.array([["a", "b", "c"]] * 3), [[0, 1, 2]], TypeError, "numeric"),
        (np.array([[0, 0, 0], [1, 0, np.nan], [0, 1, 0]]), [[0, 1, 2]], ValueError, "vertex 1"),
        (np.array([[0, 0, 0], [1, 0, 0], [0, np.inf, 0]]), [[0, 1, 2]], ValueError, "NaN or infinite"),
    ],
)
def test_bad_arrays_raise_clear_errors(V, F, exc, match):
    for name, params in FILTERS:
        with pytest.raises(exc, match=match):
            md.apply_filter(name, (V, F), **params)


@pytest.mark.parametrize(
    "name,params,exc,match",
    [
        ("filtering", {"iterations": -1}, ValueError, r"'iterations' = -1 is out of range: 0 <= iterations"),
        ("filtering", {"iterations": 2.5}, TypeError, "must be an int"),
        ("filtering", {"iterations": True}, TypeError, "must be an int"),
        ("filtering", {"weights": "cotan"}, ValueError, r"'weights' = 'cotan' is not allowed: one of"),
        ("filtering", {"weights": "meshlab_"}, ValueError, "did you mean 'meshlab'"),
        ("filtering", {"lam": 1.5}, ValueError, r"'lam' = 1.5 is out of range: 0 < lam <= 1"),
        ("filtering", {"boundary": False}, ValueError, "applies only to weights='meshlab'"),
        ("filtering", {"iteration": 3}, TypeError, "unknown parameter 'iteration' \\(did you mean 'iterations'\\?\\)"),
        ("heat", {"tau": 0.0}, ValueError, r"'tau' = 0.0 is out of range: 0 < tau <= 2"),
        ("heat", {"tau": 2.5}, ValueError, "out of range"),
        ("heat", {"time": -1.0}, ValueError, r"'time' = -1.0 is out of range: 0 <= time"),
        ("heat", {"time": float("nan")}, ValueError, "must be finite"),
        ("sobolev", {"mu": -0.1}, ValueError, r"'mu' = -0.1 is out of range: 0 <= mu"),
        ("sobolev", {"mu": "big"}, TypeError, "must be a float"),
    ],
)
def test_parameter_validation_names_parameter_value_and_range(name, params, exc, match):
    V, F = icosphere(1)
    with pytest.raises(exc, match=match):
        md.apply_filter(name, (V, F), **params)


def test_unknown_filter_suggests_a_name():
    with pytest.raises(KeyError, match="did you mean 'sobolev'"):
        md.get_filter("sobolv")


def test_heat_tau_between_one_and_bound_is_accepted_on_non_bipartite_mesh():
    V, F = icosphere(2)
    lam = md.get_operators(F, len(V)).lambda_max()
    assert lam < 2
    md.heat((V, F), tau=1.0 + 0.5 * (2 / lam - 1), time=3)

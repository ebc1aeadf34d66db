"""geometry.cross_rows: numpy's cross product bit for bit, on rows."""

from __future__ import annotations

import numpy as np
import pytest

from meshdenoise.geometry import cross_rows, face_normals


def test_cross_rows_is_numpys_cross_bit_for_bit_including_extreme_values():
    rng = np.random.default_rng(0)
    a = rng.standard_normal((1000, 3)) * 10.0 ** rng.integers(-150, 150, size=(1000, 1))
    b = rng.standard_normal((1000, 3)) * 10.0 ** rng.integers(-150, 150, size=(1000, 1))
    a[:5] = [[0.0, 0, 0], [np.inf, 1, 0], [np.nan, 0, 1], [1e308, 1e308, 0], [-0.0, 0.0, -0.0]]
    with np.errstate(all="ignore"):
        expected, got = np.cross(a, b), cross_rows(a, b)
    np.testing.assert_array_equal(got, expected)  # NaNs in the same places, every other bit the same
    assert np.array_equal(np.signbit(got), np.signbit(expected))
    # it is what the face normals are built on: anticommutative, orthogonal to both rows
    np.testing.assert_array_equal(cross_rows(b[5:], a[5:]), -cross_rows(a[5:], b[5:]))
    V = np.array([[0.0, 0, 0], [2, 0, 0], [0, 3, 0]])
    np.testing.assert_array_equal(face_normals(V, np.array([[0, 1, 2], [0, 2, 1]])), [[0.0, 0, 1], [0, 0, -1]])


@pytest.mark.parametrize("shape_a, shape_b", [((4, 2), (4, 2)), ((4, 3), (5, 3)), ((3,), (3,))])
def test_cross_rows_refuses_other_shapes(shape_a, shape_b):
    with pytest.raises(ValueError, match="shape"):
        cross_rows(np.zeros(shape_a), np.zeros(shape_b))

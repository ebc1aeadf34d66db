"""Validation of the array core's inputs: ``V (n, 3) float64`` and ``F (m, 3) int64``.

Every public entry point funnels its mesh through :func:`check_mesh_arrays`, so bad input
fails here with a message naming the problem instead of deep inside scipy or C++ code.
"""

from __future__ import annotations

import numpy as np

__all__ = ["check_mesh_arrays", "check_vertices", "MeshValidationError"]


class MeshValidationError(ValueError):
    """A mesh that the filters cannot work on (bad shape, bad index, NaN coordinates...)."""


def check_vertices(V, name: str = "V") -> np.ndarray:
    """Return ``V`` as a C-contiguous ``(n, 3) float64`` array, or raise.

    Raises
    ------
    TypeError
        If ``V`` is not numeric.
    MeshValidationError
        If its shape is not ``(n, 3)`` or a coordinate is NaN or infinite.
    """
    arr = np.asarray(V)
    if arr.dtype == object or not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
        raise TypeError(f"{name} must be a real numeric array, got dtype {arr.dtype}")
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise MeshValidationError(f"{name} must have shape (n, 3), got {arr.shape}")
    arr = np.ascontiguousarray(arr, dtype=np.float64)
    finite = np.isfinite(arr).all(axis=1)
    if not finite.all():
        bad = np.flatnonzero(~finite)
        raise MeshValidationError(
            f"{name} has {bad.size} vertices with NaN or infinite coordinates "
            f"(first: vertex {bad[0]} = {arr[bad[0]].tolist()})"
        )
    return arr


def check_mesh_arrays(V, F, *, allow_no_faces: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Check and normalise a triangle mesh given as arrays.

    Parameters
    ----------
    V : array_like, shape (n, 3)
        Vertex coordinates; converted to float64.
    F : array_like of int, shape (m, 3)
        Triangle vertex indices; converted to int64.
    allow_no_faces : bool
        Accept ``m == 0`` (a point cloud). The filters refuse it: without faces
        there is no neighbourhood to smooth over.

    Returns
    -------
    V : ndarray, shape (n, 3), float64
    F : ndarray, shape (m, 3), int64

    Raises
    ------
    TypeError
        Non-numeric vertices or non-integer faces.
    MeshValidationError
        Empty mesh, wrong shapes, face indices out of range, NaN or inf coordinates,
        or no faces (unless ``allow_no_faces``).

    Examples
    --------
    >>> V, F = check_mesh_arrays([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
    >>> V.dtype, F.dtype
    (dtype('float64'), dtype('int64'))
    """
    V = check_vertices(V)
    if V.shape[0] == 0:
        raise MeshValidationError("mesh is empty: it has no vertices")
    farr = np.asarray(F)
    if farr.size == 0:
        farr = farr.reshape(0, 3)
    if farr.dtype == object or not (np.issubdtype(farr.dtype, np.integer) or farr.size == 0):
        if np.issubdtype(farr.dtype, np.floating) and np.all(np.mod(farr, 1) == 0):
            raise TypeError(f"F must be an integer array, got dtype {farr.dtype} (cast it with F.astype(int))")
        raise TypeError(f"F must be an integer array, got dtype {farr.dtype}")
    if farr.ndim != 2 or farr.shape[1] != 3:
        raise MeshValidationError(f"F must have shape (m, 3) (triangles), got {farr.shape}")
    F = np.ascontiguousarray(farr, dtype=np.int64)
    if F.shape[0] == 0 and not allow_no_faces:
        raise MeshValidationError(
            f"mesh has {V.shape[0]} vertices and no faces: a point cloud has no neighbourhood to smooth over"
        )
    if F.size:
        lo, hi = int(F.min()), int(F.max())
        if lo < 0 or hi >= V.shape[0]:
            bad = int(np.flatnonzero((F < 0).any(axis=1) | (F >= V.shape[0]).any(axis=1))[0])
            raise MeshValidationError(
                f"face {bad} = {F[bad].tolist()} references a vertex outside 0..{V.shape[0] - 1}"
            )
    return V, F

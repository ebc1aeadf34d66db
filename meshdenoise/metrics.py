"""Quality measures of a denoised mesh against a reference: SNR, normal error, distance to the clean surface, volume change.

Each takes ``(reference, candidate)`` and is listed in :data:`METRICS`, so it is available by
name in the API, the YAML ``metrics`` step and the results tables:

==================== ==========================================================
``snr``              signal-to-noise ratio of the coordinates, dB
``normal_error_deg`` mean angle between corresponding face normals, degrees
``mean_distance``    mean distance from the candidate's vertices to the reference surface
``max_distance``     largest such distance (one-sided Hausdorff distance)
``volume_change``    relative change of enclosed volume; negative means shrinkage
==================== ==========================================================

The reference of the last four must be a mesh (its faces are used); the candidate may be a
mesh with the same faces or a bare ``(n, 3)`` array of its vertices in the reference's order.
"""

from __future__ import annotations

from typing import Any, Callable

import numpy as np

from .adapters import mesh_kind, to_arrays
from .arrays import check_vertices
from .geometry import cross_rows, face_normals, signed_volume

__all__ = [
    "snr",
    "normal_error_deg",
    "mean_distance",
    "max_distance",
    "volume_change",
    "point_surface_distances",
    "coordinates",
    "METRICS",
    "compute_metrics",
]


def coordinates(mesh: Any) -> np.ndarray:
    """Vertex coordinates ``(n, 3) float64`` of any supported mesh, or of a bare ``(n, 3)`` array."""
    if isinstance(mesh, np.ndarray) or (isinstance(mesh, (list, tuple)) and len(mesh) != 2):
        return check_vertices(mesh)
    try:
        mesh_kind(mesh)
    except TypeError:
        return check_vertices(mesh)
    return to_arrays(mesh, allow_no_faces=True)[0]


def snr(reference: Any, candidate: Any) -> float:
    """Signal-to-noise ratio of ``candidate`` against ``reference``, in dB.

    .. math:: \\mathrm{SNR}(X, Y) = -20 \\log_{10} \\frac{\\|X - Y\\|_F}{\\|Y\\|_F}

    with :math:`Y` the reference (clean) coordinates and :math:`X` the candidate's, the
    same vertices in the same order. ``inf`` when they are identical. Either argument
    may be any supported mesh type or an ``(n, 3)`` array.

    Raises
    ------
    ValueError
        Different vertex counts, or a reference with all coordinates zero.

    Examples
    --------
    >>> import numpy as np
    >>> Y = np.array([[1.0, 0, 0], [0, 1.0, 0]])
    >>> round(snr(Y, Y * 1.1), 6)  # ||X - Y|| / ||Y|| = 0.1
    20.0
    >>> snr(Y, Y)
    inf
    """
    Y = coordinates(reference)
    X = coordinates(candidate)
    if X.shape != Y.shape:
        raise ValueError(f"snr: the candidate has {X.shape[0]} vertices, the reference {Y.shape[0]}")
    ref = np.linalg.norm(Y)
    if ref == 0:
        raise ValueError("snr: the reference has all coordinates zero, so its norm is 0")
    err = np.linalg.norm(X - Y)
    if err == 0:
        return float("inf")
    return float(-20.0 * np.log10(err / ref))




def _pair(reference: Any, candidate: Any, metric: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Reference vertices and faces and candidate vertices, checked to correspond."""
    try:
        mesh_kind(reference)
    except TypeError:
        raise TypeError(
            f"{metric}: the reference must be a mesh with faces ((V, F) tuple, MeshSet, Mesh or Open3D mesh), "
            f"got {type(reference).__name__}"
        ) from None
    V_ref, F = to_arrays(reference)
    if isinstance(candidate, np.ndarray) or (isinstance(candidate, (list, tuple)) and len(candidate) != 2):
        V = check_vertices(candidate)
    else:
        V, F_c = to_arrays(candidate, allow_no_faces=True)
        if F_c.size and not np.array_equal(F_c, F):
            raise ValueError(f"{metric}: the candidate's faces differ from the reference's (same topology needed)")
    if V.shape != V_ref.shape:
        raise ValueError(f"{metric}: the candidate has {V.shape[0]} vertices, the reference {V_ref.shape[0]}")
    return V_ref, F, V


def normal_error_deg(reference: Any, candidate: Any) -> float:
    """Mean angle between the unit normals of corresponding faces, in degrees.

    .. math:: E = \\frac{1}{m} \\sum_{f=1}^{m} \\arccos\\left(\\mathrm{clamp}(n_f \\cdot n'_f, -1, 1)\\right)

    with :math:`n_f` the reference's and :math:`n'_f` the candidate's unit face
    normals (computed as :math:`\\mathrm{atan2}(\\|n_f \\times n'_f\\|, n_f \\cdot n'_f)`,
    accurate for small angles; unweighted by area, as in the feature-preserving denoising literature,
    e.g. Zheng et al. 2011, Zhang et al. 2015). Zero-area faces are left out.

    Examples
    --------
    >>> import numpy as np
    >>> V = np.array([[0., 0, 0], [1, 0, 0], [0, 1, 0]]); F = np.array([[0, 1, 2]])
    >>> round(normal_error_deg((V, F), V + [[0, 0, 0], [0, 0, 1], [0, 0, 0]]), 6)  # tilted by 45 degrees
    45.0
    """
    V_ref, F, V = _pair(reference, candidate, "normal_error_deg")
    a, b = face_normals(V_ref, F), face_normals(V, F)
    ok = (np.abs(a).sum(1) > 0) & (np.abs(b).sum(1) > 0)
    if not ok.any():
        raise ValueError("normal_error_deg: no face has a non-zero area in both meshes")
    # atan2 of (sin, cos) stays accurate near 0 where arccos loses half the digits
    sin = np.linalg.norm(cross_rows(a[ok], b[ok]), axis=1)
    cos = np.einsum("ij,ij->i", a[ok], b[ok])
    return float(np.degrees(np.arctan2(sin, cos)).mean())


def point_surface_distances(points: np.ndarray, V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Unsigned distance from each point to the triangle mesh ``(V, F)``, shape (p,).

    Uses Open3D's ``RaycastingScene.compute_distance`` (exact closest point on a BVH of
    the triangles, computed in float32: relative error about 1e-7 of the mesh size).
    """
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3d.core.Tensor(np.ascontiguousarray(V, dtype=np.float32)),
        o3d.core.Tensor(np.ascontiguousarray(F, dtype=np.uint32)),
    )
    query = o3d.core.Tensor(np.ascontiguousarray(points, dtype=np.float32))
    return scene.compute_distance(query).numpy().astype(np.float64)


def _distances(reference: Any, candidate: Any, metric: str) -> np.ndarray:
    V_ref, F, V = _pair(reference, candidate, metric)
    return point_surface_distances(V, V_ref, F)


def mean_distance(reference: Any, candidate: Any) -> float:
    """Mean distance from the candidate's vertices to the reference surface (mesh units).

    .. math:: d_{mean} = \\frac1n \\sum_i \\min_{p \\in S_{ref}} \\|x_i - p\\|

    Unlike SNR it does not penalise sliding along the surface. Computed with Open3D's
    ``RaycastingScene`` (float32, so distances below about 1e-7 of the mesh size are
    not resolved); MeshLab's ``get_hausdorff_distance`` (sampled vertices, target the
    reference) reports the same ``mean`` and ``max``.

    Examples
    --------
    >>> import numpy as np
    >>> V = np.array([[0., 0, 0], [1, 0, 0], [0, 1, 0]]); F = np.array([[0, 1, 2]])
    >>> round(mean_distance((V, F), V + [0, 0, 0.5]), 6)
    0.5
    """
    return float(_distances(reference, candidate, "mean_distance").mean())


def max_distance(reference: Any, candidate: Any) -> float:
    """Largest distance from a candidate vertex to the reference surface (one-sided Hausdorff).

    .. math:: d_{max} = \\max_i \\min_{p \\in S_{ref}} \\|x_i - p\\|

    Examples
    --------
    >>> import numpy as np
    >>> V = np.array([[0., 0, 0], [1, 0, 0], [0, 1, 0]]); F = np.array([[0, 1, 2]])
    >>> round(max_distance((V, F), V + [[0, 0, 0.1], [0, 0, -0.3], [0, 0, 0.2]]), 6)
    0.3
    """
    return float(_distances(reference, candidate, "max_distance").max())


def volume_change(reference: Any, candidate: Any) -> float:
    """Relative change of the enclosed volume, negative for shrinkage.

    .. math:: \\Delta = \\frac{\\mathrm{vol}(X) - \\mathrm{vol}(Y)}{|\\mathrm{vol}(Y)|}

    with the signed volumes of :func:`meshdenoise.geometry.signed_volume` (divergence
    theorem, both with the reference's vertex centroid as apex, so that for an open
    mesh it is the volume of the same cone).

    Examples
    --------
    >>> import numpy as np
    >>> V = np.array([[0., 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    >>> F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    >>> round(volume_change((V, F), 0.5 * V), 6)  # half the size: 1/8 of the volume
    -0.875
    """
    V_ref, F, V = _pair(reference, candidate, "volume_change")
    origin = V_ref.mean(axis=0)
    ref = signed_volume(V_ref, F, origin)
    if ref == 0:
        raise ValueError("volume_change: the reference encloses zero volume")
    return float((signed_volume(V, F, origin) - ref) / abs(ref))


# name -> function(reference, candidate) -> float. Every entry is available by name in the API,
# the YAML `metrics` step and the results tables. A new metric is added here.
METRICS: dict[str, Callable[[Any, Any], float]] = {
    "snr": snr,
    "normal_error_deg": normal_error_deg,
    "mean_distance": mean_distance,
    "max_distance": max_distance,
    "volume_change": volume_change,
}


def compute_metrics(reference: Any, candidate: Any, names: list[str] | None = None) -> dict[str, float]:
    """The named metrics (all of :data:`METRICS` by default) of ``candidate`` against ``reference``.

    Examples
    --------
    >>> import numpy as np
    >>> Y = np.array([[1.0, 0, 0], [0, 1.0, 0]])
    >>> compute_metrics(Y, Y * 1.1, ["snr"])
    {'snr': 20.0...}
    """
    chosen = list(METRICS) if names is None else names
    unknown = [n for n in chosen if n not in METRICS]
    if unknown:
        raise ValueError(f"unknown metric(s) {unknown}; known: {', '.join(METRICS)}")
    return {n: METRICS[n](reference, candidate) for n in chosen}

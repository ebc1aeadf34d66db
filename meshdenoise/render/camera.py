"""The camera: one pinhole camera framing every compared mesh, or a detail, or looking along its mean normal."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

__all__ = ["Camera", "frame_camera", "camera_around", "camera_along", "mean_normal"]


@dataclass(frozen=True)
class Camera:
    """A pinhole camera: ``eye`` looks at ``center`` with ``up`` pointing up, vertical field of view in degrees.

    The same ``Camera`` drawn by either backend puts a point at the same pixel:

    .. math:: u = \\tfrac{W}{2} + f \\frac{(p - e) \\cdot s}{(p - e) \\cdot d}, \\quad
              v = \\tfrac{H}{2} - f \\frac{(p - e) \\cdot t}{(p - e) \\cdot d}, \\quad
              f = \\frac{H / 2}{\\tan(\\mathrm{fov} / 2)}

    with :math:`d` the viewing direction, :math:`s` the right and :math:`t` the up axis.
    """

    center: tuple[float, float, float]
    eye: tuple[float, float, float]
    up: tuple[float, float, float]
    fov: float
    near: float
    far: float

    def axes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Unit vectors (right, up, forward) of the camera frame."""
        d = np.subtract(self.center, self.eye)
        d = d / np.linalg.norm(d)
        s = np.cross(d, self.up)
        s = s / np.linalg.norm(s)
        return s, np.cross(s, d), d

    def project(self, points: np.ndarray, size: tuple[int, int]) -> np.ndarray:
        """Pixel coordinates ``(k, 2)`` (column, row; float) and depth ``(k,)`` of ``(k, 3)`` points, as ``(k, 3)``."""
        w, h = size
        s, t, d = self.axes()
        rel = np.asarray(points, dtype=np.float64) - np.asarray(self.eye)
        depth = rel @ d
        f = (h / 2.0) / np.tan(np.radians(self.fov) / 2.0)
        return np.stack([w / 2.0 + f * (rel @ s) / depth, h / 2.0 - f * (rel @ t) / depth, depth], axis=1)


def frame_camera(
    vertex_sets: Sequence[np.ndarray],
    size: tuple[int, int] = (400, 400),
    view: tuple[float, float] = (0.0, 0.0),
    fov: float = 30.0,
    margin: float = 1.08,
) -> Camera:
    """One camera framing every vertex set, so compared meshes are seen from the same place.

    The camera looks at the centre of the union's bounding box from distance
    :math:`r / \\sin(\\phi / 2) \\cdot m`, with :math:`r` the largest distance of a vertex
    from that centre, :math:`\\phi` the smaller of the vertical and horizontal fields of view
    and :math:`m` the ``margin``: the bounding sphere fits in the picture.

    Parameters
    ----------
    vertex_sets : sequence of ndarray, each shape (n_k, 3)
    size : (width, height) in pixels
    view : (azimuth, elevation) in degrees
        ``(0, 0)`` looks from +z towards -z with +y up (MeshLab's default); the azimuth turns
        the eye about +y towards +x, the elevation raises it towards +y.
    fov : float
        Vertical field of view in degrees, in (0, 170).
    margin : float
        >= 1; room left around the bounding sphere.

    Examples
    --------
    >>> import numpy as np
    >>> cam = frame_camera([np.array([[-1.0, 0, 0], [1, 0, 0]])], size=(100, 100))
    >>> cam.center, round(cam.eye[2], 3)
    ((0.0, 0.0, 0.0), 4.173)
    >>> cam.project(np.array([[0.0, 0, 0]]), (100, 100))[0, :2].tolist()
    [50.0, 50.0]
    """
    center, radius = _bounding_ball(vertex_sets)
    return camera_around(center, radius, size, view, fov, margin)


def _bounding_ball(vertex_sets: Sequence[np.ndarray]) -> tuple[np.ndarray, float]:
    """The centre of the union's bounding box and the largest distance of a vertex from it."""
    pts = np.vstack([np.asarray(v, dtype=np.float64).reshape(-1, 3) for v in vertex_sets])
    center = (pts.min(axis=0) + pts.max(axis=0)) / 2.0
    return center, float(np.linalg.norm(pts - center, axis=1).max()) or 1.0


def camera_around(
    center: Sequence[float],
    radius: float,
    size: tuple[int, int] = (400, 400),
    view: tuple[float, float] = (0.0, 0.0),
    fov: float = 30.0,
    margin: float = 1.08,
) -> Camera:
    """A camera looking at ``center`` from ``view`` so that the ball of ``radius`` around it fills the picture.

    See :func:`frame_camera` (which calls this with the bounding sphere of the meshes); used
    directly to zoom on a detail.

    Examples
    --------
    >>> cam = camera_around((0.0, 0.0, 0.0), 1.0, size=(100, 100))
    >>> round(cam.eye[2], 3)
    4.173
    """
    if len(view) != 2:
        raise ValueError(f"view must be (azimuth, elevation) in degrees, got {view!r}")
    az, el = np.radians(view[0]), np.radians(view[1])
    direction = (np.sin(az) * np.cos(el), np.sin(el), np.cos(az) * np.cos(el))
    return camera_along(center, radius, direction, size, fov, margin)


def camera_along(
    center: Sequence[float],
    radius: float,
    direction: Sequence[float],
    size: tuple[int, int] = (400, 400),
    fov: float = 30.0,
    margin: float = 1.08,
) -> Camera:
    """A camera at ``center + t * direction`` looking back at ``center``, the ball of ``radius`` filling the picture.

    ``direction`` points from the centre towards the eye (a surface whose normal it is faces
    the camera). Screen up is world +y (made perpendicular to the view); looking straight
    along the y axis, -z (from above) or +z (from below).

    Examples
    --------
    >>> cam = camera_along((0.0, 0.0, 0.0), 1.0, (2.0, 0.0, 0.0), size=(100, 100))
    >>> [round(c, 3) for c in cam.eye], cam.up
    ([4.173, 0.0, 0.0], (0.0, 1.0, 0.0))
    """
    w, h = _check_size(size)
    if not 0 < fov < 170:
        raise ValueError(f"fov must be in (0, 170) degrees, got {fov!r}")
    if margin < 1:
        raise ValueError(f"margin must be >= 1, got {margin!r}")
    center = np.asarray(center, dtype=np.float64)
    radius = float(radius)
    if center.shape != (3,) or not np.isfinite(center).all() or not (np.isfinite(radius) and radius > 0):
        raise ValueError(f"the camera needs a finite centre (3,) and a radius > 0, got {center!r}, {radius!r}")
    direction = np.asarray(direction, dtype=np.float64)
    length = float(np.linalg.norm(direction)) if direction.shape == (3,) else 0.0
    if not (np.isfinite(length) and length > 0):
        raise ValueError(f"direction must be a finite non-zero vector (3,), got {direction!r}")
    direction = direction / length
    half_v = np.radians(fov) / 2.0
    half_h = np.arctan(np.tan(half_v) * w / h)
    dist = radius / np.sin(min(half_v, half_h)) * margin
    # world +y (Camera.axes makes it perpendicular); looking straight up or down, -z or +z
    up = (0.0, 1.0, 0.0) if np.hypot(direction[0], direction[2]) > 1e-6 else (0.0, 0.0, -float(np.sign(direction[1])))
    eye = center + dist * direction
    return Camera(
        tuple(float(c) for c in center), tuple(float(c) for c in eye), up, float(fov),
        near=max(dist - 1.5 * radius, dist * 1e-3), far=dist + 1.5 * radius,
    )


def _check_size(size) -> tuple[int, int]:
    try:
        w, h = (int(size[0]), int(size[1]))
    except (TypeError, ValueError, IndexError):
        raise ValueError(f"size must be (width, height) in pixels, got {size!r}") from None
    if w != size[0] or h != size[1] or w < 16 or h < 16 or w > 8192 or h > 8192:
        raise ValueError(f"size must be two integers in [16, 8192] (width, height), got {size!r}")
    return w, h


NET_NORMAL_SHARE = 0.05  # below this share of the area facing one way net, a detail faces no side


def mean_normal(V: np.ndarray, F: np.ndarray) -> tuple[float, float, float] | None:
    """The area-weighted mean normal of the faces, as a unit vector; None when the normals cancel out.

    :math:`n = \\sum_f A_f n_f / \\|\\sum_f A_f n_f\\|` (the faces' orientation decides the
    side). None when :math:`\\|\\sum_f A_f n_f\\| < 0.05 \\sum_f A_f`: no side is seen
    more than another (a closed part, a thin sheet seen from both sides), or there is no area.

    Examples
    --------
    >>> import numpy as np
    >>> V = np.array([[0.0, 0, 0], [0, 1, 0], [0, 0, 1], [0, 1, 1]]); F = np.array([[0, 1, 2], [1, 3, 2]])
    >>> mean_normal(V, F)
    (1.0, 0.0, 0.0)
    >>> mean_normal(V, np.vstack([F, F[:, ::-1]])) is None
    True
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F)
    if F.shape[0] == 0:
        return None
    cross = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])  # 2 A_f n_f
    net = cross.sum(axis=0)
    length = float(np.linalg.norm(net))
    total = float(np.linalg.norm(cross, axis=1).sum())
    if not (np.isfinite(length) and total > 0) or length < NET_NORMAL_SHARE * total:
        return None
    return tuple(float(c) + 0.0 for c in net / length)

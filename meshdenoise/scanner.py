"""A virtual range scanner: what a depth camera sees of a clean mesh, with its noise.

:func:`simulate_scan` casts one ray per pixel of a pinhole camera at a clean mesh (Open3D's
``RaycastingScene``), keeps what a scanner keeps, triangulates the range grid and adds noise
along the rays. It returns the noisy scan and the noise-free scan of the same rays (same
vertices, same faces), so that a denoiser's error can be measured vertex to vertex.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .adapters import read_mesh

__all__ = ["RangeScan", "ScannerSettings", "simulate_scan", "view_direction"]


@dataclass(frozen=True)
class ScannerSettings:
    """What the scanner keeps of its hits; passed to :func:`simulate_scan`.

    Attributes
    ----------
    max_incidence_deg : float
        A hit whose surface is seen at more than this angle from its normal (grazing) is
        dropped, and so is a triangle of the range grid whose own normal is: such a triangle
        bridges a depth jump between two surfaces. 75 degrees: structured-light and laser
        scanners lose most returns beyond 70 to 80 degrees.
    min_component_faces : int
        Pieces of the scan with fewer faces are dropped (a real scanner's software removes
        such specks; a denoiser has nothing to average on them).
    depth_power : float
        The noise grows as ``depth ** depth_power`` (2: triangulation and stereo scanners,
        whose depth error grows with the square of the distance), scaled so that the whole
        scan's root-mean-square noise is the level asked for.
    margin : float
        The camera stands where the mesh's bounding sphere, enlarged by this factor, just
        fills the vertical field of view.
    """

    max_incidence_deg: float = 75.0
    min_component_faces: int = 10
    depth_power: float = 2.0
    margin: float = 1.05

    def __post_init__(self) -> None:
        if not (0.0 < self.max_incidence_deg < 90.0):
            raise ValueError(f"ScannerSettings: max_incidence_deg = {self.max_incidence_deg!r} must be in (0, 90)")
        if int(self.min_component_faces) != self.min_component_faces or self.min_component_faces < 1:
            raise ValueError(f"ScannerSettings: min_component_faces = {self.min_component_faces!r} must be an integer >= 1")
        if not (math.isfinite(self.depth_power) and self.depth_power >= 0):
            raise ValueError(f"ScannerSettings: depth_power = {self.depth_power!r} must be a finite number >= 0")
        if not (math.isfinite(self.margin) and self.margin >= 1.0):
            raise ValueError(f"ScannerSettings: margin = {self.margin!r} must be a finite number >= 1")


@dataclass(frozen=True)
class RangeScan:
    """A simulated range scan (:func:`simulate_scan`).

    Attributes
    ----------
    V : (n, 3) float64
        The noisy scan's vertices.
    V_clean : (n, 3) float64
        The same rays' hits on the clean mesh: ``V - V_clean`` is the noise, along ``rays``.
    F : (m, 3) int64
        Faces of both, oriented towards the camera.
    pixels : (n, 2) int64
        Row and column of each vertex's pixel.
    rays : (n, 3) float64
        Unit direction from the camera to each clean hit.
    depth : (n,) float64
        Each clean hit's depth along the optical axis.
    camera : (3,) float64
        The camera's position.
    resolution : (int, int)
        Width and height in pixels.
    mean_edge : float
        Mean edge length of the clean scan (``h``).
    rho : float
        Root-mean-square noise along the rays, outliers left out, mesh units.
    """

    V: np.ndarray
    V_clean: np.ndarray
    F: np.ndarray
    pixels: np.ndarray
    rays: np.ndarray
    depth: np.ndarray
    camera: np.ndarray
    resolution: tuple[int, int]
    mean_edge: float
    rho: float

    @property
    def noisy(self) -> tuple[np.ndarray, np.ndarray]:
        """``(V, F)``."""
        return self.V, self.F

    @property
    def clean(self) -> tuple[np.ndarray, np.ndarray]:
        """``(V_clean, F)``."""
        return self.V_clean, self.F


def view_direction(azimuth_deg: float, elevation_deg: float) -> np.ndarray:
    """Unit vector from the target towards the camera; (0, 0) looks from +z with +y up, as ``meshdenoise render``.

    Examples
    --------
    >>> view_direction(0, 0).round(12).tolist(), view_direction(90, 0).round(12).tolist()
    ([0.0, 0.0, 1.0], [1.0, 0.0, 0.0])
    """
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    return np.array([math.sin(az) * math.cos(el), math.sin(el), math.cos(az) * math.cos(el)])


def _number(name: str, value: Any, *, low: float = 0.0, high: float = math.inf, low_open: bool = False) -> float:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"simulate_scan: {name} must be a number, got {value!r}")
    value = float(value)
    if not (math.isfinite(value) and (value > low if low_open else value >= low) and value <= high):
        lower = f"> {low:g}" if low_open else f">= {low:g}"
        upper = "" if high == math.inf else f" and <= {high:g}"
        raise ValueError(f"simulate_scan: parameter '{name}' = {value!r} is out of range: {lower}{upper}")
    return value


def _camera(V: np.ndarray, view: tuple[float, float], fov: float, width: int, height: int, margin: float):
    """Camera position, its axes (right, up, forward) and the pixel pitch on the image plane at distance 1."""
    centre = 0.5 * (V.min(0) + V.max(0))
    radius = float(np.linalg.norm(V - centre, axis=1).max()) * margin
    back = view_direction(*view)
    pitch = 2.0 * math.tan(math.radians(fov) / 2.0) / width  # fov is horizontal
    half_vertical = math.atan(0.5 * pitch * height)
    distance = radius / math.sin(min(half_vertical, math.atan(0.5 * pitch * width)))
    forward = -back
    up0 = np.array([0.0, 1.0, 0.0]) if abs(back[1]) < 0.999 else np.array([0.0, 0.0, -np.sign(back[1])])
    right = np.cross(forward, up0)
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    return centre + distance * back, right, up, forward, pitch


def _rays(right, up, forward, pitch, width: int, height: int) -> np.ndarray:
    """(height, width, 3) unit rays through the pixel centres (row 0 at the top)."""
    x = (np.arange(width) + 0.5 - width / 2.0) * pitch
    y = -(np.arange(height) + 0.5 - height / 2.0) * pitch
    D = forward[None, None, :] + x[None, :, None] * right[None, None, :] + y[:, None, None] * up[None, None, :]
    return D / np.linalg.norm(D, axis=2, keepdims=True)


def _cast(V: np.ndarray, F: np.ndarray, origin: np.ndarray, D: np.ndarray):
    """First hit of every ray: (hit mask, face id, barycentric u, v), each (height, width)."""
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(np.ascontiguousarray(V, dtype=np.float32)),
                        o3d.core.Tensor(np.ascontiguousarray(F, dtype=np.uint32)))
    rays = np.concatenate([np.broadcast_to(origin, D.shape), D], axis=2).astype(np.float32)
    ans = scene.cast_rays(o3d.core.Tensor(rays))
    face = ans["primitive_ids"].numpy().astype(np.int64)
    hit = np.isfinite(ans["t_hit"].numpy()) & (face != o3d.t.geometry.RaycastingScene.INVALID_ID)
    uv = ans["primitive_uvs"].numpy().astype(np.float64)
    return hit, np.where(hit, face, 0), uv[..., 0], uv[..., 1]


def _grid_faces(index: np.ndarray, P: np.ndarray) -> np.ndarray:
    """Triangles of the range grid: two per square of four hits (the shorter diagonal), one per square of three.

    ``index`` (height, width) holds the vertex of each pixel or -1. Counter-clockwise as seen from the camera.
    """
    a, b = index[:-1, :-1].ravel(), index[:-1, 1:].ravel()
    c, d = index[1:, :-1].ravel(), index[1:, 1:].ravel()
    va, vb, vc, vd = a >= 0, b >= 0, c >= 0, d >= 0
    full = va & vb & vc & vd
    out = []
    if full.any():
        fa, fb, fc, fd = a[full], b[full], c[full], d[full]
        bc = np.linalg.norm(P[fb] - P[fc], axis=1) <= np.linalg.norm(P[fa] - P[fd], axis=1)
        out += [np.stack([fa, fc, fb], 1)[bc], np.stack([fb, fc, fd], 1)[bc],
                np.stack([fa, fd, fb], 1)[~bc], np.stack([fa, fc, fd], 1)[~bc]]
    three = (va.astype(int) + vb + vc + vd) == 3
    for missing, tri in ((~vd, (a, c, b)), (~va, (b, c, d)), (~vc, (a, d, b)), (~vb, (a, c, d))):
        sel = three & missing
        out.append(np.stack([t[sel] for t in tri], 1))
    return np.concatenate(out).astype(np.int64) if out else np.zeros((0, 3), np.int64)


def _incidence_cos(P: np.ndarray, F: np.ndarray, camera: np.ndarray) -> np.ndarray:
    """|cos| of the angle between each triangle's normal and the ray to its centroid."""
    n = np.cross(P[F[:, 1]] - P[F[:, 0]], P[F[:, 2]] - P[F[:, 0]])
    ray = P[F].mean(1) - camera
    norm = np.linalg.norm(n, axis=1) * np.linalg.norm(ray, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(norm > 0, np.abs(np.einsum("ij,ij->i", n, ray)) / np.where(norm > 0, norm, 1.0), 0.0)


def _keep_large_components(F: np.ndarray, n: int, min_faces: int) -> np.ndarray:
    """Faces of the connected pieces (sharing a vertex) with at least ``min_faces`` faces."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    if len(F) == 0:
        return F
    rows = np.repeat(np.arange(len(F)), 3)
    A = sp.csr_matrix((np.ones(rows.size), (rows, F.ravel())), shape=(len(F), n))
    _, label = connected_components(A @ A.T, directed=False)
    count = np.bincount(label)
    return F[count[label] >= min_faces]


def _field(rng: np.random.Generator, shape: tuple[int, int], correlation: float) -> np.ndarray:
    """White Gaussian noise filtered by a Gaussian of standard deviation correlation / 2 pixels.

    The field's autocorrelation is then ``exp(-r^2 / correlation^2)``: it falls to 1/e at
    ``correlation`` pixels (the definition of :func:`meshdenoise.noise.correlation_length`).
    """
    from scipy.ndimage import gaussian_filter

    white = rng.standard_normal(shape)
    if correlation <= 0:
        return white
    return gaussian_filter(white, sigma=correlation / 2.0, mode="wrap", truncate=4.0)


def simulate_scan(
    mesh: Any,
    *,
    view: tuple[float, float] = (0.0, 0.0),
    resolution: tuple[int, int] = (640, 480),
    fov: float = 40.0,
    noise: float = 0.0,
    noise_in_edges: bool = True,
    correlation: float = 0.0,
    stripes: float = 0.0,
    outliers: float = 0.0,
    seed: int | np.random.Generator | None = 0,
    settings: ScannerSettings = ScannerSettings(),
) -> RangeScan:
    """Scan a clean mesh with a virtual pinhole range camera and add a scanner's noise along the rays.

    One ray per pixel; a hit is kept when its surface faces the camera within
    ``settings.max_incidence_deg``; the hits of each square of 2 x 2 pixels make two triangles
    (split along the shorter diagonal) or one (three hits), and a triangle seen at more than
    that angle is dropped (it bridges a depth jump): the scan has open borders and holes where
    the surface turns away, is hidden or leaves the image. Pieces of fewer than
    ``settings.min_component_faces`` faces are dropped. Vertex *i* is then moved along its ray
    :math:`r_i` by

    .. math:: x_i = p_i + \\rho\\, \\frac{g_i\\, (z_{u_i} + s\\, w_{\\mathrm{row}(i)})}
              {\\sqrt{\\overline{g^2 (z + s w)^2}}}\\, r_i + o_i r_i,
              \\qquad g_i = (t_i / \\bar t)^{\\,q}

    with :math:`p_i` the clean hit, :math:`z` white noise on the pixel grid filtered by a
    Gaussian so that its correlation falls to 1/e at ``correlation`` pixels, :math:`w` one
    standard normal offset per scanline (``stripes`` :math:`= s`), :math:`t_i` the depth,
    :math:`\\bar t` its median, :math:`q` = ``settings.depth_power``, and :math:`o_i` an
    outlier offset (``outliers``: that fraction of the vertices, drawn at random, moved by
    3 to 6 :math:`\\rho`, either way): the root-mean-square noise without outliers is
    exactly :math:`\\rho`.

    Parameters
    ----------
    mesh : (V, F) tuple, pymeshlab.MeshSet or Mesh, or open3d.geometry.TriangleMesh
        The clean surface.
    view : (float, float)
        Azimuth and elevation of the camera around the mesh's bounding-box centre, degrees;
        (0, 0) looks from +z with +y up. The camera stands where the bounding sphere fills
        the image.
    resolution : (int, int)
        Width and height in pixels (8 to 8192 each). The scan has at most width x height
        vertices: about ``0.4 * width * height`` for a compact object.
    fov : float
        Horizontal field of view in degrees, in (0, 170).
    noise : float
        The level :math:`\\rho`: in mean edge lengths of the clean scan with ``noise_in_edges``
        (the default; 0.1 to 0.7 is a scanner's range), else in mesh units.
    noise_in_edges : bool
    correlation : float
        Correlation length of the noise in pixels (0: independent). Structured-light
        scanners: 1 to 4.
    stripes : float
        Amplitude of the per-scanline offset relative to the grain (0: none; 0.5: half as
        strong).
    outliers : float
        Fraction of flying pixels, in [0, 0.5].
    seed : int or numpy.random.Generator, optional
        Same seed, same noise; the scan's geometry depends on no seed.
    settings : ScannerSettings

    Returns
    -------
    RangeScan
        ``.V`` noisy, ``.V_clean`` noise-free, ``.F`` the faces of both.

    Raises
    ------
    ValueError
        A parameter out of range, or the camera sees nothing of the mesh.

    Notes
    -----
    To scan a part for a denoiser's test, give a resolution whose scan edge is near the
    detail you care about, and a noise of 0.2 to 0.5 mean edge lengths: below 0.1 it is
    hard to see, above 1 the scan's triangles fold.

    Examples
    --------
    >>> from meshdenoise.shapes import icosphere
    >>> scan = simulate_scan(icosphere(4), resolution=(64, 64), noise=0.3, correlation=2, seed=1)
    >>> scan.V.shape == scan.V_clean.shape, bool(np.all(scan.F == scan.F))
    (True, True)
    >>> d = np.einsum("ij,ij->i", scan.V - scan.V_clean, scan.rays)  # along the rays
    >>> bool(np.allclose(scan.V - scan.V_clean, d[:, None] * scan.rays))
    True
    >>> round(float(np.sqrt(np.mean(d ** 2)) / scan.mean_edge), 6)
    0.3
    """
    if not isinstance(settings, ScannerSettings):
        raise TypeError(f"simulate_scan: settings must be a ScannerSettings, got {settings!r}")
    try:
        az, el = (float(x) for x in view)
    except (TypeError, ValueError):
        raise TypeError(f"simulate_scan: view must be (azimuth, elevation) in degrees, got {view!r}") from None
    if not (math.isfinite(az) and math.isfinite(el)):
        raise ValueError(f"simulate_scan: view = {view!r} must be finite degrees")
    try:
        width, height = resolution
    except (TypeError, ValueError):
        raise TypeError(f"simulate_scan: resolution must be (width, height) in pixels, got {resolution!r}") from None
    for name, value in (("resolution width", width), ("resolution height", height)):
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or not 8 <= value <= 8192:
            raise ValueError(f"simulate_scan: {name} = {value!r} must be an integer from 8 to 8192")
    width, height = int(width), int(height)
    fov = _number("fov", fov, high=170.0, low_open=True)
    if fov >= 170.0:
        raise ValueError(f"simulate_scan: parameter 'fov' = {fov!r} is out of range: > 0 and < 170")
    rho = _number("noise", noise)
    correlation = _number("correlation", correlation, high=1e4)
    stripes = _number("stripes", stripes, high=1e3)
    outliers = _number("outliers", outliers, high=0.5)
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)

    data = read_mesh(mesh)
    V0, F0 = data.V.astype(np.float64), data.F
    if len(F0) == 0:
        raise ValueError("simulate_scan: the mesh has no faces to scan")
    camera, right, up, forward, pitch = _camera(V0, (az, el), fov, width, height, settings.margin)
    D = _rays(right, up, forward, pitch, width, height)
    hit, face, u, v = _cast(V0, F0, camera, D)
    # the hit in double precision, on the clean triangle: p = (1 - u - v) A + u B + v C
    T = V0[F0[face[hit]]]
    uu, vv = u[hit][:, None], v[hit][:, None]
    P = (1.0 - uu - vv) * T[:, 0] + uu * T[:, 1] + vv * T[:, 2]
    normal = np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0])
    ray = P - camera
    ray /= np.linalg.norm(ray, axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        cos = np.abs(np.einsum("ij,ij->i", normal, ray)) / np.linalg.norm(normal, axis=1)
    limit = math.cos(math.radians(settings.max_incidence_deg))
    seen = np.zeros_like(hit)
    seen[hit] = np.nan_to_num(cos) >= limit
    index = np.full(hit.shape, -1, dtype=np.int64)
    index[hit] = np.arange(int(hit.sum()))
    index[~seen] = -1
    F = _grid_faces(index, P)
    F = F[_incidence_cos(P, F, camera) >= limit]
    F = _keep_large_components(F, len(P), int(settings.min_component_faces))
    if len(F) == 0:
        raise ValueError(f"simulate_scan: the camera at view {az:g},{el:g} (fov {fov:g} deg, {width}x{height}) sees "
                         "no surface of the mesh that faces it")
    used = np.unique(F)
    renumber = np.full(len(P), -1, dtype=np.int64)
    renumber[used] = np.arange(used.size)
    F = renumber[F]
    rows, cols = np.nonzero(hit)
    pixels = np.stack([rows, cols], 1)[used]
    P, ray = P[used], ray[used]
    depth = (P - camera) @ forward

    from .noise import mean_edge_length

    h = mean_edge_length(P, F)
    level = rho * h if noise_in_edges else rho
    z = _field(rng, (height, width), correlation)
    z /= float(np.sqrt(np.mean(z**2)))
    e = z[pixels[:, 0], pixels[:, 1]]
    if stripes > 0:
        e = e + stripes * rng.standard_normal(height)[pixels[:, 0]]
    g = (depth / float(np.median(depth))) ** settings.depth_power
    e = g * e
    rms = float(np.sqrt(np.mean(e**2)))
    e = level * e / rms if rms > 0 else np.zeros_like(e)
    count = int(round(outliers * len(P)))
    if count:
        picked = rng.choice(len(P), size=count, replace=False)
        e[picked] += rng.choice(np.array([-1.0, 1.0]), size=count) * rng.uniform(3.0, 6.0, size=count) * level
    return RangeScan(V=P + e[:, None] * ray, V_clean=P, F=F, pixels=pixels, rays=ray, depth=depth, camera=camera,
                     resolution=(width, height), mean_edge=float(h), rho=float(level))

"""The pictures: :func:`render_mesh` (one panel) and :func:`render_comparison` (meshes, heat maps, one PNG)."""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from .backends import _draw, _prestart
from .camera import Camera, _bounding_ball, _check_size, camera_along, camera_around, frame_camera, mean_normal
from .heatmaps import _arrays, _bar_top, vertex_error
from .panels import _compose
from .raster import _job
from .settings import DEFAULT_SETTINGS, RenderSettings

__all__ = ["RenderResult", "render_mesh", "render_comparison"]


@dataclass
class RenderResult:
    """What :func:`render_comparison` drew.

    Attributes
    ----------
    path : Path
        The PNG written.
    backend : str
        ``'open3d'`` or ``'matplotlib'``: the rasteriser that ran.
    backend_detail : str
        The device (e.g. ``Filament Vulkan on llvmpipe``) or why the fallback ran.
    panels : list of ndarray, each (height, width, 3) uint8
        The pictures, left to right, as pasted into the PNG.
    boxes : list of (row, column, height, width)
        Where each panel lies in the PNG.
    titles : list of str
    errors : list of ndarray
        The per-vertex values of the heat-map panels, in order (of the vertices in view when zoomed).
    error_mode : str or None
        ``'vertex'`` or ``'nearest'`` (see :func:`vertex_error`), None without heat maps.
    vmax : float or None
        The top of the colour bar.
    camera : Camera
        The camera shared by every panel.
    heat : {'error', 'change'} or None
        What the heat maps show: the error against ``reference``, or (``show_change``) the
        displacement of each later mesh from the first.
    percentile : float or None
        The percentile of the shown values the colour bar tops at (None when ``vmax`` was given).
    zoom : (centre (3,), radius in mesh units) or None
    facing : (3,) or None
        The mean normal the camera looks along (``view='facing'``, or ``zoom`` without a
        view); None when a view was used (given, or the normals cancel out).
    """

    path: Path
    backend: str
    backend_detail: str
    panels: list[np.ndarray]
    boxes: list[tuple[int, int, int, int]]
    titles: list[str]
    errors: list[np.ndarray] = field(default_factory=list)
    error_mode: str | None = None
    vmax: float | None = None
    camera: Camera | None = None
    heat: str | None = None
    percentile: float | None = None
    zoom: tuple[tuple[float, float, float], float] | None = None
    facing: tuple[float, float, float] | None = None


def render_mesh(
    mesh: Any,
    size: tuple[int, int] = (400, 400),
    camera: Camera | None = None,
    *,
    error: np.ndarray | None = None,
    vmax: float | None = None,
    cmap: str = "viridis",
    backend: str = "auto",
    settings: RenderSettings | None = None,
) -> np.ndarray:
    """One picture ``(height, width, 3) uint8`` of a mesh on a white background.

    Without ``error``: light grey, shaded by :func:`~meshdenoise.render.raster._shade`'s light. With ``error`` (one
    value per vertex): an unlit heat map on the colour map ``cmap`` from 0 to ``vmax``
    (default: the largest error). ``camera`` defaults to :func:`frame_camera` of this mesh
    alone; pass one camera to compare meshes. ``backend`` and ``settings`` as in
    :func:`render_comparison`.

    Examples
    --------
    >>> from meshdenoise.shapes import icosphere
    >>> img = render_mesh(icosphere(1), size=(32, 32), backend="matplotlib")
    >>> img.shape, bool((img < 255).any())
    ((32, 32, 3), True)
    """
    size = _check_size(size)
    V, F = _arrays(mesh, "mesh")
    camera = camera or frame_camera([V], size)
    images, _, _ = _draw([_job(V, F, camera, error, vmax, cmap)], size, camera, backend,
                         settings=settings or DEFAULT_SETTINGS)
    return images[0]


def _zoom_ball(zoom, V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, float]:
    """``zoom = (centre, radius)`` -> (centre point (3,), radius in mesh units).

    ``centre`` is a vertex index of the first mesh or a point (3,); ``radius`` is in mean
    edge lengths of the first mesh.
    """
    from ..noise import mean_edge_length

    try:
        centre, radius = zoom
    except (TypeError, ValueError):
        raise ValueError(f"zoom must be (centre, radius): a vertex index or a point (x, y, z), and a radius in "
                         f"mean edge lengths; got {zoom!r}") from None
    if isinstance(radius, (bool, np.bool_)) or not isinstance(radius, (int, float, np.integer, np.floating)) \
            or not (np.isfinite(radius) and radius > 0):
        raise ValueError(f"zoom radius must be a number > 0 (mean edge lengths), got {radius!r}")
    if isinstance(centre, (int, np.integer)) and not isinstance(centre, (bool, np.bool_)):
        if not 0 <= centre < V.shape[0]:
            raise ValueError(f"zoom centre: vertex {centre} does not exist (the first mesh has {V.shape[0]} vertices)")
        point = V[int(centre)]
    else:
        try:
            point = np.asarray(centre, dtype=np.float64)
        except (TypeError, ValueError):
            point = np.zeros(0)
        if point.shape != (3,) or not np.isfinite(point).all():
            raise ValueError(f"zoom centre must be a vertex index or a finite point (x, y, z), got {centre!r}")
    return point, float(radius) * mean_edge_length(V, F)


def _crop(V: np.ndarray, F: np.ndarray, centre: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The faces with a vertex within ``radius`` of ``centre``, compacted: (V', F', kept vertex indices)."""
    near = np.sum((V - centre) ** 2, axis=1) <= radius**2
    faces = F[near[F].any(axis=1)]
    keep = np.unique(faces)
    index = np.full(V.shape[0], -1, dtype=np.int64)
    index[keep] = np.arange(keep.size)
    return V[keep], index[faces], keep


def render_comparison(
    meshes: Sequence[Any],
    out_png: str | os.PathLike,
    reference: Any = None,
    titles: Sequence[str] | None = None,
    *,
    size: tuple[int, int] = (400, 400),
    view: tuple[float, float] | str | None = None,
    error_of: str = "last",
    error_mode: str = "auto",
    vmax: float | None = None,
    cmap: str = "viridis",
    backend: str = "auto",
    show_change: bool = False,
    percentile: float | None = None,
    zoom: tuple[Any, float] | None = None,
    settings: RenderSettings | None = None,
) -> RenderResult:
    """Meshes side by side from one camera, then heat maps of their error or change, in one PNG.

    For ``meshes = [noisy, denoised]`` and a clean ``reference`` this is the before /
    after / error picture: two lit panels and a heat map of the denoised mesh's error with
    a colour bar in mesh units. Without a reference (a real scan has none),
    ``show_change=True`` draws instead the displacement of the later meshes from the first
    (before / after / how far each vertex moved). The camera frames all meshes (and the
    reference) together, so the same mesh gives the same panel wherever it appears.

    Parameters
    ----------
    meshes : sequence of meshes
        ``(V, F)`` tuples, any type :func:`meshdenoise.adapters.read_mesh` accepts, or file paths.
    out_png : path
        Written atomically (temporary file, then rename) with the mode of any other output
        (0666 minus the umask, or the replaced file's); must end in ``.png``.
    reference : mesh, optional
        The clean mesh the errors are measured against (see :func:`vertex_error`).
    titles : sequence of str, optional
        One per mesh (default: file names, else "mesh 1", "mesh 2", ...).
    size : (width, height)
        Pixels of one panel.
    view : (azimuth, elevation) or 'facing', optional
        Degrees; see :func:`frame_camera`. ``'facing'``: look along the area-weighted mean
        normal (:func:`mean_normal`) of the first mesh (of its faces in view with ``zoom``),
        so an open surface such as a range scan faces the camera; when its normals cancel out
        (a closed mesh) the view is ``(0, 0)``. Default: ``'facing'`` with ``zoom``, else
        ``(0, 0)`` (from +z, +y up, MeshLab's default). A view given is always used.
    error_of : {'last', 'all'}
        Heat maps of the last mesh only, or of every mesh (every later mesh with
        ``show_change``); one shared colour bar.
    error_mode : {'auto', 'vertex', 'nearest'}
        See :func:`vertex_error`; with ``show_change`` the first mesh plays the reference.
    vmax : float, optional
        Top of the colour bar; default the ``percentile`` of the values shown. Larger values
        get the top colour and the bar an arrow.
    cmap : str
        A matplotlib colour map (perceptually uniform ones, e.g. viridis, read best).
    backend : {'auto', 'open3d', 'matplotlib'}
        ``'auto'``: Open3D, else matplotlib with a warning (see the module's notes).
    show_change : bool
        Without ``reference``: heat maps of the displacement from the first mesh.
    percentile : float in (0, 100], optional
        Where the colour bar tops when ``vmax`` is not given: 100 (the maximum) for errors
        against a reference, 99 for a change (a few outliers would otherwise leave the
        rest of the map dark). Written on the colour bar.
    zoom : (centre, radius), optional
        Look at a detail: ``centre`` a vertex index of the first mesh or a point (x, y, z),
        ``radius`` in mean edge lengths of the first mesh. Only the faces with a vertex in
        that ball are drawn, filling the picture; heat-map statistics and the colour bar are
        those of the vertices in view. Without ``view`` the camera looks along the
        area-weighted mean normal of the first mesh's faces in the ball (``'facing'``), so a
        detail facing sideways is not seen edge-on; when those normals cancel out (less than
        5 % of the area is net facing one way, e.g. a ball around a whole thin part) it
        keeps the view ``(0, 0)``.
    settings : RenderSettings, optional
        Where a GPU is looked for, Open3D's time per frame and tries, the z-buffer's batches
        (:class:`~meshdenoise.render.RenderSettings`); default ``RenderSettings()``.

    Returns
    -------
    RenderResult

    Examples
    --------
    >>> import tempfile, pathlib
    >>> from meshdenoise.shapes import icosphere
    >>> V, F = icosphere(1)
    >>> out = pathlib.Path(tempfile.mkdtemp()) / "cmp.png"
    >>> res = render_comparison([(V * 1.1, F), (V * 1.01, F)], out, reference=(V, F),
    ...                         size=(48, 48), backend="matplotlib")
    >>> res.titles, res.error_mode, round(res.vmax, 6), out.is_file()
    (['mesh 1', 'mesh 2', 'error of mesh 2'], 'vertex', 0.01, True)
    >>> res = render_comparison([(V, F), (V * 1.02, F)], out, show_change=True, size=(48, 48), backend="matplotlib")
    >>> res.titles[-1], res.heat, res.percentile, round(res.vmax, 6)
    ('change: mesh 1 → mesh 2', 'change', 99.0, 0.02)
    """
    size = _check_size(size)
    if view is not None and view != "facing":
        try:
            view = (float(view[0]), float(view[1])) if len(view) == 2 and not isinstance(view, str) else None
        except (TypeError, ValueError):
            view = None
        if view is None or not all(np.isfinite(view)):
            raise ValueError("view must be (azimuth, elevation) in degrees or 'facing'")
    if isinstance(meshes, (str, os.PathLike)) or (isinstance(meshes, tuple) and len(meshes) == 2
                                                  and isinstance(meshes[0], np.ndarray)):
        meshes = [meshes]  # one mesh given bare
    meshes = list(meshes)
    if not meshes:
        raise ValueError("render_comparison needs at least one mesh")
    if error_of not in ("last", "all"):
        raise ValueError(f"error_of must be 'last' or 'all', got {error_of!r}")
    if percentile is not None and (isinstance(percentile, (bool, np.bool_))
                                   or not isinstance(percentile, (int, float, np.integer, np.floating))
                                   or not 0 < percentile <= 100):
        raise ValueError(f"percentile must be a number in (0, 100], got {percentile!r}")
    if vmax is not None and not (np.isfinite(vmax) and vmax > 0):
        raise ValueError(f"vmax must be a finite number > 0, got {vmax!r}")
    out_png = Path(out_png)
    if out_png.suffix.lower() != ".png":
        raise ValueError(f"{out_png}: the picture is written as PNG, so the name must end in .png")
    if titles is None:
        titles = [Path(m).name if isinstance(m, (str, os.PathLike)) else f"mesh {i + 1}" for i, m in enumerate(meshes)]
    titles = [str(t) for t in titles]
    if len(titles) != len(meshes):
        raise ValueError(f"titles: {len(titles)} given for {len(meshes)} meshes")
    settings = settings or DEFAULT_SETTINGS
    child = _prestart(backend, size, settings)  # Open3D starts up while the meshes are read and the panels prepared
    try:
        return _render_comparison(meshes, out_png, reference, titles, size, view, error_of, error_mode, vmax, cmap,
                                  backend, show_change, percentile, zoom, child, settings)
    finally:
        if child is not None:
            child.close()


def _render_comparison(meshes, out_png, reference, titles, size, view, error_of, error_mode, vmax, cmap, backend,
                       show_change, percentile, zoom, child, settings) -> RenderResult:
    arrays = [_arrays(m, f"mesh {i + 1}") for i, m in enumerate(meshes)]
    ref = _arrays(reference, "reference") if reference is not None else None

    # heat maps: (index of the mesh, per-vertex values, title)
    heat, maps, mode_used = None, [], None
    if ref is not None:
        heat = "error"
        for k in (range(len(arrays)) if error_of == "all" else [len(arrays) - 1]):
            err, mode_used = vertex_error(arrays[k], ref, error_mode)
            maps.append((k, err, f"error of {titles[k]}"))
    elif show_change and len(arrays) > 1:
        heat = "change"
        for k in (range(1, len(arrays)) if error_of == "all" else [len(arrays) - 1]):
            err, mode_used = vertex_error(arrays[k], arrays[0], error_mode)
            maps.append((k, err, f"change: {titles[0]} → {titles[k]}"))

    # the camera: along the mean normal of what is shown of the first mesh with faces ("facing": the default
    # with zoom), else from the view given (default (0, 0))
    fixed = view if isinstance(view, tuple) else (0.0, 0.0)
    want_facing = view == "facing" or (view is None and zoom is not None)
    ball, facing = None, None
    if zoom is not None:
        centre, radius = _zoom_ball(zoom, *arrays[0])
        ball = (tuple(float(c) for c in centre), radius)
        cropped = [_crop(V, F, centre, radius) for V, F in arrays]
        if all(c[1].shape[0] == 0 for c in cropped):
            raise ValueError(f"zoom: no face has a vertex within {radius:.4g} (mesh units) of {tuple(centre)}")
        shown = [(c[0], c[1]) for c in cropped]
        maps = [(k, err[cropped[k][2]], title) for k, err, title in maps]
    else:
        shown = arrays
        centre, radius = _bounding_ball([V for V, _ in arrays] + ([ref[0]] if ref else []))
    if want_facing:
        facing = mean_normal(*next(m for m in shown if m[1].shape[0]))
    camera = (camera_along(centre, radius, facing, size) if facing is not None
              else camera_around(centre, radius, size, fixed))
    used_percentile = None
    if maps:
        if vmax is None:
            used_percentile = float(percentile if percentile is not None else (100.0 if heat == "error" else 99.0))
            vmax = _bar_top([err for _, err, _ in maps], used_percentile)
        vmax = float(vmax)
    jobs = [_job(V, F, camera) for V, F in shown if F.shape[0]]
    panel_titles = [t for t, (_, F) in zip(titles, shown) if F.shape[0]]
    column = np.cumsum([F.shape[0] > 0 for _, F in shown]) - 1  # mesh k's geometry panel
    errors, under = [], []
    for k, err, title in maps:
        if shown[k][1].shape[0]:
            jobs.append(_job(*shown[k], camera, err, vmax, cmap))
            panel_titles.append(title)
            errors.append(err)
            under.append(int(column[k]))
    panels, which, detail = _draw(jobs, size, camera, backend, child, settings)
    if heat == "change":
        label = "distance to the first mesh" if mode_used == "nearest" else "displacement from the first mesh"
    else:
        label = "distance to reference" if mode_used == "nearest" else "vertex displacement"
    boxes = _compose(out_png, panels, panel_titles, errors, vmax, cmap, label, used_percentile, under)
    return RenderResult(out_png, which, detail, panels, boxes, panel_titles, errors, mode_used,
                        vmax if maps else None, camera, heat, used_percentile, ball, facing)

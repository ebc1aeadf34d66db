"""Pictures of meshes: headless renders, error heat maps, before / after / error side by side.

Two rasterisers draw the same camera:

``open3d``
    Open3D's :class:`~open3d.visualization.rendering.OffscreenRenderer` (Filament): one
    renderer draws every panel, unlit, without shadow, SSAO or MSAA passes. On a machine
    without a GPU it runs on Mesa's software Vulkan driver (lavapipe/llvmpipe), from the
    Debian packages ``libvulkan1`` and ``mesa-vulkan-drivers``. It runs in a child process,
    started before the panels are prepared, under time limits (``MESHDENOISE_RENDER_STARTUP``,
    default 20 s, for the renderer to start; a per-frame allowance; ``MESHDENOISE_RENDER_TIMEOUT``,
    default 60 s, in all): there a missing driver aborts the process instead of raising, and
    with Open3D 0.20 on Mesa 22 llvmpipe a frame now and then stalls (it is drawn again once
    by a fresh child). Without a Vulkan loader or driver no child starts, and a failure is
    remembered for the rest of the process, so the fallback comes at once.
``auto`` (the default)
    Open3D when this machine has a GPU, else matplotlib at once: on Linux without a GPU
    device node (``/dev/dri/renderD*``, ``/dev/nvidia*``, ``/dev/dxg``) Open3D could only
    draw on the CPU Vulkan driver, whose stalls made a three-panel render wait 17-24 s
    before falling back. The check looks at a few device files (well under a millisecond).
    ``backend='open3d'`` (or ``MESHDENOISE_RENDER_BACKEND=open3d``) still tries Open3D there.
``matplotlib``
    A pure-software fallback: the same pinhole camera and a z-buffer in numpy (pixel centres
    sampled, perspective-correct depth and colours), composed and coloured with matplotlib.
    Deterministic; about as fast as Open3D on llvmpipe.

Both backends draw unlit colours computed here: the geometry panels are shaded by a light
from the camera's upper left (Lambert, two-sided), the heat maps are not shaded at all, so
a pixel's colour is the colour bar's colour for the error interpolated across the triangle.
(Open3D's lit shader also stalls for minutes on llvmpipe.)

The package's modules: :mod:`~meshdenoise.render.pictures` (:func:`render_mesh`,
:func:`render_comparison`), :mod:`~meshdenoise.render.camera` (framing, the view along a detail's
mean normal), :mod:`~meshdenoise.render.heatmaps` (the error or change per vertex, its colours),
:mod:`~meshdenoise.render.raster` (shading and the software z-buffer),
:mod:`~meshdenoise.render.offscreen` (Open3D in a child process),
:mod:`~meshdenoise.render.backends` (which one draws), :mod:`~meshdenoise.render.panels` (the PNG)
and :mod:`~meshdenoise.render.settings` (:class:`RenderSettings`, passed in).
"""

from __future__ import annotations

from .backends import BACKENDS  # the pipeline's render step checks its backend against these
from .camera import Camera, camera_along, camera_around, frame_camera, mean_normal
from .heatmaps import ERROR_MODES, error_colors, vertex_error  # ERROR_MODES: the modes vertex_error takes
from .offscreen import RenderError
from .panels import new_file_mode, panel_grid  # new_file_mode: the PNG's mode, for the pipeline's render step
from .pictures import RenderResult, render_comparison, render_mesh
from .settings import RenderSettings

__all__ = [
    "Camera",
    "RenderResult",
    "frame_camera",
    "camera_around",
    "camera_along",
    "mean_normal",
    "vertex_error",
    "error_colors",
    "render_mesh",
    "render_comparison",
    "panel_grid",
    "RenderError",
    "RenderSettings",
]

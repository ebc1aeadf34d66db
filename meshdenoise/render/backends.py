"""Which rasteriser draws: the back end asked for, ``auto``'s choice, and the fallback to matplotlib.

The back ends' functions are looked up on their modules (``offscreen._draw_open3d``,
``raster._draw_matplotlib``) when called, so that a test can stand in for one.
"""

from __future__ import annotations

import os
import warnings

import numpy as np

from . import offscreen, raster
from .camera import Camera
from .settings import DEFAULT_SETTINGS, RenderSettings

BACKENDS = ("auto", "open3d", "matplotlib")


# Why Open3D cannot be used in this process, once known: then 'auto' goes to matplotlib at once.
_OPEN3D_VERDICT: str | None = None


def _resolve_backend(backend: str) -> str:
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
    if backend == "auto":
        env = os.environ.get("MESHDENOISE_RENDER_BACKEND", "auto")
        if env not in BACKENDS:
            raise ValueError(f"MESHDENOISE_RENDER_BACKEND must be one of {BACKENDS}, got {env!r}")
        backend = env
    return backend


def _prestart(backend: str, size: tuple[int, int],
              settings: RenderSettings = DEFAULT_SETTINGS) -> offscreen._Child | None:
    """The Open3D child, started now when it will be used, so that it starts while the panels are prepared."""
    backend = _resolve_backend(backend)
    if backend == "matplotlib" or (backend == "auto" and (_OPEN3D_VERDICT is not None or offscreen._no_gpu(settings))) \
            or offscreen._vulkan_missing():
        return None
    return offscreen._Child(size)


def _draw(jobs: list[dict], size, camera: Camera, backend: str, child: offscreen._Child | None = None,
          settings: RenderSettings = DEFAULT_SETTINGS) -> tuple[list[np.ndarray], str, str]:
    """Pictures of the jobs with the chosen backend; 'auto' falls back to matplotlib with a warning."""
    global _OPEN3D_VERDICT
    backend = _resolve_backend(backend)
    reason = "requested"
    cpu_only = offscreen._no_gpu(settings) if backend == "auto" and _OPEN3D_VERDICT is None else None
    if backend == "auto" and _OPEN3D_VERDICT is not None:  # failed before in this process: do not wait again
        reason = f"Open3D failed earlier in this process: {_OPEN3D_VERDICT}"
        warnings.warn(f"{reason}; drawing with the matplotlib software rasteriser instead", UserWarning, stacklevel=3)
    elif cpu_only:  # headless without a GPU: the expected case, said in backend_detail, not a warning
        reason = cpu_only
    elif backend in ("auto", "open3d"):
        try:
            images, detail = offscreen._draw_open3d(jobs, size, camera, offscreen._render_timeout(), child, settings)
            return images, "open3d", detail
        except offscreen.RenderError as exc:
            _OPEN3D_VERDICT = str(exc)
            if backend == "open3d":
                raise
            reason = str(exc)
            warnings.warn(f"{reason}; drawing with the matplotlib software rasteriser instead "
                          "(set MESHDENOISE_RENDER_BACKEND=matplotlib to skip Open3D)", UserWarning, stacklevel=3)
    images = [raster._draw_matplotlib(job, size, camera, settings.zbuffer_chunk) for job in jobs]
    return images, "matplotlib", f"matplotlib {raster._mpl_version()} software rasteriser ({reason})"

"""The rasterisers' settings: where a GPU is looked for, how long Open3D is waited for, the z-buffer's batches.

Passed to :func:`~meshdenoise.render.render_comparison` and :func:`~meshdenoise.render.render_mesh`
as ``settings=RenderSettings(...)``; every command uses the defaults. The time limits a user sets
for one run stay environment variables (``MESHDENOISE_RENDER_STARTUP``, ``MESHDENOISE_RENDER_TIMEOUT``).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class RenderSettings:
    """How the pictures are drawn, where the defaults do not fit a machine or a test.

    Attributes
    ----------
    devices : str
        Where GPU device nodes are looked for (``backend='auto'`` draws with matplotlib at
        once when none is there).
    gpu_nodes : tuple of str
        Glob patterns, under ``devices``, of a GPU's device node: Mesa/DRM GPUs
        (``dri/renderD*``, ``dri/card*``), NVIDIA's driver (``nvidia[0-9]*``), WSL2's GPU (``dxg``).
    frame_seconds : float
        A frame's allowance in Open3D's child process: this plus ``frame_seconds_per_triangle``
        per triangle (:meth:`frame_allowance`).
    frame_seconds_per_triangle : float
        Measured 2 s for 1.3M triangles at 400x400 under a load of 15 on 2 cores.
    attempts : int
        Open3D children tried when a frame stalls (stalls come at random: a fresh child draws
        the rest), before matplotlib draws.
    zbuffer_chunk : int
        Candidate pixels per vectorised batch of the software z-buffer (1,000,000: about
        100 MB of temporaries); the picture does not depend on it.

    Examples
    --------
    >>> RenderSettings().frame_allowance(0), RenderSettings(frame_seconds=1.0).frame_seconds
    (5.0, 1.0)
    >>> RenderSettings(attempts=0)
    Traceback (most recent call last):
    ...
    ValueError: RenderSettings: attempts must be an integer >= 1, got 0
    """

    devices: str = "/dev"
    gpu_nodes: tuple[str, ...] = ("dri/renderD*", "dri/card*", "nvidia[0-9]*", "dxg")
    frame_seconds: float = 5.0
    frame_seconds_per_triangle: float = 1e-5
    attempts: int = 2
    zbuffer_chunk: int = 1_000_000

    def __post_init__(self) -> None:
        for name in ("frame_seconds", "frame_seconds_per_triangle"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not value >= 0:
                raise ValueError(f"RenderSettings: {name} must be a number of seconds >= 0, got {value!r}")
        for name in ("attempts", "zbuffer_chunk"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"RenderSettings: {name} must be an integer >= 1, got {value!r}")

    def frame_allowance(self, triangles: int) -> float:
        """Seconds a frame of ``triangles`` triangles may take in Open3D's child before it counts as stalled."""
        return self.frame_seconds + self.frame_seconds_per_triangle * triangles


DEFAULT_SETTINGS = RenderSettings()

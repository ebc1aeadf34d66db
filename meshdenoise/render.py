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
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from .adapters import read_mesh
from .io import atomic_path, load_mesh

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
]

BACKGROUND = (1.0, 1.0, 1.0)
MESH_COLOR = (0.78, 0.78, 0.78)
BACKENDS = ("auto", "open3d", "matplotlib")
ERROR_MODES = ("auto", "vertex", "nearest")


# --- camera ------------------------------------------------------------------------------------
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


# --- errors and colours -------------------------------------------------------------------------
def vertex_error(mesh: Any, reference: Any, mode: str = "auto") -> tuple[np.ndarray, str]:
    """Per-vertex error of ``mesh`` against ``reference``.

    Parameters
    ----------
    mesh, reference : a ``(V, F)`` tuple, any mesh type of :func:`meshdenoise.adapters.read_mesh`, or a file path
    mode : {'auto', 'vertex', 'nearest'}
        ``'vertex'``: :math:`e_i = \\|x_i - y_i\\|`, the displacement of vertex *i* from the
        reference's vertex *i* (the meshes must share vertex order, as noisy and denoised
        copies of one mesh do). ``'nearest'``: :math:`e_i = \\min_{y \\in S} \\|x_i - y\\|`, the
        distance to the nearest point of the reference surface *S* (Open3D's
        ``RaycastingScene.compute_distance``, in float32). ``'auto'``: ``'vertex'`` when both
        meshes have the same faces (hence the same vertex order), else ``'nearest'``.

    Returns
    -------
    error : ndarray, shape (n,), float64
    mode : str
        The mode used.

    Examples
    --------
    >>> import numpy as np
    >>> V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]); F = np.array([[0, 1, 2]])
    >>> err, how = vertex_error((V + [0, 0, 0.5], F), (V, F))
    >>> err.tolist(), how
    ([0.5, 0.5, 0.5], 'vertex')
    >>> err, how = vertex_error((V[[1, 2, 0]] + [0, 0, 0.25], F), (V, F), mode="nearest")
    >>> np.round(err, 6).tolist(), how
    ([0.25, 0.25, 0.25], 'nearest')
    """
    if mode not in ERROR_MODES:
        raise ValueError(f"error mode must be one of {ERROR_MODES}, got {mode!r}")
    V, F = _arrays(mesh, "mesh")
    Vr, Fr = _arrays(reference, "reference")
    if mode == "auto":
        mode = "vertex" if F.shape == Fr.shape and np.array_equal(F, Fr) else "nearest"
    if mode == "vertex":
        if V.shape != Vr.shape:
            raise ValueError(
                f"error mode 'vertex' needs the same vertices in the same order: the mesh has {V.shape[0]} "
                f"vertices, the reference {Vr.shape[0]}; use mode='nearest'"
            )
        return np.linalg.norm(V - Vr, axis=1), mode
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(Vr.astype(np.float32)), o3d.core.Tensor(Fr.astype(np.uint32)))
    dist = scene.compute_distance(o3d.core.Tensor(V.astype(np.float32))).numpy()
    return dist.astype(np.float64), mode


def error_colors(error: np.ndarray, vmax: float, cmap: str = "viridis") -> np.ndarray:
    """RGB colours ``(n, 3)`` in [0, 1] of errors on the colour bar from 0 to ``vmax``.

    Errors above ``vmax`` take the top colour; the colour bar then shows an arrow (it is
    drawn with ``extend='max'``), so a saturated picture is never mistaken for a scale.

    Examples
    --------
    >>> error_colors(np.array([0.0, 1.0]), vmax=1.0, cmap="gray").tolist()
    [[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]]
    """
    import matplotlib

    err = np.asarray(error, dtype=np.float64)
    if not np.isfinite(vmax) or vmax <= 0:
        raise ValueError(f"vmax must be a finite number > 0, got {vmax!r}")
    if err.size and (not np.isfinite(err).all() or err.min() < 0):
        raise ValueError("errors must be finite and >= 0")
    return matplotlib.colormaps[cmap](np.clip(err / vmax, 0.0, 1.0))[:, :3]


def _arrays(mesh: Any, what: str) -> tuple[np.ndarray, np.ndarray]:
    """(V, F) of a mesh object or file; a mesh without faces cannot be drawn."""
    if isinstance(mesh, (str, os.PathLike)):
        m = load_mesh(mesh)
        V, F = m.V, m.F
        if F.shape[0] == 0:
            raise ValueError(f"{mesh}: {what} has no faces, so there is no surface to render")
        return V, F
    data = read_mesh(mesh)
    return data.V, data.F


def new_file_mode(path: str | os.PathLike) -> int:
    """The permission bits an output written to ``path`` gets: the replaced file's, else 0666 minus the umask.

    As :class:`meshdenoise.io.atomic_path` gives every output (a temporary file from
    ``mkstemp`` is private, 0600, and would keep that mode through the rename).
    """
    from .io import _UMASK

    path = Path(path)
    return path.stat().st_mode & 0o7777 if path.exists() else 0o666 & ~_UMASK


# --- backends ------------------------------------------------------------------------------------
class RenderError(RuntimeError):
    """Open3D's OffscreenRenderer failed or did not finish in time; the message says which and why."""


def _shade(V: np.ndarray, F: np.ndarray, camera: Camera, base=MESH_COLOR) -> np.ndarray:
    """Per-vertex colours of a grey surface lit by a light from the camera's upper left.

    Lambert's law, two-sided (the back of an open surface is lit like its front, as in
    MeshLab): :math:`c_i = c_0 (0.25 + 0.75 |n_i \\cdot l|)`. Computed here for both backends,
    so they draw the same shades.
    """
    from .geometry import vertex_normals

    s, t, d = camera.axes()
    light = d - 0.5 * t + 0.3 * s
    light /= np.linalg.norm(light)
    n = vertex_normals(V, F)
    return np.asarray(base)[None, :] * (0.25 + 0.75 * np.abs(n @ light))[:, None]


_CHILD = r"""
import sys
sys.path.insert(0, sys.argv[1])
from meshdenoise.render import _open3d_child
_open3d_child(int(sys.argv[2]), int(sys.argv[3]))
"""


def _open3d_child(w: int, h: int) -> None:
    """Child process: make one Open3D renderer of ``w`` x ``h``, then draw the panels of the job named on stdin.

    Prints ``MESHDENOISE_READY`` once the renderer exists, then reads one line
    ``job.npz<TAB>out_dir<TAB>first`` and draws panels ``first``, ``first + 1``, ... unlit,
    saving each as ``out_dir/frame{k}.npy`` and printing ``MESHDENOISE_FRAME k`` as soon as
    it is drawn: the parent tells a renderer that never starts from a slow frame and keeps
    the pictures drawn before a stall. The renderer starts while the parent still prepares
    the panels.
    """
    started = time.perf_counter()
    import open3d as o3d
    import open3d.visualization.rendering as rendering

    renderer = rendering.OffscreenRenderer(w, h)
    scene = renderer.scene
    scene.set_background([*BACKGROUND, 1.0])
    view = scene.view
    view.set_post_processing(False)  # no tone mapping: pixels are the colours given
    # nothing is lit (shading is baked into the colours): no shadow map pass, no SSAO, no MSAA.
    # The shadow pass alone made a frame of a 164k-vertex mesh 4x slower on llvmpipe.
    view.set_shadowing(False)
    view.set_ambient_occlusion(False)
    view.set_antialiasing(False)
    scene.scene.enable_sun_light(False)
    scene.scene.enable_indirect_light(False)
    print(f"MESHDENOISE_READY {time.perf_counter() - started:.2f} s", flush=True)
    line = sys.stdin.readline().rstrip("\n")
    if not line:
        return
    job_path, out_dir, first = line.split("\t")
    job = np.load(job_path)
    center, eye, up = job["center"], job["eye"], job["up"]
    fov, near, far = (float(x) for x in job["lens"])
    renderer.setup_camera(fov, center, eye, up, near, far)
    material = rendering.MaterialRecord()
    material.shader = "defaultUnlit"  # the lit shader stalls for minutes on llvmpipe; shading is baked in
    for k in range(int(first), int(job["count"])):
        mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(job[f"V{k}"].astype(np.float64)),
                                         o3d.utility.Vector3iVector(job[f"F{int(job['faces'][k])}"]))
        mesh.vertex_colors = o3d.utility.Vector3dVector(job[f"C{k}"].astype(np.float64) / 255.0)
        scene.clear_geometry()
        scene.add_geometry("mesh", mesh, material)
        image = np.asarray(renderer.render_to_image())[:, :, :3].copy()
        np.save(os.path.join(out_dir, f"frame{k}.npy"), image)
        print(f"MESHDENOISE_FRAME {k} {time.perf_counter() - started:.2f} s", flush=True)
    print("MESHDENOISE_RENDERED", flush=True)
    scene.clear_geometry()  # a renderer destroyed while showing geometry aborts the process


def _render_timeout() -> float:
    return _seconds("MESHDENOISE_RENDER_TIMEOUT", "60")


def _seconds(name: str, default: str) -> float:
    text = os.environ.get(name, default)
    try:
        value = float(text)
    except ValueError:
        raise ValueError(f"{name} must be a number of seconds, got {text!r}") from None
    if value <= 0:
        raise ValueError(f"{name} must be > 0 seconds, got {text!r}")
    return value


# Why Open3D cannot be used in this process, once known: then 'auto' goes to matplotlib at once.
_OPEN3D_VERDICT: str | None = None
STARTUP_SECONDS = "20"  # default MESHDENOISE_RENDER_STARTUP: import, Filament and the Vulkan device, loaded machine
FRAME_SECONDS = 5.0  # a frame's allowance: this plus FRAME_SECONDS_PER_TRIANGLE per triangle
FRAME_SECONDS_PER_TRIANGLE = 1e-5  # measured 2 s for 1.3M triangles at 400x400 under a load of 15 on 2 cores
ATTEMPTS = 2  # a stalled frame is drawn again by a fresh child (stalls come at random); then matplotlib


def _vulkan_missing() -> str | None:
    """Why Open3D's headless renderer cannot start here (no Vulkan loader or driver), or None; no process started."""
    import ctypes.util
    import glob

    if os.environ.get("VK_ICD_FILENAMES") or os.environ.get("VK_DRIVER_FILES"):
        return None  # drivers named explicitly: let the renderer try
    if sys.platform != "linux":
        return None
    if ctypes.util.find_library("vulkan") is None:
        return "the Vulkan loader libvulkan.so.1 is not installed"
    dirs = ["/usr/share/vulkan/icd.d", "/etc/vulkan/icd.d", "/usr/local/share/vulkan/icd.d",
            *(os.path.join(d, "vulkan/icd.d") for d in os.environ.get("XDG_DATA_DIRS", "").split(":") if d)]
    if not any(glob.glob(os.path.join(d, "*.json")) for d in dirs):
        return "no Vulkan driver is installed (no ICD file in /usr/share/vulkan/icd.d)"
    return None


DEVICES = "/dev"  # where GPU device nodes are looked for
GPU_NODES = ("dri/renderD*", "dri/card*", "nvidia[0-9]*", "dxg")  # Mesa/DRM GPUs, NVIDIA's driver, WSL2's GPU


def _no_gpu() -> str | None:
    """Why Open3D would draw on the CPU here (no GPU device node on Linux), or None; a few ``stat`` calls, no process.

    Open3D 0.20's OffscreenRenderer needs a Vulkan 1.3 device. Without a GPU device node
    (``/dev/dri/renderD*``, ``/dev/nvidia0``, WSL2's ``/dev/dxg``) the only one can be Mesa's
    CPU driver (lavapipe/llvmpipe), and there Filament frames stall at random for seconds to
    minutes, so ``backend='auto'`` draws with matplotlib at once. Not checked on other systems.
    """
    import glob

    if sys.platform != "linux":
        return None
    if any(glob.glob(os.path.join(DEVICES, pattern)) for pattern in GPU_NODES):
        return None
    return (f"no GPU device ({DEVICES}/dri/renderD*, {DEVICES}/nvidia*): Open3D's renderer would run on the CPU "
            "Vulkan driver, slower than matplotlib and prone to stalls; backend 'open3d' forces it")


class _Stall(Exception):
    """The child stopped reporting: the message says what it was waiting for."""


class _Child:
    """One renderer process of ``size``, started at once; :meth:`run` gives it a job; :meth:`close` ends it."""

    def __init__(self, size: tuple[int, int]):
        import queue
        import threading

        package_parent = str(Path(__file__).resolve().parent.parent)
        self.proc = subprocess.Popen([sys.executable, "-c", _CHILD, package_parent, str(size[0]), str(size[1])],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                     text=True)
        self.started = time.monotonic()
        self.lines: queue.Queue = queue.Queue()
        self.ready = False

        def pump() -> None:
            for line in self.proc.stdout:
                self.lines.put(line)
            self.lines.put(None)

        threading.Thread(target=pump, daemon=True).start()

    def close(self) -> None:
        """Kill the child if it still runs (after its pictures, Filament's teardown takes seconds and is not needed)."""
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait()
        for stream in (self.proc.stdin, self.proc.stdout):
            try:
                stream.close()
            except OSError:  # pragma: no cover - a broken pipe to a killed child
                pass

    def run(self, job_path: Path, out_dir: Path, first: int, jobs: list[dict], startup: float, until: float) -> str:
        """Draw panels ``first``... of the job; the log. ``_Stall`` when a limit passes, ``RenderError`` on failure."""
        import queue

        try:
            self.proc.stdin.write(f"{job_path}\t{out_dir}\t{first}\n")
            self.proc.stdin.flush()
        except OSError:
            pass  # the child is gone: its log says why
        verbose = bool(os.environ.get("MESHDENOISE_RENDER_LOG"))  # the child's log with times, on stderr
        log: list[str] = []
        deadline = self.started + startup
        waiting_for = f"the renderer to start ({startup:g} s allowed, MESHDENOISE_RENDER_STARTUP)"
        if self.ready:  # pragma: no cover - a child runs one job
            deadline = time.monotonic() + 30.0
        line = ""
        try:
            while True:
                try:
                    line = self.lines.get(timeout=max(min(deadline, until) - time.monotonic(), 0.0))
                except queue.Empty:
                    if time.monotonic() >= until:
                        waiting_for = f"all pictures within MESHDENOISE_RENDER_TIMEOUT, at {waiting_for}"
                    raise _Stall(f"waited for {waiting_for}") from None
                if line is None or line.startswith("MESHDENOISE_RENDERED"):
                    break
                log.append(line)
                if verbose:
                    sys.stderr.write(f"[{time.monotonic() - self.started:6.2f} s] {line}")
                if line.startswith(("MESHDENOISE_READY", "MESHDENOISE_FRAME")):
                    self.ready = True
                    done = first if line.startswith("MESHDENOISE_READY") else int(line.split()[1]) + 1
                    if done < len(jobs):
                        allowance = FRAME_SECONDS + FRAME_SECONDS_PER_TRIANGLE * jobs[done]["F"].shape[0]
                        deadline = time.monotonic() + allowance
                        waiting_for = f"frame {done + 1} of {len(jobs)} ({allowance:.0f} s allowed)"
                    else:
                        deadline = time.monotonic() + 30.0
                        waiting_for = "the child to finish"
        finally:
            self.close()
        text = "".join(log)
        if line is None and not all((out_dir / f"frame{k}.npy").is_file() for k in range(first, len(jobs))):
            tail = " | ".join(ln.strip() for ln in text.strip().splitlines()[-3:])
            raise RenderError(
                f"Open3D's OffscreenRenderer failed (exit status {self.proc.returncode}: {tail or 'no output'}); "
                "it needs the Debian packages libvulkan1 mesa-vulkan-drivers libegl1 libgl1 "
                "(scripts/install-system-deps.sh)")
        return text


def _draw_open3d(jobs: list[dict], size, camera: Camera, timeout: float,
                 child: _Child | None = None) -> tuple[list[np.ndarray], str]:
    """Draw the panels with one Open3D OffscreenRenderer in a child process, under time limits.

    A child process because on a software Vulkan driver a missing library aborts the
    process (it does not raise) and a frame can stall for minutes (seen with Open3D 0.20 on
    Mesa 22 llvmpipe); the parent then falls back instead of hanging or dying. Without a
    Vulkan loader or driver no child is started at all. The child (``child``, when
    :func:`render_comparison` started it early so that it starts up while the panels are
    prepared) must report its renderer ready within ``MESHDENOISE_RENDER_STARTUP`` seconds
    (default 20) of its start, each frame within :data:`FRAME_SECONDS` plus
    :data:`FRAME_SECONDS_PER_TRIANGLE` per triangle, and everything within ``timeout``; a
    stalled frame is drawn again once by a fresh child, keeping the pictures already drawn.
    Panels sharing one face array send it once; coordinates go as float32, colours as bytes.
    """
    from importlib.metadata import version

    missing = _vulkan_missing()
    if missing:
        raise RenderError(f"Open3D's OffscreenRenderer cannot start: {missing} (the Debian packages libvulkan1 "
                          "mesa-vulkan-drivers; scripts/install-system-deps.sh)")
    startup = _seconds("MESHDENOISE_RENDER_STARTUP", STARTUP_SECONDS)
    until = time.monotonic() + timeout
    with tempfile.TemporaryDirectory(prefix="meshdenoise-render-") as tmp:
        out_dir = Path(tmp)
        job_path = out_dir / "job.npz"
        arrays = {"size": np.array(size), "center": np.array(camera.center), "eye": np.array(camera.eye),
                  "up": np.array(camera.up), "lens": np.array([camera.fov, camera.near, camera.far]),
                  "count": np.array(len(jobs))}
        faces: list[np.ndarray] = []
        which = []
        for k, job in enumerate(jobs):
            F = job["F"]
            same = next((i for i, G in enumerate(faces) if G is F or (G.shape == F.shape and np.array_equal(G, F))),
                        None)
            if same is None:
                faces.append(F)
                same = len(faces) - 1
                arrays[f"F{same}"] = F.astype(np.int32)
            which.append(same)
            arrays[f"V{k}"] = job["V"].astype(np.float32)
            arrays[f"C{k}"] = np.round(np.clip(job["colors"], 0.0, 1.0) * 255).astype(np.uint8)
        arrays["faces"] = np.array(which)
        np.savez(job_path, **arrays)
        stalls = []
        text = ""
        for _ in range(ATTEMPTS):
            first = next((k for k in range(len(jobs)) if not (out_dir / f"frame{k}.npy").is_file()), len(jobs))
            child = child or _Child(size)
            try:
                text = child.run(job_path, out_dir, first, jobs, startup, until)
                break
            except _Stall as exc:
                stalls.append(str(exc))
                if time.monotonic() >= until or "to start" in str(exc):
                    break  # out of time, or the renderer never starts here: no second try
            finally:
                child.close()
                child = None
        if stalls and not all((out_dir / f"frame{k}.npy").is_file() for k in range(len(jobs))):
            raise RenderError("Open3D's OffscreenRenderer did not finish: " + "; then ".join(stalls))
        images = [np.load(out_dir / f"frame{k}.npy") for k in range(len(jobs))]
    device = next((ln.split(":", 1)[1].strip() for ln in text.splitlines() if "device driver:" in ln), "")
    backend = next((ln.split(":", 1)[1].strip() for ln in text.splitlines() if "resolved backend:" in ln), "")
    extra = ", ".join(x for x in (f"Filament {backend}" if backend else "", device) if x)
    retried = f", {len(stalls)} stalled frame(s) drawn again" if stalls else ""
    detail = f"{extra}{retried}".lstrip(", ")
    return images, f"Open3D {version('open3d')} OffscreenRenderer" + (f" ({detail})" if detail else "")


def _resolve_backend(backend: str) -> str:
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
    if backend == "auto":
        env = os.environ.get("MESHDENOISE_RENDER_BACKEND", "auto")
        if env not in BACKENDS:
            raise ValueError(f"MESHDENOISE_RENDER_BACKEND must be one of {BACKENDS}, got {env!r}")
        backend = env
    return backend


def _prestart(backend: str, size: tuple[int, int]) -> _Child | None:
    """The Open3D child, started now when it will be used, so that it starts while the panels are prepared."""
    backend = _resolve_backend(backend)
    if backend == "matplotlib" or (backend == "auto" and (_OPEN3D_VERDICT is not None or _no_gpu())) \
            or _vulkan_missing():
        return None
    return _Child(size)


def _draw(jobs: list[dict], size, camera: Camera, backend: str,
          child: _Child | None = None) -> tuple[list[np.ndarray], str, str]:
    """Pictures of the jobs with the chosen backend; 'auto' falls back to matplotlib with a warning."""
    global _OPEN3D_VERDICT
    backend = _resolve_backend(backend)
    reason = "requested"
    cpu_only = _no_gpu() if backend == "auto" and _OPEN3D_VERDICT is None else None
    if backend == "auto" and _OPEN3D_VERDICT is not None:  # failed before in this process: do not wait again
        reason = f"Open3D failed earlier in this process: {_OPEN3D_VERDICT}"
        warnings.warn(f"{reason}; drawing with the matplotlib software rasteriser instead", UserWarning, stacklevel=3)
    elif cpu_only:  # headless without a GPU: the expected case, said in backend_detail, not a warning
        reason = cpu_only
    elif backend in ("auto", "open3d"):
        try:
            images, detail = _draw_open3d(jobs, size, camera, _render_timeout(), child)
            return images, "open3d", detail
        except RenderError as exc:
            _OPEN3D_VERDICT = str(exc)
            if backend == "open3d":
                raise
            reason = str(exc)
            warnings.warn(f"{reason}; drawing with the matplotlib software rasteriser instead "
                          "(set MESHDENOISE_RENDER_BACKEND=matplotlib to skip Open3D)", UserWarning, stacklevel=3)
    images = [_draw_matplotlib(job, size, camera) for job in jobs]
    return images, "matplotlib", f"matplotlib {_mpl_version()} software rasteriser ({reason})"


ZBUFFER_CHUNK = 1_000_000  # candidate pixels per vectorised batch (about 100 MB of temporaries)


def _draw_matplotlib(job: dict, size, camera: Camera) -> np.ndarray:
    """The software rasteriser: a z-buffer in numpy, pixel centres sampled, colours of the matplotlib colour map.

    Every triangle in front of the near plane is projected with ``camera``; the pixels whose
    centres fall inside it (barycentric coordinates >= 0) get its perspective-correct depth
    and attribute, and each pixel keeps the nearest. Geometry panels interpolate the shaded
    vertex colours; heat maps interpolate the scalar and colour it afterwards (Gouraud),
    as the colour bar reads. Vectorised in batches of :data:`ZBUFFER_CHUNK` candidate
    pixels: a triangle smaller than a pixel costs one candidate at most, so a 600k-vertex
    mesh takes about a second, where the painter's algorithm this replaces took 34 s.
    """
    V, F = job["V"], job["F"]
    w, h = size
    heat = job.get("scalar") is not None
    attr = np.asarray(job["scalar"], dtype=np.float64)[:, None] if heat else np.asarray(job["colors"], np.float64)
    proj = camera.project(V, size)
    zv = proj[:, 2]
    F = F[(zv[F] > camera.near).all(axis=1)]
    x = proj[:, 0] - 0.5  # pixel (c, r) has its centre at (c + 0.5, r + 0.5): integer coordinates after the shift
    y = proj[:, 1] - 0.5
    xs, ys = x[F], y[F]
    x0 = np.maximum(np.ceil(xs.min(axis=1)), 0).astype(np.int64)
    x1 = np.minimum(np.floor(xs.max(axis=1)), w - 1).astype(np.int64)
    y0 = np.maximum(np.ceil(ys.min(axis=1)), 0).astype(np.int64)
    y1 = np.minimum(np.floor(ys.max(axis=1)), h - 1).astype(np.int64)
    nx, ny = x1 - x0 + 1, y1 - y0 + 1
    some = (nx > 0) & (ny > 0)
    F, x0, y0, nx, ny = F[some], x0[some], y0[some], nx[some], ny[some]
    rows = np.maximum(1, ZBUFFER_CHUNK // nx)  # a triangle larger than a batch is cut into bands of rows
    pieces = -(-ny // rows)
    if (pieces > 1).any():
        idx = np.repeat(np.arange(F.shape[0]), pieces)
        k = np.arange(idx.size) - np.repeat(np.cumsum(pieces) - pieces, pieces)
        band0 = y0[idx] + k * rows[idx]
        ny = np.minimum(rows[idx], y0[idx] + ny[idx] - band0)
        F, x0, nx, y0 = F[idx], x0[idx], nx[idx], band0
    count = nx * ny
    depth = np.full(w * h, np.inf)
    value = np.zeros((w * h, attr.shape[1]))
    ends = np.cumsum(count)
    start = 0
    while start < F.shape[0]:
        base = ends[start - 1] if start else 0
        stop = max(int(np.searchsorted(ends, base + ZBUFFER_CHUNK, side="right")), start + 1)
        sl = slice(start, stop)
        c = count[sl]
        face = np.repeat(np.arange(start, stop), c)
        offset = np.arange(int(c.sum())) - np.repeat(np.cumsum(c) - c, c)
        px = x0[face] + offset % nx[face]
        py = y0[face] + offset // nx[face]
        a, b, d = F[face, 0], F[face, 1], F[face, 2]
        det = (y[b] - y[d]) * (x[a] - x[d]) + (x[d] - x[b]) * (y[a] - y[d])
        ok = det != 0
        det = np.where(ok, det, 1.0)
        l0 = ((y[b] - y[d]) * (px - x[d]) + (x[d] - x[b]) * (py - y[d])) / det
        l1 = ((y[d] - y[a]) * (px - x[d]) + (x[a] - x[d]) * (py - y[d])) / det
        l2 = 1.0 - l0 - l1
        inside = ok & (l0 >= -1e-9) & (l1 >= -1e-9) & (l2 >= -1e-9)
        l0, l1, l2, a, b, d = l0[inside], l1[inside], l2[inside], a[inside], b[inside], d[inside]
        pix = (py * w + px)[inside]
        inv = l0 / zv[a] + l1 / zv[b] + l2 / zv[d]  # 1/z is linear on the screen
        z = 1.0 / inv
        order = np.lexsort((z, pix))  # per pixel, nearest first
        pix, z = pix[order], z[order]
        first = np.concatenate([[True], pix[1:] != pix[:-1]]) if pix.size else np.zeros(0, bool)
        sel = order[first]
        pix, z = pix[first], z[first]
        better = z < depth[pix]
        sel, pix = sel[better], pix[better]
        depth[pix] = z[better]
        wa, wb, wd = (l0[sel] / zv[a[sel]], l1[sel] / zv[b[sel]], l2[sel] / zv[d[sel]])
        value[pix] = (wa[:, None] * attr[a[sel]] + wb[:, None] * attr[b[sel]] + wd[:, None] * attr[d[sel]]) \
            / inv[sel][:, None]
        start = stop
    hit = np.isfinite(depth)
    image = np.empty((w * h, 3))
    image[:] = BACKGROUND
    if heat:
        image[hit] = job["cmap"](job["norm"](value[hit, 0]))[:, :3]
    else:
        image[hit] = np.clip(value[hit], 0.0, 1.0)
    return np.round(image.reshape(h, w, 3) * 255).astype(np.uint8)


def _mpl_version() -> str:
    import matplotlib

    return matplotlib.__version__


def _job(V, F, camera: Camera, error=None, vmax=None, cmap: str = "viridis") -> dict:
    """What one panel needs: geometry, per-vertex colours, and for heat maps the scalar and scale."""
    if error is None:
        return {"V": V, "F": F, "colors": _shade(V, F, camera)}
    import matplotlib
    from matplotlib.colors import Normalize

    error = np.asarray(error, dtype=np.float64)
    if error.shape != (V.shape[0],):
        raise ValueError(f"error must have one value per vertex, shape ({V.shape[0]},), got {error.shape}")
    vmax = _default_vmax([error]) if vmax is None else vmax
    return {"V": V, "F": F, "colors": error_colors(error, vmax, cmap), "scalar": np.minimum(error, vmax),
            "norm": Normalize(0.0, vmax), "cmap": matplotlib.colormaps[cmap]}


def render_mesh(
    mesh: Any,
    size: tuple[int, int] = (400, 400),
    camera: Camera | None = None,
    *,
    error: np.ndarray | None = None,
    vmax: float | None = None,
    cmap: str = "viridis",
    backend: str = "auto",
) -> np.ndarray:
    """One picture ``(height, width, 3) uint8`` of a mesh on a white background.

    Without ``error``: light grey, shaded by :func:`_shade`'s light. With ``error`` (one
    value per vertex): an unlit heat map on the colour map ``cmap`` from 0 to ``vmax``
    (default: the largest error). ``camera`` defaults to :func:`frame_camera` of this mesh
    alone; pass one camera to compare meshes. ``backend`` as in :func:`render_comparison`.

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
    images, _, _ = _draw([_job(V, F, camera, error, vmax, cmap)], size, camera, backend)
    return images[0]


def _default_vmax(errors: Sequence[np.ndarray]) -> float:
    """The largest error shown; a tiny positive scale when all are zero (identical meshes)."""
    top = max((float(e.max()) for e in errors if e.size), default=0.0)
    return top if top > 0 else 1e-12


# --- side by side --------------------------------------------------------------------------------
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


def _zoom_ball(zoom, V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, float]:
    """``zoom = (centre, radius)`` -> (centre point (3,), radius in mesh units).

    ``centre`` is a vertex index of the first mesh or a point (3,); ``radius`` is in mean
    edge lengths of the first mesh.
    """
    from .noise import mean_edge_length

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


def _bar_top(values: Sequence[np.ndarray], percentile: float) -> float:
    """The ``percentile`` of all shown values; the maximum when that is 0; a tiny scale when all are 0."""
    every = np.concatenate([np.ravel(v) for v in values]) if values else np.zeros(0)
    if every.size == 0:
        return 1e-12
    top = float(np.percentile(every, percentile))
    if top <= 0:
        top = float(every.max())
    return top if top > 0 else 1e-12


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
    child = _prestart(backend, size)  # Open3D starts up while the meshes are read and the panels prepared
    try:
        return _render_comparison(meshes, out_png, reference, titles, size, view, error_of, error_mode, vmax, cmap,
                                  backend, show_change, percentile, zoom, child)
    finally:
        if child is not None:
            child.close()


def _render_comparison(meshes, out_png, reference, titles, size, view, error_of, error_mode, vmax, cmap, backend,
                       show_change, percentile, zoom, child) -> RenderResult:
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
    panels, which, detail = _draw(jobs, size, camera, backend, child)
    if heat == "change":
        label = "distance to the first mesh" if mode_used == "nearest" else "displacement from the first mesh"
    else:
        label = "distance to reference" if mode_used == "nearest" else "vertex displacement"
    boxes = _compose(out_png, panels, panel_titles, errors, vmax, cmap, label, used_percentile, under)
    return RenderResult(out_png, which, detail, panels, boxes, panel_titles, errors, mode_used,
                        vmax if maps else None, camera, heat, used_percentile, ball, facing)


TITLE_BAND = 40  # pixels above each row of panels for titles
BAR_BAND = 110  # pixels right of the panels for the colour bar
GAP = 8  # pixels between panels in a row
MAX_PER_ROW = 4  # panels in a row before they go into a grid


def panel_grid(n_geometry: int, under: Sequence[int]) -> list[tuple[int, int]]:
    """(row, column) of each panel: the geometry panels, then one heat map per index in ``under``.

    Up to :data:`MAX_PER_ROW` panels in all stand in one row (before / after / error). More
    go into a grid of at most :data:`MAX_PER_ROW` columns: the meshes in the first rows, then
    each heat map under the mesh it colours (``under[j]`` is that mesh's geometry panel), so
    the first mesh of a change map has an empty place below it.

    Examples
    --------
    >>> panel_grid(2, [1])
    [(0, 0), (0, 1), (0, 2)]
    >>> panel_grid(4, [1, 2, 3])
    [(0, 0), (0, 1), (0, 2), (0, 3), (1, 1), (1, 2), (1, 3)]
    >>> panel_grid(5, [4])
    [(0, 0), (0, 1), (0, 2), (0, 3), (1, 0), (2, 0)]
    """
    if n_geometry + len(under) <= MAX_PER_ROW:
        return [(0, k) for k in range(n_geometry + len(under))]
    cols = min(MAX_PER_ROW, max(n_geometry, 1))
    places = [divmod(k, cols) for k in range(n_geometry)]
    first_heat_row = -(-n_geometry // cols)
    heat_rows = sorted({m // cols for m in under})  # only rows holding a heat map, packed
    return places + [(first_heat_row + heat_rows.index(m // cols), m % cols) for m in under]


def _compose(out_png: Path, panels, titles, errors, vmax, cmap, label, percentile,
             under: Sequence[int] | None = None) -> list[tuple[int, int, int, int]]:
    """Paste the panels pixel for pixel (``figimage``, no resampling) in :func:`panel_grid`'s places, with
    titles and a colour bar right of the heat maps."""
    import matplotlib
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.colorbar import ColorbarBase
    from matplotlib.colors import Normalize
    from matplotlib.figure import Figure
    from matplotlib.ticker import FuncFormatter

    h, w = panels[0].shape[:2]
    n_geometry = len(panels) - len(errors)
    if under is None:
        under = [n_geometry - len(errors) + j for j in range(len(errors))]
    places = panel_grid(n_geometry, list(under))
    n_rows = max(r for r, _ in places) + 1
    n_cols = max(c for _, c in places) + 1
    grid_w = n_cols * w + (n_cols - 1) * GAP
    width = grid_w + (BAR_BAND if errors else 0)
    height = n_rows * (h + TITLE_BAND)
    fig = Figure(figsize=(width / 100.0, height / 100.0), dpi=100, facecolor="white")
    FigureCanvasAgg(fig)
    boxes = []
    for k, (img, title, (r, c)) in enumerate(zip(panels, titles, places)):
        x0, top = c * (w + GAP), r * (h + TITLE_BAND)
        fig.figimage(img, xo=x0, yo=height - top - TITLE_BAND - h, origin="upper")
        boxes.append((top + TITLE_BAND, x0, h, w))
        lines = [title.replace("$", r"\$")]  # a file name is text, never mathtext
        if k >= n_geometry:
            e = errors[k - n_geometry]
            lines.append(f"max {e.max():.3g}, RMS {np.sqrt(np.mean(e**2)):.3g}")
        fig.text((x0 + w / 2) / width, 1 - (top + 4) / height, "\n".join(lines), ha="center", va="top",
                 fontsize=9, wrap=False, clip_on=True)
    if errors:
        rows = [r for r, _ in places[n_geometry:]]
        top = min(rows) * (h + TITLE_BAND) + TITLE_BAND  # the bar spans the rows of heat maps
        span = (max(rows) + 1) * (h + TITLE_BAND) - top
        cax = fig.add_axes([(grid_w + 4) / width, (height - top - 0.92 * span) / height,
                            14 / width, 0.84 * span / height])
        over = any(float(e.max()) > vmax for e in errors)
        bar = ColorbarBase(cax, cmap=matplotlib.colormaps[cmap], norm=Normalize(0.0, vmax),
                           extend="max" if over else "neither")
        bar.ax.tick_params(labelsize=8)
        bar.ax.yaxis.set_major_formatter(FuncFormatter(lambda x, _: f"{x:.3g}"))  # no offset text to clip
        top = "maximum" if percentile is None or percentile >= 100 else f"{_ordinal(percentile)} percentile"
        if percentile is None:
            top = "given vmax"
        bar.set_label(f"{label}\n(mesh units), top = {top}", fontsize=7)
    with atomic_path(out_png) as tmp:
        fig.savefig(tmp, dpi=100, format="png", facecolor="white")
    return boxes


def _ordinal(p: float) -> str:
    """'99th', '95th', '99.5th', '1st', '2nd', '3rd', '12th'."""
    text = f"{p:g}"
    if not float(p).is_integer():
        return text + "th"
    n = int(p)
    suffix = "th" if 10 <= n % 100 <= 20 else {1: "st", 2: "nd", 3: "rd"}.get(n % 10, "th")
    return f"{n}{suffix}"

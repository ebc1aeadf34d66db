"""The Open3D back end: Open3D's OffscreenRenderer (Filament) in a child process, under time limits.

A child process because on a software Vulkan driver a missing library aborts the process (it
does not raise) and a frame can stall for minutes (seen with Open3D 0.20 on Mesa 22 llvmpipe).
Also whether this machine can run it at all: a Vulkan loader and driver (:func:`_vulkan_missing`),
a GPU device node (:func:`_no_gpu`), both answered without starting a process.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from .camera import Camera
from .raster import BACKGROUND
from .settings import DEFAULT_SETTINGS, RenderSettings


class RenderError(RuntimeError):
    """Open3D's OffscreenRenderer failed or did not finish in time; the message says which and why."""


_CHILD = r"""
import sys
sys.path.insert(0, sys.argv[1])
from meshdenoise.render.offscreen import _open3d_child
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


STARTUP_SECONDS = "20"  # default MESHDENOISE_RENDER_STARTUP: import, Filament and the Vulkan device, loaded machine


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


def _no_gpu(settings: RenderSettings = DEFAULT_SETTINGS) -> str | None:
    """Why Open3D would draw on the CPU here (no GPU device node on Linux), or None; a few ``stat`` calls, no process.

    Open3D 0.20's OffscreenRenderer needs a Vulkan 1.3 device. Without a GPU device node
    (``/dev/dri/renderD*``, ``/dev/nvidia0``, WSL2's ``/dev/dxg``) the only one can be Mesa's
    CPU driver (lavapipe/llvmpipe), and there Filament frames stall at random for seconds to
    minutes, so ``backend='auto'`` draws with matplotlib at once. Not checked on other systems.
    ``settings.devices`` and ``settings.gpu_nodes`` say where to look.
    """
    import glob

    if sys.platform != "linux":
        return None
    if any(glob.glob(os.path.join(settings.devices, pattern)) for pattern in settings.gpu_nodes):
        return None
    devices = settings.devices
    return (f"no GPU device ({devices}/dri/renderD*, {devices}/nvidia*): Open3D's renderer would run on the CPU "
            "Vulkan driver, slower than matplotlib and prone to stalls; backend 'open3d' forces it")


class _Stall(Exception):
    """The child stopped reporting: the message says what it was waiting for."""


class _Child:
    """One renderer process of ``size``, started at once; :meth:`run` gives it a job; :meth:`close` ends it.

    ``program`` is the Python code the child runs (:data:`_CHILD`).
    """

    def __init__(self, size: tuple[int, int], program: str = _CHILD):
        import queue
        import threading

        package_parent = str(Path(__file__).resolve().parents[2])  # the folder holding meshdenoise/
        self.proc = subprocess.Popen([sys.executable, "-c", program, package_parent, str(size[0]), str(size[1])],
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

    def run(self, job_path: Path, out_dir: Path, first: int, jobs: list[dict], startup: float, until: float,
            settings: RenderSettings = DEFAULT_SETTINGS) -> str:
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
                        allowance = settings.frame_allowance(jobs[done]["F"].shape[0])
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


def _draw_open3d(jobs: list[dict], size, camera: Camera, timeout: float, child: _Child | None = None,
                 settings: RenderSettings = DEFAULT_SETTINGS) -> tuple[list[np.ndarray], str]:
    """Draw the panels with one Open3D OffscreenRenderer in a child process, under time limits.

    A child process because on a software Vulkan driver a missing library aborts the
    process (it does not raise) and a frame can stall for minutes (seen with Open3D 0.20 on
    Mesa 22 llvmpipe); the parent then falls back instead of hanging or dying. Without a
    Vulkan loader or driver no child is started at all. The child (``child``, when
    :func:`render_comparison` started it early so that it starts up while the panels are
    prepared) must report its renderer ready within ``MESHDENOISE_RENDER_STARTUP`` seconds
    (default 20) of its start, each frame within its allowance
    (:meth:`RenderSettings.frame_allowance`), and everything within ``timeout``; a stalled
    frame is drawn again by a fresh child (``settings.attempts`` children in all), keeping the
    pictures already drawn.
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
        for _ in range(settings.attempts):
            first = next((k for k in range(len(jobs)) if not (out_dir / f"frame{k}.npy").is_file()), len(jobs))
            child = child or _Child(size)
            try:
                text = child.run(job_path, out_dir, first, jobs, startup, until, settings)
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

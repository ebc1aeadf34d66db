"""Scan-sized meshes: automatic parameters, filters, the command line and the peers at 100k to 5M vertices.

Meshes: the elephant (24,955 vertices, ``MESHDENOISE_DATA``) Loop-subdivided by Open3D's
``subdivide_loop`` 1, 2 and 3 times (99,832, 399,340 and 1,597,372 vertices); for 5M, the
elephant first decimated by Open3D's ``simplify_quadric_decimation`` to 39,060 triangles, then
Loop-subdivided 4 times (4,999,676 vertices, 9,999,360 faces: level 4 of the whole elephant
would be 6.4M). Gaussian noise of 0.5 mean edge length along the vertex normals
(:func:`meshdenoise.add_normal_noise`, seed 0). Made once and cached under
``~/.cache/meshdenoise/scale`` (``--cache-dir``): clean and noisy ``.npz`` and the noisy
mesh as binary PLY for the command line.

Per size and method, two cells, each a fresh subprocess killed after ``--timeout``
seconds (recorded as ``> T s``; what finished before is kept):

- *in process* (``--no-inproc`` skips it): ``choose_parameters(mesh, method)`` (seconds), the
  filter at those parameters on a cold operator cache (seconds), the SNR of its result against the
  clean mesh, and the oracle's SNR: the best over a small grid of the method's main parameter
  scored against the clean mesh (the automatic value included, so oracle >= auto). The
  grid: iterative methods (``filtering``, ``taubin``, ``two_stage``) walk one run past
  the chosen count; the others try the chosen value times 1/3 and 3.
- *end to end*: ``meshdenoise denoise --method M IN.ply OUT.ply`` (``meshdenoise denoise
  IN.ply OUT.ply`` for ``default``: read, choose, filter, guard, write) as a subprocess: wall
  seconds and its peak resident memory (``ru_maxrss`` of that child, from ``os.wait4``; Linux
  starts it at the parent's peak, so this process stays small and makes the meshes in a child),
  also per vertex.

The peers (``--peers``, each in its own subprocess with the same timeout, at their default
settings, on the noisy mesh's arrays): MeshLib's ``meshDenoiseViaNormals`` (default
``DenoiseViaNormalsSettings``; when ``meshlib`` is installed), MeshLab's two-step smoothing
(``apply_coord_two_steps_smoothing()``: 3 steps, 60 degrees, 20 normal and 20 fitting steps) and
Taubin (``apply_coord_taubin_smoothing()``: lambda 0.5, mu -0.53, 10 steps) through pymeshlab, and
Open3D's ``filter_smooth_taubin(10, 0.5, -0.53)``. Per peer: the call's seconds, the child's wall
seconds (imports, the mesh given to the library and taken back included; no file read or written),
its peak resident memory and the SNR against the clean mesh.

And two pairs, each timed in one process with its peer (cold caches, wall and CPU
seconds, growth of the resident high-water mark per vertex):

- ``two_stage(iterations=1, normal_iterations=20, vertex_iterations=20)`` against
  pymeshlab ``apply_coord_two_steps_smoothing(stepsmoothnum=1, stepnormalnum=20,
  stepfitnum=20)`` (MeshLab's default counts per outer iteration);
- ``taubin(iterations=10, lam=0.5, mu=-0.53, weights="open3d")`` against Open3D
  ``filter_smooth_taubin(10, 0.5, -0.53)``, with the largest coordinate difference.

The machine's load average is recorded per cell: on a shared machine wall times grow with
it (CPU seconds are given for the pairs).

Usage::

    python benchmarks/scale.py --sizes 400k,1.6M --timeout 900 --out benchmarks/results/scale   # OUT.txt and OUT.json
    python benchmarks/scale.py --sizes 400k,1.6M,5M --methods default --no-inproc --no-pairs --peers \
        --timeout 900 --peer-timeout 300 --out benchmarks/results/scale   # the table of docs/scale.md
    python benchmarks/scale.py --sizes 1.6M --pairs-only
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import platform
import re
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

SIZES = {"100k": 1, "400k": 2, "1.6M": 3, "5M": 4}  # label -> Loop subdivision levels
DECIMATED = {"5M": 39_060}  # label -> the elephant's triangles after quadric decimation, before subdividing
PEERS = ("MeshLib denoise", "MeshLab two-step", "MeshLab Taubin", "Open3D Taubin")
DEFAULT = "default"  # the row of `meshdenoise denoise IN OUT` with no method: choose_default, then its filter
METHODS = ("filtering", "heat", "taubin", "sobolev", "sobolev_bilaplacian", "sobolev_normal", "sobolev_gls", "two_stage",
           DEFAULT, "sobolev_axes", "sinkhorn")
NOISE_EDGES = 0.5  # noise standard deviation in mean edge lengths
TWO_STAGE_COUNTS = (1, 20, 20)  # outer, normal, vertex iterations (MeshLab's defaults per outer iteration)
TAUBIN_ARGS = (10, 0.5, -0.53)
CONTINUOUS = {  # main parameter of the methods without an iteration count to walk
    "heat": "time",
    "sobolev": "mu",
    "sobolev_bilaplacian": "mu",
    "sobolev_normal": "mu",
    "sobolev_gls": "mu",
    "sobolev_axes": ("mu1", "mu2", "mu3"),  # the three weights scaled together
    "sinkhorn": "t",  # its chosen iteration count kept
}
GRID = (1.0 / 3.0, 3.0)


# --- meshes -------------------------------------------------------------------------------
def cache_dir(arg: str | None) -> Path:
    base = Path(arg) if arg else Path(os.environ.get("MESHDENOISE_CACHE") or Path.home() / ".cache" / "meshdenoise")
    return base / "scale"


def prepare(label: str, folder: Path) -> dict:
    """Clean and noisy meshes of ``label`` (cached): paths and sizes."""
    levels = SIZES[label]
    folder.mkdir(parents=True, exist_ok=True)
    stem = f"elephant-o3dloop{levels}" + (f"-dec{DECIMATED[label]}" if label in DECIMATED else "")
    npz, ply = folder / f"{stem}.npz", folder / f"{stem}-noisy.ply"
    if not (npz.is_file() and ply.is_file()):
        import open3d as o3d

        from meshdenoise import add_normal_noise
        from meshdenoise.data import data_file
        from meshdenoise.io import load_arrays, save_mesh
        from meshdenoise.operators import Operators

        V, F = load_arrays(data_file("elephant-50kv.off"))
        mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(V), o3d.utility.Vector3iVector(F.astype(np.int32)))
        if label in DECIMATED:
            mesh = mesh.simplify_quadric_decimation(target_number_of_triangles=DECIMATED[label])
        if levels:
            mesh = mesh.subdivide_loop(number_of_iterations=levels)
        V, F = np.asarray(mesh.vertices).copy(), np.asarray(mesh.triangles).astype(np.int64)
        e = Operators(F, len(V)).edges
        h = float(np.linalg.norm(V[e[:, 0]] - V[e[:, 1]], axis=1).mean())
        rho = NOISE_EDGES * h
        Vn, _ = add_normal_noise((V, F), rho, seed=0)
        save_mesh(ply, Vn, F)
        tmp = npz.with_name(npz.name + f".tmp{os.getpid()}.npz")
        np.savez(tmp, V=V, F=F, Vn=Vn, rho=rho, h=h)
        os.replace(tmp, npz)
    with np.load(npz) as z:
        n, m, rho, h = len(z["V"]), len(z["F"]), float(z["rho"]), float(z["h"])
    return {"label": label, "npz": str(npz), "ply": str(ply), "n": n, "m": m, "rho": rho, "h": h}


def load(npz: str):
    with np.load(npz) as z:
        return z["V"], z["F"], z["Vn"]


def code_version() -> str:
    """The checkout's commit (short hash), with ``+dirty`` when tracked files differ from it; ``unknown`` without git."""
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True, check=True)
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=ROOT, capture_output=True,
                               text=True, check=True)
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return head.stdout.strip() + ("+dirty" if dirty.stdout.strip() else "")


# --- memory of this process (Linux) -------------------------------------------------------------
def _status(field: str) -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1]) * 1024
    return 0


def reset_peak() -> int:
    """Reset the resident high-water mark to the current resident size; return that size (bytes)."""
    try:
        Path("/proc/self/clear_refs").write_text("5")
    except OSError:
        pass
    return _status("VmRSS")


def peak() -> int:
    return _status("VmHWM")


# --- children -----------------------------------------------------------------------------------
def emit(**record) -> None:
    print(json.dumps(record), flush=True)


def timed(fn):
    w, c = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - w, time.process_time() - c


def child_inproc(npz: str, method: str) -> None:
    """Choose, filter (cold), SNR, oracle grid; one JSON line per finished stage."""
    import meshdenoise as md
    from meshdenoise.operators import clear_cache

    V, F, Vn = load(npz)
    emit(stage="noisy", snr=md.snr(V, Vn))
    if method == DEFAULT:  # denoise(mesh) with no method: the filter and its parameters chosen
        from meshdenoise.policy import choose_default

        choice, wall, cpu = timed(lambda: choose_default((Vn, F)))
        method, params = choice.method, dict(choice.params)
    else:
        choice = None
        params, wall, cpu = timed(lambda: md.choose_parameters((Vn, F), method))
    params = {k: (v.item() if isinstance(v, np.generic) else v) for k, v in params.items()}
    emit(stage="choose", seconds=wall, cpu=cpu, params=params, method=method)
    clear_cache()
    def run():  # what denoise does after choosing: the filter (the default's fold guard is not timed here)
        return md.apply_filter(method, (Vn, F), **params)

    (X, _), wall, cpu = timed(run)
    auto_snr = md.snr(V, X)
    emit(stage="filter", seconds=wall, cpu=cpu, snr=auto_snr)
    del X
    best = (auto_snr, params)
    if method in CONTINUOUS:
        name = CONTINUOUS[method]
        for factor in GRID:
            names = name if isinstance(name, tuple) else (name,)
            trial = {**params, **{k: params[k] * factor for k in names}}
            if method == "heat":  # a chosen iteration count belongs to the chosen time: let it follow
                trial.pop("iterations", None)
            s = md.snr(V, md.apply_filter(method, (Vn, F), **trial)[0])
            if s > best[0]:
                best = (s, trial)
    else:  # iterative: walk one run, one step at a time, a few steps past the chosen count
        k = int(params["iterations"])
        stop = k + 3 if method == "two_stage" else max(2 * k, k + 5)
        step = {**params, "iterations": 1}
        X = Vn
        for i in range(1, stop + 1):
            X = md.apply_filter(method, (X, F), **step)[0]
            s = md.snr(V, X)
            if s > best[0]:
                best = (s, {**params, "iterations": i})
    emit(stage="oracle", snr=best[0], params=best[1])


def child_pair(npz: str, which: str) -> None:
    """Ours against the library peer in this one process: wall, CPU, high-water growth."""
    import meshdenoise as md
    from meshdenoise.operators import clear_cache
    from meshdenoise.shapes import box

    V, F, Vn = load(npz)
    n = len(V)
    if which == "two_stage":
        import pymeshlab

        it, nn, nv = TWO_STAGE_COUNTS
        md.two_stage(box(4), iterations=1)  # load the compiled kernels (cached on disk) before timing
        clear_cache()
        base = reset_peak()
        ours, wall, cpu = timed(lambda: md.two_stage((Vn, F), iterations=it, normal_iterations=nn, vertex_iterations=nv)[0])
        emit(stage="ours", seconds=wall, cpu=cpu, peak_growth=peak() - base, bytes_per_vertex=(peak() - base) / n)
        del ours
        ms = pymeshlab.MeshSet()
        ms.add_mesh(pymeshlab.Mesh(vertex_matrix=Vn, face_matrix=F.astype(np.int32)))
        base = reset_peak()
        _, wall, cpu = timed(lambda: ms.apply_coord_two_steps_smoothing(stepsmoothnum=it, stepnormalnum=nn, stepfitnum=nv))
        emit(stage="theirs", seconds=wall, cpu=cpu, peak_growth=peak() - base, bytes_per_vertex=(peak() - base) / n)
    else:
        import open3d as o3d

        k, lam, mu = TAUBIN_ARGS
        md.taubin(box(4), iterations=1, weights="open3d")
        clear_cache()
        base = reset_peak()
        ours, wall, cpu = timed(lambda: md.taubin((Vn, F), iterations=k, lam=lam, mu=mu, weights="open3d")[0])
        emit(stage="ours", seconds=wall, cpu=cpu, peak_growth=peak() - base, bytes_per_vertex=(peak() - base) / n)
        mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(Vn), o3d.utility.Vector3iVector(F.astype(np.int32)))
        base = reset_peak()
        out, wall, cpu = timed(lambda: mesh.filter_smooth_taubin(k, lambda_filter=lam, mu=mu))
        emit(stage="theirs", seconds=wall, cpu=cpu, peak_growth=peak() - base, bytes_per_vertex=(peak() - base) / n)
        emit(stage="difference", max_abs=float(np.abs(np.asarray(out.vertices) - ours).max()), scale=float(np.abs(Vn).max()))


def child_snr(npz: str, out: str) -> None:
    """The SNR of the command line's output file against the clean mesh."""
    import meshdenoise as md
    from meshdenoise.io import load_arrays

    V, _, Vn = load(npz)
    emit(stage="snr", snr=md.snr(V, load_arrays(out)[0]), noisy=md.snr(V, Vn))


def child_peer(npz: str, name: str) -> None:
    """One peer at its default settings on the noisy mesh: the call's seconds and the SNR of its result."""
    import meshdenoise as md

    V, F, Vn = load(npz)
    if name == "MeshLib denoise":
        from meshlib import mrmeshnumpy as mn
        from meshlib import mrmeshpy as mr

        mesh = mn.meshFromFacesVerts(np.ascontiguousarray(F, dtype=np.int32), np.ascontiguousarray(Vn))
        settings = mr.DenoiseViaNormalsSettings()
        _, wall, cpu = timed(lambda: mr.meshDenoiseViaNormals(mesh, settings))
        X = np.asarray(mn.getNumpyVerts(mesh), dtype=np.float64)
    elif name.startswith("MeshLab"):
        import pymeshlab

        ms = pymeshlab.MeshSet()
        ms.add_mesh(pymeshlab.Mesh(vertex_matrix=Vn, face_matrix=F.astype(np.int32)))
        call = ms.apply_coord_two_steps_smoothing if name == "MeshLab two-step" else ms.apply_coord_taubin_smoothing
        _, wall, cpu = timed(call)
        X = np.asarray(ms.current_mesh().vertex_matrix(), dtype=np.float64)
    else:
        import open3d as o3d

        mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(Vn), o3d.utility.Vector3iVector(F.astype(np.int32)))
        k, lam, mu = TAUBIN_ARGS
        out, wall, cpu = timed(lambda: mesh.filter_smooth_taubin(k, lambda_filter=lam, mu=mu))
        X = np.asarray(out.vertices, dtype=np.float64)
    emit(stage="call", seconds=wall, cpu=cpu, snr=md.snr(V, X) if X.shape == V.shape else None)


# --- running cells with a time limit --------------------------------------------------------------
def run_limited(cmd: list[str], timeout: float) -> dict:
    """Run ``cmd`` in its own session; kill it after ``timeout`` s. Wall time, peak RSS (``wait4``), stdout lines."""
    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    with tempfile.TemporaryFile(mode="w+") as out, tempfile.TemporaryFile(mode="w+") as err:
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, stdout=out, stderr=err, env=env, start_new_session=True, cwd=str(ROOT))
        timed_out = False
        while True:
            pid, status, usage = os.wait4(proc.pid, os.WNOHANG)
            if pid:
                break
            if time.perf_counter() - t0 > timeout:
                timed_out = True
                os.killpg(proc.pid, signal.SIGKILL)
                pid, status, usage = os.wait4(proc.pid, 0)
                break
            time.sleep(0.05)
        wall = time.perf_counter() - t0
        proc.returncode = 0  # reaped by wait4
        out.seek(0)
        err.seek(0)
        printed = out.read().splitlines()
        records = [json.loads(line) for line in printed if line.startswith("{")]
        # the default's choice as the command prints it: "IN.ply: filter: two_stage (k=v, ...), chosen in 5.7 s"
        chosen = next((line.split(": filter: ", 1)[1].rsplit(", chosen in", 1)[0] for line in printed
                       if ": filter: " in line), None)
        lines = err.read().strip().splitlines()
        tail = lines[-3:]
        # the command line's stage lines (a stage over 2 s): "IN.ply: choosing the filter: 24.5 s", "...: running M: 9.1 s"
        stages = {m[1]: float(m[2]) for m in (STAGE_LINE.match(line) for line in lines) if m}
    return {
        "wall": wall,
        "timed_out": timed_out,
        "exit": None if timed_out else os.waitstatus_to_exitcode(status),
        "maxrss": usage.ru_maxrss * 1024,
        "records": {r.pop("stage"): r for r in records},
        "stderr_tail": tail,
        "stages": stages,
        "chosen": chosen,
    }


STAGE_LINE = re.compile(r"^.*?: (choosing the filter|running \w+): ([0-9.]+) s$")


def me(*args: str) -> list[str]:
    return [sys.executable, str(Path(__file__).resolve()), *args]


def run_size(mesh: dict, methods: list[str], timeout: float, pairs: bool, e2e: bool, cells: bool, workdir: Path,
             criterion: str | None = None, peers: bool = False, peer_timeout: float | None = None,
             over: dict | None = None) -> dict:
    """The cells of one mesh. ``over``: peer -> the smaller size it ran out of time on (then not run here, and
    recorded as over the time limit: it would take longer on a larger mesh); updated."""
    over = {} if over is None else over
    peer_timeout = timeout if peer_timeout is None else peer_timeout
    result = {"mesh": mesh, "methods": {}, "pairs": {}, "peers": {}}
    for method in methods if cells or e2e else []:
        row = {"load_before": os.getloadavg()[0]}
        if cells:
            row["inproc"] = run_limited(me("--child", "inproc", mesh["npz"], method), timeout)
        if e2e:
            out = workdir / f"out-{mesh['label']}-{method}.ply"
            cli = "import sys; from meshdenoise.cli import main; sys.argv[0] = 'meshdenoise'; main()"
            how = [] if method == DEFAULT else ["--method", method]
            if criterion is not None and method != DEFAULT:
                how += ["--criterion", criterion]
            cmd = [sys.executable, "-c", cli, "denoise", *how, mesh["ply"], str(out)]
            row["e2e"] = run_limited(cmd, timeout)
            if out.exists():
                if not cells:  # the result's SNR, read back in a child (this process stays small)
                    got = run_limited(me("--child", "snr", mesh["npz"], str(out)), 600.0)["records"].get("snr")
                    row["e2e"]["snr"] = got["snr"] if got else None
                    row["e2e"]["snr_noisy"] = got["noisy"] if got else None
                out.unlink()
        row["load_after"] = os.getloadavg()[0]
        result["methods"][method] = row
        print(format_row(mesh, method, row), flush=True)
    for name in PEERS if peers else ():
        library = "meshlib" if name.startswith("MeshLib") else "pymeshlab" if name.startswith("MeshLab") else "open3d"
        if importlib.util.find_spec(library) is None:
            cell = {"missing": library, "load": os.getloadavg()[0]}
        elif name in over:
            cell = {"skipped": over[name], "load": os.getloadavg()[0]}
        else:
            load_before = os.getloadavg()[0]
            cell = run_limited(me("--child", "peer", mesh["npz"], name), peer_timeout)
            cell["load"] = load_before
            if cell["timed_out"]:
                over[name] = mesh["label"]
        result["peers"][name] = cell
        print(format_peer(mesh, name, cell, peer_timeout), flush=True)
    if pairs:
        for which in ("two_stage", "taubin"):
            cell = run_limited(me("--child", "pair", mesh["npz"], which), max(timeout, 600.0))
            cell["load"] = os.getloadavg()[0]
            result["pairs"][which] = cell
            print(format_pair(mesh, which, cell), flush=True)
    return result


# --- table --------------------------------------------------------------------------------------
def _s(record: dict | None, key: str, cell: dict, timeout: float, fmt: str = "{:.1f}") -> str:
    if record is not None and key in record:
        return fmt.format(record[key])
    if cell is not None and cell.get("timed_out"):
        return f"> {timeout:.0f}"
    return "fail" if cell is not None else "-"


def format_row(mesh: dict, method: str, row: dict, timeout: float | None = None) -> str:
    timeout = timeout if timeout is not None else ARGS_TIMEOUT
    inproc = row.get("inproc")
    rec = inproc["records"] if inproc else {}
    e2e = row.get("e2e")
    if e2e is None:
        e2e_s = peak_s = bpv = "-"
    elif e2e["timed_out"]:
        e2e_s, peak_s, bpv = f"> {timeout:.0f}", "-", "-"
    elif e2e["exit"] != 0:
        e2e_s, peak_s, bpv = "fail", "-", "-"
    else:
        e2e_s = f"{e2e['wall']:.1f}"
        peak_s = f"{e2e['maxrss'] / 2**20:.0f}"
        bpv = f"{e2e['maxrss'] / mesh['n']:.0f}"
    params = rec.get("choose", {}).get("params")
    if method == DEFAULT and params is not None and rec.get("choose", {}).get("method"):
        params = {"method": rec["choose"]["method"], **params}
    ptext = ", ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}" for k, v in (params or {}).items())
    if not ptext and (e2e or {}).get("chosen"):
        ptext = e2e["chosen"] + "*"
    choose_s = _s(rec.get("choose"), "seconds", inproc, timeout)
    filter_s = _s(rec.get("filter"), "seconds", inproc, timeout, "{:.2f}")
    stages = (e2e or {}).get("stages") or {}
    auto_snr = _s(rec.get("filter"), "snr", inproc, timeout, "{:.2f}")
    noisy_snr = _s(rec.get("noisy"), "snr", inproc, timeout, "{:.2f}")
    if inproc is None and (e2e or {}).get("snr_noisy") is not None:
        noisy_snr = f"{e2e['snr_noisy']:.2f}"
    if inproc is None and stages:  # the command's own stage times (marked *): the choice, then the filter with its guard
        choose_s = next((f"{v:.1f}*" for k, v in stages.items() if k == "choosing the filter"), choose_s)
        filter_s = next((f"{v:.1f}*" for k, v in stages.items() if k.startswith("running")), filter_s)
    if inproc is None and (e2e or {}).get("snr") is not None:  # the command's output read back (marked *)
        auto_snr = f"{e2e['snr']:.2f}*"
    return (
        f"| {mesh['label']} | {method} | {choose_s} "
        f"| {filter_s} | {e2e_s} | {peak_s} | {bpv} "
        f"| {noisy_snr} | {auto_snr} "
        f"| {_s(rec.get('oracle'), 'snr', inproc, timeout, '{:.2f}')} | {ptext} | {row['load_before']:.1f} |"
    )


def format_pair(mesh: dict, which: str, cell: dict) -> str:
    rec = cell["records"]
    ours, theirs = rec.get("ours"), rec.get("theirs")
    peer = "pymeshlab two-step" if which == "two_stage" else "Open3D filter_smooth_taubin"
    if not (ours and theirs):
        return f"| {mesh['label']} | {which} vs {peer} | {'timed out' if cell['timed_out'] else 'failed'} | | | | | | | |"
    diff = rec.get("difference")
    dtext = f"{diff['max_abs'] / diff['scale']:.1e}" if diff else "-"
    return (
        f"| {mesh['label']} | {which} vs {peer} | {ours['seconds']:.2f} ({ours['cpu']:.2f}) "
        f"| {theirs['seconds']:.2f} ({theirs['cpu']:.2f}) | {theirs['seconds'] / ours['seconds']:.2f} "
        f"| {theirs['cpu'] / ours['cpu']:.2f} | {ours['bytes_per_vertex']:.0f} | {theirs['bytes_per_vertex']:.0f} "
        f"| {dtext} | {cell['load']:.1f} |"
    )


def format_peer(mesh: dict, name: str, cell: dict, timeout: float) -> str:
    if "missing" in cell:
        return f"| {mesh['label']} | {name} | not installed ({cell['missing']}) | | | | | | {cell['load']:.1f} |"
    if "skipped" in cell:
        return (f"| {mesh['label']} | {name} | > {timeout:.0f} (not run: over {timeout:.0f} s at {cell['skipped']}) "
                f"| | | | | {PEER_CALLS[name]} | {cell['load']:.1f} |")
    rec = cell["records"].get("call")
    if cell["timed_out"]:
        call = f"{rec['seconds']:.1f}" if rec else f"> {timeout:.0f}"
        return f"| {mesh['label']} | {name} | {call} | > {timeout:.0f} | - | - | - | - | {cell['load']:.1f} |"
    if rec is None or cell["exit"] != 0:
        return f"| {mesh['label']} | {name} | fail | | | | | {' '.join(cell['stderr_tail'])[:80]} | {cell['load']:.1f} |"
    snr = f"{rec['snr']:.2f}" if rec.get("snr") is not None else "-"
    return (f"| {mesh['label']} | {name} | {rec['seconds']:.1f} ({rec['cpu']:.1f}) | {cell['wall']:.1f} "
            f"| {cell['maxrss'] / 2**20:.0f} | {cell['maxrss'] / mesh['n']:.0f} | {snr} | {PEER_CALLS[name]} "
            f"| {cell['load']:.1f} |")


PEER_CALLS = {
    "MeshLib denoise": "mrmeshpy.meshDenoiseViaNormals(mesh, DenoiseViaNormalsSettings())",
    "MeshLab two-step": "pymeshlab apply_coord_two_steps_smoothing() (3, 60 deg, 20, 20)",
    "MeshLab Taubin": "pymeshlab apply_coord_taubin_smoothing() (0.5, -0.53, 10 steps)",
    "Open3D Taubin": "open3d filter_smooth_taubin(10, 0.5, -0.53)",
}
PEER_HEADER = (
    "| size | peer | call s (CPU s) | child wall s | peak MB | peak B/vertex | SNR | call | load |\n"
    "|---|---|---|---|---|---|---|---|---|"
)
ROW_HEADER = (
    "| size | method | choose s | filter s | end-to-end s | peak MB | peak B/vertex | SNR noisy | SNR auto "
    "| SNR oracle | chosen | load |\n|---|---|---|---|---|---|---|---|---|---|---|---|"
)
PAIR_HEADER = (
    "| size | pair | ours s (CPU s) | peer s (CPU s) | peer / ours wall | peer / ours CPU | ours B/vertex "
    "| peer B/vertex | max diff / max coord | load |\n|---|---|---|---|---|---|---|---|---|---|"
)
ARGS_TIMEOUT = 120.0


def main(argv: list[str] | None = None) -> None:
    global ARGS_TIMEOUT
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--child"]:
        kind, a, b = argv[1:4]
        if kind == "prepare":
            emit(stage="mesh", **prepare(a, Path(b)))
        else:
            {"inproc": child_inproc, "pair": child_pair, "peer": child_peer, "snr": child_snr}[kind](a, b)
        return
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", default="100k,400k", help="comma-separated, of " + ", ".join(SIZES))
    ap.add_argument("--methods", default=",".join(METHODS), help="comma-separated filters")
    ap.add_argument("--timeout", type=float, default=120.0, help="seconds per cell (a slower cell is recorded as '> T')")
    ap.add_argument("--out", default=None, help="write OUT.txt (the tables) and OUT.json (everything)")
    ap.add_argument("--cache-dir", default=None)
    ap.add_argument("--no-pairs", action="store_true", help="skip the same-process comparisons with MeshLab / Open3D")
    ap.add_argument("--pairs-only", action="store_true", help="only the same-process comparisons")
    ap.add_argument("--no-e2e", action="store_true", help="skip the command-line cells")
    ap.add_argument("--peer-timeout", type=float, default=None,
                    help="seconds per peer (default: --timeout); a peer over it is not run on the larger sizes")
    ap.add_argument("--no-inproc", action="store_true", help="skip the in-process cells (choose, filter, oracle)")
    ap.add_argument("--peers", action="store_true",
                    help="time the peers at their default settings, each in its own subprocess: " + ", ".join(PEERS))
    ap.add_argument("--criterion", choices=("sure", "normals"), default=None,
                    help="the command-line cells' --criterion (default: each filter's own; the in-process cells "
                         "always time the SURE rule)")
    args = ap.parse_args(argv)
    ARGS_TIMEOUT = args.timeout
    sizes = [s.strip() for s in args.sizes.split(",") if s.strip()]
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    for s in sizes:
        if s not in SIZES:
            ap.error(f"--sizes: unknown size {s!r}; known: {', '.join(SIZES)}")
    for m in methods:
        if m not in METHODS:
            ap.error(f"--methods: unknown method {m!r}; known: {', '.join(METHODS)}")
    folder = cache_dir(args.cache_dir)
    started = time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime())
    uptime_before = subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()
    commit = code_version()
    print(f"{started}; commit {commit}; {uptime_before}", flush=True)
    print(ROW_HEADER, flush=True)
    results = []
    over: dict = {}  # peer -> the size it ran out of time on
    with tempfile.TemporaryDirectory() as work:
        for label in sizes:
            # in a child, so that this process stays small: Linux starts a child's ru_maxrss at its parent's peak
            made = run_limited(me("--child", "prepare", label, str(folder)), 3600.0)
            if "mesh" not in made["records"]:
                sys.exit(f"scale.py: could not make the {label} mesh: {' '.join(made['stderr_tail'])}")
            mesh = made["records"]["mesh"]
            print(f"<!-- {label}: n={mesh['n']} m={mesh['m']} rho={mesh['rho']:.4g} (mean edge {mesh['h']:.4g}) -->", flush=True)
            results.append(
                run_size(mesh, methods, args.timeout, not args.no_pairs, not (args.no_e2e or args.pairs_only),
                         not (args.pairs_only or args.no_inproc), Path(work), args.criterion, args.peers,
                         args.peer_timeout, over)
            )
    uptime_after = subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()
    meta = {
        "started": started,
        "uptime_before": uptime_before,
        "uptime_after": uptime_after,
        "machine": {"cpus": os.cpu_count(), "platform": platform.platform(), "python": platform.python_version()},
        "timeout": args.timeout,
        "peer_timeout": args.peer_timeout,
        "criterion": args.criterion,
        "commit": commit,
        "command": "python benchmarks/scale.py " + " ".join(argv),
    }
    text = [
        f"# benchmarks/scale.py, {started}",
        f"command: {meta['command']}",
        f"commit: {commit}",
        f"machine: {os.cpu_count()} cores, shared with other jobs; uptime before: {uptime_before}; after: {uptime_after}",
        f"noise: {NOISE_EDGES} mean edge length along the normals, seed 0; timeout per cell: {args.timeout:.0f} s"
        + (f", per peer: {args.peer_timeout:.0f} s" if args.peers and args.peer_timeout is not None else ""),
        "choose s, filter s, SNR auto: in process, or with * the command's own stages (the filter with the default's fold "
        "guard) and its output file read back; "
        "end-to-end s and peak: the command `meshdenoise denoise [--method M] IN.ply OUT.ply` in a fresh process",
        "",
    ]
    if not args.pairs_only:
        text += [ROW_HEADER] + [format_row(r["mesh"], m, row) for r in results for m, row in r["methods"].items()] + [""]
    if args.peers:
        peer_timeout = args.timeout if args.peer_timeout is None else args.peer_timeout
        text += [PEER_HEADER] + [format_peer(r["mesh"], n, c, peer_timeout) for r in results
                                 for n, c in r["peers"].items()] + [""]
    if not args.no_pairs:
        text += [PAIR_HEADER] + [format_pair(r["mesh"], w, c) for r in results for w, c in r["pairs"].items()] + [""]
    print("\n".join(text[7:]))
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out + ".txt").write_text("\n".join(text) + "\n")
        Path(args.out + ".json").write_text(json.dumps({"meta": meta, "results": results}, indent=1) + "\n")
        print(f"wrote {args.out}.txt and {args.out}.json")


if __name__ == "__main__":
    main()

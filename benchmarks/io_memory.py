"""Peak memory and time of ``meshdenoise info`` on a large binary PLY (issue 17: under 1.5 GB at 8M faces).

Writes a triangulated ``k x k`` grid (``2 k^2`` faces, float32 coordinates, ``list uchar int
vertex_indices``, the layout MeshLab writes) into a temporary folder, runs
``meshdenoise info --json`` on it in a child process and reports the child's peak resident
memory (``getrusage(RUSAGE_CHILDREN).ru_maxrss``; each run in its own fresh wrapper
process so that the figures do not mix) and wall time. ``--compare PATH`` also runs the
same command with ``PYTHONPATH=PATH`` (another checkout, e.g. the code before this change).
Also measured: refusing a 200 MB file of random bytes (issue 19, item 14), and with
``--text-faces`` the text formats (ASCII PLY, OFF, OBJ as ``save_arrays`` writes them).

    PYTHONPATH=. python benchmarks/io_memory.py --faces 8000000 [--text-faces 2000000] [--compare /path/to/old/checkout]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def write_grid_ply(path: Path, faces: int) -> tuple[int, int]:
    """A flat ``k x k`` grid triangulated into ``2 k^2 >= faces`` triangles, as binary little-endian PLY."""
    k = int(np.ceil(np.sqrt(faces / 2)))
    n = (k + 1) ** 2
    x, y = np.meshgrid(np.arange(k + 1, dtype=np.float32), np.arange(k + 1, dtype=np.float32), indexing="ij")
    V = np.stack([x.ravel(), y.ravel(), (np.sin(x) * np.cos(y)).ravel().astype(np.float32)], axis=1)
    head = (f"ply\nformat binary_little_endian 1.0\ncomment io_memory benchmark grid\nelement vertex {n}\n"
            "property float x\nproperty float y\nproperty float z\n"
            f"element face {2 * k * k}\nproperty list uchar int vertex_indices\nend_header\n").encode()
    with open(path, "wb") as fh:
        fh.write(head)
        fh.write(np.ascontiguousarray(V, "<f4").tobytes())
        del V, x, y
        rec = np.empty(2 * k, np.dtype([("k", "u1"), ("i", "<i4", 3)]))
        rec["k"] = 3
        j = np.arange(k, dtype=np.int64)
        for r in range(k):  # one row of squares at a time: bounded memory
            a, b = r * (k + 1) + j, (r + 1) * (k + 1) + j
            rec["i"][0::2] = np.stack([a, b, a + 1], axis=1)
            rec["i"][1::2] = np.stack([a + 1, b, b + 1], axis=1)
            fh.write(rec.tobytes())
    return n, 2 * k * k


_CHILD = """
import resource, subprocess, sys, time, json
t = time.perf_counter()
p = subprocess.run(sys.argv[1:], capture_output=True, text=True)
dt = time.perf_counter() - t
print(json.dumps({"rc": p.returncode, "seconds": dt,
                  "peak_mib": resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024,
                  "stdout": p.stdout, "stderr": p.stderr[-3000:]}))
"""


def measure(args: list[str], pythonpath: str) -> dict:
    """Run ``meshdenoise *args`` with ``PYTHONPATH``; its peak RSS (MiB), time (s) and output."""
    env = {**os.environ, "PYTHONPATH": pythonpath}
    cmd = [sys.executable, "-c", _CHILD, sys.executable, "-c", "from meshdenoise.cli import cli; cli()", *args]
    # cwd outside any checkout: `python -c` puts the current folder first on sys.path, before PYTHONPATH
    out = subprocess.run(cmd, capture_output=True, text=True, env=env, check=True, cwd=tempfile.gettempdir())
    return json.loads(out.stdout)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--faces", type=int, default=8_000_000)
    ap.add_argument("--compare", default=None, help="another checkout to run the same commands with (old code)")
    ap.add_argument("--garbage-mb", type=int, default=200)
    ap.add_argument("--out", default=None, help="also write the table to this file")
    ap.add_argument("--text-faces", type=int, default=0,
                    help="also time `info` on ASCII PLY, OFF and OBJ grids of this many faces (written by save_arrays)")
    a = ap.parse_args()
    rows = []
    load = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        ply = Path(tmp) / "grid.ply"
        t = time.perf_counter()
        n, m = write_grid_ply(ply, a.faces)
        gen = time.perf_counter() - t
        size = ply.stat().st_size
        garbage = {}
        rng = np.random.default_rng(0)
        for ext in (".ply", ".obj", ".off", ".stl"):
            g = Path(tmp) / f"garbage{ext}"
            with open(g, "wb") as fh:
                for _ in range(a.garbage_mb):
                    fh.write(rng.integers(0, 256, 1 << 20, dtype=np.uint8).tobytes())
            garbage[ext] = g
        text = Path(tmp) / "garbage_text.obj"  # printable text with line ends, no NUL: passes the NUL check
        with open(text, "wb") as fh:
            for _ in range(a.garbage_mb):
                fh.write(rng.integers(32, 127, 1 << 20, dtype=np.uint8).tobytes().replace(b"~", b"\n"))
        garbage["printable text .obj"] = text
        text_files, text_n, text_m = [], 0, 0
        if a.text_faces:
            sys.path.insert(0, str(ROOT))
            from meshdenoise.io import load_mesh, save_arrays

            small = Path(tmp) / "small.ply"
            text_n, text_m = write_grid_ply(small, a.text_faces)
            mesh = load_mesh(small)
            for ext in (".ply", ".off", ".obj"):
                text_files.append(save_arrays(Path(tmp) / f"grid_text{ext}", mesh.V, mesh.F, binary=False))
            del mesh
        checkouts = [("this checkout", str(ROOT))] + ([("compare: " + a.compare, a.compare)] if a.compare else [])
        for label, pp in checkouts:
            r = measure(["info", "--json", str(ply)], pp)
            ok = r["rc"] == 0
            faces = json.loads(r["stdout"][r["stdout"].index("{"):])["faces"] if ok else None
            rows.append((label, f"info --json, {m:,} faces, {n:,} vertices, {size / 2**20:.0f} MiB binary PLY",
                         r["rc"], r["peak_mib"], r["seconds"], "" if ok else r["stderr"].strip().splitlines()[-1][:100]))
            if ok:
                assert faces == m, (faces, m)
            for ext, g in garbage.items():
                r = measure(["info", str(g)], pp)
                what = ext if ext.startswith("printable") else f"random bytes named {ext}"
                rows.append((label, f"info on {a.garbage_mb} MiB of {what}", r["rc"],
                             r["peak_mib"], r["seconds"], r["stderr"].strip().splitlines()[-1][:100] if r["stderr"] else ""))
            for tp in text_files:
                r = measure(["info", "--json", str(tp)], pp)
                rows.append((label, f"info --json, {text_m:,} faces, {text_n:,} vertices, {tp.stat().st_size / 2**20:.0f} "
                             f"MiB {tp.suffix[1:].upper()}{' ASCII' if tp.suffix == '.ply' else ''}", r["rc"],
                             r["peak_mib"], r["seconds"], "" if r["rc"] == 0 else r["stderr"].strip()[-100:]))
            base = measure(["--help"], pp)
            rows.append((label, "--help (interpreter and imports only)", base["rc"], base["peak_mib"], base["seconds"], ""))
    lines = [f"# meshdenoise io memory benchmark ({time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; "
             f"load average {load[0]:.1f} {load[1]:.1f} {load[2]:.1f} on {os.cpu_count()} cores; grid written in {gen:.1f} s)",
             f"# command: PYTHONPATH=. python benchmarks/io_memory.py --faces {a.faces}"
             + (f" --text-faces {a.text_faces}" if a.text_faces else "")
             + (f" --compare {a.compare}" if a.compare else ""),
             "", "| code | command | exit | peak RSS (MiB) | time (s) | message |", "|---|---|---|---|---|---|"]
    for label, what, rc, peak, sec, msg in rows:
        lines.append(f"| {label} | {what} | {rc} | {peak:.0f} | {sec:.1f} | {msg.replace('|', '/')} |")
    text = "\n".join(lines) + "\n"
    print(text)
    if a.out:
        Path(a.out).parent.mkdir(parents=True, exist_ok=True)
        Path(a.out).write_text(text)


if __name__ == "__main__":
    main()

"""Load: 200 small meshes, 10 of them broken, through `meshdenoise run`.

Every good mesh is written and equals the filter applied to its arrays; every broken one is
listed (stderr and the results table) with an error naming it; the peak memory of the run
does not grow with the number of meshes (50 vs 200).

``python -m tests.test_load`` prints the peak memory and run time of each mode.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

import meshdenoise as md
from meshdenoise.io import load_mesh, save_arrays
from meshdenoise.shapes import icosphere

from .brokenmeshes import cases

EXTS = [(".ply", True), (".ply", False), (".off", True), (".obj", True), (".stl", True)]
BROKEN = ["truncated_binary.ply", "truncated_ascii.stl", "nan.off", "missing_vertex.obj", "empty.ply",
          "random_bytes.stl", "two_vertex_face.off", "zero_index.obj", "huge_count.ply", "point_cloud.ply"]
PIPELINE = """inputs: "{folder}/*"
output_dir: {out}
steps:
  - sobolev: {{mu: 1.0}}
  - save: {{path: "{{stem}}_out.ply"}}
results: results
"""


def make_batch(folder: Path, n: int, n_broken: int = 10) -> tuple[dict, list[str]]:
    """``n`` meshes in ``folder``: the good ones (name -> (V, F)) and the names of the broken ones."""
    folder.mkdir(parents=True)
    V0, F = icosphere(3)  # 642 vertices: big enough that a mesh kept alive per task would show in memory
    rng = np.random.default_rng(n)
    corpus = {c.name: c for c in cases()}
    broken_at = set(np.linspace(0, n - 1, n_broken).astype(int).tolist())
    good, broken = {}, []
    for k in range(n):
        if k in broken_at:
            case = corpus[BROKEN[len(broken) % len(BROKEN)]]
            name = f"m{k:03d}{case.ext}"
            (folder / name).write_bytes(case.data)
            broken.append(name)
            continue
        ext, binary = EXTS[k % len(EXTS)]
        V = V0 * rng.uniform(0.5, 2.0) + rng.normal(scale=0.02, size=V0.shape)
        if ext == ".stl" and binary:
            V = V.astype(np.float32).astype(np.float64)  # what the file can hold
        save_arrays(folder / f"m{k:03d}{ext}", V, F, binary=binary)
        good[f"m{k:03d}{ext}"] = (V, F)
    return good, broken


def run_batch(tmp: Path, n: int, serial: bool) -> dict:
    """Run the batch in a child process; returns its exit code, stderr, peak RSS (MiB) and time."""
    good, broken = make_batch(tmp / "in", n)
    out = tmp / "out"
    yaml = tmp / "pipeline.yaml"
    yaml.write_text(PIPELINE.format(folder=tmp / "in", out=out))
    args = [sys.executable, "-c", "from meshdenoise.cli import main; main()", "run", str(yaml)]
    args += ["--serial"] if serial else ["--workers", "2"]
    start = time.perf_counter()
    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "COLUMNS": "400"})
    stdout, stderr = proc.communicate(timeout=300)
    seconds = time.perf_counter() - start
    # RUSAGE_CHILDREN holds the largest peak of the waited-for descendants (Dask workers included)
    import resource

    peak_kib = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    return {"code": proc.returncode, "stdout": stdout, "stderr": stderr, "good": good, "broken": broken,
            "out": out, "seconds": seconds, "peak_mib": peak_kib / 1024}


def _peak_of_child(args: list[str]) -> float:
    """Peak RSS (MiB) of one child process, measured by wait4 for that child alone."""
    proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            env={**os.environ, "COLUMNS": "400"})
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    return usage.ru_maxrss / 1024


def check_outputs(r: dict) -> None:
    assert r["code"] == 2, r["stderr"][-2000:]  # some inputs were broken (bad input), nothing else failed
    flat = " ".join(r["stderr"].split())
    for name in r["broken"]:
        assert name in flat, f"{name} is not listed among the errors"
    assert f"{len(r['broken'])} of {len(r['good']) + len(r['broken'])} task(s) failed" in flat
    rows = json.loads((r["out"] / "results.json").read_text())
    status = {Path(row["input"]).name: row for row in rows}
    assert sorted(k for k, row in status.items() if row["status"] != "ok") == sorted(r["broken"])
    for name in r["broken"]:
        assert name in status[name]["error"]
    written = sorted(p.name for p in r["out"].iterdir() if p.name.endswith("_out.ply"))
    assert written == sorted(f"{Path(n).stem}_out.ply" for n in r["good"])
    assert not [p for p in r["out"].iterdir() if p.name.startswith(".")], "temporary files left behind"
    for name, (V, F) in r["good"].items():
        out = load_mesh(r["out"] / f"{Path(name).stem}_out.ply")
        expected = md.sobolev((V, F), mu=1.0)[0]
        if name.endswith(".stl"):  # vertex numbering is the STL reader's
            np.testing.assert_allclose(out.V[out.F], expected[F], rtol=0, atol=1e-9)
        else:
            np.testing.assert_array_equal(out.F, F)
            np.testing.assert_allclose(out.V, expected, rtol=0, atol=1e-9)


def test_200_meshes_with_10_broken_through_run_on_dask(tmp_path):
    r = run_batch(tmp_path, 200, serial=False)
    check_outputs(r)


def test_memory_is_flat_from_50_to_200_meshes(tmp_path):
    peaks = {}
    for n in (50, 200):
        folder = tmp_path / f"b{n}"
        make_batch(folder / "in", n)
        yaml = folder / "pipeline.yaml"
        yaml.write_text(PIPELINE.format(folder=folder / "in", out=folder / "out"))
        peaks[n] = _peak_of_child([sys.executable, "-c", "from meshdenoise.cli import main; main()",
                                   "run", str(yaml), "--serial"])
        assert len(list((folder / "out").glob("*_out.ply"))) == n - 10
    # 4x the meshes: the peak may grow by the results rows only (under 1 KiB per mesh); one mesh kept
    # alive per task (arrays, MeshSet, cached operators) would add tens of MiB
    assert peaks[200] - peaks[50] < 10, peaks


if __name__ == "__main__":
    import tempfile

    for n in (50, 200):
        with tempfile.TemporaryDirectory() as d:
            folder = Path(d)
            make_batch(folder / "in", n)
            yaml = folder / "pipeline.yaml"
            yaml.write_text(PIPELINE.format(folder=folder / "in", out=folder / "out"))
            base = [sys.executable, "-c", "from meshdenoise.cli import main; main()", "run", str(yaml)]
            t = time.perf_counter()
            peak = _peak_of_child(base + ["--serial"])
            print(f"{n} meshes (10 broken), --serial: peak RSS {peak:.1f} MiB, {time.perf_counter() - t:.1f} s")
        with tempfile.TemporaryDirectory() as d:
            # a fresh parent, so that RUSAGE_CHILDREN holds this run's processes (Dask workers included) only
            code = ("import sys, resource; from pathlib import Path; from tests.test_load import run_batch, check_outputs;"
                    f"r = run_batch(Path({d!r}), {n}, serial=False); check_outputs(r);"
                    "print(r['peak_mib'], r['seconds'])")
            peak, seconds = map(float, subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                                                      check=True).stdout.split())
            print(f"{n} meshes (10 broken), Dask 2 workers: peak RSS of the largest process {peak:.1f} MiB, {seconds:.1f} s")

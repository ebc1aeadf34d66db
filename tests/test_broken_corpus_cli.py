"""The broken-file corpus through the command line: `meshdenoise info`, `denoise` and `run`.

For each file of tests/brokenmeshes.py and each command: a file that must be refused stops
the command with a message naming the file and the problem, no traceback, no output file
(not even a partial or temporary one) and the input unchanged; a file that must be read
gives the right result, compared with the filter applied to the intended arrays.

Commands run in this process through click's runner (fast); a few run as real processes
to check the exit code and the absence of a traceback end to end.
"""

from __future__ import annotations

import hashlib
import json
import re
import subprocess
import sys

import numpy as np
import pytest
from click.testing import CliRunner

import meshdenoise as md
from meshdenoise.cli import cli
from meshdenoise.io import load_mesh

from .brokenmeshes import cases

CASES = cases()
REFUSED = [c for c in CASES if c.expect == "refuse"]
POINT_CLOUDS = [c for c in CASES if c.expect == "read" and c.F.shape[0] == 0]
READ = [c for c in CASES if c.expect == "read" and c.F.shape[0] > 0]
COMMANDS = ("info", "denoise", "run")
PIPELINE = """inputs: {input}
output_dir: {out}
steps:
  - sobolev: {{mu: 1.0}}
  - save: {{path: "{{stem}}_out.ply"}}
"""


def _sha(path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _invoke(command: str, src, tmp_path):
    """Run one command on ``src``; returns (result, the output file it should write, the output folder)."""
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    if command == "info":
        args, target = ["info", "--json", str(src)], None
    elif command == "denoise":
        target = out_dir / "denoised.ply"
        args = ["denoise", str(src), str(target), "--method", "sobolev", "--param", "mu=1.0"]
    else:
        yaml = tmp_path / "pipeline.yaml"
        yaml.write_text(PIPELINE.format(input=src, out=out_dir))
        target = out_dir / f"{src.stem}_out.ply"
        args = ["run", str(yaml), "--serial"]
    result = CliRunner().invoke(cli, args, catch_exceptions=True)
    return result, target, out_dir


def _flat(text: str) -> str:
    """Rich wraps long messages at the terminal width (inside long paths too): join the lines."""
    return re.sub(r"\s+", " ", text)


def _no_traceback(result) -> None:
    assert result.exception is None or isinstance(result.exception, SystemExit), (
        f"uncaught {type(result.exception).__name__}: {result.exception}"
    )
    assert "Traceback" not in result.output + result.stderr


# info describes a point cloud (test_info_describes_point_clouds); denoise and run must refuse it
STOPPING = [(c, cmd) for c in REFUSED for cmd in COMMANDS] + [(c, cmd) for c in POINT_CLOUDS for cmd in ("denoise", "run")]


@pytest.mark.parametrize("case,command", STOPPING, ids=lambda x: getattr(x, "name", x))
def test_refused_file_stops_with_message_naming_file_and_problem(tmp_path, case, command):
    src = tmp_path / case.name
    src.write_bytes(case.data)
    digest = _sha(src)
    result, _, out_dir = _invoke(command, src, tmp_path)
    _no_traceback(result)
    assert result.exit_code != 0
    message = _flat(result.stderr)
    pattern = case.match if case.expect == "refuse" else r"(?i)no faces|point cloud"
    assert case.name in re.sub(r"\s", "", message) and re.search(pattern, message), message
    assert list(out_dir.iterdir()) == [], "an output file (or a temporary one) was left behind"
    assert _sha(src) == digest


@pytest.mark.parametrize("command", ["denoise", "run"])
def test_bad_input_exit_code_is_2_for_denoise_and_run(tmp_path, command):
    codes = {}
    for case in REFUSED + POINT_CLOUDS:
        sub = tmp_path / f"{command}-{case.name}"
        sub.mkdir()
        src = sub / case.name
        src.write_bytes(case.data)
        codes[case.name] = _invoke(command, src, sub)[0].exit_code
    assert {k: v for k, v in codes.items() if v != 2} == {}


@pytest.mark.parametrize("case", REFUSED, ids=lambda c: c.name)
def test_info_exit_code_is_2_for_refused_files(tmp_path, case):
    src = tmp_path / case.name
    src.write_bytes(case.data)
    assert _invoke("info", src, tmp_path)[0].exit_code == 2


@pytest.mark.parametrize("case", POINT_CLOUDS, ids=lambda c: c.name)
def test_info_describes_point_clouds(tmp_path, case):
    src = tmp_path / case.name
    src.write_bytes(case.data)
    result, _, _ = _invoke("info", src, tmp_path)
    assert result.exit_code == 0, result.stderr
    info = json.loads(result.output)
    assert (info["vertices"], info["faces"]) == (len(case.V), 0)


@pytest.mark.parametrize("command", COMMANDS)
@pytest.mark.parametrize("case", READ, ids=lambda c: c.name)
def test_unusual_but_legal_file_gives_the_right_result(tmp_path, case, command):
    src = tmp_path / case.name
    src.write_bytes(case.data)
    digest = _sha(src)
    result, target, out_dir = _invoke(command, src, tmp_path)
    _no_traceback(result)
    assert result.exit_code == 0, _flat(result.stderr)
    assert _sha(src) == digest
    if command == "info":
        info = json.loads(result.output)
        assert (info["vertices"], info["faces"]) == (len(case.V), len(case.F))
        for key, value in (case.info or {}).items():
            assert info[key] == value, key
        return
    assert [p.name for p in out_dir.iterdir()] == [target.name]  # nothing else, no temporary file
    out = load_mesh(target)
    # the filter on the intended arrays; `denoise` moves open borders along their normals by default, a pipeline's
    # filter step moves them freely (as the API's filter does)
    motion = "normal" if command == "denoise" else "free"
    expected = md.sobolev((case.V, case.F), mu=1.0, boundary_motion=motion)[0]
    if case.same_faces_geometry:  # STL: the reader numbers the vertices
        np.testing.assert_allclose(out.V[out.F], expected[case.F], rtol=0, atol=1e-9)
    else:
        np.testing.assert_array_equal(out.F, case.F)
        np.testing.assert_allclose(out.V, expected, rtol=0, atol=1e-9)
    if case.colors is not None:  # 8-bit colours on output, as MeshLab keeps them: 0.051 comes back as 13/255
        np.testing.assert_allclose(out.vertex_colors[:, :3], case.colors, rtol=0, atol=0.5 / 255 + 1e-12)
    else:  # no colours in, no colours out (pymeshlab's default white is not written)
        assert out.vertex_colors is None
        assert b"red" not in target.read_bytes()[:400]


@pytest.mark.parametrize("ext", [".ply", ".off", ".obj"])
def test_colourless_input_gives_colourless_output_in_every_format(tmp_path, ext):
    case = next(c for c in CASES if c.name == "plain.off")
    src = tmp_path / case.name
    src.write_bytes(case.data)
    dst = tmp_path / f"out{ext}"
    result = CliRunner().invoke(cli, ["denoise", str(src), str(dst), "--method", "sobolev", "--param", "mu=1.0"])
    assert result.exit_code == 0, result.stderr
    text = dst.read_bytes()
    assert load_mesh(dst).vertex_colors is None
    if ext == ".off":
        assert text.startswith(b"OFF\n")
    elif ext == ".obj":  # every vertex line has exactly 3 numbers
        assert {len(ln.split()) for ln in text.decode().splitlines() if ln.startswith("v ")} == {4}
    else:
        assert b"property uchar red" not in text


def test_coloured_input_keeps_its_colours_exactly(tmp_path):
    case = next(c for c in CASES if c.name == "colour_int.coff.off")
    src = tmp_path / case.name
    src.write_bytes(case.data)
    dst = tmp_path / "out.ply"
    result = CliRunner().invoke(cli, ["denoise", str(src), str(dst), "--method", "sobolev", "--defaults"])
    assert result.exit_code == 0, result.stderr
    np.testing.assert_array_equal(np.rint(load_mesh(dst).vertex_colors[:, :3] * 255), np.rint(case.colors * 255))


def _selection_case(name="meshlab_selection.ply"):
    return next(c for c in CASES if c.name == name)


def test_region_from_selection_moves_only_the_selected_vertices(tmp_path):
    case = _selection_case()
    src = tmp_path / case.name
    src.write_bytes(case.data)
    dst = tmp_path / "out.ply"
    result = CliRunner().invoke(cli, ["denoise", str(src), str(dst), "--method", "sobolev", "--param", "mu=1.0",
                                      "--region-from-selection"])
    assert result.exit_code == 0, result.stderr
    out = load_mesh(dst)
    region = np.flatnonzero(case.selection)
    expected = md.sobolev((case.V, case.F), mu=1.0, region=region)[0]
    np.testing.assert_allclose(out.V, expected, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(out.V[~case.selection], case.V[~case.selection])
    assert not np.allclose(out.V[case.selection], case.V[case.selection])


def test_pinned_selection_keeps_the_selected_vertices(tmp_path):
    case = _selection_case()
    src = tmp_path / case.name
    src.write_bytes(case.data)
    dst = tmp_path / "out.ply"
    result = CliRunner().invoke(cli, ["denoise", str(src), str(dst), "--method", "sobolev", "--param", "mu=1.0",
                                      "--pinned", "selection"])
    assert result.exit_code == 0, result.stderr
    out = load_mesh(dst)
    expected = md.sobolev((case.V, case.F), mu=1.0, pinned=np.flatnonzero(case.selection))[0]
    np.testing.assert_allclose(out.V, expected, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(out.V[case.selection], case.V[case.selection])


@pytest.mark.parametrize("key", ["region", "pinned"])
def test_pipeline_selection_comes_from_the_ply(tmp_path, key):
    case = _selection_case()
    src = tmp_path / case.name
    src.write_bytes(case.data)
    out_dir = tmp_path / "out"
    yaml = tmp_path / "p.yaml"
    yaml.write_text(f"inputs: {src}\noutput_dir: {out_dir}\nsteps:\n  - sobolev: {{mu: 1.0, {key}: selection}}\n"
                    "  - save: {path: \"{stem}_out.ply\"}\n")
    result = CliRunner().invoke(cli, ["run", str(yaml), "--serial"])
    assert result.exit_code == 0, result.output + result.stderr
    out = load_mesh(out_dir / "meshlab_selection_out.ply")
    expected = md.sobolev((case.V, case.F), mu=1.0, **{key: np.flatnonzero(case.selection)})[0]
    np.testing.assert_allclose(out.V, expected, rtol=0, atol=1e-12)


@pytest.mark.parametrize("name", ["meshlab_selection_bad_face.ply", "meshlab_selection_negative_face.ply",
                                  "truncated_binary.ply", "random_bytes.ply", "plain_ascii.ply"])
def test_region_from_selection_on_a_broken_or_selectionless_file_names_the_real_problem(tmp_path, name):
    """The file goes through our reader first (pymeshlab's loader crashed on bad face indices)."""
    case = next(c for c in CASES if c.name == name)
    src = tmp_path / case.name
    src.write_bytes(case.data)
    dst = tmp_path / "out" / "o.ply"
    proc = subprocess.run([sys.executable, "-c", "from meshdenoise.cli import main; main()", "denoise", str(src),
                           str(dst), "--method", "sobolev", "--defaults", "--region-from-selection"],
                          capture_output=True, text=True, timeout=120, env={**_env(), "COLUMNS": "500"})
    assert proc.returncode == 2, (proc.returncode, proc.stderr)
    message = _flat(proc.stderr)
    assert "Traceback" not in message and case.name in message
    expected = case.match if case.expect == "refuse" else r"stores no selection"
    assert re.search(expected, message), message
    assert not dst.parent.exists()


def test_info_json_is_valid_json_even_when_the_diagonal_overflows(tmp_path):
    src = tmp_path / "huge.off"
    src.write_text("OFF\n3 1 0\n-1.7e308 0 0\n1.7e308 0 0\n0 1.7e308 0\n3 0 1 2\n")
    result = CliRunner().invoke(cli, ["info", "--json", str(src)])
    assert result.exit_code == 0, result.stderr

    def no_constant(name):
        raise AssertionError(f"not JSON: {name}")

    info = json.loads(result.output, parse_constant=no_constant)
    assert info["bbox_diagonal"] is None and info["bbox_max"][0] == 1.7e308


def test_output_path_equal_to_input_is_refused_and_input_kept(tmp_path):
    src = tmp_path / "plain.off"
    src.write_bytes(next(c for c in CASES if c.name == "plain.off").data)
    digest = _sha(src)
    result = CliRunner().invoke(cli, ["denoise", str(src), str(src), "--method", "sobolev", "--defaults"])
    assert result.exit_code == 2 and "neveroverwritten" in re.sub(r"\s", "", result.stderr)
    assert _sha(src) == digest


@pytest.mark.parametrize("command", COMMANDS)
def test_real_process_on_a_truncated_file_exits_cleanly(tmp_path, command):
    """End to end in a child process: the exit code is not a crash and stderr has no traceback."""
    case = next(c for c in CASES if c.name == "truncated_binary.ply")
    src = tmp_path / case.name
    src.write_bytes(case.data)
    out_dir = tmp_path / "out"
    args = {"info": ["info", str(src)],
            "denoise": ["denoise", str(src), str(out_dir / "o.ply"), "--method", "sobolev", "--defaults"],
            "run": ["run", str(tmp_path / "p.yaml")]}[command]
    (tmp_path / "p.yaml").write_text(PIPELINE.format(input=src, out=out_dir))
    proc = subprocess.run([sys.executable, "-c", "from meshdenoise.cli import main; main()", *args],
                          capture_output=True, text=True, timeout=120, env={**_env(), "COLUMNS": "500"})
    assert proc.returncode in (1, 2), proc.stderr
    assert "Traceback" not in proc.stderr and case.name in proc.stderr and "truncated" in proc.stderr
    assert not out_dir.exists() or list(out_dir.iterdir()) == []


def _env() -> dict:
    import os

    return dict(os.environ)

"""Classes of defects found by a hostile user: each test covers its class, not only the case found.

Documented for users in docs/reliability.md ("Interrupts, warnings and files", "Numbers", "Vertex options").
"""

from __future__ import annotations

import hashlib
import os
import re
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import yaml
from click.testing import CliRunner
from hypothesis import given, settings
from hypothesis import strategies as st

import meshdenoise as md
from meshdenoise.cli import cli
from meshdenoise.io import STL_TOLERANCE, MeshFileError, PrecisionWarning, atomic_path, float32_move, load_mesh, save_mesh
from meshdenoise.pipeline.mlx import mlx_to_steps, steps_to_mlx
from meshdenoise.pipeline.errors import PipelineValidationError
from meshdenoise.pipeline.yamlsource import NumberLoader, load_yaml
from meshdenoise.pipeline.variables import parse_assignment
from meshdenoise.registry import ParameterError, parse_number
from meshdenoise.shapes import grid, icosphere

SCRIPT = Path(sys.executable).parent / "meshdenoise"  # the console script of this environment
REPO = Path(__file__).resolve().parents[1]


def _cli(*args):
    return CliRunner().invoke(cli, [str(a) for a in args], catch_exceptions=True)


def _one_line_error(result, *needles, code=2):
    """Exit ``code``, no traceback, a single ``error:`` line (and nothing else on stderr) holding every needle."""
    assert result.exception is None or isinstance(result.exception, SystemExit), (
        f"uncaught {type(result.exception).__name__}: {result.exception}")
    text = result.output + result.stderr
    assert "Traceback" not in text and "Usage:" not in text, text
    assert result.exit_code == code, text
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    errors = [line for line in lines if line.startswith("error:")]
    assert len(errors) == 1 and lines[-1] == errors[0], result.stderr
    for needle in needles:
        assert needle in errors[0], (needle, errors[0])
    return errors[0]


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture
def mesh_file(tmp_path):
    return save_mesh(tmp_path / "sphere.ply", *icosphere(1))


def _default_sigint() -> None:
    """In the child before exec: Ctrl-C's default action, as a terminal starts a program. A suite run in the
    background of a non-interactive shell (``make test &``) has SIGINT ignored, and an ignored signal is inherited."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _env(**extra) -> dict:
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_CACHE")}
    env.update(extra)
    return env


# --- inputs are never overwritten, whatever the spelling ---------------------------------------------------
def _spell(path: Path, how: str) -> str:
    if how == "same":
        return str(path)
    if how == "dot":
        return f"{path.parent}/./{path.name}"
    if how == "dotdot":
        (path.parent / "sub").mkdir(exist_ok=True)
        return str(path.parent / "sub" / ".." / path.name)
    link = path.parent / f"{how}{path.suffix}"
    if how == "symlink":
        link.symlink_to(path)
    else:
        os.link(path, link)
    return str(link)


@pytest.mark.parametrize("how", ["same", "dot", "dotdot", "symlink", "hardlink"])
@pytest.mark.parametrize("command", ["mlx2yaml", "yaml2mlx"])
def test_a_conversion_never_writes_onto_its_input(tmp_path, command, how):
    src = tmp_path / "q.yaml"
    src.write_text("inputs: in.ply\nsteps:\n  - sobolev: {mu: 1}\n  - save: {path: o.ply}\n")
    if command == "mlx2yaml":
        src = tmp_path / "q.mlx"
        src.write_text(steps_to_mlx([{"sobolev": {"mu": 1.0}}]))
    before = _sha(src)
    out = _spell(src, how)
    _one_line_error(_cli(command, src, "-o", out), "input files are never overwritten", Path(out).name)
    assert _sha(src) == before and (how != "symlink" or Path(out).is_symlink())


@pytest.mark.parametrize("how", ["dotdot", "symlink", "hardlink"])
def test_denoise_never_writes_onto_its_input(tmp_path, mesh_file, how):
    before = _sha(mesh_file)
    _one_line_error(_cli("denoise", "--method", "sobolev", "--defaults", mesh_file, _spell(mesh_file, how)), "never overwritten")
    assert _sha(mesh_file) == before


# --- outputs replace files only -------------------------------------------------------------------------
def _non_file(tmp_path: Path, kind: str, name: str) -> Path:
    """``tmp_path/name``, a symbolic link to a device, a pipe, a folder or a name with no mesh extension."""
    link = tmp_path / name
    if kind == "device":
        link.symlink_to("/dev/full")
    elif kind == "fifo":
        os.mkfifo(tmp_path / f"fifo{link.suffix}")
        link.symlink_to(tmp_path / f"fifo{link.suffix}")
    elif kind == "folder":
        (tmp_path / f"folder{link.suffix}").mkdir()
        link.symlink_to(tmp_path / f"folder{link.suffix}")
    else:
        link.symlink_to(tmp_path / "no_extension")
    return link


@pytest.mark.parametrize("kind", ["device", "fifo", "folder", "no_extension"])
def test_an_out_that_is_no_mesh_file_is_one_line(tmp_path, mesh_file, kind):
    out = _non_file(tmp_path, kind, "o.ply")
    _one_line_error(_cli("denoise", "--method", "sobolev", "--defaults", mesh_file, out), "o.ply")
    assert out.is_symlink() and not (tmp_path / "no_extension").exists()
    assert kind != "fifo" or (tmp_path / "fifo.ply").is_fifo()


@pytest.mark.parametrize("kind", ["device", "fifo", "folder"])
def test_a_conversion_output_that_is_no_file_is_one_line(tmp_path, kind):
    src = tmp_path / "q.yaml"
    src.write_text("inputs: in.ply\nsteps:\n  - sobolev: {mu: 1}\n")
    out = _non_file(tmp_path, kind, "o.mlx")
    _one_line_error(_cli("yaml2mlx", src, "-o", out), "o.mlx")
    assert out.is_symlink()


def test_every_write_refuses_to_replace_a_pipe_or_a_folder(tmp_path):
    fifo = tmp_path / "f.ply"
    os.mkfifo(fifo)
    (tmp_path / "d.ply").mkdir()
    for path in (fifo, tmp_path / "d.ply"):
        with pytest.raises(MeshFileError, match="not a file"):
            with atomic_path(path) as tmp:
                tmp.write_text("x")
    assert fifo.is_fifo() and (tmp_path / "d.ply").is_dir() and sorted(p.name for p in tmp_path.iterdir()) == ["d.ply", "f.ply"]


def test_a_pipeline_saving_onto_a_pipe_is_an_output_failure(tmp_path, mesh_file):
    out = tmp_path / "out"
    out.mkdir()
    os.mkfifo(out / "r.ply")
    p = tmp_path / "p.yaml"
    p.write_text(f"inputs: {mesh_file}\noutput_dir: {out}\nsteps:\n  - sobolev: {{mu: 1}}\n  - save: {{path: r.ply}}\n")
    r = _cli("run", p, "--serial")
    assert r.exit_code == 2 and "not a file" in r.stderr and (out / "r.ply").is_fifo(), r.output


def test_only_the_error_is_printed_when_a_conversion_cannot_be_written(tmp_path):
    script = tmp_path / "s.mlx"
    script.write_text(steps_to_mlx([{"apply_coord_taubin_smoothing": {"stepsmoothnum": 2}}]))
    pipeline = tmp_path / "p.yaml"  # its save step is left out of a script, with a note
    pipeline.write_text("inputs: in.ply\nsteps:\n  - apply_coord_taubin_smoothing: {stepsmoothnum: 2}\n  - save: {path: o.ply}\n")
    assert "note:" in _cli("yaml2mlx", pipeline).stderr and "note:" in _cli("mlx2yaml", script).stderr
    for args in (["mlx2yaml", script, "-o", "/proc/p.yaml"], ["yaml2mlx", pipeline, "-o", "/proc/p.mlx"]):
        r = _cli(*args)
        _one_line_error(r, "/proc/p.")
        assert "note:" not in r.stderr


# --- a folder or a missing file as an argument: one line -------------------------------------------------
def test_file_and_folder_arguments_click_refuses_are_one_line(tmp_path, mesh_file):
    folder = tmp_path / "scans.ply"
    folder.mkdir()
    plain = tmp_path / "plain.txt"
    plain.write_text("x")
    yml = tmp_path / "p.yaml"
    yml.write_text("inputs: in.ply\nsteps: [sobolev]\n")
    cases = [
        (["denoise", folder, tmp_path / "o.ply"], "a folder, not a file (IN)"),
        (["denoise", mesh_file, folder], "a folder, not a file (OUT)"),
        (["info", folder], "a folder, not a file"),
        (["run", folder], "a folder, not a file"),
        (["mlx2yaml", folder], "a folder, not a file"),
        (["mlx2yaml", tmp_path / "missing.mlx"], "no such file"),
        (["yaml2mlx", yml, "-o", folder], "a folder, not a file"),
        (["render", mesh_file, folder, "--png", tmp_path / "x.png"], "a folder, not a file"),
        (["show", folder], "a folder, not a file"),
        (["demo", "--mesh", folder], "a folder, not a file (--mesh)"),
        (["demo", "--out", plain], "a file, not a folder (--out)"),
        (["report", plain], "a file, not a folder"),
    ]
    for args, needle in cases:
        line = _one_line_error(_cli(*args), needle)
        assert str(folder) in line or str(plain) in line or "missing.mlx" in line, line


# --- binary STL's float32 is said -------------------------------------------------------------------------
@pytest.mark.parametrize("offset", [0.0, 1e3, 1e5, 1e6, 1e7])
def test_binary_stl_warns_exactly_when_float32_moves_a_vertex_noticeably(tmp_path, offset):
    V, F = icosphere(2)
    V = V * 0.02 + np.array([offset, 2 * offset, 10.0])
    path = tmp_path / "scan.stl"
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        save_mesh(path, V, F)
        save_mesh(tmp_path / "scan.ply", V, F)
        save_mesh(tmp_path / "ascii.stl", V, F, binary=False)
    said = [w for w in caught if issubclass(w.category, PrecisionWarning)]
    back = load_mesh(path)
    moves = np.sqrt(((back.V[back.F] - V[F]) ** 2).sum(axis=2))  # STL keeps the corners in face order
    move, h = float32_move(V, F)
    assert move == pytest.approx(moves.max(), rel=1e-12, abs=1e-300)
    assert len(said) == (1 if moves.max() > STL_TOLERANCE * h else 0), [str(w.message) for w in caught]
    if said:
        assert str(path) in str(said[0].message) and f"{moves.max():.3g}" in str(said[0].message)
    np.testing.assert_array_equal(load_mesh(tmp_path / "scan.ply").V, V)
    assert offset < 1e6 or said  # the georeferenced scans of the report warn


def test_the_command_line_says_the_stl_precision_in_one_line(tmp_path):
    V, F = icosphere(2)
    save_mesh(tmp_path / "geo.ply", V * 0.02 + np.array([1e6, 2e6, 10.0]), F)
    r = _cli("denoise", "--method", "sobolev", "--defaults", tmp_path / "geo.ply", tmp_path / "geo.stl")
    assert r.exit_code == 0, r.output
    lines = [line for line in r.stderr.splitlines() if "float32" in line]
    assert len(lines) == 1 and lines[0].startswith(f"warning: {tmp_path / 'geo.stl'}: binary STL"), r.stderr
    assert "Warning" not in r.stderr and ".py:" not in r.stderr


# --- one number reader -------------------------------------------------------------------------------------
NOT_DECIMAL = ["0x10", "0b11", "0o10", "1:30", "1:30.5", "-0x10"]


def _denoise_param(tmp_path, mesh_file, name, text):
    method = "filtering" if name == "iterations" else "sobolev"
    return _cli("denoise", "--method", method, "--param", f"{name}={text}", mesh_file, tmp_path / "o.ply")


def _pipeline_with(tmp_path, mesh_file, name, text, how):
    method = "filtering" if name == "iterations" else "sobolev"
    value = '"${v}"' if how == "set" else text
    p = tmp_path / "p.yaml"
    p.write_text(f"inputs: {mesh_file}\noutput_dir: {tmp_path / 'out'}\nsteps:\n  - {method}: {{{name}: {value}}}\n"
                 "  - save: {path: o.ply}\n")
    return _cli("run", p, "--serial", *(["--set", f"v={text}"] if how == "set" else []))


@pytest.mark.parametrize("how", ["param", "set", "yaml"])
@pytest.mark.parametrize("name", ["iterations", "mu"])
@pytest.mark.parametrize("text", NOT_DECIMAL)
def test_yaml_1_1_number_forms_are_refused_however_they_arrive(tmp_path, mesh_file, text, name, how):
    r = _denoise_param(tmp_path, mesh_file, name, text) if how == "param" else _pipeline_with(tmp_path, mesh_file, name, text, how)
    _one_line_error(r, f"'{name}'", repr(text))
    with pytest.raises(TypeError):  # as parse_number itself says
        parse_number(text, int if name == "iterations" else float)


@pytest.mark.parametrize("how", ["param", "set", "yaml"])
def test_a_leading_zero_is_decimal_however_the_number_arrives(tmp_path, mesh_file, how):
    r = _denoise_param(tmp_path, mesh_file, "mu", "010") if how == "param" else _pipeline_with(tmp_path, mesh_file, "mu", "010", how)
    assert r.exit_code == 0, r.output
    out = tmp_path / ("o.ply" if how == "param" else "out/o.ply")
    V, F = load_mesh(mesh_file).V, load_mesh(mesh_file).F
    np.testing.assert_allclose(load_mesh(out).V, md.sobolev((V, F), mu=10.0)[0], rtol=0, atol=1e-12)


_NUMBERISH = st.text(alphabet="0123456789_.:eExXbBoO+- ", min_size=1, max_size=9).filter(str.strip)


@settings(max_examples=400, deadline=None)
@given(_NUMBERISH)
def test_yaml_reads_a_number_exactly_when_parse_number_does(text):
    """--param, --set and pipeline files read values with one loader, whose numbers are parse_number's."""
    try:
        value = yaml.load(text, Loader=NumberLoader)  # noqa: S506 (a safe loader)
    except yaml.YAMLError:
        return
    assert parse_assignment(f"x={text}")[1] == value
    try:
        assert load_yaml(f"x: {text}\n")["x"] == value
    except PipelineValidationError:  # '0:' is a value alone, not after a key
        pass
    if isinstance(value, bool) or value is None or not isinstance(value, (int, float)):
        with pytest.raises(TypeError):
            parse_number(text, float)
        return
    assert parse_number(text, float) == float(value)
    if isinstance(value, int):
        assert parse_number(text, int) == value


# --- --set names a variable the pipeline has --------------------------------------------------------------
def test_set_of_a_name_the_pipeline_does_not_have_is_refused(tmp_path, mesh_file):
    p = tmp_path / "p.yaml"
    p.write_text(f"variables: {{mu: 1}}\ninputs: {mesh_file}\noutput_dir: {tmp_path / 'out'}\nsteps:\n"
                 "  - sobolev: {mu: '${mu}', tol: '${alpha}'}\n  - save: {path: '{stem}_{setting}.ply'}\nsweep: {k: [1, 2]}\n")
    for name in ("nosuch", "MU", "mu_"):
        for extra in ([], ["--check"]):
            _one_line_error(_cli("run", p, "--set", f"{name}=5", "--set", "alpha=1e-8", *extra),
                            f"--set {name}", "alpha, k, mu")
    assert _cli("run", p, "--check", "--set", "mu=2", "--set", "k=3", "--set", "alpha=1e-8").exit_code == 0
    from meshdenoise.pipeline import load_pipeline

    with pytest.raises(PipelineValidationError, match="no variable 'nosuch'"):
        load_pipeline(p, overrides={"nosuch": 1, "alpha": 1e-8})


# --- vertex options ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("args", [["--pinned", "selection"], ["--region-from-selection"]])
def test_selection_options_on_a_file_without_selection_are_refused(tmp_path, mesh_file, args):
    _one_line_error(_cli("denoise", "--method", "sobolev", "--defaults", *args, mesh_file, tmp_path / "o.ply"), "sphere.ply", "selection")
    assert not (tmp_path / "o.ply").exists()


@pytest.mark.parametrize("key", ["pinned", "region"])
def test_a_pipeline_selection_on_a_mesh_without_one_is_bad_input(tmp_path, mesh_file, key):
    p = tmp_path / "p.yaml"
    p.write_text(f"inputs: {mesh_file}\noutput_dir: {tmp_path / 'out'}\nsteps:\n  - sobolev: {{{key}: selection}}\n"
                 "  - save: {path: o.ply}\n")
    r = _cli("run", p, "--serial")
    assert r.exit_code == 2 and f"{key}: selection" in r.stderr and "no selected vertex" in r.stderr, r.output
    assert not (tmp_path / "out" / "o.ply").exists()


@pytest.mark.parametrize("key", ["pinned", "region"])
def test_the_api_refuses_a_selection_that_selects_nothing(key):
    import pymeshlab

    V, F = icosphere(2)
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(V, F.astype(np.int32)))
    with pytest.raises(ValueError, match=f"{key}='selection': the mesh has no selected vertex"):
        md.sobolev(ms, mu=1.0, **{key: "selection"})
    np.testing.assert_array_equal(ms.current_mesh().vertex_matrix(), V)


@pytest.mark.parametrize("name", ["sobolev", "filtering", "taubin"])
@pytest.mark.parametrize("key", ["pinned", "region"])
@pytest.mark.parametrize("bad,shown", [([-1], -1), ([0, 5, -3], -3), (np.array([-162]), -162), ([162], 162), ([0, 10**9], 10**9)])
def test_vertex_indices_outside_the_mesh_are_refused_showing_the_index(name, key, bad, shown):
    V, F = icosphere(2)  # 162 vertices
    with pytest.raises(ValueError, match=rf"{key}: vertex index {shown} is out of range 0\.\.161"):
        md.apply_filter(name, (V, F), **{key: bad})


def test_a_pinned_index_outside_the_mesh_in_a_pipeline_is_bad_input(tmp_path, mesh_file):
    p = tmp_path / "p.yaml"
    p.write_text(f"inputs: {mesh_file}\noutput_dir: {tmp_path / 'out'}\nsteps:\n  - sobolev: {{pinned: [0, 99999]}}\n")
    r = _cli("run", p, "--serial")
    assert r.exit_code == 2 and "vertex index 99999" in r.stderr, r.output


def test_preserve_volume_on_a_flat_mesh_is_bad_input(tmp_path):
    save_mesh(tmp_path / "flat.ply", *grid(6, 6))
    _one_line_error(_cli("denoise", "--method", "sobolev", "--defaults", "--preserve-volume", tmp_path / "flat.ply", tmp_path / "o.ply"),
                    "flat.ply", "preserve_volume", "encloses no volume")
    with pytest.raises(ParameterError, match="preserve_volume"):
        md.sobolev(grid(6, 6), preserve_volume=True)


@pytest.mark.parametrize("call", [
    lambda mesh: md.denoise(mesh, method="nosuch"),
    lambda mesh: md.apply_filter("nosuch", mesh),
    lambda mesh: md.get_filter("nosuch"),
    lambda mesh: md.choose_parameters(mesh, method="nosuch"),
    lambda mesh: md.get_filter(3),
])
def test_an_unknown_filter_is_a_value_error_showing_the_name(call):
    with pytest.raises(ValueError, match=r"unknown filter ('nosuch'|3); known filters: .*sobolev") as info:
        call(icosphere(1))
    assert isinstance(info.value, KeyError)


# --- warnings: one plain line each -------------------------------------------------------------------------
def test_every_warning_on_the_command_line_is_one_plain_line(tmp_path, mesh_file, monkeypatch):
    from meshdenoise.pipeline import runner

    real = runner.run_step

    def warning_step(step, ctx):
        warnings.warn("a step said [bold]this[/bold]\non two lines", UserWarning)
        warnings.warn("and this", DeprecationWarning)
        return real(step, ctx)

    monkeypatch.setattr(runner, "run_step", warning_step)
    p = tmp_path / "p.yaml"
    p.write_text(f"inputs: {mesh_file}\noutput_dir: {tmp_path / 'out'}\nsteps:\n  - sobolev: {{mu: 1}}\n")
    for args in (["denoise", "--method", "sobolev", "--defaults", mesh_file, tmp_path / "o.ply"], ["run", p, "--serial"]):
        r = _cli(*args)
        assert r.exit_code == 0, r.output
        assert "warning: a step said [bold]this[/bold] on two lines" in r.stderr.splitlines(), r.stderr
        assert "warning: and this" in r.stderr.splitlines()
        assert "Warning:" not in r.stderr and ".py:" not in r.stderr, r.stderr


def test_warnings_of_dask_workers_come_back_as_one_line_each(tmp_path):
    V, F = icosphere(2)
    for k in range(2):
        save_mesh(tmp_path / f"geo{k}.ply", V * 0.02 + np.array([1e6, 2e6, 10.0 + k]), F)
    p = tmp_path / "p.yaml"
    p.write_text(f"inputs: [geo0.ply, geo1.ply]\noutput_dir: {tmp_path / 'out'}\nsteps:\n  - sobolev: {{mu: 1}}\n"
                 "  - save: {path: '{stem}.stl'}\n")
    r = subprocess.run([sys.executable, "-c", "import sys; from meshdenoise.cli import main; sys.argv[1:] = ['run', "
                        f"{str(p)!r}, '--workers', '2']; main()"], capture_output=True, text=True, timeout=600, env=_env())
    assert r.returncode == 0, r.stderr
    said = [line for line in r.stderr.splitlines() if "float32" in line]
    assert sorted(said) == sorted(f"warning: {tmp_path / 'out' / f'geo{k}.stl'}: binary STL stores float32 coordinates: "
                                  f"{line.split('coordinates: ', 1)[1]}" for k, line in enumerate(sorted(said)))
    assert len(said) == 2 and "UserWarning" not in r.stderr and "PrecisionWarning" not in r.stderr, r.stderr


@pytest.mark.parametrize("method", ["sobolev_bilaplacian", "taubin", "sobolev", "heat"])
def test_a_warning_never_advises_the_filter_being_run(method):
    from meshdenoise.tuning.choose import LESS_SHRINKING, _warn_if_worse_than_input

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        _warn_if_worse_than_input(method, {"x": 1}, SimpleNamespace(position_gain_db=-3.0), {"x": 0.1}, 1.0, 2.0)
    advice = re.search(r"shrinks less \(([^)]*)\)$", str(caught[0].message)).group(1).split(", ")
    assert method not in advice and advice == [f for f in LESS_SHRINKING if f != method], advice


# --- Ctrl-C: exit 130, no traceback, no Aborted!, cleanup done -----------------------------------------------
@pytest.mark.parametrize("command", ["denoise", "run"])
def test_an_interrupted_command_exits_130_without_aborted(tmp_path, mesh_file, monkeypatch, command):
    from meshdenoise.pipeline import runner

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(runner, "run_step", interrupted)
    p = tmp_path / "p.yaml"
    p.write_text(f"inputs: {mesh_file}\noutput_dir: {tmp_path / 'out'}\nsteps:\n  - sobolev: {{mu: 1}}\n")
    args = ["denoise", "--method", "sobolev", "--defaults", mesh_file, tmp_path / "o.ply"] if command == "denoise" else ["run", p, "--serial"]
    r = _cli(*args)
    assert r.exit_code == 130 and "Aborted" not in r.output + r.stderr and "Traceback" not in r.stderr, r.output


_SLOW_RUN = r"""
import sys, time
sys.argv[0] = "meshdenoise"  # as the console script: what meshdenoise._launch looks for
import meshdenoise.io as mio

def slow(fh, *args, **kwargs):
    fh.write(b"ply\n" * 1000)
    fh.flush()
    print("writing", flush=True)
    time.sleep(60)  # the signal arrives here, mid-write

mio._WRITERS[".ply"] = slow
from meshdenoise.cli import main
sys.argv[1:] = sys.argv[2:]
main()
"""


@pytest.mark.parametrize("command", ["denoise", "run"])
def test_sigint_mid_write_exits_130_and_leaves_nothing(tmp_path, mesh_file, command):
    out = tmp_path / "out"
    p = tmp_path / "p.yaml"
    p.write_text(f"inputs: {mesh_file}\noutput_dir: {out}\nsteps:\n  - sobolev: {{mu: 1}}\n  - save: {{path: r.ply}}\n")
    args = ["denoise", "--method", "sobolev", "--defaults", str(mesh_file), str(out / "r.ply")] if command == "denoise" else ["run", str(p), "--serial"]
    proc = subprocess.Popen([sys.executable, "-c", _SLOW_RUN, "-", *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env=_env(), preexec_fn=_default_sigint)
    try:
        while True:
            line = proc.stdout.readline()
            assert line, proc.stderr.read()
            if line.strip() == "writing":
                break
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 130 and "Traceback" not in err and "Aborted" not in err, (proc.returncode, err)
    assert not out.exists() or [p.name for p in out.iterdir() if p.name.endswith(".ply")] == [], list(out.iterdir())


_INTERRUPTED_IMPORT = r"""
import builtins, sys
sys.argv[0] = sys.argv[1]
real = builtins.__import__

def interrupting(name, *args, **kwargs):
    if name == "scipy.sparse":
        raise KeyboardInterrupt
    return real(name, *args, **kwargs)

builtins.__import__ = interrupting
from meshdenoise.cli import main
main()
"""


@pytest.mark.parametrize("program", ["meshdenoise", "someone_elses_script.py"])
def test_ctrl_c_while_loading_is_130_in_the_command_and_a_keyboard_interrupt_elsewhere(program):
    r = subprocess.run([sys.executable, "-c", _INTERRUPTED_IMPORT, program, "filters"], capture_output=True, text=True,
                       timeout=300, env=_env())
    if program == "meshdenoise":
        assert r.returncode == 130 and r.stderr == "" and r.stdout == "", (r.returncode, r.stderr)
    else:  # a library is imported as Python does it: the interrupt goes on to its caller
        assert r.returncode != 0 and "KeyboardInterrupt" in r.stderr, (r.returncode, r.stderr)


@pytest.mark.skipif(not SCRIPT.is_file(), reason="no meshdenoise console script beside this Python")
@pytest.mark.parametrize("delay", [0.15, 0.5])
def test_a_real_ctrl_c_while_the_program_loads_is_130_and_silent(delay):
    proc = subprocess.Popen([str(SCRIPT), "filters"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=_env(),
                            preexec_fn=_default_sigint)
    time.sleep(delay)
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=120)
    if proc.returncode == 0:  # it had loaded and finished: nothing to say about an interrupt
        pytest.skip(f"the program finished within {delay} s")
    assert proc.returncode == 130 and err == "", (proc.returncode, err)


@pytest.mark.skipif(not SCRIPT.is_file(), reason="no meshdenoise console script beside this Python")
def test_ctrl_c_during_a_dask_batch_exits_130_without_traceback(tmp_path):
    # six 41k-vertex meshes (the default takes seconds on each): the batch outlasts the cluster's start and the
    # signal's delay however fast the filters get (four 10k-vertex meshes once finished before it)
    V, F = icosphere(6)
    for k in range(6):
        save_mesh(tmp_path / f"s{k}.ply", md.add_normal_noise((V, F), 0.01, seed=k)[0], F)
    out = tmp_path / "out"
    p = tmp_path / "p.yaml"
    names = ", ".join(f"s{k}.ply" for k in range(6))
    p.write_text(f"inputs: [{names}]\noutput_dir: {out}\nsteps:\n  - denoise\n  - save: {{path: '{{stem}}.ply'}}\n")
    proc = subprocess.Popen([str(SCRIPT), "run", str(p), "--workers", "2"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env=_env(), preexec_fn=_default_sigint)
    try:
        assert "task(s)" in proc.stdout.readline()  # the plan is checked: the cluster starts now
        time.sleep(3.0)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=180)
    finally:
        proc.kill()
    assert proc.returncode == 130, (proc.returncode, err)
    assert "Traceback" not in err and "Aborted" not in err, err
    assert not out.exists() or not [q.name for q in out.iterdir() if q.name.startswith(".")]


# --- a read-only installation ----------------------------------------------------------------------------
_NO_CACHE_PLACE = r"""
import os, sys
import numba.core.caching as caching

def unwritable(self):  # what numba meets when the package folder and HOME cannot be written (even as root)
    raise OSError(13, "Permission denied")

caching.InTreeCacheLocator.ensure_cache_path = unwritable
caching.UserWideCacheLocator.ensure_cache_path = unwritable
sys.path.insert(0, sys.argv[1])
import probe_module
try:
    caching.FunctionCache(probe_module.kernel)
    print("numba found a place", flush=True)
except RuntimeError as exc:
    print("numba alone:", exc, flush=True)

import numpy as np
import meshdenoise.kernels as k
import numba
print("CACHE", k.CACHE, "DIR", numba.config.CACHE_DIR, "COMPILED", k.compiled_here(), flush=True)
if sys.argv[2] == "compile":  # one small kernel, compiled and cached
    out = np.zeros((1, 3))
    k.unit_into(out, 0, 3.0, 4.0, 0.0)
    print("RESULT", out.tolist(), flush=True)
sys.argv[0] = "meshdenoise"
sys.argv[1:] = sys.argv[3:]
from meshdenoise.cli import main
main()
"""


def _without_a_cache_place(tmp_path, compile_, *args, **env):
    (tmp_path / "probe_module.py").write_text("def kernel():\n    pass\n")
    return subprocess.run([sys.executable, "-c", _NO_CACHE_PLACE, str(tmp_path), compile_, *map(str, args)],
                          capture_output=True, text=True, timeout=600, env=_env(TMPDIR=str(tmp_path / "tmp"), **env))


def test_a_read_only_installation_caches_its_kernels_in_a_private_temporary_folder(tmp_path, mesh_file):
    (tmp_path / "tmp").mkdir()
    first = _without_a_cache_place(tmp_path, "no", "denoise", "--method", "sobolev", "--defaults", mesh_file, tmp_path / "a.ply")
    assert first.returncode == 0, first.stderr
    assert "numba alone: cannot cache function 'kernel': no locator available" in first.stdout  # the simulation is real
    place = tmp_path / "tmp" / f"meshdenoise-numba-{os.getuid()}"
    assert f"CACHE True DIR {place} COMPILED False" in first.stdout
    assert "first run of this installation" in first.stderr  # the compile note still works
    second = _without_a_cache_place(tmp_path, "compile", "filters")
    assert second.returncode == 0 and "RESULT [[0.6, 0.8, 0.0]]" in second.stdout, second.stderr
    assert place.stat().st_mode & 0o777 == 0o700 and any(place.rglob("*.nbi"))
    third = _without_a_cache_place(tmp_path, "no", "denoise", "--method", "sobolev", "--defaults", mesh_file, tmp_path / "b.ply")
    assert third.returncode == 0 and f"CACHE True DIR {place} COMPILED True" in third.stdout, third.stderr
    assert "first run of this installation" not in third.stderr


def test_a_cache_folder_owned_by_someone_else_is_not_used(tmp_path, mesh_file):
    if os.getuid() != 0:
        pytest.skip("needs root to give the folder away")
    place = tmp_path / "tmp" / f"meshdenoise-numba-{os.getuid()}"
    place.mkdir(parents=True)
    os.chown(place, 12345, 12345)  # another user's folder, whose cache files would run as code
    r = _without_a_cache_place(tmp_path, "no", "filters")
    assert r.returncode == 0 and "CACHE True" in r.stdout, r.stderr
    used = r.stdout.split("DIR ", 1)[1].split(" ", 1)[0]
    assert used != str(place) and Path(used).name.startswith("meshdenoise-numba-") and not any(place.iterdir())


def test_an_unusable_numba_cache_dir_of_the_user_means_no_cache_not_a_crash(tmp_path):
    (tmp_path / "tmp").mkdir()
    blocker = tmp_path / "a_file"
    blocker.write_text("not a folder")
    r = _without_a_cache_place(tmp_path, "compile", "filters", NUMBA_CACHE_DIR=str(blocker / "cache"))
    assert r.returncode == 0, r.stderr
    assert "CACHE False" in r.stdout and "RESULT [[0.6, 0.8, 0.0]]" in r.stdout and "sobolev" in r.stdout


# --- progress -------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("total", [1, 2, 4, None])
def test_the_progress_count_never_passes_its_total(total):
    import io

    from rich.console import Console

    import meshdenoise.progress as progress

    out = io.StringIO()
    listener = progress.RichProgress("scan.ply", Console(file=out, force_terminal=True, width=100), total=total,
                                     show_after=0.0)
    time.sleep(0.1)
    seen = []
    with progress.listening(listener):
        for k in range(6):
            with progress.stage(f"stage {k}"):
                with progress.stage("inside"):  # part of its stage: not counted
                    pass
                task = listener._progress.tasks[0]
                seen.append((task.completed, task.total))
            task = listener._progress.tasks[0]
            seen.append((task.completed, task.total))
    assert all(t is None or c <= t for c, t in seen), seen
    assert seen[-1] == (6, None if total is None or total < 6 else total)
    shown = [(int(a), int(b)) for a, b in re.findall(r"(\d+)/(\d+)", out.getvalue())]
    assert all(a <= b for a, b in shown), shown


# --- MeshLab percentages stay percentages ---------------------------------------------------------------------
@pytest.mark.parametrize("name,param,percent", [
    ("meshing_decimation_clustering", "threshold", 5.0),
    ("meshing_merge_close_vertices", "threshold", 50.0),
    ("apply_coord_laplacian_smoothing_scale_dependent", "delta", 2.0),
    ("meshing_isotropic_explicit_remeshing", "targetlen", 3.0),
])
def test_mlx2yaml_keeps_a_meshlab_percentage_that_scales_with_each_mesh(tmp_path, name, param, percent):
    import pymeshlab

    from meshdenoise.pipeline.schema import build_plan
    from meshdenoise.pipeline.runner import run_task

    V, F = icosphere(3)

    def meshset(scale):
        ms = pymeshlab.MeshSet()
        ms.add_mesh(pymeshlab.Mesh(V * scale, F.astype(np.int32)))
        return ms

    ms = meshset(1.0)
    getattr(ms, name)(**{param: pymeshlab.PercentageValue(percent)})
    ms.save_filter_script(str(tmp_path / "s.mlx"))
    notes = []
    steps = mlx_to_steps((tmp_path / "s.mlx").read_text(), "s.mlx", warn=notes.append)
    assert steps[0][name][param] == f"{percent:g}%" and any(f"'{param}'" in n.lower() for n in notes), (steps, notes)
    # on a mesh ten times larger the step does what the percentage does there, not the first mesh's length
    src = save_mesh(tmp_path / "big.ply", V * 10, F)
    plan = build_plan({"inputs": str(src), "steps": steps + [{"save": {"path": "o.ply"}}]}, "t.yaml",
                      base_dir=tmp_path, output_dir=tmp_path / "out")
    run_task(plan.tasks[0])
    expected = meshset(10.0)
    getattr(expected, name)(**{param: pymeshlab.PercentageValue(percent)})
    got = load_mesh(tmp_path / "out" / "o.ply")
    assert got.V.shape == expected.current_mesh().vertex_matrix().shape
    np.testing.assert_allclose(got.V, expected.current_mesh().vertex_matrix(), atol=1e-5)


def test_a_percentage_without_its_range_stays_a_length():
    text = ('<!DOCTYPE FilterScript>\n<FilterScript>\n <filter name="Merge Close Vertices">\n'
            '  <Param name="Threshold" type="RichAbsPerc" value="0.25"/>\n </filter>\n</FilterScript>\n')
    assert mlx_to_steps(text) == [{"meshing_merge_close_vertices": {"threshold": 0.25}}]


# --- sample meshes -----------------------------------------------------------------------------------------
def test_sample_meshes_are_paths_pymeshlab_loads_and_the_callers_take(tmp_path):
    import pymeshlab

    from meshdenoise.data import sample_mesh

    for name in ("bunny.obj", "rangemaps/face000.ply"):
        path = sample_mesh(name)
        assert isinstance(path, str)
        ms = pymeshlab.MeshSet()
        ms.load_new_mesh(path)
        assert ms.current_mesh().vertex_number() == load_mesh(path).V.shape[0]
    p = tmp_path / "p.yaml"
    p.write_text("inputs: '{samples}/bunny.obj'\nsteps: [sobolev]\n")
    r = _cli("run", p, "--check")
    assert r.exit_code == 0 and "1 task(s)" in r.output, r.output

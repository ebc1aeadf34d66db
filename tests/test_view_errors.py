"""render, show and report: bad option values, unknown options and missing arguments are one ``error:`` line, exit 2.

click would print its usage block ("Usage: ... Try '... --help' for help. Error: Invalid value for ...");
the commands say bad input as the rest of the command line does: one line naming the option.
"""

import pytest
from click.testing import CliRunner

from meshdenoise.cli import cli
from meshdenoise.io import save_mesh
from meshdenoise.shapes import icosphere


@pytest.fixture
def mesh(tmp_path):
    return save_mesh(tmp_path / "s.ply", *icosphere(1))


def _invoke(args):
    return CliRunner().invoke(cli, args, prog_name="meshdenoise")


def _one_line(result):
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert result.exit_code == 2, result.output
    assert len(lines) == 1 and lines[0].startswith("error: "), result.output
    assert "Usage:" not in result.output and "Traceback" not in result.output
    return lines[0]


@pytest.mark.parametrize("extra, shown", [
    (["--backend", "foo"], "error: --backend: 'foo' is not one of 'auto', 'open3d', 'matplotlib'"),
    (["--error-mode", "x"], "error: --error-mode: 'x' is not one of"),
    (["--vmax", "-1"], "error: --vmax: -1.0 is not in the range"),
    (["--vmax", "abc"], "error: --vmax: expected a number, got 'abc'"),
    (["--percentile", "200"], "error: --percentile: 200.0 is not in the range"),
    (["--percentile", "0"], "error: --percentile:"),
    (["--bogus", "1"], "error: No such option '--bogus'"),
    (["--size"], "error: Option '--size' requires an argument"),
    (["--size", "3x3"], "error: --size: '3x3': width and height must be 16..4096 pixels"),
    (["--view", "up"], "error: --view: expected AZIMUTH,ELEVATION"),
    (["--zoom", "1"], "error: --zoom: expected VERTEX,RADIUS"),
])
@pytest.mark.parametrize("command", ["render", "show"])
def test_bad_view_options_are_one_line(tmp_path, mesh, command, extra, shown):
    args = [command, str(mesh), str(mesh), "--png", str(tmp_path / "x.png"), *extra]
    line = _one_line(_invoke(args))
    assert line.startswith(shown), line
    if "--size" not in extra and "--view" not in extra and "--zoom" not in extra:  # click's: the help to read
        assert line.endswith(f"(meshdenoise {command} --help)"), line
    assert not (tmp_path / "x.png").exists()


def test_missing_arguments_and_files_are_one_line(tmp_path, mesh):
    line = _one_line(_invoke(["render", str(mesh), str(mesh)]))
    assert line == "error: Missing option '--png' (meshdenoise render --help)"
    line = _one_line(_invoke(["render", str(mesh), "--png", str(tmp_path / "x.png")]))
    assert line == "error: Missing argument 'AFTER' (meshdenoise render --help)"
    line = _one_line(_invoke(["show"]))
    assert line == "error: Missing argument 'MESHES...' (meshdenoise show --help)"
    line = _one_line(_invoke(["render", str(tmp_path / "nope.ply"), str(mesh), "--png", "x.png"]))
    assert line == f"error: {tmp_path / 'nope.ply'}: no such file or folder (BEFORE)"
    line = _one_line(_invoke(["report", "--bogus"]))
    assert line.startswith("error: No such option '--bogus'") and line.endswith("(meshdenoise report --help)")


def test_help_is_still_click_help(mesh):
    result = _invoke(["render", "--help"])
    assert result.exit_code == 0 and result.output.startswith("Usage: meshdenoise render")

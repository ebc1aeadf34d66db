"""The console script and `make demo`'s job."""

import subprocess
import sys
from pathlib import Path

import numpy as np
from click.testing import CliRunner

import meshdenoise as md
from meshdenoise.cli import cli
from meshdenoise.data import sample_mesh
from meshdenoise.io import load_arrays


def test_demo_writes_meshes_and_improves_snr(tmp_path):
    result = CliRunner().invoke(cli, ["demo", "--out", str(tmp_path / "demo")])
    assert result.exit_code == 0, result.output
    for name in ("noisy", "filtering", "heat", "sobolev"):
        assert (tmp_path / "demo" / f"{name}.ply").is_file()
    V, F = load_arrays(sample_mesh("bunny.obj"))
    Vn, Fn = load_arrays(tmp_path / "demo" / "noisy.ply")
    np.testing.assert_array_equal(Fn, F)
    noisy = md.snr(V, Vn)
    for name in ("filtering", "heat", "sobolev"):
        Y, _ = load_arrays(tmp_path / "demo" / f"{name}.ply")
        assert md.snr(V, Y) > noisy + 5, name
    assert "SNR (dB)" in result.output and str(tmp_path / "demo") in result.output


def test_console_script_help_and_filters():
    exe = Path(sys.executable).parent / "meshdenoise"
    out = subprocess.run([str(exe), "--help"], capture_output=True, text=True, check=True).stdout
    assert "demo" in out and "filters" in out
    out = subprocess.run([str(exe), "filters"], capture_output=True, text=True, check=True).stdout
    for name in ("filtering", "heat", "sobolev", "iterations", "tau", "mu"):
        assert name in out
    bad = subprocess.run([str(exe), "demo", "--noise", "-1"], capture_output=True, text=True)
    assert bad.returncode == 2 and "--noise" in bad.stderr

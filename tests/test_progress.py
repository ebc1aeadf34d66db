"""Progress reporting (meshdenoise.progress) and what the command line shows of it."""

from __future__ import annotations

import io
import time

from click.testing import CliRunner
from rich.console import Console

import meshdenoise.progress as progress
from meshdenoise.cli import cli
from meshdenoise.io import save_mesh
from meshdenoise.noise import add_normal_noise
from meshdenoise.shapes import icosphere


def test_a_stage_with_nobody_listening_does_nothing():
    with progress.stage("anything"):
        x = 1
    assert x == 1


def test_log_progress_writes_one_line_per_stage_that_took_long_enough():
    lines = []
    with progress.listening(progress.LogProgress("scan [1].ply", lines.append, min_seconds=0.05)):
        with progress.stage("quick"):
            pass
        with progress.stage("slow"):
            time.sleep(0.06)
    assert len(lines) == 1 and lines[0].startswith("scan [1].ply: slow: ")


def test_rich_progress_shows_the_stage_and_the_count_and_reads_no_markup():
    out = io.StringIO()
    console = Console(file=out, force_terminal=True, width=100)
    listener = progress.RichProgress("scan [b]x[/b].ply", console, total=2, show_after=0.0)
    time.sleep(0.2)  # the timer shows the bar
    with progress.listening(listener):
        with progress.stage("choosing [red]mu[/red]"):
            time.sleep(0.3)
        with progress.stage("running"):
            pass
    text = out.getvalue()
    assert "scan [b]x[/b].ply" in text and "choosing [red]mu[/red]" in text


def test_cli_denoise_prints_a_line_for_each_long_stage_when_not_on_a_terminal(tmp_path, monkeypatch):
    monkeypatch.setattr(progress, "SHOW_AFTER", 0.0)
    V, F = icosphere(3)
    Vn = add_normal_noise((V, F), 0.02, seed=0)[0]
    src = tmp_path / "noisy.ply"
    save_mesh(src, Vn, F)
    result = CliRunner().invoke(cli, ["denoise", str(src), str(tmp_path / "out.ply")])
    assert result.exit_code == 0, result.output
    from meshdenoise.policy import choose_default

    method = choose_default((Vn, F)).method
    for text in ("noisy.ply: choosing the filter: ", f"noisy.ply: running {method}: "):
        assert text in result.stderr

"""`make demo`'s table: its title and caption stay whole at 80 columns, and user text is never markup."""

from pathlib import Path

from rich.console import Console

from meshdenoise.demo import demo_table

ROWS = [{"method": "noisy", "params": "rho=0.01", "snr_db": 34.71, "ms": 0.0, "file": Path("out/noisy.ply")},
        {"method": "sobolev", "params": "mu=1.29", "snr_db": 46.15, "ms": 3.4, "file": Path("out/sobolev.ply")}]


def _render(path, width=80, n=28088, noise=0.01, seed=0):
    console = Console(width=width, record=True, color_system=None)
    console.print(demo_table(ROWS, Path(path), n, noise, seed, width=width))
    return console.export_text()


def test_title_and_caption_are_one_line_each_at_80_columns():
    text = _render("bunny.obj")
    lines = [line.strip() for line in text.splitlines()]
    assert "bunny.obj: 28,088 vertices" in lines
    assert "noise 0.01 x bbox diagonal, seed 0; parameters from the noisy mesh alone" in lines
    assert max(len(line) for line in text.splitlines()) <= 80
    assert "46.15" in text and "sobolev.ply" in text


def test_bracketed_mesh_names_are_shown_as_written():
    text = _render("[red]scan[x].ply", seed=12)
    assert "[red]scan[x].ply: 28,088 vertices" in text
    assert "seed 12; parameters" in text

"""benchmarks/filter_time.py: the per-50,000-vertex rate, the table's marks and its files."""

import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))

import filter_time as ft  # noqa: E402


def test_table_gives_seconds_per_50k_vertices_and_marks_cells_over_three():
    cells = [{"row": "A", "filter": "sobolev", "vertices": 25_000, "time_s": 1.4},  # 2.8 s per 50k: met
             {"row": "A", "filter": "taubin", "vertices": 25_000, "time_s": 1.6},  # 3.2: over
             {"row": "B", "filter": "sobolev", "vertices": 100_000, "error": "timeout after 1 s"}]
    text = ft.table(cells, "cmd", "a note [x]")
    assert "| sobolev | 1.4 (2.8) | fails: timeout after 1 s |" in text
    assert "| taubin | **1.6 (3.2)** | fails: not run |" in text
    assert "1 of 2 cells at or under 3 s per 50,000 vertices." in text and "a note [x]" in text
    assert "A (25,000)" in text and "B (100,000)" in text


def test_main_runs_every_cell_once_with_default_as_none_and_writes_both_files(tmp_path, monkeypatch):
    runs = []

    def fake(row, name, timeout):
        runs.append((row, name))
        return {"time_s": 0.5, "params": {"x": len(runs)}} if name != "taubin" else {"error": "exit 1"}

    meshes = {"tiny": lambda: {"Vn": np.zeros((10, 3))}}
    out = tmp_path / "t.md"
    monkeypatch.setattr(sys, "argv", ["filter_time.py", "--filters", "default", "sobolev", "taubin", "--out", str(out)])
    ft._main(fake, ["tiny"], meshes, lambda: ["unused"])
    assert runs == [("tiny", None), ("tiny", "sobolev"), ("tiny", "taubin")]
    cells = json.loads(out.with_suffix(".json").read_text())
    assert [c["filter"] for c in cells] == ["default", "sobolev", "taubin"] and cells[2]["error"] == "exit 1"
    assert "| default | **0.5 (2500.0)** |" in out.read_text()  # 0.5 s on 10 vertices: 2,500 s per 50,000
    assert not list(tmp_path.glob("*.tmp"))

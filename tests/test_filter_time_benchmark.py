"""benchmarks/filter_time.py: the per-50,000-vertex rate, the table's marks and its files."""

import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))

import filter_time as ft  # noqa: E402


def test_limit_is_three_seconds_up_to_50k_vertices_then_proportional():
    assert ft.limit(10) == ft.limit(50_000) == 3.0 and ft.limit(100_000) == 6.0


def test_table_marks_cells_over_their_limit():
    cells = [{"row": "A", "filter": "sobolev", "vertices": 25_000, "time_s": 2.9},
             {"row": "A", "filter": "taubin", "vertices": 25_000, "time_s": 3.2},  # over 3 s
             {"row": "B", "filter": "sobolev", "vertices": 100_000, "time_s": 5.5},  # within 6 s
             {"row": "B", "filter": "taubin", "vertices": 100_000, "error": "timeout after 1 s"}]
    text = ft.table(cells, "cmd", "a note [x]")
    assert "| sobolev | 2.90 | 5.50 |" in text and "| taubin | **3.20** | fails: timeout after 1 s |" in text
    assert "2 of 3 cells within their limit." in text and "a note [x]" in text
    assert "A (25,000; 3.0 s)" in text and "B (100,000; 6.0 s)" in text


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
    assert "| default | 0.50 |" in out.read_text()
    assert {p.name for p in tmp_path.iterdir()} == {"t.md", "t.json"}  # no temporary file left

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


def test_ab_summary_counts_cells_within_the_limit_by_fastest_and_median_call():
    """benchmarks/filter_time_ab.py's table: min / median per code, bold over the limit, the same-parameters column."""
    import argparse

    import pytest

    import filter_time_ab as ab

    def rec(code, row, name, n, t, params):
        return {"code": code, "row": row, "filter": name, "vertices": n, "time_s": t, "params": params}

    records = [rec("aaa", "R", "gls", 25_000, t, {"b": 3}) for t in (3.4, 2.9, 3.6)]
    records += [rec("bbb", "R", "gls", 25_000, t, {"b": 3}) for t in (3.1, 3.2, 3.3)]
    records += [rec(code, "S", "axes", 100_000, 5.0, {"m": code}) for code in ("aaa", "bbb")]
    text = ab.summary(records, ("aaa", "bbb"), [("R", "gls"), ("S", "axes")], "cmd")
    assert "| R: `gls` | 2.90 / **3.40** (3) | **3.10** / **3.20** (3) | yes |" in text
    assert "| S: `axes` | 5.00 / 5.00 (1) | 5.00 / 5.00 (1) | no |" in text  # 6 s for 100,000 vertices
    assert "aaa: 2 of 2 cells within their limit by the fastest call, 1 by the median." in text
    assert "bbb: 1 of 2 cells within their limit by the fastest call, 1 by the median." in text
    assert ab.parse_cell("elephant rho=0.2:sobolev_gls") == ("elephant rho=0.2", "sobolev_gls")
    with pytest.raises(argparse.ArgumentTypeError, match="ROW:FILTER"):
        ab.parse_cell("no filter")

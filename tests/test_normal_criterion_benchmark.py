"""benchmarks/normal_criterion.py: ratios against the stored oracles, the table, and --keep merging runs."""

import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))

import normal_criterion as nc  # noqa: E402


def _oracles(path):
    cells = [{"row": r, "filter": f, "oracle": {"ne": 10.0}, "auto": {"ne": 12.0, "snr": 30.0}, "ratio": 1.2}
             for r in ("A", "B") for f in ("sobolev", "taubin")]
    path.write_text(json.dumps(cells))
    return path


def test_ratio_and_table_count_cells_within_ten_percent():
    assert nc.ratio(10.5, 10.0) == 1.05 and nc.ratio(9.0, 10.0) == 1.0  # beating the stored oracle counts as it
    cells = [{"row": "A", "filter": "sobolev", "ne": 10.5, "oracle_ne": 10.0, "ratio": 1.05, "sure_ratio": 1.2,
              "snr": 30.0, "sure_snr": 31.0, "time": 1.0},
             {"row": "A", "filter": "taubin", "ne": 12.0, "oracle_ne": 10.0, "ratio": 1.2, "sure_ratio": 1.05,
              "snr": 30.0, "sure_snr": 31.0, "time": 1.0},
             {"row": "B", "filter": "sobolev", "error": "timeout after 1 s"}]
    text = nc.table(cells, "cmd", "a note [x]")
    assert "1 of 2 cells within 10 % (position SURE: 1 of the same cells)" in text
    assert "**12.00 / 10.00 = 1.200 (1.050)**" in text and "fails: timeout after 1 s" in text and "a note [x]" in text


def test_keep_measures_only_the_cells_asked_and_keeps_the_rest(tmp_path, monkeypatch):
    oracles = _oracles(tmp_path / "o.json")
    runs = []

    def fake(row, name, timeout):
        runs.append((row, name))
        return {"normal_error_deg": 10.0 + len(runs), "snr_db": 30.0, "time_s": 1.0, "params": {"x": len(runs)}}

    monkeypatch.setattr(nc, "run_cell", fake)
    out = tmp_path / "t.md"
    nc.main(["--oracles", str(oracles), "--filters", "sobolev", "taubin", "--out", str(out)])
    assert runs == [("A", "sobolev"), ("A", "taubin"), ("B", "sobolev"), ("B", "taubin")]
    nc.main(["--oracles", str(oracles), "--rows", "B", "--filters", "taubin", "--keep", "--out", str(out)])
    cells = json.loads(out.with_suffix(".json").read_text())
    assert [(c["row"], c["filter"]) for c in cells] == runs[:4]  # the order kept, nothing lost
    assert [c["params"]["x"] for c in cells] == [1, 2, 3, 5]  # only (B, taubin) measured again
    nc.main(["--oracles", str(oracles), "--rows", "B", "--filters", "taubin", "--out", str(out)])
    assert len(json.loads(out.with_suffix(".json").read_text())) == 1  # without --keep: this run's cells only
    later = tmp_path / "later.json"  # a later oracle file's cell replaces the first file's
    later.write_text(json.dumps([{"row": "B", "filter": "taubin", "oracle": {"ne": 5.0}, "auto": {"ne": 6.0, "snr": 1.0},
                                  "ratio": 1.2}]))
    nc.main(["--oracles", str(oracles), str(later), "--rows", "B", "--filters", "taubin", "--out", str(out)])
    (cell,) = json.loads(out.with_suffix(".json").read_text())
    assert cell["oracle_ne"] == 5.0 and cell["ratio"] == (10.0 + len(runs)) / 5.0


def test_normal_risk_parts_add_up_on_the_tiny_row():
    """benchmarks/normal_risk_parts.py: the estimate is its parts' sum, and the realised terms match their model's scale."""
    import normal_risk_parts as nrp

    import pytest

    rows = nrp.parts("tiny", [2], [0, 1, 4], probes=4, directions="clean")
    for r in rows:
        assert r["estimate"] == pytest.approx(r["residual"] + r["trace"] - r["noise"])
        assert r["linearised_truth"] >= 0 and 0 <= r["mean_angle_deg"] <= 180
    zero = rows[0]  # no smoothing: H = I, so the trace terms are twice the noise terms and nothing is left
    assert zero["residual"] == 0 and zero["trace"] == pytest.approx(2 * zero["noise"])
    assert zero["trace_realised"] == pytest.approx(2 * zero["noise_realised"])
    assert zero["estimate"] == pytest.approx(zero["noise"])

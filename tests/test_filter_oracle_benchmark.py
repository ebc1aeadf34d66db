"""benchmarks/filter_oracle.py: the 1-D search, the walk along a run, ratios and the summary, one cell on tiny."""

import math
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))

import filter_oracle as fo  # noqa: E402

from meshdenoise.metrics import normal_error_deg  # noqa: E402
from meshdenoise.registry import apply_filter  # noqa: E402


# ----------------------------------------------------------------------------- minimize_log
def test_minimize_log_finds_an_interior_minimum_to_tol():
    calls = []

    def f(t):
        calls.append(t)
        return 1.0 + (t - 0.37) ** 2

    t, v, edge, memo = fo.minimize_log(f, 0.0, tol=0.01)
    assert abs(t - 0.37) < 0.01 and not edge
    assert v == pytest.approx(1.0, abs=1e-4)
    assert len(calls) == len(memo) == len(set(calls))  # every point evaluated once


def test_minimize_log_extends_the_grid_towards_a_minimum_beyond_it():
    # the minimum at 2.1 lies past the first grid (+-1 decade) but within 8 extensions of 0.25
    t, _, edge, _ = fo.minimize_log(lambda t: abs(t - 2.1), 0.0)
    assert abs(t - 2.1) < 0.01 and not edge


def test_minimize_log_flags_a_minimum_beyond_its_extensions():
    t, _, edge, memo = fo.minimize_log(lambda t: -t, 0.0, extend=2)  # decreasing for ever
    assert edge
    end = 1.0 + 2 * 0.25  # the grid's last point after two extensions; golden section then looks past it
    assert end in memo and end < t < end + 0.25 and t == max(memo)


def test_minimize_log_keeps_the_grid_best_when_golden_section_misses_it():
    # a narrow well at a grid point, a wider but shallower one elsewhere: the grid's best is never lost
    f = lambda t: 0.0 if abs(t - 0.5) < 1e-9 else 1.0 + 0.1 * abs(t + 0.3)  # noqa: E731
    t, v, _, _ = fo.minimize_log(f, 0.0)
    assert t == pytest.approx(0.5) and v == 0.0


def test_minimize_log_reuses_a_memo():
    memo = {}
    fo.minimize_log(lambda t: (t - 0.2) ** 2, 0.0, memo=memo)
    count = len(memo)
    fo.minimize_log(lambda t: pytest.fail("evaluated again"), 0.0, memo=memo)
    assert len(memo) == count


@pytest.mark.parametrize("kw", [{"spacing": 0}, {"tol": -1.0}, {"half_width": 0.0}, {"extend": -1}])
def test_minimize_log_rejects_bad_settings(kw):
    with pytest.raises(ValueError, match="minimize_log"):
        fo.minimize_log(lambda t: t * t, 0.0, **kw)


# ----------------------------------------------------------------------------- walk, ratio, summary
def test_walk_path_scores_the_input_and_stops_past_the_minimum():
    seen = []

    def scorer(X, params):
        seen.append(params["k"])
        return abs(float(X[0, 0]) - 7.0)

    w = fo._walk_path(scorer, np.zeros((1, 3)), lambda X: X + 1.0, lambda k: {"k": k})
    assert w["best_k"] == 7 and w["stop"] == "past minimum"
    assert seen == list(range(0, 2 * 7 + 20 + 1))  # k = 0 (the input) .. 2 k_best + 20
    w0 = fo._walk_path(lambda X, p: float(X[0, 0]), np.zeros((1, 3)), lambda X: X + 1.0, lambda k: {"k": k})
    assert w0["best_k"] == 0


def test_walk_path_thins_long_walks_but_finds_a_far_minimum():
    seen = []

    def scorer(X, params):
        seen.append(params["k"])
        return abs(float(X[0, 0]) - 1234.0)

    w = fo._walk_path(scorer, np.zeros((1, 3)), lambda X: X + 1.0, lambda k: {"k": k})
    assert w["stop"] == "past minimum" and w["steps"] == 2 * w["best_k"] + 20
    assert abs(w["best_k"] - 1234) <= 1234 // fo.WALK_DENSE  # within the stride (about 1 % of the count)
    assert seen[:fo.WALK_DENSE + 1] == list(range(fo.WALK_DENSE + 1))
    assert len(seen) == w["scored"] < w["steps"] / 4
    assert all(fo.walk_scored(k) for k in seen) and seen == sorted(seen)


def test_ratio_and_outside():
    assert fo.ratio(2.2, 2.0) == pytest.approx(1.1)
    assert fo.ratio(0.0, 0.0) == 1.0 and math.isinf(fo.ratio(1.0, 0.0))
    with pytest.raises(ValueError, match="ratio"):
        fo.ratio(-1.0, 2.0)
    cells = [{"filter": "a", "row": "r1", "ratio": 1.10}, {"filter": "b", "row": "r1", "ratio": 1.3},
             {"filter": "c", "row": "r2", "ratio": 1.2}, {"filter": "d", "row": "r2", "status": "not measured (x)"}]
    assert fo.outside(cells) == [("b", "r1", 1.3), ("c", "r2", 1.2)]  # 1.10 itself is within the target


def test_table_summary_names_the_cells_outside_and_the_missing():
    cell = {"row": "r1", "filter": "f", "n": 3, "ratio": 1.25, "edges": ["mu"], "oracle_is_auto": False,
            "auto": {"ne": 5.0, "snr": 10.0, "time": 0.1, "params": {"mu": 1.0}}, "auto_reapplied_ne": 5.0,
            "oracle": {"ne": 4.0, "snr": 11.0, "params": {"mu": 2.0}}, "grid_best": {"ne": 4.0},
            "oracle_time": 1.0, "evaluations": 9, "grid": "g"}
    text = fo.table([cell, {"row": "r2", "filter": "f", "status": "not measured (> 5 s)"}], ["r1", "r2"], ["f"],
                    "cmd", "note")
    assert "| f | 1.250 **>1.10** (e) | not measured (> 5 s) |" in text
    assert "**Outside 10 % (1 of 1 measured cells)**, worst first:" in text
    assert "- f (1 of 1): r1 1.250" in text
    assert "Not measured: f on r2 (> 5 s)." in text


# ----------------------------------------------------------------------------- one cell, checked independently
def test_sobolev_cell_on_tiny_is_the_best_of_a_dense_scan():
    cell = fo.measure("tiny", "sobolev")
    m = fo.MESHES["tiny"]()
    V0, F, Vn = m["V0"], m["F"], m["Vn"]
    assert cell["auto_reapplied_ne"] == pytest.approx(cell["auto"]["ne"], rel=1e-9)
    mu = cell["oracle"]["params"]["mu"]
    again = normal_error_deg((V0, F), apply_filter("sobolev", (Vn, F), mu=mu)[0])
    assert again == pytest.approx(cell["oracle"]["ne"], rel=1e-9)
    scan = [normal_error_deg((V0, F), apply_filter("sobolev", (Vn, F), mu=10.0**t)[0])
            for t in np.linspace(math.log10(mu) - 1.0, math.log10(mu) + 1.0, 81)]
    assert cell["oracle"]["ne"] <= min(scan) * 1.01  # the oracle is the best to 1 %
    assert cell["ratio"] == pytest.approx(cell["auto"]["ne"] / cell["oracle"]["ne"])

"""benchmarks/scale.py's cell runner: time limit, the child's own peak memory, the table's cells."""

import importlib.util
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def scale():
    spec = importlib.util.spec_from_file_location("scale_benchmark", ROOT / "benchmarks" / "scale.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_a_cell_over_its_time_limit_is_killed_and_keeps_what_it_printed(scale):
    code = "import json, time; print(json.dumps({'stage': 'choose', 'seconds': 1.5}), flush=True); time.sleep(30)"
    cell = scale.run_limited([sys.executable, "-c", code], timeout=1.0)
    assert cell["timed_out"] and cell["exit"] is None
    assert cell["wall"] < 10
    assert cell["records"] == {"choose": {"seconds": 1.5}}
    row = {"inproc": cell, "e2e": cell, "load_before": 1.0}
    text = scale.format_row({"label": "1k", "n": 1000}, "heat", row, timeout=1.0)
    assert "| 1.5 | > 1 | > 1 |" in text  # choose finished, the filter and the command line did not


def test_the_peak_memory_is_the_childs_own():
    """Measured from a small parent, as the benchmark is (Linux starts a child's ru_maxrss at its parent's peak)."""
    import json
    import subprocess

    code = (
        "import json, sys, importlib.util as u; s = u.spec_from_file_location('s', sys.argv[1]); m = u.module_from_spec(s); "
        "s.loader.exec_module(m); "
        "small = m.run_limited([sys.executable, '-c', 'pass'], 60); "
        "big = m.run_limited([sys.executable, '-c', 'import numpy as np; a = np.ones(40_000_000); a += 1'], 60); "
        "print(json.dumps([small['exit'], big['exit'], small['maxrss'], big['maxrss']]))"
    )
    out = subprocess.run([sys.executable, "-c", code, str(ROOT / "benchmarks" / "scale.py")], capture_output=True, text=True)
    small_exit, big_exit, small, big = json.loads(out.stdout.strip().splitlines()[-1])
    assert small_exit == 0 and big_exit == 0
    assert big - small > 300e6  # 320 MB of float64 touched
    assert small < 100e6


def test_a_failing_cell_says_so(scale):
    cell = scale.run_limited([sys.executable, "-c", "raise SystemExit(3)"], timeout=60)
    assert cell["exit"] == 3 and not cell["timed_out"]
    mesh = {"label": "1k", "n": 1000}
    assert "| fail |" in scale.format_row(mesh, "heat", {"e2e": cell, "load_before": 0.5}, timeout=60)


def test_code_version_names_the_checkout_commit():
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parent.parent
    sys.path.insert(0, str(root / "benchmarks"))
    import scale

    head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=root, capture_output=True, text=True).stdout.strip()
    assert scale.code_version().split("+")[0] == head


def test_the_default_row_runs_choose_default_and_names_its_filter(scale, tmp_path):
    """The `default` row: choose_default in the child, the filter it picked, its name in the table."""
    import numpy as np

    from meshdenoise import add_normal_noise
    from meshdenoise.shapes import icosphere

    V, F = icosphere(2)
    Vn, _ = add_normal_noise((V, F), 0.02, seed=0)
    npz = tmp_path / "tiny.npz"
    np.savez(npz, V=V, F=F, Vn=Vn, rho=0.02, h=0.1)
    cell = scale.run_limited(scale.me("--child", "inproc", str(npz), scale.DEFAULT), 300)
    assert cell["exit"] == 0, cell["stderr_tail"]
    chosen = cell["records"]["choose"]
    from meshdenoise import auto_filters

    assert chosen["method"] in auto_filters()  # the filter the default picked (its candidates change with it)
    assert cell["records"]["oracle"]["snr"] >= cell["records"]["filter"]["snr"]
    text = scale.format_row({"label": "1k", "n": len(V)}, scale.DEFAULT, {"inproc": cell, "load_before": 0.0}, timeout=300)
    assert f"method={chosen['method']}" in text

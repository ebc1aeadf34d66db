"""``python -m meshdenoise.warmup``: the kernels compiled at installation (``make`` runs it before its stamp)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from meshdenoise import add_normal_noise
from meshdenoise.io import save_arrays
from meshdenoise.kernels import compiled_here
from meshdenoise.shapes import torus
from meshdenoise.warmup import WARMUP_MESH, compile_kernels, main

ROOT = Path(__file__).resolve().parent.parent


def test_compile_kernels_runs_the_default_and_leaves_the_cache_filled(tmp_path):
    V, F = torus(40, 20)
    Vn, _ = add_normal_noise((V, F), 0.02, seed=1)
    path = save_arrays(tmp_path / "torus.ply", Vn, F)
    done = compile_kernels(path)
    assert done["mesh"] == str(path) and done["vertices"] == len(V) and done["seconds"] > 0
    assert isinstance(done["compiled"], bool)
    assert compiled_here()


def test_warmup_main_says_one_line_and_exits_2_on_a_bad_mesh(tmp_path, capsys):
    missing = tmp_path / "missing.ply"
    assert main([str(missing)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"meshdenoise.warmup: {missing}:") and "Traceback" not in err[0]
    assert main(["a.ply", "b.ply"]) == 2
    assert "usage: python -m meshdenoise.warmup [MESH]" in capsys.readouterr().err
    V, F = torus(24, 12)
    path = save_arrays(tmp_path / "small.ply", V + 0.01 * np.random.default_rng(0).standard_normal(V.shape), F)
    assert main([str(path)]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert len(out) == 1 and out[0].startswith("meshdenoise: ") and "small.ply (288 vertices) in " in out[0]


def test_make_compiles_the_kernels_when_it_installs_the_package():
    """The install recipe runs the warm-up after pip and before its stamp (a failed warm-up leaves no stamp), on the
    main job's own scan."""
    recipe = re.search(r"^\$\(STAMP\):.*?\n((?:\t.*\n)+)", (ROOT / "Makefile").read_text(), re.M).group(1)
    lines = [line.strip() for line in recipe.splitlines()]
    pip = max(i for i, line in enumerate(lines) if "pip install" in line)
    warm = lines.index("$(BIN)/python -m meshdenoise.warmup")
    stamp = lines.index("@touch $(STAMP)")
    assert pip < warm < stamp
    assert WARMUP_MESH == "rangemaps/face000.ply" and "rangemaps/face000.ply" in (ROOT / "Makefile").read_text()

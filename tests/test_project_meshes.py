"""The meshes in meshes/ are exactly what meshes/make_meshes.py generates, and every filter runs on them."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

import meshdenoise as md
from meshdenoise.io import load_mesh

ROOT = Path(__file__).resolve().parent.parent


def _script():
    spec = importlib.util.spec_from_file_location("make_meshes", ROOT / "meshes" / "make_meshes.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("name", sorted(_script().MESHES))
def test_committed_mesh_equals_generated(name, tmp_path):
    committed = load_mesh(ROOT / "meshes" / name)
    V, F = _script().MESHES[name]()
    np.testing.assert_array_equal(committed.V, V)
    np.testing.assert_array_equal(committed.F, F)


@pytest.mark.parametrize("name", sorted(_script().MESHES))
def test_every_filter_runs_on_a_noisy_project_mesh(name):
    mesh = load_mesh(ROOT / "meshes" / name)
    V, F = mesh.V, mesh.F
    rho = 0.01 * float(np.linalg.norm(V.max(0) - V.min(0)))
    Vn, _ = md.add_normal_noise((V, F), rho=rho, seed=0)
    for spec in md.list_filters():
        assert np.isfinite(spec.public((Vn, F))[0]).all(), spec.name

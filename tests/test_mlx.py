"""MeshLab filter scripts: round trips, and the produced .mlx applied by pymeshlab gives our runner's mesh."""

import numpy as np
import pymeshlab

from meshdenoise.data import sample_mesh
from meshdenoise.io import load_arrays, save_mesh
from meshdenoise.pipeline.mlx import mlx_to_steps, steps_to_mlx
from meshdenoise.pipeline.schema import build_plan
from meshdenoise.pipeline.runner import run_task
from meshdenoise.shapes import icosphere

STEPS = [
    {"apply_coord_laplacian_smoothing": {"stepsmoothnum": 2, "boundary": False}},
    "meshing_remove_duplicate_vertices",
    {"compute_normal_per_vertex": {"weightmode": "By Angle"}},
    {"apply_coord_taubin_smoothing": {"lambda_": 0.4, "mu": -0.45, "stepsmoothnum": 3}},
    {"sobolev": {"mu": 0.5}},
]


def test_yaml_mlx_yaml_identical():
    assert mlx_to_steps(steps_to_mlx(STEPS)) == STEPS


def test_mlx_yaml_mlx_equivalent_on_gui_scripts(tmp_path):
    # A script as MeshLab writes it (every parameter), recorded here by pymeshlab itself.
    V, F = icosphere(2)
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(V, F.astype(np.int32)))
    ms.apply_coord_laplacian_smoothing(stepsmoothnum=2)
    ms.compute_normal_per_vertex(weightmode="By Area")
    ms.meshing_merge_close_vertices(threshold=pymeshlab.PureValue(0.001))
    ms.save_filter_script(str(tmp_path / "gui.mlx"))
    for text in ((tmp_path / "gui.mlx").read_text(), sample_mesh("sample_filter_script.mlx").read_text()):
        steps = mlx_to_steps(text)
        assert mlx_to_steps(steps_to_mlx(steps)) == steps
    steps = mlx_to_steps((tmp_path / "gui.mlx").read_text())
    assert steps[0] == {"apply_coord_laplacian_smoothing": {"stepsmoothnum": 2, "boundary": True, "cotangentweight": True, "selected": False}}
    assert steps[1] == {"compute_normal_per_vertex": {"weightmode": "By Area"}}


def test_produced_mlx_applied_by_pymeshlab_equals_our_runner(tmp_path):
    V, F = icosphere(2)
    V = V + np.random.default_rng(1).normal(scale=0.02, size=V.shape)
    src = save_mesh(tmp_path / "in.ply", V, F)
    pym_steps = STEPS[:4]
    (tmp_path / "s.mlx").write_text(steps_to_mlx(pym_steps))
    ms = pymeshlab.MeshSet()
    ms.load_new_mesh(str(src))
    ms.load_filter_script(str(tmp_path / "s.mlx"))
    ms.apply_filter_script()
    plan = build_plan({"inputs": str(src), "steps": pym_steps + [{"save": {"path": "o.ply"}}]}, "t.yaml",
                      base_dir=tmp_path, output_dir=tmp_path / "out")
    run_task(plan.tasks[0])
    got, _ = load_arrays(tmp_path / "out" / "o.ply")
    np.testing.assert_allclose(got, ms.current_mesh().vertex_matrix(), atol=1e-6)


# --- the MeshLab name table: versioned data, checked against the installed pymeshlab ------------------
def test_meshlab_table_agrees_with_installed_pymeshlab():
    from importlib.metadata import version

    from meshdenoise.pipeline.meshlab_names import FILTERS, PYMESHLAB_VERSION, table_differences

    assert len(FILTERS) > 200
    diff = table_differences()
    assert not diff, (
        f"the table was recorded with pymeshlab {PYMESHLAB_VERSION}, pymeshlab {version('pymeshlab')} is installed; "
        "regenerate it (python -m meshdenoise.pipeline.meshlab_table -o meshdenoise/pipeline/meshlab_filters.json). "
        "Differences:\n" + "\n".join(diff)
    )


def test_meshlab_table_file_is_what_the_generator_writes():
    from importlib import resources

    from meshdenoise.pipeline import meshlab_table
    from meshdenoise.pipeline.meshlab_names import FILTERS, PYMESHLAB_VERSION, TABLE_FILE

    text = resources.files("meshdenoise.pipeline").joinpath(TABLE_FILE).read_text(encoding="utf-8")
    assert meshlab_table.to_json(FILTERS, PYMESHLAB_VERSION) == text
    # one filter recorded afresh from pymeshlab's save_filter_script gives the stored entry
    assert meshlab_table.record("apply_coord_taubin_smoothing") == FILTERS["apply_coord_taubin_smoothing"]
    assert FILTERS["apply_coord_taubin_smoothing"]["meshlab"] == "Taubin Smooth"


def test_meshlab_table_is_package_data():
    import tomllib
    from pathlib import Path

    conf = tomllib.loads((Path(__file__).parents[1] / "pyproject.toml").read_text())
    assert "meshlab_filters.json" in conf["tool"]["setuptools"]["package-data"]["meshdenoise.pipeline"]


def test_meshlab_table_check_reports_what_pymeshlab_lacks(monkeypatch):
    from meshdenoise.pipeline import meshlab_names

    fake = {
        "no_such_filter": {"meshlab": "Nothing", "params": {}},
        "apply_coord_taubin_smoothing": {"meshlab": "Taubin Smooth", "params": {"lambda_": {}, "mu": {}, "stepsmoothnum": {}, "selected": {}, "bogus": {}}},
    }
    monkeypatch.setattr(meshlab_names, "FILTERS", fake)
    diff = "\n".join(meshlab_names.table_differences())
    assert "'no_such_filter'" in diff and "'bogus'" in diff, diff

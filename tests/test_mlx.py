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

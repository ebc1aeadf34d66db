"""MeshLab filter scripts: round trips, and the produced .mlx applied by pymeshlab gives our runner's mesh."""

from pathlib import Path

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
    for text in ((tmp_path / "gui.mlx").read_text(), Path(sample_mesh("sample_filter_script.mlx")).read_text()):
        steps = mlx_to_steps(text, warn=lambda message: None)
        # a percentage (MeshLab's RichAbsPerc) has no script form of its own: a script holds one mesh's length
        steps = [_without_percentages(step) for step in steps]
        assert mlx_to_steps(steps_to_mlx(steps)) == steps
    steps = mlx_to_steps((tmp_path / "gui.mlx").read_text(), warn=lambda message: None)
    assert steps[0] == {"apply_coord_laplacian_smoothing": {"stepsmoothnum": 2, "boundary": True, "cotangentweight": True, "selected": False}}
    assert steps[1] == {"compute_normal_per_vertex": {"weightmode": "By Area"}}


def _without_percentages(step):
    if not isinstance(step, dict):
        return step
    name, params = next(iter(step.items()))
    kept = {k: v for k, v in params.items() if not (isinstance(v, str) and v.endswith("%"))}
    return {name: kept} if kept else name


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


# --- MeshLab interop from the command line -------------------------------------------------------------
import pytest  # noqa: E402
import yaml  # noqa: E402
from click.testing import CliRunner  # noqa: E402

from meshdenoise.cli import cli  # noqa: E402

OLD_SCRIPT = """<!DOCTYPE FilterScript>
<FilterScript>
 <filter name="Transform: Rotate">
  <Param name="rotAxis" type="RichEnum" value="3" enum_cardinality="4" enum_val0="X axis" enum_val1="Y axis" enum_val2="Z axis" enum_val3="custom axis"/>
  <Param name="rotCenter" type="RichEnum" value="0" enum_cardinality="3" enum_val0="origin" enum_val1="barycenter" enum_val2="custom point"/>
  <Param name="angle" type="RichDynamicFloat" value="90" min="-360" max="360"/>
  <Param name="customAxis" type="RichPoint3f" x="0" y="0" z="1"/>
  <Param name="customCenter" type="RichPoint3f" x="0" y="0" z="0"/>
  <Param name="snapFlag" type="RichBool" value="false"/>
  <Param name="snapAngle" type="RichFloat" value="30"/>
  <Param name="Freeze" type="RichBool" value="true"/>
  <Param name="allLayers" type="RichBool" value="false"/>
 </filter>
 <filter name="Matrix: Set/Copy Transformation">
  <Param name="TransformMatrix" type="RichMatrix44f" val0="2" val1="0" val2="0" val3="0" val4="0" val5="2" val6="0" val7="0" val8="0" val9="0" val10="2" val11="0" val12="0" val13="0" val14="0" val15="1"/>
  <Param name="compose" type="RichBool" value="false"/>
  <Param name="Freeze" type="RichBool" value="true"/>
  <Param name="allLayers" type="RichBool" value="false"/>
 </filter>
 <filter name="Set Mesh Camera">
  <Param name="Shot" type="RichShotf"/>
 </filter>
</FilterScript>
"""


def _cli(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def test_mlx2yaml_reads_points_and_matrices_and_keeps_a_camera_step_with_a_note(tmp_path):
    script = tmp_path / "old.mlx"
    script.write_text(OLD_SCRIPT)
    V, F = icosphere(1)
    src = save_mesh(tmp_path / "in.ply", V, F)
    result = _cli("mlx2yaml", script, "-o", tmp_path / "p.yaml")
    assert result.exit_code == 0, result.output
    assert "parameter 'Shot' has type 'RichShotf'" in result.output and "left out" in result.output
    steps = yaml.safe_load((tmp_path / "p.yaml").read_text())["steps"]
    assert steps[0]["compute_matrix_from_rotation"]["customaxis"] == [0.0, 0.0, 1.0]
    assert steps[1]["set_matrix"]["transformmatrix"] == [2.0, 0, 0, 0, 0, 2.0, 0, 0, 0, 0, 2.0, 0, 0, 0, 0, 1.0]
    assert steps[2] == "set_camera_per_mesh"
    # the converted pipeline runs: rotation by 90 degrees about z, then scaling by 2
    run = _cli("run", tmp_path / "p.yaml", "--input", src, "--out", tmp_path / "out", "--serial")
    assert run.exit_code == 0, run.output
    got = load_arrays(tmp_path / "out" / "in_out.ply")[0]
    expected = 2 * np.column_stack([-V[:, 1], V[:, 0], V[:, 2]])
    np.testing.assert_allclose(got, expected, atol=1e-5)


def test_mlx2yaml_writes_a_placeholder_input_that_check_names(tmp_path):
    script = tmp_path / "s.mlx"
    script.write_text(steps_to_mlx(STEPS[:1]))
    result = _cli("mlx2yaml", script, "-o", tmp_path / "p.yaml")
    assert result.exit_code == 0, result.output
    text = (tmp_path / "p.yaml").read_text()
    assert "inputs: SET-YOUR-MESH.ply   # set your mesh file(s)" in text
    assert "placeholder" in result.output
    check = _cli("run", "--check", tmp_path / "p.yaml")
    assert check.exit_code == 2
    assert f"{tmp_path / 'p.yaml'}:2: inputs: 'SET-YOUR-MESH.ply' is the placeholder mlx2yaml writes" in check.output


def test_mlx_yaml_mlx_round_trip_on_the_command_line_without_skip_other(tmp_path):
    script = tmp_path / "s.mlx"
    script.write_text(steps_to_mlx(STEPS))
    assert _cli("mlx2yaml", script, "-o", tmp_path / "p.yaml").exit_code == 0
    back = _cli("yaml2mlx", tmp_path / "p.yaml", "-o", tmp_path / "back.mlx")
    assert back.exit_code == 0, back.output
    assert "'save': left out" in back.output
    assert mlx_to_steps((tmp_path / "back.mlx").read_text()) == STEPS
    # other steps with no script form still need --skip-other
    (tmp_path / "m.yaml").write_text("steps:\n  - sobolev: {mu: 1}\n  - metrics: {}\n")
    refused = _cli("yaml2mlx", tmp_path / "m.yaml")
    assert refused.exit_code == 2 and f"{tmp_path / 'm.yaml'}:3: step 2 'metrics'" in refused.output
    assert "--skip-other" in refused.output
    assert _cli("yaml2mlx", tmp_path / "m.yaml", "--skip-other").exit_code == 0


def test_a_float_parameter_given_as_an_integer_is_written_as_richfloat():
    text = steps_to_mlx([{"sobolev": {"mu": 1}}, {"filtering": {"iterations": 3}}])
    assert '<Param name="mu" type="RichFloat" value="1"' in text
    assert '<Param name="iterations" type="RichInt" value="3"' in text
    assert mlx_to_steps(text) == [{"sobolev": {"mu": 1.0}}, {"filtering": {"iterations": 3}}]


def test_pipelines_accept_meshlab_gui_names_with_a_note(tmp_path):
    V, F = icosphere(2)
    V = V + np.random.default_rng(1).normal(scale=0.02, size=V.shape)
    src = save_mesh(tmp_path / "in.ply", V, F)
    p = tmp_path / "p.yaml"
    p.write_text("inputs: in.ply\nsteps:\n  - Taubin Smooth: {lambda: 0.4, mu: -0.45, stepSmoothNum: 3}\n  - save: {path: o.ply}\n")
    result = _cli("run", p, "--out", tmp_path / "out")
    assert result.exit_code == 0, result.output
    out = " ".join(result.output.split())
    assert "'Taubin Smooth' is MeshLab's name of the pymeshlab filter 'apply_coord_taubin_smoothing'" in out
    assert "'stepSmoothNum' is MeshLab's name of apply_coord_taubin_smoothing's parameter 'stepsmoothnum'" in out
    assert "'lambda' is MeshLab's name" in out
    ms = pymeshlab.MeshSet()
    ms.load_new_mesh(str(src))
    ms.apply_coord_taubin_smoothing(lambda_=0.4, mu=-0.45, stepsmoothnum=3)
    np.testing.assert_allclose(load_arrays(tmp_path / "out" / "o.ply")[0], ms.current_mesh().vertex_matrix(), atol=1e-6)
    # and yaml2mlx writes the MeshLab names back
    assert '<filter name="Taubin Smooth">' in steps_to_mlx([{"Taubin Smooth": {"stepSmoothNum": 3}}])


@pytest.mark.parametrize(
    "steps, expected",
    [
        ("  - 3\n", "step 1: a step is a name or a one-key mapping"),
        ("  - null\n", "step 1: a step is a name or a one-key mapping"),
        ("  - [sobolev, heat]\n", "step 1: a step is a name or a one-key mapping"),
        ("  - sobolev: {mu: 1}\n    heat: {tau: 1}\n", "step 1: a step is one name with its parameters, this one has 2 keys"),
        ("  - sobolev: 3\n", "step 1 'sobolev': parameters must be a mapping"),
        ("  - 5: {mu: 1}\n", "step 1: a step's name is a string"),
        ("  - sobolev: {mu: abc}\n", "step 1 'sobolev': parameter 'mu' must be a float"),
        ("  - apply_coord_laplacian_smoothing: {stepsmoothnum: abc}\n", "step 1 'apply_coord_laplacian_smoothing': parameter 'stepsmoothnum' must be a"),
    ],
)
def test_yaml2mlx_refuses_malformed_steps_naming_file_line_and_step(tmp_path, steps, expected):
    p = tmp_path / "p.yaml"
    p.write_text("steps:\n  - sobolev: {mu: 1}\n" + steps.replace("step 1", "step 2"))
    result = _cli("yaml2mlx", p, "-o", tmp_path / "o.mlx")
    assert result.exit_code == 2, result.output
    assert f"{p}:3: " + expected.replace("step 1", "step 2") in " ".join(result.output.split()), result.output
    assert "Traceback" not in result.output and not (tmp_path / "o.mlx").exists()


@pytest.mark.parametrize(
    "param, expected",
    [
        ('<Param name="angle" type="RichDynamicFloat" value="abc"/>', "parameter 'angle' (RichDynamicFloat) value='abc' is not a number"),
        ('<Param name="Freeze" type="RichBool" value="maybe"/>', "parameter 'Freeze' (RichBool) value='maybe' is not true or false"),
        ('<Param name="customAxis" type="RichPoint3f" x="0" y="0"/>', "parameter 'customAxis' (RichPoint3f) has no 'z' attribute"),
        ('<Param name="angle" type="RichFloat"/>', "parameter 'angle' (RichFloat) has no 'value' attribute"),
    ],
)
def test_mlx2yaml_errors_name_file_filter_and_parameter(tmp_path, param, expected):
    script = tmp_path / "bad.mlx"
    script.write_text(f'<!DOCTYPE FilterScript>\n<FilterScript>\n <filter name="Transform: Rotate">\n  {param}\n </filter>\n</FilterScript>\n')
    result = _cli("mlx2yaml", script, "-o", tmp_path / "o.yaml")
    assert result.exit_code == 2, result.output
    assert f"{script}: filter 1 'Transform: Rotate': {expected}" in " ".join(result.output.split()), result.output
    assert not (tmp_path / "o.yaml").exists()
    unknown = tmp_path / "unknown.mlx"
    unknown.write_text('<FilterScript><filter name="No Such Filter"/></FilterScript>')
    result = _cli("mlx2yaml", unknown)
    assert result.exit_code == 2 and f"{unknown}: filter 1 'No Such Filter': MeshLab filter" in " ".join(result.output.split())


def test_mlx2yaml_and_yaml2mlx_make_a_missing_output_folder(tmp_path):
    """Like every other output of the tool (atomic_path makes the folder): a new folder is not an error."""
    script = tmp_path / "s.mlx"
    script.write_text(steps_to_mlx(STEPS[:1]))
    target = tmp_path / "new" / "deeper" / "p.yaml"
    assert _cli("mlx2yaml", script, "-o", target).exit_code == 0 and target.is_file()
    (tmp_path / "afile").write_text("x")
    blocked = _cli("mlx2yaml", script, "-o", tmp_path / "afile" / "p.yaml")
    assert blocked.exit_code == 2 and "cannot be written" in blocked.output and "Traceback" not in blocked.output


def test_a_misspelt_meshlab_gui_name_gets_the_pymeshlab_name_as_hint(tmp_path):
    from meshdenoise.pipeline.errors import PipelineValidationError
    from meshdenoise.pipeline.steps import parse_step

    with pytest.raises(PipelineValidationError, match=r"did you mean 'apply_coord_taubin_smoothing', MeshLab's 'Taubin Smooth'\?"):
        parse_step({"Taubin Smoth": {}}, 1, "t.yaml", 3)

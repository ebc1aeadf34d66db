"""YAML pipelines: validation (file, line, step; exit 2; nothing written), failures (exit 1, inputs untouched), sweeps, Dask."""

import hashlib
import json

import numpy as np
import pytest
from click.testing import CliRunner

import meshdenoise as md
from meshdenoise.cli import cli
from meshdenoise.io import load_arrays, load_mesh, save_mesh
from meshdenoise.shapes import icosphere


def _sphere_file(tmp_path, name="s.ply", rho=0.02, seed=0):
    V, F = icosphere(2)
    Vn, _ = md.add_normal_noise((V, F), rho=rho, seed=seed)
    return save_mesh(tmp_path / name, Vn, F)


def _write(tmp_path, text):
    p = tmp_path / "p.yaml"
    p.write_text(text)
    return p


def _run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def _digest(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.mark.parametrize(
    "steps, line, expected",
    [
        ("  - sobolv: {mu: 1}\n", 4, "did you mean 'sobolev'"),
        ("  - sobolev: {mu: 1}\n  - apply_coord_laplacian_smoothing: {stepsmothnum: 3}\n", 5, "did you mean 'stepsmoothnum'"),
        ("  - sobolev:\n      mu: -1\n", 5, "out of range"),
        ("  - apply_coord_laplacian_smoothing: {stepsmoothnum: 2.5}\n", 4, "must be an int, got 2.5 (RichInt)"),
        ("  - compute_normal_per_vertex: {weightmode: By Angel}\n", 4, "did you mean 'By Angle'"),
        ("  - filtering: {pinned: boundry}\n", 4, "did you mean 'boundary'"),
        ("  - sobolev: {mu: '${nu}'}\n", 4, "undefined variable"),
        ("  - metrics: {reference: {before: clean}}\n", 4, "no earlier step has label 'clean'"),
    ],
)
def test_validation_errors_name_file_line_step_and_write_nothing(tmp_path, steps, line, expected):
    src = _sphere_file(tmp_path)
    p = _write(tmp_path, f"inputs: s.ply\noutput_dir: {tmp_path / 'out'}\nsteps:\n{steps}  - save: {{path: x.ply}}\n")
    result = _run("run", p)
    assert result.exit_code == 2, result.output
    assert f"{p}:{line}" in result.output and expected in result.output, result.output
    assert not (tmp_path / "out").exists()
    assert src.is_file()


def test_missing_input_and_overwriting_input_are_validation_errors(tmp_path):
    _sphere_file(tmp_path)
    p = _write(tmp_path, "inputs: [s.ply, nothere.ply]\nsteps: [sobolev]\n")
    result = _run("run", p)
    assert result.exit_code == 2 and "nothere.ply" in result.output and f"{p}:1" in result.output
    p = _write(tmp_path, f"inputs: s.ply\nsteps:\n  - save: {{path: {tmp_path / 's.ply'}}}\n")
    result = _run("run", p)
    assert result.exit_code == 2 and "overwrite the input" in result.output


def test_runtime_failure_exit_1_names_step_no_partial_output_input_untouched(tmp_path):
    src = _sphere_file(tmp_path)
    before = _digest(src)
    out = tmp_path / "out"
    # The first save is staged; pymeshlab then fails inside step 2 (its expression parser): nothing may be written.
    from meshdenoise.shapes import grid

    V, F = grid(6, 6)
    save_mesh(tmp_path / "flat.ply", V, F)
    flat_before = _digest(tmp_path / "flat.ply")
    p = _write(tmp_path, f"inputs: flat.ply\noutput_dir: {out}\nsteps:\n  - save: {{path: a.ply}}\n"
               "  - compute_selection_by_condition_per_vertex: {condselect: '((x'}\n  - save: {path: b.ply}\n")
    result = _run("run", p)
    assert result.exit_code == 1, result.output
    assert "flat.ply" in result.output and "step 2 'compute_selection_by_condition_per_vertex'" in result.output
    assert f"{p}:5" in result.output and "PyMeshLabException" in result.output
    assert not out.exists() or not any(out.iterdir())
    # preserve_volume on a flat mesh (no volume to keep) is bad input: exit 2, nothing written either
    p = _write(tmp_path, f"inputs: flat.ply\noutput_dir: {out}\nsteps:\n  - save: {{path: a.ply}}\n  - sobolev: {{preserve_volume: true}}\n  - save: {{path: b.ply}}\n")
    result = _run("run", p)
    assert result.exit_code == 2, result.output
    assert "step 2 'sobolev'" in result.output and "preserve_volume" in result.output and f"{p}:5" in result.output
    assert not out.exists() or not any(out.iterdir())
    assert _digest(tmp_path / "flat.ply") == flat_before and _digest(src) == before


def test_our_filter_pymeshlab_open3d_steps_match_direct_calls(tmp_path):
    import pymeshlab

    src = _sphere_file(tmp_path)
    out = tmp_path / "out"
    p = _write(tmp_path, f"variables: {{mu: 0.5}}\ninputs: s.ply\noutput_dir: {out}\nsteps:\n"
               "  - sobolev: {mu: '${mu}', pinned: boundary}\n  - apply_coord_laplacian_smoothing: {stepsmoothnum: 2}\n"
               "  - open3d.filter_smooth_simple: {number_of_iterations: 2}\n  - save: {path: r.ply}\n")
    assert _run("run", p, "--set", "mu=2").exit_code == 0
    V, F = load_arrays(src)
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(md.sobolev((V, F), mu=2.0)[0], F.astype(np.int32)))
    ms.apply_coord_laplacian_smoothing(stepsmoothnum=2)
    import open3d as o3d

    m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(ms.current_mesh().vertex_matrix()), o3d.utility.Vector3iVector(F))
    expected = np.asarray(m.filter_smooth_simple(number_of_iterations=2).vertices)
    got, _ = load_arrays(out / "r.ply")
    np.testing.assert_allclose(got, expected, atol=1e-6)  # binary PLY stores float32


def test_sweep_writes_csv_and_json_one_row_per_setting_and_input(tmp_path):
    _sphere_file(tmp_path, "a.ply", seed=1)
    _sphere_file(tmp_path, "b.ply", seed=2)
    out = tmp_path / "out"
    p = _write(tmp_path, f"inputs: ['a.ply', 'b.ply']\noutput_dir: {out}\nsteps:\n  - add_noise: {{rho: 0.01, label: clean}}\n"
               "  - sobolev: {mu: '${mu}'}\n  - metrics: {reference: {before: clean}}\n  - save: {path: '{stem}_{setting}.ply'}\n"
               "sweep: {mu: [0.5, 2]}\n")
    result = _run("run", p, "--serial")
    assert result.exit_code == 0, result.output
    rows = json.loads((out / "results.json").read_text())
    assert sorted((r["input"].split("/")[-1], r["mu"]) for r in rows) == [("a.ply", 0.5), ("a.ply", 2), ("b.ply", 0.5), ("b.ply", 2)]
    csv_lines = (out / "results.csv").read_text().splitlines()
    assert len(csv_lines) == 5 and "snr" in csv_lines[0]
    for r in rows:  # the SNR is recomputed here from the written files and an independent noise draw
        V, F = load_arrays(tmp_path / r["input"].split("/")[-1])
        Vn, _ = md.add_normal_noise((V, F), rho=0.01, seed=0)
        Y, _ = load_arrays(out / f"{r['input'].split('/')[-1][0]}_mu={r['mu']}.ply")
        assert abs(md.snr(V, Y) - r["snr"]) < 1e-3
        np.testing.assert_allclose(Y, md.sobolev((Vn, F), mu=float(r["mu"]))[0], atol=1e-6)


def test_shipped_scan_cleanup_on_range_scan(tmp_path):
    out = tmp_path / "out"
    result = _run("run", "pipelines/scan_cleanup.yaml", "--out", out, "--serial")
    assert result.exit_code == 0, result.output
    written = list(out.glob("*_clean.ply"))
    assert [w.name for w in written] == ["face000_clean.ply"]
    from meshdenoise.meshinfo import mesh_info

    info = mesh_info(*load_arrays(written[0]))
    assert info["unreferenced_vertices"] == 0 and info["duplicate_vertices"] == 0 and info["non_manifold_edges"] == 0


def test_dask_local_cluster_batch_with_one_corrupt_mesh_matches_serial(tmp_path):
    from distributed import LocalCluster

    inputs = tmp_path / "in"
    inputs.mkdir()
    for k in range(19):
        V, F = icosphere(1)
        Vn, _ = md.add_normal_noise((V, F), rho=0.02, seed=k)
        save_mesh(inputs / f"m{k:02d}.ply", Vn, F)
    (inputs / "m19.ply").write_bytes(b"ply\nformat ascii 1.0\nelement vertex 3\nthis is not a mesh\n")
    digests = {p.name: _digest(p) for p in inputs.iterdir()}
    text = "inputs: 'in/*.ply'\nsteps:\n  - sobolev: {mu: 1}\n  - save: {path: '{stem}_out.ply'}\n"
    p = _write(tmp_path, text)
    serial = _run("run", p, "--out", tmp_path / "serial", "--serial")
    assert serial.exit_code == 2  # the only failure is an unreadable input: bad input
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1", dashboard_address=None) as cluster:
        result = _run("run", p, "--out", tmp_path / "dask", "--scheduler", cluster.scheduler_address)
    assert result.exit_code == 2, result.output
    rows = json.loads((tmp_path / "dask" / "results.json").read_text())
    assert len(rows) == 20
    failed = [r for r in rows if r["status"] != "ok"]
    assert len(failed) == 1 and "m19.ply" in failed[0]["error"]
    for k in range(19):
        name = f"m{k:02d}_out.ply"
        assert _digest(tmp_path / "dask" / name) == _digest(tmp_path / "serial" / name)
    assert not (tmp_path / "dask" / "m19_out.ply").exists()
    assert {p.name: _digest(p) for p in inputs.iterdir()} == digests


def test_denoise_command_pinned_boundary_and_preserve_volume(tmp_path):
    from meshdenoise.shapes import grid
    from meshdenoise.geometry import signed_volume

    V, F = grid(8, 8)
    V = V + np.random.default_rng(0).normal(scale=0.01, size=V.shape)
    save_mesh(tmp_path / "g.ply", V, F)
    V32, _ = load_arrays(tmp_path / "g.ply")
    assert _run("denoise", tmp_path / "g.ply", tmp_path / "o.ply", "--method", "filtering", "--param", "iterations=5", "--pinned", "boundary").exit_code == 0
    W, _ = load_arrays(tmp_path / "o.ply")
    ops = md.get_operators(F, len(V))
    np.testing.assert_array_equal(W[ops.boundary_vertices], V32[ops.boundary_vertices])
    assert not np.allclose(W, V32)
    S, SF = _sphere_file(tmp_path, "s.ply"), None
    assert _run("denoise", S, tmp_path / "v.ply", "--method", "sobolev", "--param", "mu=5", "--preserve-volume").exit_code == 0
    X, F2 = load_arrays(S)
    Y, _ = load_arrays(tmp_path / "v.ply")
    assert abs(signed_volume(Y, F2) / signed_volume(X, F2) - 1) < 1e-5  # float32 file round trip
    bad = _run("denoise", S, tmp_path / "w.ply", "--method", "sobolev", "--param", "muu=5")
    assert bad.exit_code == 2 and "did you mean 'mu'" in bad.output and not (tmp_path / "w.ply").exists()


@pytest.mark.data
def test_shipped_paper_elephant_reproduces_the_paper_row(tmp_path):
    """One setting of the shipped paper pipeline, recomputed here through the API."""
    import json

    import meshdenoise as md
    from meshdenoise.io import load_arrays

    from .conftest import data_mesh_path

    elephant = data_mesh_path("elephant-50kv.off")  # skips with a reason on a clone without the meshes
    out = tmp_path / "out"
    result = _run("run", "pipelines/paper_elephant.yaml", "--out", out, "--serial", "--set", "rho=0.2", "--set", "method=filtering")
    assert result.exit_code == 0, result.output
    (row,) = json.loads((out / "results.json").read_text())
    V, F = load_arrays(elephant)
    Vn, _ = md.add_normal_noise((V, F), rho=0.2, seed=0)
    assert row["noisy.snr"] == pytest.approx(md.snr(V, Vn), abs=1e-9)
    k = row["auto.filtering.iterations"]
    assert row["denoised.snr"] == pytest.approx(md.snr(V, md.filtering((Vn, F), iterations=k)[0]), abs=1e-9)
    assert abs(row["denoised.snr"] - 26.81) < 0.5  # the paper's best filtering SNR, reached without the clean mesh


def test_shipped_compare_meshlab_runs_every_filter(tmp_path):
    """The shipped comparison on a small mesh: every row runs, and ours match direct API calls."""
    import json

    import meshdenoise as md
    from meshdenoise.io import save_arrays
    from meshdenoise.shapes import torus

    V, F = torus(40, 16)
    src = save_arrays(tmp_path / "torus.ply", V, F)
    out = tmp_path / "out"
    result = _run("run", "pipelines/compare_meshlab.yaml", "--input", src, "--out", out, "--serial")
    assert result.exit_code == 0, result.output
    rows = {r["method"]: r for r in json.loads((out / "results.json").read_text())}
    import yaml

    methods = yaml.safe_load(open("pipelines/compare_meshlab.yaml"))["sweep"]["method"]
    assert set(rows) == set(methods) and all(r["status"] == "ok" for r in rows.values())
    rho = 0.005 * float(np.linalg.norm(V.max(0) - V.min(0)))
    Vn, _ = md.add_normal_noise((V, F), rho=rho, seed=0)
    for name in ("filtering", "sobolev", "taubin"):
        assert rows[name]["snr"] == pytest.approx(md.snr(V, md.apply_filter(name, (Vn, F))[0]), abs=1e-9), name


def test_render_step_draws_before_after_error_and_is_staged(tmp_path):
    """The render step: noisy / denoised / error heat map in one PNG, written only if the task succeeds."""
    from PIL import Image

    from meshdenoise.shapes import grid

    save_mesh(tmp_path / "sphere.ply", *icosphere(2))
    out = tmp_path / "out"
    p = _write(tmp_path, (
        "inputs: sphere.ply\n"
        f"output_dir: {out}\n"
        "steps:\n"
        "  - add_noise: {rho: 0.02, seed: 0, label: clean}\n"
        "  - sobolev: {mu: 1, label: noisy}\n"
        "  - render: {path: '{stem}.png', meshes: [noisy, result], reference: clean, size: [120, 100], backend: matplotlib}\n"
    ))
    result = _run("run", p, "--serial")
    assert result.exit_code == 0, result.output
    image = Image.open(out / "sphere.png")
    assert image.width >= 3 * 120 and image.height >= 100  # noisy, denoised and the heat map of the last
    assert list(out.glob(".*")) == []  # no temporary left behind
    # a later step fails: the picture of that task must not be left behind
    save_mesh(tmp_path / "flat.ply", *grid(6, 6))
    out2 = tmp_path / "out2"
    p2 = _write(tmp_path, (
        "inputs: flat.ply\n"
        f"output_dir: {out2}\n"
        "steps:\n"
        "  - render: {path: '{stem}.png', backend: matplotlib, size: [64, 64]}\n"
        "  - compute_selection_by_condition_per_vertex: {condselect: '((x'}\n"
    ))
    assert _run("run", p2, "--serial").exit_code == 1
    assert not out2.exists() or list(out2.iterdir()) == []


def test_render_step_names_are_checked_before_running(tmp_path):
    save_mesh(tmp_path / "sphere.ply", *icosphere(1))
    p = _write(tmp_path, "inputs: sphere.ply\nsteps:\n  - render: {path: a.png, meshes: [input, cleen]}\n")
    result = _run("run", p)
    assert result.exit_code == 2 and "'cleen' is neither input, result nor the label" in result.output
    p = _write(tmp_path, "inputs: sphere.ply\nsteps:\n  - render: {path: a.png, mehses: [input]}\n")
    result = _run("run", p)
    assert result.exit_code == 2 and "did you mean 'meshes'" in result.output


def test_render_step_draws_a_scans_change_and_a_zoom_like_the_api(tmp_path):
    """change / percentile / zoom reach render_comparison: the step's PNG equals the API's on the same meshes."""
    from PIL import Image

    from meshdenoise.render import render_comparison

    V, F = icosphere(3)
    Vn, _ = md.add_normal_noise((V, F), rho=0.02, seed=0)
    save_mesh(tmp_path / "scan.ply", Vn, F)
    out = tmp_path / "out"
    p = _write(tmp_path, (
        "inputs: scan.ply\n"
        f"output_dir: {out}\n"
        "steps:\n"
        "  - sobolev: {mu: 1}\n"
        "  - render: {path: '{stem}.png', change: true, percentile: 95, zoom: [0, 4], size: [96, 96], backend: matplotlib}\n"
    ))
    result = _run("run", p, "--serial")
    assert result.exit_code == 0, result.output
    Vs = md.sobolev((Vn, F), mu=1)[0]
    api = render_comparison([(Vn, F), (Vs, F)], tmp_path / "api.png", titles=["input", "result"], size=(96, 96), backend="matplotlib",
                            show_change=True, percentile=95, zoom=(0, 4.0))
    assert api.percentile == 95
    assert np.array_equal(np.asarray(Image.open(out / "scan.png")), np.asarray(Image.open(tmp_path / "api.png")))


@pytest.mark.parametrize("bad, shown", [
    ("change: 1", "change: expected true or false"),
    ("change: true, reference: input", "it goes without reference"),
    ("percentile: 0", "0 < p <= 100"),
    ("zoom: [0]", "zoom: expected [vertex, radius]"),
    ("zoom: [1.5, 2]", "zoom: expected [vertex, radius]"),
    ("zoom: [0, 0, 0, -1]", "radius > 0"),
])
def test_render_step_change_options_are_checked(tmp_path, bad, shown):
    save_mesh(tmp_path / "sphere.ply", *icosphere(1))
    p = _write(tmp_path, f"inputs: sphere.ply\nsteps:\n  - render: {{path: a.png, {bad}}}\n")
    result = _run("run", p, "--check")
    assert result.exit_code == 2 and shown in result.output, result.output


# --- pipeline state: arrays and attributes, a MeshSet only around pymeshlab steps -------------------
def test_mesh_state_round_trips_attributes_through_a_meshset():
    from meshdenoise.pipeline.state import MeshState

    V, F = icosphere(1)
    rng = np.random.default_rng(0)
    vsel = rng.random(len(V)) < 0.3
    fsel = rng.random(len(F)) < 0.3
    state = MeshState(V, F, rng.random((len(V), 4)), rng.random((len(F), 4)), rng.random(len(V)), rng.random(len(F)), vsel, fsel)
    back = MeshState.from_meshset(state.meshset())
    np.testing.assert_array_equal(back.V, V)
    np.testing.assert_array_equal(back.F, F)
    np.testing.assert_array_equal(back.vertex_selection, vsel)
    np.testing.assert_array_equal(back.face_selection, fsel)
    np.testing.assert_allclose(back.vertex_quality, state.vertex_quality)
    np.testing.assert_allclose(back.face_quality, state.face_quality)
    # MeshLab stores colours as 8-bit
    np.testing.assert_allclose(back.vertex_colors, state.vertex_colors, atol=1 / 255)
    np.testing.assert_allclose(back.face_colors, state.face_colors, atol=1 / 255)
    # our filter keeps every attribute (same vertices), and drops the cached MeshSet
    moved = back.with_vertices(V * 2)
    assert moved._meshset is None and moved.vertex_selection is back.vertex_selection


def test_pipeline_selection_and_quality_survive_our_filters(tmp_path):
    """pymeshlab selects, our filter moves only the selection, a later pymeshlab step still sees quality."""
    V, F = icosphere(2)
    Vn, _ = md.add_normal_noise((V, F), rho=0.02, seed=1)
    save_mesh(tmp_path / "s.ply", Vn, F)
    p = _write(tmp_path, f"""inputs: s.ply
output_dir: {tmp_path / 'out'}
steps:
  - compute_scalar_by_function_per_vertex: {{q: "x"}}
  - compute_selection_by_condition_per_vertex: {{condselect: "x > 0"}}
  - sobolev: {{mu: 1, region: selection}}
  - compute_selection_by_condition_per_vertex: {{condselect: "q > 0"}}
  - sobolev: {{mu: 1, pinned: selection}}
  - save: {{path: r.ply}}
""")
    result = _run("run", p)
    assert result.exit_code == 0, result.output
    R = load_arrays(tmp_path / "out" / "r.ply")[0]
    first = md.sobolev((Vn, F), mu=1, region=Vn[:, 0] > 0)[0]
    # the quality q = x was set before the first filter moved the vertices: the selection is by the old x
    second = md.sobolev((first, F), mu=1, pinned=Vn[:, 0] > 0)[0]
    np.testing.assert_allclose(R, second, atol=1e-6)  # PLY stores float32
    assert not np.allclose(second, first)


def test_one_metrics_module_lists_every_metric_explicitly():
    import ast
    import importlib.util
    import inspect

    import meshdenoise.metrics as metrics

    assert list(metrics.METRICS) == ["snr", "normal_error_deg", "mean_distance", "max_distance", "volume_change"]
    # registration is the literal in metrics.py: no module fills METRICS by side effect, and no alias module is left
    tree = ast.parse(inspect.getsource(metrics))
    assert not [n for n in ast.walk(tree) if isinstance(n, (ast.Import, ast.ImportFrom))
                and "metrics" in (getattr(n, "module", None) or "")]
    assert importlib.util.find_spec("meshdenoise.quality_metrics") is None
    assert importlib.util.find_spec("meshdenoise.auto") is None  # choose_parameters lives in meshdenoise.tuning


def test_check_reports_every_problem_at_once_with_lines(tmp_path):
    _sphere_file(tmp_path)
    p = _write(tmp_path, f"""inputs: [s.ply, missing.ply]
output_dir: {tmp_path / 'out'}
colour: red
steps:
  - sobolv: {{mu: 1}}
  - apply_coord_laplacian_smoothing: {{stepsmothnum: 3}}
  - sobolev: {{mu: -1}}
  - save: {{path: x.ply}}
""")
    result = _run("run", "--check", p)
    assert result.exit_code == 2, result.output
    out = result.output
    for expected in (f"{p}:1: inputs: no such file 'missing.ply'", f"{p}:3: unknown key 'colour'",
                     f"{p}:5: step 1 'sobolv': unknown step", f"{p}:6: step 2", "did you mean 'stepsmoothnum'",
                     f"{p}:7: step 3 'sobolev'", "out of range", "5 problems; nothing was run"):
        assert expected in out, out
    assert out.count("error:") == 5, out
    assert not (tmp_path / "out").exists()


def test_problems_under_a_sweep_are_reported_once(tmp_path):
    from meshdenoise.pipeline import PipelineValidationError, load_pipeline

    _sphere_file(tmp_path)
    p = _write(tmp_path, "inputs: s.ply\nsweep: {mu: [1, 2, 3]}\nsteps:\n  - sobolv: {mu: '${mu}'}\n  - heat: {tau: -1}\n")
    with pytest.raises(PipelineValidationError) as info:
        load_pipeline(p)
    assert [line.split(": ")[1] for line in info.value.problems] == ["step 1 'sobolv'", "step 2 'heat'"]


# --- batches of inputs sharing a file name (a benchmark folder of pairs) ------------------------------------
def _pairs(tmp_path, names=("Bunny", "Block", "Fandisk")):
    V, F = icosphere(2)
    for k, name in enumerate(names):
        d = tmp_path / "bench" / name
        d.mkdir(parents=True)
        save_mesh(d / "Original.obj", V * (k + 1), F)
        Vn, _ = md.add_normal_noise((V * (k + 1), F), rho=0.02, seed=k)
        save_mesh(d / "Noisy.obj", Vn, F)
    return V, F


def test_benchmark_folder_of_pairs_runs_in_one_pipeline(tmp_path):
    V, F = _pairs(tmp_path)
    p = _write(tmp_path, f"""inputs: bench/*/Noisy.obj
output_dir: {tmp_path / 'out'}
steps:
  - sobolev: {{mu: 1}}
  - metrics: {{reference: "{{dir}}/Original.obj", metrics: [snr, mean_distance, normal_error_deg]}}
  - save: {{path: "{{parent}}_clean.ply"}}
""")
    result = _run("run", p, "--serial")
    assert result.exit_code == 0, result.output
    rows = json.loads((tmp_path / "out" / "results.json").read_text())
    for k, name in enumerate(("Block", "Bunny", "Fandisk")):  # inputs sorted by path
        row = next(r for r in rows if f"/{name}/" in r["input"])
        k_orig = ("Bunny", "Block", "Fandisk").index(name)
        noisy = load_arrays(tmp_path / "bench" / name / "Noisy.obj")[0]
        expected = md.snr((V * (k_orig + 1), F), md.sobolev((noisy, F), mu=1)[0])
        assert row["snr"] == pytest.approx(expected, rel=1e-6)
        assert (tmp_path / "out" / f"{name}_clean.ply").is_file()
    # the terminal table names each input by its shortest distinguishing path, and cuts no column
    for name in ("Block/Noisy.obj", "Bunny/Noisy.obj", "Fandisk/Noisy.obj", "mean_distance", "normal_error_deg"):
        assert name in result.output, result.output
    assert "…" not in result.output


def test_per_input_reference_must_exist_for_every_input(tmp_path):
    _pairs(tmp_path)
    (tmp_path / "bench" / "Block" / "Original.obj").unlink()
    p = _write(tmp_path, "inputs: bench/*/Noisy.obj\nsteps:\n  - metrics: {reference: '{dir}/Original.obj'}\n")
    result = _run("run", "--check", p)
    assert result.exit_code == 2
    assert f"{p}:3: step 1 'metrics': reference: no such file" in result.output and "for input Block/Noisy.obj" in result.output


def test_output_collision_names_two_different_tasks(tmp_path):
    _pairs(tmp_path, ("Bunny", "Block"))
    p = _write(tmp_path, f"inputs: bench/*/Noisy.obj\noutput_dir: {tmp_path / 'out'}\nsteps:\n  - save: {{path: '{{stem}}_clean.ply'}}\n")
    result = _run("run", "--check", p)
    assert result.exit_code == 2
    text = " ".join(result.output.split())
    assert "for both Block/Noisy.obj (step 1) and Bunny/Noisy.obj (step 1)" in text, text
    assert "{parent}" in text


def test_distinguishing_names():
    from pathlib import Path

    from meshdenoise.pipeline.schema import distinguishing_names

    paths = [Path("/a/x/m.ply"), Path("/b/x/m.ply"), Path("/b/y/m.ply"), Path("/c/n.ply")]
    assert [distinguishing_names(paths)[p] for p in paths] == ["a/x/m.ply", "b/x/m.ply", "y/m.ply", "n.ply"]
    assert distinguishing_names([Path("/a/m.ply")]) == {Path("/a/m.ply"): "m.ply"}


def test_steps_command_lists_every_step_and_only_parameters_the_checker_knows(tmp_path):
    from meshdenoise.pipeline.errors import PipelineValidationError
    from meshdenoise.pipeline.steps import BUILTIN_STEPS, OPEN3D_OPS, parse_step
    from meshdenoise.registry import list_filters

    result = _run("steps", "--json")
    assert result.exit_code == 0, result.output
    steps = {s["name"]: s for s in json.loads(result.output)}
    expected = set(BUILTIN_STEPS) | {f"open3d.{k}" for k in OPEN3D_OPS} | {s.name for s in list_filters()}
    assert expected <= set(steps)
    assert [p["name"] for p in steps["render"]["params"]] == ["path", "meshes", "reference", "titles", "size", "backend", "cmap", "vmax", "change", "percentile", "zoom"]
    # every listed parameter is one the step's checker accepts by name (a wrong value, never an unknown name)
    for name in expected:
        for p in steps[name]["params"]:
            try:
                parse_step({name: {p["name"]: object()}}, 1, "t.yaml", 1)
            except PipelineValidationError as exc:
                assert "unknown parameter" not in str(exc), (name, p["name"], str(exc))
    text = _run("steps").output
    assert "render: draw meshes" in text and "    vmax (float): top of the colour bar" in text


def test_help_groups_commands_by_what_the_user_does_and_every_command_still_works():
    from meshdenoise.cli import SECTIONS

    result = _run("--help")
    assert result.exit_code == 0
    text = result.output
    heads = [text.index(f"\n{title}:\n") for title, _ in SECTIONS]
    assert heads == sorted(heads)
    listed = [name for _, names in SECTIONS for name in names]
    assert sorted(listed) == sorted(cli.commands), "every command is in exactly one section"
    for title, names in SECTIONS:
        section = text[text.index(f"\n{title}:\n"):]
        for name in names:
            assert f"\n  {name} " in section.split("\n\n")[0] + "\n", (title, name)
            assert _run(name, "--help").exit_code == 0


def test_one_parameter_check_for_our_filters_builtin_open3d_and_pymeshlab_steps(monkeypatch):
    """registry.Param.check is the one check: every kind of step goes through it."""
    from meshdenoise.pipeline.errors import PipelineValidationError
    from meshdenoise.pipeline.steps import parse_step
    from meshdenoise.registry import Param

    calls = []
    original = Param.check

    def spy(self, value, where=""):
        calls.append(self.name)
        return original(self, value, where)

    monkeypatch.setattr(Param, "check", spy)
    for step, name in [({"sobolev": {"mu": 2}}, "mu"), ({"add_noise": {"rho": 0.1}}, "rho"),
                       ({"open3d.filter_smooth_simple": {"number_of_iterations": 2}}, "number_of_iterations"),
                       ({"apply_coord_laplacian_smoothing": {"stepsmoothnum": 2}}, "stepsmoothnum")]:
        calls.clear()
        parse_step(step, 1, "t.yaml", 1)
        assert name in calls, (step, calls)
    # and so a non-finite number is refused for a pymeshlab float as for ours
    with pytest.raises(PipelineValidationError, match=r"t.yaml:1: step 1 'apply_coord_taubin_smoothing': parameter 'lambda_' = nan must be finite"):
        parse_step({"apply_coord_taubin_smoothing": {"lambda_": float("nan")}}, 1, "t.yaml", 1)


def test_errors_carry_their_parameter_and_a_step_error_names_its_key_line(tmp_path):
    """The checks attach the key an error is about (``exc.parameter``); the step's parser names that key's line
    from it, not from what the message quotes ('mux' below suggests 'mu', on the line above)."""
    from meshdenoise.pipeline import pymeshlab_steps
    from meshdenoise.registry import ParameterTypeError, ParameterValueError, get_filter

    spec = get_filter("sobolev")
    for given, kind, key in (({"mu": -1}, ParameterValueError, "mu"), ({"mu": "x"}, ParameterTypeError, "mu"),
                             ({"mux": 1}, ParameterTypeError, "mux")):
        with pytest.raises(kind) as info:
            spec.resolve(given, "here")
        assert info.value.parameter == key and isinstance(info.value, (TypeError, ValueError))
    with pytest.raises(ValueError) as info:
        pymeshlab_steps.check_parameters("apply_coord_laplacian_smoothing", {"stepsmothnum": 3}, "here")
    assert info.value.parameter == "stepsmothnum"
    _sphere_file(tmp_path)
    for steps, line, expected in (
        ("  - sobolev:\n      mu: 1\n      mux: 2\n", 6, "unknown parameter 'mux' (did you mean 'mu'?)"),
        ("  - sobolev:\n      mu: 1\n      preserve_volume: 3\n", 6, "preserve_volume must be true or false, got 3"),
        ("  - denoise:\n      method: sobolev\n      pinned: boundry\n", 6, "pinned: 'boundry' is not understood"),
    ):
        p = _write(tmp_path, f"inputs: s.ply\noutput_dir: {tmp_path / 'out'}\nsteps:\n{steps}")
        result = _run("run", "--check", p)
        step = steps.split(":")[0].strip("- ")
        assert result.exit_code == 2 and f"{p}:{line}: step 1 '{step}': " in result.output, result.output
        assert expected in result.output, result.output


@pytest.mark.parametrize(
    "path, expected",
    [("{stem:>99999999999}.ply", "width 99999999999 is more than 255"), ("{stem.ply", "path template '{stem.ply'"),
     ("{nope}.ply", "'nope'"), ("{stem:d}.ply", "path template '{stem:d}.ply'")],
)
def test_bad_path_templates_are_validation_errors(tmp_path, path, expected):
    _sphere_file(tmp_path)
    p = _write(tmp_path, f"inputs: s.ply\nsteps:\n  - save: {{path: '{path}'}}\n")
    result = _run("run", "--check", p)
    assert result.exit_code == 2 and expected in result.output and "Traceback" not in result.output, result.output


def test_pipeline_files_that_are_not_utf8_are_refused_cleanly(tmp_path):
    p = tmp_path / "p.yaml"
    p.write_bytes("inputs: caf\u00e9.ply\nsteps: [sobolev]\n".encode("latin-1"))
    result = _run("run", "--check", p)
    assert result.exit_code == 2 and "not utf-8 text" in result.output.lower() and str(p) in result.output, result.output
    p.write_bytes("steps: [sobolev]\n".encode("utf-16"))
    assert _run("run", "--check", p).exit_code == 2


@pytest.mark.parametrize(
    "step, shown",
    [("add_noise: {rho: 1.0e+308}", "rho=1e+308"),
     ("apply_coord_taubin_smoothing: {lambda_: 1.0e+300, stepsmoothnum: 3}", "lambda_=1e+300")],
)
def test_a_step_making_non_finite_coordinates_is_blamed_itself(tmp_path, step, shown):
    _sphere_file(tmp_path)
    p = _write(tmp_path, f"inputs: s.ply\noutput_dir: {tmp_path / 'out'}\nsteps:\n  - {step}\n  - sobolev: {{mu: 1}}\n  - save: {{path: o.ply}}\n")
    result = _run("run", p)
    assert result.exit_code == 2, result.output
    text = " ".join(result.output.split())
    name = step.split(":")[0]
    assert f"step 1 '{name}' with" in text and "produced non-finite coordinates" in text and shown in text, text
    assert not (tmp_path / "out" / "o.ply").exists()


def test_batch_failure_lines_and_table_show_brackets_in_paths_verbatim(tmp_path):
    d = tmp_path / "in[x]"
    d.mkdir()
    good = _sphere_file(d, "scan [final].ply")
    (d / "bad [1].ply").write_text("ply\nformat ascii 1.0\nelement vertex 3\nend_header\n0 0 0\n")
    p = _write(tmp_path, f"inputs: ['{d}/scan [final].ply', '{d}/bad [1].ply']\noutput_dir: {tmp_path / 'out'}\nsteps:\n  - sobolev: {{mu: 1}}\n  - save: {{path: '{{stem}}_c.ply'}}\n")
    result = _run("run", p, "--serial")
    assert result.exit_code == 2, result.output
    assert "failed: " in result.output and "bad [1].ply" in result.output, result.output
    assert "scan [final].ply" in result.output and (tmp_path / "out" / "scan [final]_c.ply").is_file()
    assert good.is_file()


def test_pymeshlab_integers_beyond_cpp_int_are_refused_before_running(tmp_path):
    from meshdenoise.pipeline.errors import PipelineValidationError
    from meshdenoise.pipeline.steps import parse_step

    parse_step({"apply_coord_laplacian_smoothing": {"stepsmoothnum": 2**31 - 1}}, 1, "t.yaml", 2)
    with pytest.raises(PipelineValidationError, match=r"t.yaml:2: step 1 'apply_coord_laplacian_smoothing': parameter 'stepsmoothnum' = 2147483648 is out of range"):
        parse_step({"apply_coord_laplacian_smoothing": {"stepsmoothnum": 2**31}}, 1, "t.yaml", 2)


@pytest.mark.parametrize(
    "step",
    ["open3d.filter_smooth_laplacian: {lambda_filter: 1.0e+300}", "open3d.filter_smooth_taubin: {lambda_filter: 2}",
     "open3d.filter_smooth_taubin: {mu: 0.5}"],
)
def test_open3d_smoothing_parameters_are_range_checked(tmp_path, step):
    _sphere_file(tmp_path)
    p = _write(tmp_path, f"inputs: s.ply\nsteps:\n  - {step}\n")
    result = _run("run", "--check", p)
    assert result.exit_code == 2 and "is out of range" in result.output, result.output


def test_a_sweep_of_a_billion_settings_is_refused_before_it_is_built(tmp_path):
    import resource

    _sphere_file(tmp_path)
    values = "[" + ", ".join(str(k) for k in range(10)) + "]"
    sweep = ", ".join(f"v{k}: {values}" for k in range(9))  # 10^9 settings in a few hundred bytes
    p = _write(tmp_path, f"inputs: s.ply\nsweep: {{{sweep}}}\nsteps:\n  - sobolev: {{mu: 1}}\n")
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    result = _run("run", "--check", p)
    assert result.exit_code == 2, result.output
    assert f"{p}:2: sweep:" in result.output and "= 1000000000 settings, more than the limit" in result.output, result.output
    assert resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before < 200_000  # kB: nothing was expanded


def test_steps_command_describes_named_steps_and_pymeshlab_filters():
    result = _run("steps", "--json", "Taubin Smooth", "render")
    assert result.exit_code == 0, result.output
    taubin, render = json.loads(result.output)
    assert taubin["name"] == "apply_coord_taubin_smoothing" and render["name"] == "render"
    params = {p["name"]: p for p in taubin["params"]}
    from meshdenoise.pipeline.pymeshlab_steps import _probe

    assert set(params) == set(_probe().filter_parameter_values("apply_coord_taubin_smoothing"))
    assert params["stepsmoothnum"]["type"] == "RichInt" and "stepSmoothNum" in params["stepsmoothnum"]["help"]
    assert params["mu"]["default"] == -0.53
    normals = json.loads(_run("steps", "--json", "compute_normal_per_vertex").output)[0]
    assert normals["params"][0]["default"] == "Simple Average"
    bad = _run("steps", "sobolv")
    assert bad.exit_code == 2 and "did you mean 'sobolev'" in bad.output

"""save: the vertex normals a pymeshlab normal step computed, and float32 PLY coordinates.

A pipeline's ``compute_normal_per_vertex`` before ``save`` writes MeshLab's normals as they are; a
later step that moves the vertices makes ``save`` write normals recomputed from them (MeshLab's
filters update the normals of what they move); ``precision: float32`` writes PLY ``float``
coordinates that read back as ``V.astype(float32)``, warning when that moves a georeferenced scan.
"""

import warnings

import numpy as np
import pymeshlab
import pytest
from click.testing import CliRunner

import meshdenoise as md
from meshdenoise.cli import cli
from meshdenoise.geometry import vertex_normals
from meshdenoise.io import MeshFileError, PrecisionWarning, load_mesh, save_mesh
from meshdenoise.shapes import icosphere


def _run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def _pipeline(tmp_path, steps: str, name="s.ply", mesh=None):
    V, F = mesh if mesh is not None else icosphere(2)
    if mesh is None:
        V, _ = md.add_normal_noise((V, F), rho=0.02, seed=1)
    save_mesh(tmp_path / name, V, F)
    p = tmp_path / "p.yaml"
    p.write_text(f"inputs: {name}\noutput_dir: {tmp_path / 'out'}\nsteps:\n{steps}")
    return p, V, F


def _ply_header(path) -> list[str]:
    head = path.read_bytes().split(b"end_header")[0].decode()
    return head.splitlines()


def _pymeshlab_normals(path):
    ms = pymeshlab.MeshSet()
    ms.load_new_mesh(str(path))
    return ms.current_mesh().vertex_normal_matrix()


def _meshlab_computes(V, F, **params):
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(V, F.astype(np.int32)))
    ms.compute_normal_per_vertex(**params)
    return ms.current_mesh().vertex_normal_matrix()


@pytest.mark.parametrize("weightmode", ["Simple Average", "By Angle", "By Area"])
def test_normals_of_a_pymeshlab_normal_step_are_written_as_computed(tmp_path, weightmode):
    p, V, F = _pipeline(tmp_path, f"  - compute_normal_per_vertex: {{weightmode: {weightmode}}}\n"
                                  "  - save: {path: r.ply}\n")
    result = _run("run", p)
    assert result.exit_code == 0, result.output
    out = tmp_path / "out" / "r.ply"
    head = _ply_header(out)
    assert "property double nx" in head and "property double x" in head
    want = _meshlab_computes(V, F, weightmode=weightmode)
    np.testing.assert_array_equal(_pymeshlab_normals(out), want)  # double in the file: exactly MeshLab's
    np.testing.assert_array_equal(load_mesh(out).V, V)


def test_normals_follow_later_steps_that_keep_or_move_the_vertices(tmp_path):
    # a selection keeps the vertices: the computed normals are kept
    p, V, F = _pipeline(tmp_path, "  - compute_normal_per_vertex: {weightmode: By Area}\n"
                                  "  - compute_selection_by_condition_per_vertex: {condselect: 'x > 0'}\n"
                                  "  - save: {path: kept.ply}\n"
                                  "  - sobolev: {mu: 1}\n"
                                  "  - save: {path: moved.ply}\n")
    result = _run("run", p)
    assert result.exit_code == 0, result.output
    np.testing.assert_array_equal(_pymeshlab_normals(tmp_path / "out" / "kept.ply"),
                                  _meshlab_computes(V, F, weightmode="By Area"))
    # our filter moved them: the moved vertices' normals (compute_normal_per_vertex's default)
    moved = load_mesh(tmp_path / "out" / "moved.ply")
    assert not np.array_equal(moved.V, V)
    np.testing.assert_allclose(_pymeshlab_normals(tmp_path / "out" / "moved.ply"), vertex_normals(moved.V, moved.F),
                               atol=1e-15)
    np.testing.assert_allclose(vertex_normals(moved.V, moved.F), _meshlab_computes(moved.V, moved.F), atol=1e-12)


def test_no_normal_step_writes_no_normals_and_normals_false_writes_none(tmp_path):
    p, V, F = _pipeline(tmp_path, "  - apply_coord_laplacian_smoothing: {stepsmoothnum: 1}\n"
                                  "  - save: {path: plain.ply}\n"
                                  "  - compute_normal_per_vertex\n"
                                  "  - save: {path: none.ply, normals: false}\n"
                                  "  - save: {path: n.obj}\n")
    result = _run("run", p)
    assert result.exit_code == 0, result.output
    assert not any("nx" in line for line in _ply_header(tmp_path / "out" / "plain.ply"))
    assert not any("nx" in line for line in _ply_header(tmp_path / "out" / "none.ply"))
    obj = (tmp_path / "out" / "n.obj").read_text().splitlines()
    vn = np.array([[float(x) for x in line.split()[1:]] for line in obj if line.startswith("vn ")])
    smoothed = load_mesh(tmp_path / "out" / "n.obj")
    np.testing.assert_array_equal(vn, _meshlab_computes(smoothed.V, smoothed.F))
    np.testing.assert_array_equal(smoothed.F, F)


@pytest.mark.parametrize("binary", [True, False])
def test_float32_ply_reads_back_as_the_float32_coordinates(tmp_path, binary):
    V, F = icosphere(3)
    V = V * 0.37 + 0.1
    N = vertex_normals(V, F)
    out = save_mesh(tmp_path / "f.ply", V, F, binary=binary, precision="float32", vertex_normals=N)
    head = _ply_header(out)
    assert {"property float x", "property float nz"} <= set(head) and not any("double" in h for h in head)
    back = load_mesh(out)
    if binary:
        np.testing.assert_array_equal(back.V, V.astype(np.float32))
    else:  # ASCII writes 9 digits: read as float32 they are the same floats
        np.testing.assert_array_equal(back.V.astype(np.float32), V.astype(np.float32))
    np.testing.assert_array_equal(_pymeshlab_normals(out).astype(np.float32), N.astype(np.float32))
    double = save_mesh(tmp_path / "d.ply", V, F, binary=binary, vertex_normals=N)
    assert out.stat().st_size < double.stat().st_size * 0.75


def test_float32_pipeline_save_and_the_georeferenced_warning(tmp_path):
    V, F = icosphere(2)
    geo = V * 0.5 + np.array([4.5e5, 5.2e6, 300.0])  # UTM-like offsets, half-metre detail
    p, _, _ = _pipeline(tmp_path, "  - save: {path: r.ply, precision: float32}\n", mesh=(geo, F))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = _run("run", p)
    assert result.exit_code == 0, result.output
    text = result.output + " ".join(str(w.message) for w in caught)
    assert "float32" in text and "precision float64" in text, text
    np.testing.assert_array_equal(load_mesh(tmp_path / "out" / "r.ply").V, geo.astype(np.float32))
    with pytest.warns(PrecisionWarning, match="PLY .precision float32."):
        save_mesh(tmp_path / "g.ply", geo, F, precision="float32")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        save_mesh(tmp_path / "small.ply", V, F, precision="float32")  # near the origin: no warning


@pytest.mark.parametrize("step, shown", [
    ("{path: r.obj, precision: float32}", "'precision': precision 'float32' is for PLY only"),
    ("{path: r.ply, precision: half}", "precision"),
    ("{path: r.ply, precision: 32}", "precision"),
    ("{path: r.ply, normals: maybe}", "normals"),
])
def test_bad_save_options_are_one_line_at_check_time(tmp_path, step, shown):
    p, _, _ = _pipeline(tmp_path, f"  - save: {step}\n")
    result = _run("run", p, "--check")
    assert result.exit_code == 2, result.output
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and "p.yaml" in lines[0] and "save" in lines[0], result.output
    assert shown.split(":")[-1].strip() in lines[0] or shown in lines[0], result.output
    assert not (tmp_path / "out").exists()


def test_save_mesh_refuses_bad_normals_and_precision_and_leaves_nothing(tmp_path):
    V, F = icosphere(1)
    for kwargs, shown in [({"precision": "float32"}, "PLY only"), ({"precision": "half"}, "precision"),
                          ({"vertex_normals": np.zeros((3, 3))}, "vertex_normals"),
                          ({"vertex_normals": np.full(V.shape, np.nan)}, "finite")]:
        path = tmp_path / ("m.obj" if kwargs.get("precision") == "float32" else "m.ply")
        with pytest.raises(MeshFileError, match=shown) as info:
            save_mesh(path, V, F, **kwargs)
        assert str(path) in str(info.value) and "\n" not in str(info.value)
        assert not path.exists()

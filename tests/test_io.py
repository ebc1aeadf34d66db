"""meshdenoise.io against other implementations: pymeshlab and Open3D read what we write,
we read what they read, round trips are exact, writes are atomic and errors name the file."""

from __future__ import annotations

import glob

import numpy as np
import pytest

from meshdenoise.data import sample_mesh
from meshdenoise.io import MeshFileError, atomic_path, load_arrays, load_mesh, save_arrays, save_mesh
from meshdenoise.shapes import icosphere, torus

from .conftest import data_mesh_path

FORMATS = [(".ply", True), (".ply", False), (".off", True), (".obj", True), (".stl", True), (".stl", False)]


_ALIVE: list = []


def _pymeshlab_arrays(path):
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.load_new_mesh(str(path))
    m = ms.current_mesh()
    _ALIVE.append(ms)  # the Mesh is a view into the MeshSet: keep the MeshSet alive
    return m, m.vertex_matrix(), m.face_matrix()


@pytest.mark.parametrize("ext,binary", FORMATS)
def test_round_trip_and_pymeshlab_open3d_read_what_we_write(tmp_path, ext, binary):
    import open3d as o3d

    V, F = torus(9, 7)
    V = V + np.random.default_rng(0).normal(scale=1e-3, size=V.shape)  # digits that float32 would lose
    path = save_arrays(tmp_path / f"t{ext}", V, F, binary=binary)
    m = load_mesh(path)
    if ext == ".stl" and binary:  # float32 corners, merged back into shared vertices
        np.testing.assert_array_equal(m.V[m.F], V.astype(np.float32).astype(np.float64)[F])
        assert m.V.shape == V.shape
    elif ext == ".stl":  # ASCII: 17 digits, corners merged back
        np.testing.assert_array_equal(m.V[m.F], V[F])
        assert m.V.shape == V.shape
    else:  # exact: double in PLY, 17 digits in text
        np.testing.assert_array_equal(m.V, V)
        np.testing.assert_array_equal(m.F, F)
    _, Vp, Fp = _pymeshlab_arrays(path)
    np.testing.assert_allclose(Vp[Fp], V[F], atol=1e-6)
    o = o3d.io.read_triangle_mesh(str(path))
    Vo, Fo = np.asarray(o.vertices), np.asarray(o.triangles)
    np.testing.assert_allclose(Vo[Fo], V[F], atol=1e-6)


@pytest.mark.parametrize("ext", [".ply", ".off", ".obj"])
def test_colours_round_trip_and_pymeshlab_sees_them(tmp_path, ext):
    V, F = icosphere(1)
    C = np.random.default_rng(1).integers(0, 256, size=(len(V), 4)) / 255.0
    if ext == ".obj":
        C[:, 3] = 1.0  # OBJ has RGB only
    path = save_mesh(tmp_path / f"c{ext}", V, F, C)
    np.testing.assert_allclose(load_mesh(path).vertex_colors, C, atol=1e-12)
    m, _, _ = _pymeshlab_arrays(path)
    assert m.has_vertex_color()
    np.testing.assert_allclose(m.vertex_color_matrix()[:, :3], C[:, :3], atol=1 / 255 + 1e-9)


SAMPLES = ["airplane.obj", "bone.ply", "bunny10k_textured.obj", "colored_airplane.ply", "cow.obj", "cube.obj"]


@pytest.mark.parametrize("name", SAMPLES)
def test_reads_pymeshlab_samples_as_pymeshlab_does(name):
    path = sample_mesh(name)
    m = load_mesh(path)
    pm, Vp, Fp = _pymeshlab_arrays(path)
    np.testing.assert_array_equal(m.V, Vp)
    np.testing.assert_array_equal(m.F, Fp)
    assert (m.vertex_colors is not None) == pm.has_vertex_color()
    if pm.has_vertex_color():
        np.testing.assert_allclose(m.vertex_colors, pm.vertex_color_matrix(), atol=1 / 255 + 1e-9)


def test_reads_a_binary_ply_range_map_as_pymeshlab_does():
    path = sorted(glob.glob(str(sample_mesh("bunny.obj").parent / "rangemaps" / "*.ply")))[0]
    m = load_mesh(path)
    _, Vp, Fp = _pymeshlab_arrays(path)
    np.testing.assert_array_equal(m.V, Vp)
    np.testing.assert_array_equal(m.F, Fp)


@pytest.mark.data
@pytest.mark.parametrize("name", ["nefertiti.off", "elephant-50kv.off"])
def test_reads_the_papers_meshes_as_pymeshlab_does(name):
    path = data_mesh_path(name)
    m = load_mesh(path)
    _, Vp, Fp = _pymeshlab_arrays(path)
    np.testing.assert_array_equal(m.V, Vp)
    np.testing.assert_array_equal(m.F, Fp)
    assert m.notes == []


def test_polygons_are_fans_and_noted(tmp_path):
    p = tmp_path / "pent.off"
    p.write_text("OFF\n5 1 0\n0 0 0\n1 0 0\n1 1 0\n0.5 1.5 0\n0 1 0\n5 0 1 2 3 4\n")
    m = load_mesh(p)
    assert m.F.tolist() == [[0, 1, 2], [0, 2, 3], [0, 3, 4]]
    assert any("triangulated" in n for n in m.notes)


def test_off_colour_forms(tmp_path):
    p = tmp_path / "c.off"
    p.write_text("COFF\n3 1 0\n0 0 0 255 0 0 255\n1 0 0 0 255 0 255\n0 1 0 0 0 255 255\n3 0 1 2\n")
    np.testing.assert_array_equal(load_mesh(p).vertex_colors, [[1, 0, 0, 1], [0, 1, 0, 1], [0, 0, 1, 1]])
    p.write_text("COFF\n3 1 0\n0 0 0 1.0 0.5 0 1.0\n1 0 0 0 1.0 0 1.0\n0 1 0 0 0 1.0 1.0\n3 0 1 2 0.2 0.2 0.2\n")
    m = load_mesh(p)
    np.testing.assert_array_equal(m.vertex_colors[0], [1, 0.5, 0, 1])
    assert m.F.tolist() == [[0, 1, 2]]  # the face colour is not an index


def test_obj_line_continuation_and_vertex_w(tmp_path):
    p = tmp_path / "w.obj"
    p.write_text("v 0 0 0 1\nv 1 0 0 1\nv 0 1 0 1\nf 1 \\\n2 3\n")
    m = load_mesh(p)
    assert m.F.tolist() == [[0, 1, 2]] and m.V.shape == (3, 3)


def test_error_names_line_of_bad_number(tmp_path):
    p = tmp_path / "bad.obj"
    p.write_text("v 0 0 0\nv 1 0 0\nv 0 one 0\nf 1 2 3\n")
    with pytest.raises(MeshFileError, match=r"bad\.obj: line 3: 'one' is not a number"):
        load_mesh(p)


def test_missing_file_directory_and_extension(tmp_path):
    with pytest.raises(MeshFileError, match=r"nope\.ply: no such file"):
        load_mesh(tmp_path / "nope.ply")
    (tmp_path / "dir.ply").mkdir()
    with pytest.raises(MeshFileError, match=r"dir\.ply: not a regular file"):
        load_mesh(tmp_path / "dir.ply")
    with pytest.raises(MeshFileError, match=r"unsupported extension '\.xyz'"):
        load_mesh(tmp_path / "a.xyz")


def test_unreadable_file(tmp_path, monkeypatch):
    p = save_arrays(tmp_path / "locked.ply", *icosphere(0))

    def denied(self):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(type(p), "read_bytes", denied)  # chmod 0 does not stop root
    with pytest.raises(MeshFileError, match=r"locked\.ply: cannot be read \(Permission denied\)"):
        load_mesh(p)


def test_save_refuses_bad_arrays_naming_the_file_and_writes_nothing(tmp_path):
    V, F = icosphere(0)
    Vn = V.copy()
    Vn[3, 0] = np.nan
    with pytest.raises(MeshFileError, match=r"out\.ply: cannot be written: .*vertex 3"):
        save_arrays(tmp_path / "out.ply", Vn, F)
    with pytest.raises(MeshFileError, match=r"out\.ply: .*outside 0\.\.11"):
        save_arrays(tmp_path / "out.ply", V, F + 1)
    with pytest.raises(MeshFileError, match=r"pc\.stl: STL stores triangles only"):
        save_arrays(tmp_path / "pc.stl", V, np.zeros((0, 3), int))
    with pytest.raises(MeshFileError, match=r"vertex_colors must lie in \[0, 1\]"):
        save_mesh(tmp_path / "out.ply", V, F, np.full((len(V), 3), 2.0))
    assert list(tmp_path.iterdir()) == []


def test_a_failed_write_keeps_the_old_file_and_leaves_no_temporary(tmp_path, monkeypatch):
    import meshdenoise.io as mio

    V, F = icosphere(1)
    target = save_arrays(tmp_path / "keep.ply", V, F)
    before = target.read_bytes()

    def boom(fh, *args):
        fh.write(b"ply\nformat ascii 1.0\n")  # a half-written file...
        raise OSError(28, "No space left on device")  # ...then the disk fills up

    monkeypatch.setitem(mio._WRITERS, ".ply", boom)
    with pytest.raises(MeshFileError, match=r"keep\.ply: cannot be written \(No space left on device\)"):
        save_arrays(target, V * 2, F)
    assert target.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["keep.ply"]


def test_unwritable_folder(tmp_path, monkeypatch):
    import tempfile

    def denied(*args, **kwargs):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(tempfile, "mkstemp", denied)  # a read-only folder does not stop root
    with pytest.raises(MeshFileError, match=r"x\.ply: cannot be written \(Permission denied\)"):
        save_arrays(tmp_path / "x.ply", *icosphere(0))
    assert list(tmp_path.iterdir()) == []


def test_atomic_path_removes_temporary_on_error(tmp_path):
    with pytest.raises(RuntimeError):
        with atomic_path(tmp_path / "a.off") as tmp:
            tmp.write_text("partial")
            raise RuntimeError("stop")
    assert list(tmp_path.iterdir()) == []


def test_load_arrays_matches_load_mesh(tmp_path):
    V, F = icosphere(1)
    p = save_arrays(tmp_path / "s.off", V, F)
    V1, F1 = load_arrays(p)
    np.testing.assert_array_equal(V1, V)
    np.testing.assert_array_equal(F1, F)


def test_a_fifo_or_device_is_refused_at_once_instead_of_blocking(tmp_path):
    import os

    fifo = tmp_path / "pipe.ply"
    os.mkfifo(fifo)  # opening it for reading would block until a writer comes
    with pytest.raises(MeshFileError, match=r"pipe\.ply: not a regular file"):
        load_mesh(fifo)
    dev = tmp_path / "zero.stl"
    dev.symlink_to("/dev/zero")  # endless bytes
    with pytest.raises(MeshFileError, match=r"zero\.stl: not a regular file"):
        load_mesh(dev)


def test_written_files_get_the_usual_mode_and_keep_a_replaced_files_mode(tmp_path):
    """Atomic writes go through a private temporary file; the result must not stay private (0600)."""
    import os

    from meshdenoise.io import save_mesh
    from meshdenoise.shapes import icosphere

    mask = os.umask(0)  # read the process umask (the writer reads the same one at import)
    os.umask(mask)
    path = save_mesh(tmp_path / "new.ply", *icosphere(1))
    assert path.stat().st_mode & 0o777 == 0o666 & ~mask
    os.chmod(path, 0o640)
    save_mesh(path, *icosphere(1))
    assert path.stat().st_mode & 0o777 == 0o640

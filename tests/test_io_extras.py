"""A scanner PLY's other data (quality, confidence, flags, normals, a camera, a range grid) read and written again:
values and types exact, pymeshlab reads what we write, and what a change of the mesh makes meaningless is dropped."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from meshdenoise.io import load_mesh, save_mesh
from meshdenoise.shapes import grid

CAMERA = ("view_px", "view_py", "view_pz", "focal")


def _scan_ply(path, V, F, *, ascii_format=False, normals=None, grid_lists=True):
    """A PLY written by hand the way a range scanner does: camera first, per-vertex extras, face quality."""
    n, m = len(V), len(F)
    quality = np.linspace(0.0, 1.0, n, dtype=np.float32)
    flags = np.where(np.arange(n) % 3 == 0, 0x20, 0).astype(np.int32)  # every third vertex selected (MeshLab's bit)
    conf = (np.arange(n) % 7).astype(np.uint8)
    fq = np.arange(m, dtype=np.float32) / 10
    head = ["ply", f"format {'ascii' if ascii_format else 'binary_little_endian'} 1.0", "comment a scanner",
            "element camera 1", *[f"property float {c}" for c in CAMERA],
            f"element vertex {n}", "property float x", "property float y", "property float z"]
    if normals is not None:
        head += ["property float nx", "property float ny", "property float nz"]
    head += ["property int flags", "property float quality", "property uchar confidence",
             f"element face {m}", "property list uchar int vertex_indices", "property float quality"]
    cells = [[0], [], [2]] if grid_lists else [[0], [1], [2]]
    head += [f"element range_grid {len(cells)}", "property list uchar int vertex_indices", "end_header"]
    camera = (1.5, -2.0, 30.0, 800.0)
    with open(path, "wb") as fh:
        fh.write(("\n".join(head) + "\n").encode())
        if ascii_format:
            fh.write((" ".join(map(str, camera)) + "\n").encode())
            for i in range(n):
                nn = " ".join(f"{x:.9g}" for x in normals[i]) + " " if normals is not None else ""
                fh.write(f"{V[i, 0]:.9g} {V[i, 1]:.9g} {V[i, 2]:.9g} {nn}{flags[i]} {quality[i]:.9g} {conf[i]}\n".encode())
            for j in range(m):
                fh.write(f"3 {F[j, 0]} {F[j, 1]} {F[j, 2]} {fq[j]:.9g}\n".encode())
            for c in cells:
                fh.write((" ".join(map(str, [len(c), *c])) + "\n").encode())
        else:
            fh.write(struct.pack("<4f", *camera))
            for i in range(n):
                fh.write(struct.pack("<3f", *V[i]))
                if normals is not None:
                    fh.write(struct.pack("<3f", *normals[i]))
                fh.write(struct.pack("<ifB", flags[i], quality[i], conf[i]))
            for j in range(m):
                fh.write(struct.pack("<B3if", 3, *F[j], fq[j]))
            for c in cells:
                fh.write(struct.pack(f"<B{len(c)}i", len(c), *c))
    return {"quality": quality, "flags": flags, "confidence": conf, "face_quality": fq, "camera": camera, "cells": cells}


def _mesh():
    V, F = grid(6, 5)
    V = V.astype(np.float32).astype(np.float64)  # exactly representable in the file's float32
    return V, F


@pytest.mark.parametrize("ascii_in", [False, True])
@pytest.mark.parametrize("binary_out", [True, False])
def test_extras_written_again_exactly(tmp_path, ascii_in, binary_out):
    V, F = _mesh()
    want = _scan_ply(tmp_path / "scan.ply", V, F, ascii_format=ascii_in)
    m = load_mesh(tmp_path / "scan.ply")
    assert m.extras.describe() == ["vertex flags", "vertex quality", "vertex confidence", "face quality",
                                   "camera", "range_grid"]
    V2 = m.V + 0.25
    out = save_mesh(tmp_path / "out.ply", V2, m.F, binary=binary_out, extras=m.extras)
    r = load_mesh(out)
    np.testing.assert_array_equal(r.V, V2)
    for name, dtype in (("quality", "f4"), ("flags", "i4"), ("confidence", "u1")):
        t, a = r.extras.vertex[name]
        assert t == dtype
        np.testing.assert_array_equal(a, want[name])
    np.testing.assert_array_equal(r.extras.face["quality"][1], want["face_quality"])
    (cam_name, _, _, cam), (grid_name, count, _, cells) = r.extras.other_elements()
    assert (cam_name, grid_name, count) == ("camera", "range_grid", 3)
    assert [float(np.asarray(cam[c]).ravel()[0]) for c in CAMERA] == list(want["camera"])
    assert [np.asarray(c).astype(int).tolist() for c in cells["vertex_indices"]] == want["cells"]
    header = out.read_bytes().split(b"end_header")[0].decode()
    assert header.index("element camera") < header.index("element vertex") < header.index("element face") \
        < header.index("element range_grid")  # the file's element order kept


def test_pymeshlab_reads_the_quality_we_write(tmp_path):
    import pymeshlab

    V, F = _mesh()
    want = _scan_ply(tmp_path / "scan.ply", V, F)
    m = load_mesh(tmp_path / "scan.ply")
    out = save_mesh(tmp_path / "out.ply", m.V * 2, m.F, extras=m.extras)
    ms = pymeshlab.MeshSet()
    ms.load_new_mesh(str(out))
    mm = ms.current_mesh()
    np.testing.assert_allclose(mm.vertex_matrix(), m.V * 2)
    np.testing.assert_allclose(mm.vertex_scalar_array(), want["quality"])
    np.testing.assert_allclose(mm.face_scalar_array(), want["face_quality"])
    np.testing.assert_array_equal(mm.vertex_selection_array(), want["flags"] == 0x20)


def test_normals_recomputed_from_the_new_coordinates(tmp_path):
    V, F = _mesh()
    stale = np.tile([1.0, 0.0, 0.0], (len(V), 1))
    _scan_ply(tmp_path / "scan.ply", V, F, normals=stale)
    m = load_mesh(tmp_path / "scan.ply")
    assert m.extras.normals and "nx" not in m.extras.vertex
    V2 = m.V.copy()
    V2[:, 2] = 0.3 * V2[:, 0]  # a tilted plane: every normal is (-0.3, 0, 1) / |.| (up to orientation)
    out = save_mesh(tmp_path / "out.ply", V2, m.F, extras=m.extras)
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.load_new_mesh(str(out))
    N = ms.current_mesh().vertex_normal_matrix()
    expect = np.array([-0.3, 0.0, 1.0]) / np.hypot(0.3, 1.0)
    np.testing.assert_allclose(np.abs(N @ expect), 1.0, atol=1e-6)


def test_a_changed_mesh_drops_what_refers_to_its_vertices(tmp_path):
    V, F = _mesh()
    _scan_ply(tmp_path / "scan.ply", V, F)
    extras = load_mesh(tmp_path / "scan.ply").extras
    same = extras.for_mesh(len(V), len(F))
    assert same.describe() == extras.describe()
    fewer = extras.for_mesh(len(V) - 1, len(F) - 2)  # a cleaning step removed a vertex and two faces
    assert fewer.describe() == ["camera"]  # the view point stays true; quality, flags, the grid's indices do not
    faces_only = extras.for_mesh(len(V), len(F) + 1)
    assert "face quality" not in faces_only.describe() and "vertex quality" in faces_only.describe()
    kept = F[(F < len(V) - 1).all(axis=1)]
    out = save_mesh(tmp_path / "out.ply", V[:-1], kept, extras=extras)  # save_mesh applies for_mesh itself
    assert load_mesh(out).extras.describe() == ["camera"]


def test_selection_bit_follows_the_current_selection(tmp_path):
    V, F = _mesh()
    want = _scan_ply(tmp_path / "scan.ply", V, F)
    extras = load_mesh(tmp_path / "scan.ply").extras
    sel = np.zeros(len(V), bool)
    sel[:4] = True
    flags = extras.with_selection(sel).vertex["flags"][1]
    np.testing.assert_array_equal(flags & 0x20 != 0, sel)
    np.testing.assert_array_equal(flags & ~0x20, want["flags"] & ~0x20)  # the other bits untouched
    assert not (extras.with_selection(None).vertex["flags"][1] & 0x20).any()


def test_polygon_faces_lose_their_face_properties(tmp_path):
    p = tmp_path / "quads.ply"
    p.write_text("ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
                 "property float quality\nelement face 1\nproperty list uchar int vertex_indices\n"
                 "property float quality\nend_header\n0 0 0 1\n1 0 0 2\n1 1 0 3\n0 1 0 4\n4 0 1 2 3 9\n")
    m = load_mesh(p)
    assert len(m.F) == 2 and m.extras.face == {}  # one quad, two triangles: face i is no longer face i
    np.testing.assert_array_equal(m.extras.vertex["quality"][1], [1, 2, 3, 4])


def test_other_formats_have_no_extras(tmp_path):
    V, F = _mesh()
    for ext in (".obj", ".off", ".stl"):
        assert load_mesh(save_mesh(tmp_path / f"t{ext}", V, F)).extras is None


def _cli(*args):
    from click.testing import CliRunner

    from meshdenoise.cli import cli

    return CliRunner().invoke(cli, [str(a) for a in args])


def test_denoise_command_keeps_a_scans_extras(tmp_path):
    V, F = _mesh()
    V[:, 2] = 0.05 * np.random.default_rng(0).standard_normal(len(V))
    want = _scan_ply(tmp_path / "scan.ply", V.astype(np.float32).astype(np.float64), F)
    result = _cli("denoise", tmp_path / "scan.ply", tmp_path / "out.ply", "--method", "sobolev", "--param", "mu=1")
    assert result.exit_code == 0, result.output
    r = load_mesh(tmp_path / "out.ply")
    assert r.extras.describe() == ["vertex flags", "vertex quality", "vertex confidence", "face quality",
                                   "camera", "range_grid"]
    np.testing.assert_array_equal(r.extras.vertex["quality"][1], want["quality"])
    np.testing.assert_array_equal(r.extras.vertex["flags"][1], want["flags"])  # the selection read is the one written
    assert not np.allclose(r.V, load_mesh(tmp_path / "scan.ply").V)  # it did smooth


def test_pipeline_cleaning_step_keeps_only_what_stays_true(tmp_path):
    V, F = _mesh()
    V = np.vstack([V, [[9.0, 9.0, 9.0]]])  # one vertex on no face: removed by the cleaning step
    want = _scan_ply(tmp_path / "scan.ply", V.astype(np.float32).astype(np.float64), F)
    p = tmp_path / "p.yaml"
    p.write_text(f"inputs: {tmp_path / 'scan.ply'}\noutput_dir: {tmp_path / 'out'}\nsteps:\n"
                 "  - meshing_remove_unreferenced_vertices\n  - save: {path: clean.ply}\n")
    result = _cli("run", p)
    assert result.exit_code == 0, result.output
    r = load_mesh(tmp_path / "out" / "clean.ply")
    assert len(r.V) == len(V) - 1
    # flags, confidence and the grid's indices refer to the old vertices: dropped; the camera stays true, and
    # MeshLab's quality went through its step with the vertices (as MeshLab itself would save it)
    assert r.extras.describe() == ["vertex quality", "face quality", "camera"]
    np.testing.assert_array_equal(r.extras.vertex["quality"][1], want["quality"][:-1])
    np.testing.assert_array_equal(r.extras.face["quality"][1], want["face_quality"])

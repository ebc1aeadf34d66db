"""Binary PLY read from the file into the arrays, and PLY tables written piece by piece.

A binary PLY over 64 KiB is read by :func:`meshdenoise.io.ply_read._read_ply_file` (no copy of the file
in memory); every other file through its bytes. The two readers must agree on everything: arrays, colours,
selection, extras, notes and errors. The writer writes its vertex and face tables in pieces of
``_CHUNK_RECORDS`` records; the file must be the same bytes as one table written at once.
"""

from __future__ import annotations

import io
import tracemalloc

import numpy as np
import pytest

from meshdenoise.io import MeshFileError, load_mesh, save_mesh
from meshdenoise.io import ply_read, ply_write
from meshdenoise.io.errors import _Malformed
from meshdenoise.shapes import icosphere

from .brokenmeshes import cases, ply_bytes


def _outcome(read):
    notes: list[str] = []
    try:
        out = read(notes)
    except (_Malformed, ValueError, IndexError, OverflowError) as exc:
        return type(exc).__name__, str(exc)
    V, F, colors, selection, extras = out
    extra = None if extras is None else (sorted(extras.vertex), sorted(extras.face), extras.normals,
                                         [(e[0], e[1]) for e in extras.elements],
                                         {k: a.tolist() for k, (_, a) in {**extras.vertex, **extras.face}.items()})
    return (np.asarray(V).tolist(), np.asarray(F).tolist(), None if colors is None else colors.tolist(),
            None if selection is None else selection.tolist(), extra, notes)


@pytest.mark.parametrize("case", [c for c in cases() if c.ext == ".ply" and ply_read._streamable(c.data)],
                         ids=lambda c: c.name)
def test_the_file_reader_agrees_with_the_bytes_reader_on_every_binary_ply_of_the_corpus(case):
    from_bytes = _outcome(lambda notes: ply_read._read_ply(case.data, notes))
    from_file = _outcome(lambda notes: ply_read._read_ply_file(io.BytesIO(case.data), len(case.data), notes))
    assert repr(from_file) == repr(from_bytes)  # repr: NaN coordinates compare equal


@pytest.mark.parametrize("endian", ["<", ">"])
@pytest.mark.parametrize("layout", ["plain", "colours", "quads", "mixed polygons", "face property", "trailing", "truncated"])
def test_large_binary_files_read_from_the_file_as_from_their_bytes(tmp_path, monkeypatch, endian, layout):
    monkeypatch.setattr(ply_read, "_CHUNK_RECORDS", 100)  # many pieces, the last one short
    V, F = icosphere(3)  # 642 vertices, 1280 faces
    colors = np.random.default_rng(0).integers(0, 256, (len(V), 3)) if layout == "colours" else None
    faces = [list(f) for f in F]
    if layout == "quads":
        faces = [list(F[i]) + [F[i + 1][2]] for i in range(0, len(F) - 1, 2)]
    elif layout == "mixed polygons":
        faces = faces[:-2] + [list(F[-2]) + [F[-1][2]]]
    data = ply_bytes(V, faces, binary=True, endian=endian, colors=colors, extra_face_prop=layout == "face property")
    if layout == "trailing":
        data += b"\x00" * 7
    elif layout == "truncated":
        data = data[:-5]
    from_bytes = _outcome(lambda notes: ply_read._read_ply(data, notes))
    from_file = _outcome(lambda notes: ply_read._read_ply_file(io.BytesIO(data), len(data), notes))
    assert repr(from_file) == repr(from_bytes)  # repr: NaN coordinates compare equal
    p = tmp_path / "m.ply"
    p.write_bytes(data)
    if layout != "truncated":
        np.testing.assert_array_equal(load_mesh(p).V, V)


def test_a_large_binary_ply_is_read_into_its_arrays_without_a_copy_of_the_file(tmp_path):
    V, F = icosphere(6)  # 40,962 vertices, 81,920 faces: a 2 MB file
    p = save_mesh(tmp_path / "big.ply", V, F)
    size = p.stat().st_size
    tracemalloc.start()
    try:
        m = load_mesh(p)
        arrays = m.V.nbytes + m.F.nbytes
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    np.testing.assert_array_equal(m.V, V)
    np.testing.assert_array_equal(m.F, F)
    assert size > 1 << 20
    # the arrays, the topology notes' sort keys (3 int64 per face, twice) and small buffers; the bytes path held the file too
    assert peak < arrays + 2 * 24 * len(F) + (1 << 20), (peak, arrays, size)


@pytest.mark.parametrize("binary", [True, False])
@pytest.mark.parametrize("what", ["plain", "float32", "colours", "normals", "extras"])
def test_tables_written_in_pieces_are_the_bytes_of_one_table(tmp_path, monkeypatch, binary, what):
    V, F = icosphere(2)
    kw = {}
    if what == "float32":
        kw["precision"] = "float32"
    elif what == "colours":
        kw["vertex_colors"] = np.random.default_rng(1).random((len(V), 4))
    elif what == "normals":
        kw["vertex_normals"] = V / np.linalg.norm(V, axis=1, keepdims=True)
    elif what == "extras":
        src = tmp_path / "src.ply"
        quality = np.arange(len(V), dtype=np.float32)
        data = ply_bytes(V, F, binary=True, extra_face_prop=True)
        src.write_bytes(data)
        kw["extras"] = load_mesh(src).extras.with_quality(quality, None)
    whole = save_mesh(tmp_path / "whole.ply", V, F, binary=binary, **kw).read_bytes()
    monkeypatch.setattr(ply_write, "_CHUNK_RECORDS", 7)
    pieces = save_mesh(tmp_path / "pieces.ply", V, F, binary=binary, **kw).read_bytes()
    assert pieces == whole
    back = load_mesh(tmp_path / "pieces.ply")
    np.testing.assert_array_equal(back.F, F)
    if what != "float32":
        np.testing.assert_array_equal(back.V, V)


def test_writing_holds_no_second_copy_of_the_arrays(tmp_path):
    V, F = icosphere(6)
    tracemalloc.start()
    try:
        base = tracemalloc.get_traced_memory()[0]
        save_mesh(tmp_path / "big.ply", V, F)
        peak = tracemalloc.get_traced_memory()[1] - base
    finally:
        tracemalloc.stop()
    # the faces checked as int64 arrays (check_mesh_arrays returns the caller's array) and one buffer of records
    assert peak < (2 << 20), peak


def test_a_truncated_large_binary_ply_names_the_file(tmp_path):
    V, F = icosphere(6)
    p = save_mesh(tmp_path / "cut.ply", V, F)
    p.write_bytes(p.read_bytes()[:-100])
    with pytest.raises(MeshFileError, match=r"cut\.ply: truncated"):
        load_mesh(p)

"""meshdenoise.io against other implementations: pymeshlab and Open3D read what we write,
we read what they read, round trips are exact, writes are atomic and errors name the file."""

from __future__ import annotations

import glob
from pathlib import Path

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
    path = sorted(glob.glob(str(Path(sample_mesh("bunny.obj")).parent / "rangemaps" / "*.ply")))[0]
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

    def denied(*args, **kwargs):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr("meshdenoise.io.load.open", denied, raising=False)  # chmod 0 does not stop root
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


_SLOW_WRITER = r"""
import signal, sys, time
import numpy as np
import meshdenoise.io as mio
from meshdenoise.shapes import icosphere

def slow(fh, V, F, C, binary, extras=None):
    fh.write(b"# half of an OBJ\n" * 1000)
    fh.flush()
    print("writing", flush=True)
    for _ in range(600):
        time.sleep(0.05)   # the signal arrives here, mid-write

mio._WRITERS[".obj"] = slow
if sys.argv[2] == "chained":
    def previous(signum, frame):
        print("previous handler ran", flush=True)
        sys.exit(7)
    signal.signal(signal.SIGTERM, previous)
mio.save_mesh(sys.argv[1], *icosphere(1))
"""


@pytest.mark.parametrize("mode", ["default", "chained"])
def test_sigterm_mid_write_removes_the_temporary_file(tmp_path, mode):
    """SIGTERM while a mesh is being written: no hidden temporary file is left, no destination is
    created, and the signal then has its previous effect (default: the process ends by SIGTERM)."""
    import os
    import signal
    import subprocess
    import sys

    out = tmp_path / "out" / "big.obj"
    proc = subprocess.Popen([sys.executable, "-c", _SLOW_WRITER, str(out), mode], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env={**os.environ})
    try:
        assert proc.stdout.readline().strip() == "writing", proc.stderr.read()
        hidden = [p.name for p in out.parent.iterdir()]
        assert len(hidden) == 1 and hidden[0].startswith(".big.") and hidden[0].endswith(".obj"), hidden
        proc.send_signal(signal.SIGTERM)
        rest, err = proc.communicate(timeout=30)
    finally:
        proc.kill()
    if mode == "default":
        assert proc.returncode == -signal.SIGTERM, (proc.returncode, err)
    else:
        assert proc.returncode == 7 and "previous handler ran" in rest, (proc.returncode, rest, err)
    assert list(out.parent.iterdir()) == [], "the temporary file was left behind"


# ------------------------------------------------------------------ classes of malformed and unusual files
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from .brokenmeshes import OCTA_F, OCTA_V, cases, ply_bytes, stl_binary  # noqa: E402

PROPS = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


@PROPS
@given(seps=st.lists(st.sampled_from([" ", "  ", "\t", "\n", "\r\n", " \n ", "\n\n"]), min_size=1, max_size=200),
       binary_tail=st.booleans())
def test_ascii_ply_is_a_stream_of_numbers_any_whitespace_reads_the_same(tmp_path, seps, binary_tail):
    """PLY ASCII records are whitespace-separated numbers: any layout (one line, one number per line,
    CRLF, blank lines) gives the same arrays (the arrays are the generator's, not the reader's)."""
    good = ply_bytes(OCTA_V, OCTA_F, binary=False)
    cut = good.index(b"end_header\n") + 11
    tokens = good[cut:].split()
    body = b"".join(t + seps[i % len(seps)].encode() for i, t in enumerate(tokens))
    p = tmp_path / "layout.ply"
    p.write_bytes(good[:cut] + (body if not binary_tail else body.rstrip()))
    m = load_mesh(p)
    np.testing.assert_array_equal(m.V, OCTA_V)
    np.testing.assert_array_equal(m.F, OCTA_F)


TEXT_READS = [c for c in cases() if c.expect == "read" and not c.data.startswith(b"\xef\xbb\xbf")
              and (c.ext in (".obj", ".off") or (c.ext == ".ply" and b"format ascii" in c.data[:80])
                   or (c.ext == ".stl" and c.data.lstrip()[:5] == b"solid" and b"\x00" not in c.data))]


@pytest.mark.parametrize("case", TEXT_READS, ids=lambda c: c.name)
def test_a_utf8_byte_order_mark_changes_nothing_on_any_text_file(tmp_path, case):
    p = tmp_path / case.name
    p.write_bytes(case.data)
    plain = load_mesh(p)
    p.write_bytes(b"\xef\xbb\xbf" + case.data)
    m = load_mesh(p)
    np.testing.assert_array_equal(m.V, plain.V)
    np.testing.assert_array_equal(m.F, plain.F)
    assert any("byte-order mark" in n for n in m.notes), m.notes


@PROPS
@given(value=st.one_of(st.integers(-1000, -1), st.integers(256, 100000)), column=st.integers(0, 2),
       row=st.integers(0, 5))
def test_integer_colours_out_of_0_255_are_refused_never_wrapped(tmp_path, value, column, row):
    cols = np.full((6, 3), 100)
    good = ply_bytes(OCTA_V, OCTA_F, binary=False, colors=cols)
    lines = good.split(b"\n")
    at = lines.index(b"end_header") + 1 + row
    toks = lines[at].split()
    toks[3 + column] = str(value).encode()
    lines[at] = b" ".join(toks)
    p = tmp_path / "c.ply"
    p.write_bytes(b"\n".join(lines))
    name = ("red", "green", "blue")[column]
    with pytest.raises(MeshFileError, match=rf"vertex {row}: {name} = {value} is outside"):
        load_mesh(p)
    # the same in a COFF file
    off = ["COFF", "6 8 0"] + [" ".join(repr(float(c)) for c in v) + " 100 100 100 255" for v in OCTA_V]
    off += ["3 " + " ".join(str(i) for i in f) for f in OCTA_F]
    toks = off[2 + row].split()
    toks[3 + column] = str(value)
    off[2 + row] = " ".join(toks)
    q = tmp_path / "c.off"
    q.write_text("\n".join(off) + "\n")
    with pytest.raises(MeshFileError, match=rf"vertex {row} has colour .*outside 0..255"):
        load_mesh(q)


@PROPS
@given(value=st.one_of(st.floats(-1e6, -1e-6), st.floats(1.000001, 1e6), st.just(float("nan"))),
       inside=st.floats(0, 1))
def test_float_colours_outside_0_1_are_refused_and_inside_kept_exactly(tmp_path, value, inside):
    head = ("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
            "property float red\nproperty float green\nproperty float blue\nelement face 1\n"
            "property list uchar int vertex_indices\nend_header\n")
    rows = f"0 0 0 {inside!r} 0 0\n1 0 0 0 0 0\n0 1 0 0 0 {{}}\n3 0 1 2\n"
    p = tmp_path / "f.ply"
    p.write_text(head + rows.format(repr(1.0 - inside)))
    np.testing.assert_array_equal(load_mesh(p).vertex_colors[[0, 2], [0, 2]], [inside, 1.0 - inside])
    p.write_text(head + rows.format(repr(value)))
    with pytest.raises(MeshFileError, match=r"vertex 2: blue = .* is outside the range of a float colour"):
        load_mesh(p)


@PROPS
@given(extra=st.binary(min_size=1, max_size=300))
def test_binary_stl_longer_than_declared_is_read_with_a_note_naming_the_extra_bytes(tmp_path, extra):
    p = tmp_path / "x.stl"
    p.write_bytes(stl_binary(OCTA_V, OCTA_F) + extra)
    m = load_mesh(p)
    np.testing.assert_array_equal(m.V[m.F], OCTA_V[OCTA_F])
    assert any(f"{len(extra)} extra bytes after the 8 triangles" in n for n in m.notes), m.notes


@pytest.mark.parametrize("ext,start", [(".ply", b"\x93NUMPY"), (".obj", b"v 0 0 0\n\x00"), (".off", b"OFF\n\x00"),
                                       (".obj", b"printable"),
                                       (".stl", b"\x01" * 84), (".ply", b"ply\nformat binary_little_endian 1.0\n")])
def test_garbage_is_refused_from_its_first_bytes_without_reading_the_file(tmp_path, ext, start):
    """A 24 MB file of random bytes is refused with a peak of well under its size (it used to be read,
    copied and decoded whole: 0.5-1.7 GB for 200 MB)."""
    import tracemalloc

    p = tmp_path / f"garbage{ext}"
    rng = np.random.default_rng(0)
    if start == b"printable":  # text with line ends and no NUL byte: no OBJ statement in its first 64 KiB
        p.write_bytes(rng.integers(32, 127, 24 << 20, dtype=np.uint8).tobytes().replace(b"~", b"\n"))
    else:
        p.write_bytes(start + rng.integers(0, 256, 24 << 20, dtype=np.uint8).tobytes())
    tracemalloc.start()
    try:
        with pytest.raises(MeshFileError, match=r"(?i)not|truncated|header") as info:
            load_mesh(p)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert str(info.value).startswith(str(p))
    limit = 3 << 20 if start.startswith(b"ply") else 1 << 20  # a PLY header may be up to 1 MiB long
    assert peak < limit, (peak, str(info.value))


@pytest.mark.parametrize("ext,binary", FORMATS)
def test_no_colours_in_no_colours_out(tmp_path, ext, binary):
    V, F = icosphere(1)
    p = save_arrays(tmp_path / f"a{ext}", V, F, binary=binary)
    assert load_mesh(p).vertex_colors is None
    text = p.read_bytes()[:300]
    assert b"red" not in text and not text.startswith(b"COFF")


@pytest.mark.parametrize("case", [c for c in cases() if c.ext in (".obj", ".off")], ids=lambda c: c.name)
def test_fast_number_stream_readers_agree_with_the_line_readers_on_the_corpus(tmp_path, case, monkeypatch):
    """OBJ and OFF files of the plain layout are parsed as one number stream; every file of the corpus
    gives the same arrays, notes and errors with that path switched off."""
    from meshdenoise.io import obj, off

    p = tmp_path / case.name
    p.write_bytes(case.data)

    def outcome():
        try:
            m = load_mesh(p)
            return m.V.tolist(), m.F.tolist(), m.notes, None if m.vertex_colors is None else m.vertex_colors.tolist()
        except MeshFileError as exc:
            return str(exc)

    fast = outcome()
    monkeypatch.setattr(obj, "_read_obj_fast", lambda data, notes: None)
    monkeypatch.setattr(off, "_read_off_fast", lambda data, notes: None)
    assert outcome() == fast


@PROPS
@given(level=st.integers(0, 2), quads=st.booleans(), ragged=st.integers(-1, 30), ext=st.sampled_from([".obj", ".off"]),
       scale=st.sampled_from([1e-300, 1e-3, 1.0, 1e5, 1e300]))
def test_fast_readers_take_plain_files_and_give_up_on_anything_ragged(tmp_path, level, quads, ragged, ext, scale):
    import meshdenoise.io as mio
    from meshdenoise.io import obj, off

    V, F = icosphere(level)
    V = V * scale
    faces = F if not quads else np.hstack([F[: len(F) // 2 * 2: 2], F[1: len(F) // 2 * 2: 2, :1]])
    p = tmp_path / f"m{ext}"
    if ext == ".obj":
        lines = [f"v {x!r} {y!r} {z!r}" for x, y, z in V.tolist()] + ["f " + " ".join(str(i + 1) for i in f) for f in faces]
    else:
        lines = ["OFF", f"{len(V)} {len(faces)} 0"] + [f"{x!r} {y!r} {z!r}" for x, y, z in V.tolist()]
        lines += [f"{len(f)} " + " ".join(str(i) for i in f) for f in faces]
    if 0 <= ragged < len(lines) - 2:  # one number more on one line (a legal OFF face colour, or an error)
        lines[ragged + 2] += " 0"
    p.write_text("\n".join(lines) + "\n")
    reader = obj._read_obj_fast if ext == ".obj" else off._read_off_fast
    fast = reader(p.read_bytes(), [])
    assert (fast is None) == (ragged >= 0 and ragged < len(lines) - 2)
    slow_reader = obj._read_obj if ext == ".obj" else off._read_off
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(obj, "_read_obj_fast", lambda data, notes: None)
        mp.setattr(off, "_read_off_fast", lambda data, notes: None)
        try:
            slow = slow_reader(p.read_bytes(), [])
        except mio._Malformed:
            slow = None
    if fast is not None:
        np.testing.assert_array_equal(fast[0], slow[0])
        np.testing.assert_array_equal(fast[1], slow[1])
        np.testing.assert_array_equal(fast[0], V)  # exact: 17 digits parse back to the same doubles

"""Every file of the generated corpus (tests/brokenmeshes.py) is read right or refused clearly.

Reading happens in this process: the readers are numpy only, so a broken file cannot crash
it. A second test reads every case in a child process with a time limit, to prove that
no case hangs or kills the interpreter.
"""

from __future__ import annotations

import hashlib
import re
import subprocess
import sys

import numpy as np
import pytest

from meshdenoise.io import MeshFileError, load_mesh

from .brokenmeshes import cases, write_corpus

CASES = cases()


def test_corpus_covers_the_issue():
    names = {c.name for c in CASES}
    required = [
        "truncated_ascii.ply", "truncated_binary.ply", "truncated_binary.stl", "truncated_ascii.stl",
        "cr_only.off", "crlf.off", "quads.obj", "ngons.obj", "negative_indices.obj", "tex_normal_indices.obj",
        "comments_blank_lines.obj", "missing_vertex.off", "nan.off", "inf.obj", "zero_area_duplicate_faces.off",
        "unreferenced_vertices.off", "nonmanifold_edge.off", "nonmanifold_vertex.obj", "three_components.ply",
        "empty.ply", "random_bytes.stl", "point_cloud.ply",
    ]
    assert not [n for n in required if n not in names]
    assert len(names) == len(CASES)


@pytest.mark.parametrize("case", [c for c in CASES if c.expect == "read"], ids=lambda c: c.name)
def test_unusual_but_legal_files_are_read_right(tmp_path, case):
    path = tmp_path / case.name
    path.write_bytes(case.data)
    m = load_mesh(path)
    assert m.V.dtype == np.float64 and m.F.dtype == np.int64
    if case.same_faces_geometry:  # STL: vertex numbering is the reader's; geometry per face is not
        assert m.V.shape == case.V.shape
        np.testing.assert_array_equal(m.V[m.F], case.V[case.F])
    else:
        np.testing.assert_array_equal(m.V, case.V)
        np.testing.assert_array_equal(m.F, case.F)
    if case.match:
        assert any(re.search(case.match, n) for n in m.notes), m.notes
    if case.colors is not None:
        np.testing.assert_allclose(m.vertex_colors[:, :3], case.colors)
    else:
        assert m.vertex_colors is None
    if case.selection is not None:
        np.testing.assert_array_equal(m.selection, case.selection)
    else:
        assert m.selection is None
    assert path.read_bytes() == case.data  # never changed by reading


@pytest.mark.parametrize("case", [c for c in CASES if c.expect == "refuse"], ids=lambda c: c.name)
def test_broken_files_are_refused_naming_file_and_problem(tmp_path, case):
    path = tmp_path / case.name
    path.write_bytes(case.data)
    with pytest.raises(MeshFileError, match=case.match) as info:
        load_mesh(path)
    message = str(info.value)
    assert message.startswith(f"{path}: "), message
    assert "\n" not in message and len(message) < 400, message
    assert path.read_bytes() == case.data


def test_no_case_hangs_or_crashes_the_interpreter(tmp_path):
    written = write_corpus(tmp_path)
    digests = {p: hashlib.sha256(p.read_bytes()).hexdigest() for _, p in written}
    script = (
        "import sys\nfrom meshdenoise.io import load_mesh, MeshFileError\n"
        "for p in sys.argv[1:]:\n"
        "    try:\n        load_mesh(p); print('read', p)\n"
        "    except MeshFileError:\n        print('refused', p)\n"
    )
    proc = subprocess.run([sys.executable, "-c", script, *[str(p) for _, p in written]],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr[-2000:]
    outcome = dict(line.split(" ", 1)[::-1] for line in proc.stdout.splitlines())
    for case, p in written:
        assert outcome[str(p)] == ("read" if case.expect == "read" else "refused"), case.name
        assert hashlib.sha256(p.read_bytes()).hexdigest() == digests[p]


@pytest.mark.parametrize("cut", [0.05, 0.1, 0.3, 0.5, 0.9, 0.999])
@pytest.mark.parametrize("ext,binary", [(".ply", True), (".ply", False), (".stl", True), (".stl", False),
                                        (".off", False), (".obj", False)])
def test_any_truncation_is_refused_or_reads_a_prefix_that_is_a_valid_mesh(tmp_path, ext, binary, cut):
    """Cutting a file anywhere must never give garbage: either an error, or (OBJ only, which
    has no counts) the mesh of the complete lines before the cut."""
    from meshdenoise.io import save_arrays
    from meshdenoise.shapes import icosphere

    V, F = icosphere(2)
    full = save_arrays(tmp_path / f"full{ext}", V, F, binary=binary).read_bytes()
    path = tmp_path / f"cut{ext}"
    path.write_bytes(full[: int(len(full) * cut)])
    try:
        m = load_mesh(path)
    except MeshFileError as exc:
        assert str(exc).startswith(str(path))
        return
    assert ext == ".obj", f"a truncated {ext} file was accepted"
    k, j = m.V.shape[0], m.F.shape[0]
    if path.read_bytes().endswith(b"\n"):  # cut at the end of a line: exactly the complete lines
        np.testing.assert_array_equal(m.V, V[:k])
        np.testing.assert_array_equal(m.F, F[:j])
        return
    assert any("may be truncated" in n for n in m.notes), m.notes
    if j == 0:  # cut among the vertices: the last one may be cut inside a number (the note says so)
        np.testing.assert_array_equal(m.V[: k - 1], V[: k - 1])
    else:  # cut among the faces: every vertex complete, the last face may lack digits (checked range)
        np.testing.assert_array_equal(m.V, V)
        np.testing.assert_array_equal(m.F[: j - 1], F[: j - 1])


def test_random_garbage_never_escapes_as_another_exception(tmp_path):
    """Random mutations of valid files: load_mesh either reads or raises MeshFileError."""
    from meshdenoise.io import save_arrays
    from meshdenoise.shapes import icosphere

    rng = np.random.default_rng(7)
    V, F = icosphere(1)
    for ext, binary in [(".ply", True), (".ply", False), (".off", True), (".obj", True), (".stl", True), (".stl", False)]:
        full = bytearray(save_arrays(tmp_path / f"full{ext}", V, F, binary=binary).read_bytes())
        for trial in range(40):
            data = bytearray(full)
            for pos in rng.integers(0, len(data), size=rng.integers(1, 6)):
                data[pos] = int(rng.integers(0, 256))
            p = tmp_path / f"m{trial}{ext}"
            p.write_bytes(bytes(data))
            try:
                m = load_mesh(p)
            except MeshFileError:
                continue
            assert np.isfinite(m.V).all() and ((m.F >= 0) & (m.F < len(m.V))).all()

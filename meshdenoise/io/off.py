"""OFF (and COFF): reading, fast for plain files, line by line with named errors for the rest; writing."""

from __future__ import annotations

import re

import numpy as np

from .errors import _Malformed
from .tables import _check_indices, _colour_bytes, _decode_text, _fast_table, _float_table, _int_table, _line_table, _lines, _rows_text, _triangulate, _vertex_and_face_rows


_OFF_HEADER = re.compile(r"^(ST)?(C)?(N)?(4)?(n)?OFF$")


def _read_off_fast(data: bytes, notes: list[str]):
    """Plain ``OFF`` files of triangles or equal polygons, with no comment, colour or blank line
    (what most tools write): parsed as one number stream. None for anything else."""
    if b"#" in data or b"\n" not in data or not data.startswith(b"OFF"):
        return None
    first, rest = data.split(b"\n", 1)
    head = first.split()
    if head[0] != b"OFF":
        return None
    if len(head) == 1:
        if b"\n" not in rest:
            return None
        second, rest = rest.split(b"\n", 1)
        head = head + second.split()
    if len(head) != 4 or not all(t.isdigit() for t in head[1:]):
        return None
    nv, nf = int(head[1]), int(head[2])
    table = _line_table(rest)
    if table is None or table[1].size != nv + nf or nv == 0:
        return None
    rows = _vertex_and_face_rows(table, nv, nf, 4)  # OFF faces start with their vertex count
    if rows is None:
        return None
    V, Fr = rows
    if nf == 0:
        return V, np.zeros((0, 3), np.int64), None
    k = Fr.shape[1] - 1
    if not (Fr[:, 0] == k).all() or not np.all(np.mod(Fr[:, 1:], 1) == 0):
        return None
    P = Fr[:, 1:].astype(np.int64)
    del table, Fr  # the number table: free it before the faces are split
    ids = np.arange(nf)
    _check_indices(P, ids, nv)
    return V, _triangulate([(ids, P)], notes), None


def _read_off(data: bytes, notes: list[str]):
    fast = _read_off_fast(data, notes)
    if fast is not None:
        return fast
    text = _decode_text(data, "an OFF")
    raw = _lines(text, notes)
    if "#" in text:
        raw = [ln.split("#", 1)[0] for ln in raw]
    lines = [(i, ln) for i, ln in enumerate(raw, 1) if ln and not ln.isspace()]
    if not lines:
        raise _Malformed("the file has only comments")
    head = lines[0][1].split()
    m = _OFF_HEADER.match(head[0])
    if not m:
        raise _Malformed(f"not an OFF file: the first word is {head[0][:40]!r}, expected OFF, COFF, NOFF or STOFF")
    if m.group(4) or m.group(5):
        raise _Malformed(f"{head[0]} (4D or n-dimensional OFF) is not supported: only 3D meshes")
    if len(head) > 1 and head[1].upper() == "BINARY":
        raise _Malformed("binary OFF is not supported: convert it to PLY")
    rest = lines[1:]
    counts = head[1:]
    if not counts:
        if not rest:
            raise _Malformed("truncated: the file ends after the OFF header, before the vertex and face counts")
        counts = rest[0][1].split()
        rest = rest[1:]
    try:
        nv, nf = int(counts[0]), int(counts[1])
    except (ValueError, IndexError):
        raise _Malformed(f"the counts line must be 'vertices faces edges', got {' '.join(counts)!r}") from None
    if nv < 0 or nf < 0:
        raise _Malformed(f"negative counts: {nv} vertices, {nf} faces")
    if nv + nf > len(rest):
        raise _Malformed(
            f"truncated: the header declares {nv} vertices and {nf} faces, but the file ends after "
            f"{len(rest)} data lines"
        )
    if len(rest) > nv + nf:
        notes.append(f"{len(rest) - nv - nf} lines after the declared faces ignored")
    ncoord = 3 + (3 if m.group(3) else 0) + (2 if m.group(1) else 0)
    vlines, flines = rest[:nv], rest[nv:nv + nf]
    V, colors = _off_vertices(vlines, ncoord, head[0], bool(m.group(2)))
    T = _fast_table([ln for _, ln in flines])
    if T is not None and T.shape[1] >= 4 and (T[:, 0] == T[0, 0]).all() and 3 <= T[0, 0] <= T.shape[1] - 1:
        P = T[:, 1:1 + int(T[0, 0])]
        if np.all(np.mod(P, 1) == 0):
            P = P.astype(np.int64)
            ids = np.arange(nf)
            _check_indices(P, ids, nv)
            return V, _triangulate([(ids, P)], notes), colors
    F = _polygon_rows([ln.split() for _, ln in flines], [i for i, _ in flines], nv, notes)
    return V, F, colors


def _off_vertices(vlines, ncoord: int, keyword: str, has_colours: bool):
    nv = len(vlines)
    if nv == 0:
        return np.zeros((0, 3)), None
    T = _fast_table([ln for _, ln in vlines])
    if T is None:  # rows of different lengths, or a bad number: find which
        rows = [ln.split() for _, ln in vlines]
        lengths = np.fromiter(map(len, rows), dtype=np.int64, count=nv)
        if lengths.min() < ncoord:
            k = int(np.argmin(lengths))
            raise _Malformed(f"line {vlines[k][0]}: a {keyword} vertex needs {ncoord} numbers, got {lengths[k]}")
        V = _float_table([t[:3] for t in rows], "vertex", [i for i, _ in vlines])
        return V, None
    if T.shape[1] < ncoord:
        raise _Malformed(f"line {vlines[0][0]}: a {keyword} vertex needs {ncoord} numbers, got {T.shape[1]}")
    colors = None
    if has_colours and T.shape[1] in (ncoord + 3, ncoord + 4):
        C = T[:, ncoord:]
        integers = not any(c in tok for tok in vlines[0][1].split()[ncoord:] for c in ".eE")  # 0..255, else 0..1
        hi = 255.0 if integers else 1.0
        bad = ~((C >= 0) & (C <= hi)).all(axis=1)
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            raise _Malformed(
                f"line {vlines[k][0]}: vertex {k} has colour {C[k].tolist()} outside "
                f"{'0..255 (integer colours)' if integers else '[0, 1] (float colours)'}; {int(bad.sum())} "
                "vertices out of range in all (refused rather than wrapped or clipped)"
            )
        if integers:
            C = C / 255.0
        colors = np.hstack([C, np.ones((nv, 1))]) if C.shape[1] == 3 else C
    return np.ascontiguousarray(T[:, :3]), colors


def _polygon_rows(rows: list[list[str]], linenos: list[int], nv: int, notes: list[str]) -> np.ndarray:
    """OFF face lines ``k i_1 ... i_k [colour]``, grouped by length so that each group is one array."""
    if not rows:
        return np.zeros((0, 3), np.int64)
    lengths = np.fromiter((len(r) for r in rows), dtype=np.int64, count=len(rows))
    groups = []
    for L in np.unique(lengths):
        ids = np.flatnonzero(lengths == L)
        sub = [rows[i] for i in ids]
        ks = _int_table([r[:1] for r in sub], "face", [linenos[i] for i in ids])[:, 0]
        for k in np.unique(ks):
            sel = ids[ks == k]
            if k < 0 or 1 + k > L:
                i = int(sel[0])
                raise _Malformed(f"line {linenos[i]}: a face of {k} vertices needs {1 + k} numbers, got {L}")
            P = _int_table([rows[i][1:1 + k] for i in sel], "face", [linenos[i] for i in sel])
            _check_indices(P, sel, nv)
            groups.append((sel, P))
    return _triangulate(groups, notes)


def _write_off(fh, V, F, C, binary, extras=None, normals=None, coordinate="f8"):  # extras: PLY only; no normals
    fh.write(f"{'COFF' if C is not None else 'OFF'}\n{len(V)} {len(F)} 0\n".encode())
    if C is None:
        fh.write(_rows_text(V, "%.17g"))
    else:
        vals = np.empty((len(V), 7), dtype=object)
        vals[:, :3], vals[:, 3:] = V, _colour_bytes(C)
        fh.write((("%.17g %.17g %.17g %d %d %d %d\n" * len(V)) % tuple(vals.ravel().tolist())).encode())
    fh.write(_rows_text(np.hstack([np.full((len(F), 1), 3), F]), "%d"))

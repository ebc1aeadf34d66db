"""OBJ: reading (``v`` and ``f`` statements; the rest noted and ignored), fast for bare meshes; writing."""

from __future__ import annotations

import re
from collections import Counter

import numpy as np

from .errors import _Malformed
from .tables import _decode_text, _fast_table, _float_table, _line_table, _rows_text, _triangulate, _vertex_and_face_rows


_OBJ_IGNORED = {"vt", "vn", "vp", "g", "o", "s", "mtllib", "usemtl", "cstype", "deg", "bmat", "step", "curv",
                "curv2", "surf", "parm", "trim", "hole", "scrv", "sp", "end", "con", "mg", "bevel", "c_interp",
                "d_interp", "lod", "shadow_obj", "trace_obj", "ctech", "stech", "maplib", "usemap", "call", "csh"}


_OBJ_KEYWORD = re.compile(r"^[ \t]*([^\s#]+)", re.M)
_OBJ_V = re.compile(r"^[ \t]*v[ \t]+([^\n]*)", re.M)
_OBJ_F = re.compile(r"^[ \t]*f[ \t]+([^\n]*)", re.M)


_V_F_TO_SPACE = bytes.maketrans(b"vf", b"  ")


def _read_obj_fast(data: bytes, notes: list[str]):
    """OBJ files made only of ``v x y z`` lines then ``f i j k ...`` lines with positive indices (after
    optional leading comments; what most tools write for a bare mesh): parsed as one number stream.
    None for anything else (the line-by-line reader handles every other form)."""
    pos = 0
    while data.startswith(b"#", pos):
        pos = data.find(b"\n", pos) + 1
        if pos == 0:
            return None
    body = data[pos:]
    if not body.endswith(b"\n") or not body.startswith(b"v ") or any(c in body for c in (b"#", b"/", b"\\", b"\r")):
        return None
    nv = body.count(b"\nv ") + 1
    nf = body.count(b"\nf ")
    if nv + nf != body.count(b"\n") or (nf and body.rfind(b"\nv ") > body.find(b"\nf ")):
        return None
    table = _line_table(body.translate(_V_F_TO_SPACE))
    del body
    if table is None or table[1].size != nv + nf:
        return None
    rows = _vertex_and_face_rows(table, nv, nf, 3)
    if rows is None:
        return None
    V, Fr = rows
    if nf == 0:
        return V, np.zeros((0, 3), np.int64), None
    if not (np.all(np.mod(Fr, 1) == 0) and Fr.min() >= 1 and Fr.max() <= nv):
        return None  # relative or out-of-range indices: the line reader says which line
    P = Fr.astype(np.int64)
    del table, Fr  # the number table: free it before the faces are split
    P -= 1
    return V, _triangulate([(np.arange(nf), P)], notes), None


def _read_obj(data: bytes, notes: list[str]):
    fast = _read_obj_fast(data, notes)
    if fast is not None:
        return fast
    # Whole-text regular expressions and numpy's parser instead of a Python loop over lines.
    text = _decode_text(data, "an OBJ")
    if "\r" in text:
        if "\n" not in text:
            notes.append("CR-only (classic Mac) line endings")
        text = text.replace("\r\n", "\n").replace("\r", "\n")
    tail = text.rstrip(" \t")
    if tail and not tail.endswith("\n") and re.search(r"^[ \t]*[vf][ \t][^\n]*\Z", tail, re.M):
        notes.append("the last line has no end of line: the file may be truncated (OBJ has no counts to check)")
    if "#" in text:
        text = re.sub(r"#[^\n]*", "", text)
    if "\\\n" in text:  # line continuation: keep the line count so that messages stay right
        text = re.sub(r"\\\n([^\n]*)", lambda mo: " " + mo.group(1) + "\n", text)
    keywords = Counter(_OBJ_KEYWORD.findall(text))
    unknown = {k: c for k, c in keywords.items() if k not in _OBJ_IGNORED and k not in ("v", "f", "l", "p")}
    v_bodies = _OBJ_V.findall(text)
    if not v_bodies:
        what = f" (unknown statements: {', '.join(repr(k[:20]) for k in list(unknown)[:3])})" if unknown else ""
        raise _Malformed(f"no vertices: not an OBJ mesh{what}")
    if unknown:
        notes.append(f"{sum(unknown.values())} lines with unknown statements ignored ({', '.join(list(unknown)[:5])})")
    if keywords.get("l", 0) + keywords.get("p", 0):
        n_lp = keywords.get("l", 0) + keywords.get("p", 0)
        notes.append(f"{n_lp} line and point elements (l, p) ignored: only faces are read")

    def lineno(regex, k):
        pos = next(mo.start() for j, mo in enumerate(regex.finditer(text)) if j == k)
        return text.count("\n", 0, pos) + 1

    V, colors = _obj_vertices(v_bodies, lambda k: lineno(_OBJ_V, k), notes)
    n = V.shape[0]
    f_bodies = _OBJ_F.findall(text)
    if not f_bodies:
        return V, np.zeros((0, 3), np.int64), colors
    joined = "\n".join(f_bodies)
    if "/" in joined:
        joined = re.sub(r"/[^ \t\n]*", "", joined)  # keep the vertex index of v/vt/vn
    f_lines = joined.split("\n")
    T = _fast_table(f_lines)
    if T is not None:
        groups_raw = [(np.arange(len(f_lines)), T)]
    else:
        rows = [ln.split() for ln in f_lines]
        lengths = np.fromiter(map(len, rows), dtype=np.int64, count=len(rows))
        groups_raw = []
        for L in np.unique(lengths):
            ids = np.flatnonzero(lengths == L)
            where = lambda k, ids=ids: lineno(_OBJ_F, ids[k])  # noqa: E731
            groups_raw.append((ids, _float_table([rows[i] for i in ids], "face", None, where)))
    nv_at = None
    if any((R < 0).any() for _, R in groups_raw):  # relative indices: count the vertices before each face
        v_pos = np.fromiter((mo.start() for mo in _OBJ_V.finditer(text)), dtype=np.int64)
        f_pos = np.fromiter((mo.start() for mo in _OBJ_F.finditer(text)), dtype=np.int64)
        nv_at = np.searchsorted(v_pos, f_pos)
    groups = []
    for ids, R in groups_raw:
        if R.shape[1] < 3:
            raise _Malformed(f"line {lineno(_OBJ_F, ids[0])}: a face needs at least 3 vertices, got {R.shape[1]}")
        bad = (np.mod(R, 1) != 0).any(axis=1) | (R == 0).any(axis=1)
        if bad.any():
            r = int(ids[np.flatnonzero(bad)[0]])
            raise _Malformed(
                f"line {lineno(_OBJ_F, r)}: face {f_bodies[r].strip()!r}: vertex indices are integers "
                "from 1 (or negative, relative to the last vertex); 0 is not allowed"
            )
        R = R.astype(np.int64)
        before = nv_at[ids][:, None] if nv_at is not None else n
        P = np.where(R > 0, R - 1, before + R)
        bad = ((P < 0) | (P >= n) | ((R < 0) & (P >= before))).any(axis=1)
        if bad.any():
            r = int(ids[np.flatnonzero(bad)[0]])
            defined = f"; {int(nv_at[r])} defined before this line" if nv_at is not None else ""
            raise _Malformed(
                f"line {lineno(_OBJ_F, r)}: face {f_bodies[r].strip()!r} references a vertex that does not exist "
                f"(the file has {n} vertices{defined})"
            )
        groups.append((ids, P))
    return V, _triangulate(groups, notes), colors


def _obj_vertices(bodies, lineno, notes):
    T = _fast_table(bodies)
    if T is None:
        rows = [b.split() for b in bodies]
        lengths = np.fromiter(map(len, rows), dtype=np.int64, count=len(rows))
        if lengths.min() < 3:
            k = int(np.argmin(lengths))
            raise _Malformed(f"line {lineno(k)}: a vertex needs 3 coordinates, got {lengths[k]}")
        notes.append("extra numbers on some vertex lines ignored (colours only kept when every vertex has them)")
        return _float_table([r[:3] for r in rows], "vertex", None, lineno), None
    if T.shape[1] < 3:
        raise _Malformed(f"line {lineno(0)}: a vertex needs 3 coordinates, got {T.shape[1]}")
    colors = None
    if T.shape[1] in (6, 7):
        C = T[:, 3:]
        colors = np.hstack([C, np.ones((len(T), 1))]) if C.shape[1] == 3 else C
        if not (np.isfinite(colors).all() and colors.min() >= 0 and colors.max() <= 1):
            notes.append("vertex colours outside [0, 1] ignored")
            colors = None
    return np.ascontiguousarray(T[:, :3]), colors


def _write_obj(fh, V, F, C, binary, extras=None, normals=None, coordinate="f8"):  # extras: PLY only
    fh.write(b"# written by meshdenoise\n")
    fh.write(_rows_text(V if C is None else np.hstack([V, C[:, :3]]), "%.17g", "v "))
    if normals is None:
        fh.write(_rows_text(F + 1, "%d", "f "))
        return
    fh.write(_rows_text(normals, "%.17g", "vn "))  # normal i is vertex i's: faces 'f a//a b//b c//c'
    if len(F):
        fh.write((("f %d//%d %d//%d %d//%d\n" * len(F)) % tuple(np.repeat(F + 1, 2, axis=1).ravel().tolist())).encode())

"""PLY reading: the header, ASCII as one number stream, binary through structured dtypes; colours, selection and the other properties kept (:class:`~meshdenoise.io.meshfile.PlyExtras`)."""

from __future__ import annotations

import re

import numpy as np

from .errors import _Malformed
from .meshfile import _RECOMPUTED, PlyExtras
from .tables import _BLANK, _check_indices, _triangulate


_PLY_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
              "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
              "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}


def _ply_type(name: str, lineno: int) -> str:
    if name not in _PLY_TYPES:
        raise _Malformed(f"header line {lineno}: unknown property type {name!r}")
    return _PLY_TYPES[name]


def _ply_header(data: bytes):
    if not (data.startswith(b"ply\n") or data.startswith(b"ply\r\n")):
        raise _Malformed("not a PLY file: it does not start with the line 'ply'")
    m = re.search(rb"end_header[ \t]*\r?\n", data[:1 << 20])
    if not m:
        raise _Malformed(
            "the PLY header has no 'end_header' line (file truncated inside the header, or not a PLY file)"
        )
    try:
        head = data[:m.start()].decode("ascii").splitlines()
    except UnicodeDecodeError:
        raise _Malformed("the PLY header is not ASCII text") from None
    fmt, elements = None, []
    for lineno, line in enumerate(head[1:], 2):
        toks = line.split()
        if not toks or toks[0] in ("comment", "obj_info"):
            continue
        if toks[0] == "format":
            if len(toks) < 2 or toks[1] not in ("ascii", "binary_little_endian", "binary_big_endian"):
                raise _Malformed(f"header line {lineno}: unknown format {' '.join(toks[1:])!r}")
            fmt = toks[1]
        elif toks[0] == "element":
            try:
                count = int(toks[2])
            except (IndexError, ValueError):
                raise _Malformed(f"header line {lineno}: expected 'element <name> <count>', got {line!r}") from None
            if count < 0:
                raise _Malformed(f"header line {lineno}: negative element count {count}")
            elements.append((toks[1], count, []))
        elif toks[0] == "property":
            if not elements:
                raise _Malformed(f"header line {lineno}: property before any element")
            if len(toks) == 5 and toks[1] == "list":
                elements[-1][2].append((toks[4], (_ply_type(toks[2], lineno), _ply_type(toks[3], lineno))))
            elif len(toks) == 3:
                elements[-1][2].append((toks[2], _ply_type(toks[1], lineno)))
            else:
                raise _Malformed(f"header line {lineno}: malformed property line {line!r}")
        else:
            raise _Malformed(f"header line {lineno}: unknown keyword {toks[0][:30]!r}")
    if fmt is None:
        raise _Malformed("the PLY header has no 'format' line")
    return fmt, elements, m.end()


def _read_ply(data: bytes, notes: list[str]):
    fmt, elements, offset = _ply_header(data)
    if fmt == "ascii":
        values = _ply_ascii_values(data, offset, elements, notes)
    else:
        endian = "<" if fmt == "binary_little_endian" else ">"
        values = {}
        for name, count, props in elements:
            values[name], offset = _ply_binary_element(data, offset, count, props, name, endian)
        if len(data) > offset:
            notes.append(
                f"{len(data) - offset} bytes after the last declared element ('{elements[-1][0]}', "
                f"{elements[-1][1]} records) ignored: the header's count may be wrong"
            )
    return _ply_mesh(elements, values, notes)


# Records per piece when a binary PLY is read from its file: one reused buffer of a few MB between the file
# and the arrays, instead of the whole file as bytes (80 MB for the 1.6M-vertex scale mesh) beside them.
_CHUNK_RECORDS = 1 << 16
_BINARY_PLY = re.compile(rb"ply\r?\n(?:(?:comment|obj_info)[^\n]*\n)*format[ \t]+binary_")


def _streamable(head: bytes) -> bool:
    """Whether a file starting with ``head`` is a binary PLY (read from the file by :func:`_read_ply_file`)."""
    return _BINARY_PLY.match(head) is not None


def _read_ply_file(fh, size: int, notes: list[str]):
    """A binary PLY read from the open file ``fh`` (``size`` bytes) element by element into its arrays:
    the coordinates straight into ``V`` (n, 3) float64, the triangles into ``F`` (m, 3) int64, each
    other property into its own array, through a buffer of :data:`_CHUNK_RECORDS` records.

    What :func:`_read_ply` gives for the file's bytes: the same arrays, notes and errors. A file whose
    lists vary in length (polygons of several sizes) is read through that function.
    """
    fh.seek(0)
    fmt, elements, offset = _ply_header(fh.read(min(size, 1 << 20)))
    if fmt == "ascii":
        fh.seek(0)
        return _read_ply(fh.read(), notes)
    endian = "<" if fmt == "binary_little_endian" else ">"
    values = {}
    for name, count, props in elements:
        got = _ply_binary_element_file(fh, size, offset, count, props, name, endian)
        if got is None:  # lists of varying length: the bytes reader, record by record
            fh.seek(0)
            return _read_ply(fh.read(), notes)
        values[name], offset = got
    if size > offset:
        notes.append(
            f"{size - offset} bytes after the last declared element ('{elements[-1][0]}', "
            f"{elements[-1][1]} records) ignored: the header's count may be wrong"
        )
    return _ply_mesh(elements, values, notes)


def _ply_binary_element_file(fh, size, offset, count, props, name, endian):
    """:func:`_ply_binary_element` reading from the file: ``(values, next offset)``, or None when the
    records' lists vary in length. Vertex ``x y z`` come as columns of one (count, 3) float64 array,
    kept under ``"#xyz"``; a list of 3 integer indices as one (count, 3) int64 array."""
    empty = _sized_element(props, count, size - offset, name)
    if empty is not None:
        return empty, offset
    fields, pos = [], offset
    for pname, t in props:
        if isinstance(t, str):
            fields.append((pname, endian + t))
            pos += np.dtype(t).itemsize
        else:
            width = np.dtype(t[0]).itemsize
            if pos + width > size:
                raise _Malformed(f"truncated inside element '{name}'")
            fh.seek(pos)
            k = int(np.frombuffer(fh.read(width), endian + t[0], 1)[0])
            fields.append((pname + "#count", endian + t[0]))
            fields.append((pname, endian + t[1], (k,)))
            pos += width + k * np.dtype(t[1]).itemsize
    dt = np.dtype(fields)
    lists = [p for p, t in props if not isinstance(t, str)]
    if count * dt.itemsize > size - offset:
        if lists:
            return None
        raise _Malformed(f"truncated: element '{name}' needs {count * dt.itemsize} bytes, {size - offset} left")
    names = [p for p, _ in props]
    xyz = name == "vertex" and all(c in names for c in "xyz") and all(isinstance(dict(props)[c], str) for c in "xyz")
    out = {}
    if xyz:
        V = np.empty((count, 3))
        out.update({"#xyz": V, "x": V[:, 0], "y": V[:, 1], "z": V[:, 2]})
    for pname, t in props:
        if pname in out:
            continue
        if isinstance(t, str):
            out[pname] = np.empty(count, endian + t)
        else:
            k = dt[pname].shape[0]
            integer = np.dtype(t[1]).kind in "iu"
            out[pname] = np.empty((count, k), np.int64 if integer and k == 3 else endian + t[1])
    fh.seek(offset)
    if xyz and len(props) == 3 and dt == np.dtype([("x", "<f8"), ("y", "<f8"), ("z", "<f8")]) \
            and np.little_endian:  # the file's records are V's rows: read straight into it
        if fh.readinto(out["#xyz"].view(np.uint8).reshape(-1)) != count * 24:
            raise _Malformed(f"truncated: the file ends inside element '{name}'")
        return out, offset + count * dt.itemsize
    buf = np.empty(min(count, _CHUNK_RECORDS), dt)
    raw = buf.view(np.uint8)
    for a in range(0, count, _CHUNK_RECORDS):
        k = min(_CHUNK_RECORDS, count - a)
        if fh.readinto(raw[:k * dt.itemsize]) != k * dt.itemsize:
            raise _Malformed(f"truncated: the file ends inside element '{name}'")
        rec = buf[:k]
        if not all((rec[p + "#count"] == dt[p].shape[0]).all() for p in lists):
            return None
        for pname in names:
            out[pname][a:a + k] = rec[pname]
    return {p: out[p] for p in ["#xyz"] * xyz + names}, offset + count * dt.itemsize


def _ply_ascii_values(data: bytes, offset: int, elements, notes: list[str]) -> dict:
    """ASCII PLY read as one stream of numbers (records may span or share lines, as the format allows),
    parsed by numpy's C tokenizer into a float64 array: no Python object per line or number."""
    body = data[offset:]
    if b"\x00" in body:
        raise _Malformed("not an ASCII PLY file: it contains binary data (NUL bytes) where text is expected")
    if _BLANK.fullmatch(body):
        T = np.zeros(0)
    else:
        try:
            T = np.fromstring(body, dtype=np.float64, sep=" ")
        except ValueError:
            _ply_ascii_bad_token(body, offset, data)
            raise
    del body
    values, pos = {}, 0
    for name, count, props in elements:
        values[name], pos = _ply_ascii_element(T, pos, count, props, name)
    if pos < T.size:
        last, count, props = elements[-1]
        got = values[last]
        stride = sum(1 if np.ndim(got[p]) == 1 else 1 + got[p].shape[1] for p, _ in props) \
            if all(isinstance(got[p], np.ndarray) for p, _ in props) else 0
        extra = (T.size - pos) / stride if stride else 0
        more = f" ({extra:g} more records of '{last}')" if extra == int(extra) and extra else ""
        notes.append(
            f"{T.size - pos} numbers after the last declared element ('{last}', {count} records) ignored{more}: "
            "the header's count may be wrong"
        )
    return values


def _ply_ascii_bad_token(body: bytes, offset: int, data: bytes) -> None:
    """Raise naming the line and the first token of ``body`` that is not a number (error path only)."""
    for mo in re.finditer(rb"\S+", body):
        tok = mo.group()
        try:
            float(tok)
        except ValueError:
            line = data.count(b"\n", 0, offset + mo.start()) + 1
            raise _Malformed(f"line {line}: {tok[:40].decode('latin-1')!r} is not a number") from None


def _ply_ascii_element(T: np.ndarray, pos: int, count: int, props, name: str):
    """One element's records from the number stream ``T`` at ``pos``; returns ``(values, next pos)``."""
    left = T.size - pos
    lists = [j for j, (_, t) in enumerate(props) if not isinstance(t, str)]
    if count == 0:
        return {p: (np.zeros(0) if isinstance(t, str) else np.zeros((0, 3))) for p, t in props}, pos
    if not props:
        return {}, pos
    # Fixed layout: every list as long as the first record's (all triangles, say), checked after.
    stride, col, layout = 0, pos, []
    for pname, t in props:
        if isinstance(t, str):
            layout.append((pname, stride, None))
            stride, col = stride + 1, col + 1
        else:
            if col >= T.size:
                stride = None
                break
            k = T[col]
            if not (k >= 0 and k == int(k)):
                raise _Malformed(f"element '{name}' record 0: list '{pname}' has length {k:g}, not a count")
            k = int(k)
            layout.append((pname, stride, k))
            stride, col = stride + 1 + k, col + 1 + k
    if stride is not None and count * stride <= left:
        block = T[pos:pos + count * stride].reshape(count, stride)
        if all((block[:, start] == k).all() for _, start, k in layout if k is not None):
            out = {}
            for pname, start, k in layout:
                out[pname] = block[:, start] if k is None else block[:, start + 1:start + 1 + k]
            return out, pos + count * stride
    if not lists:
        whole = left // len(props)
        raise _Malformed(f"truncated: element '{name}' declares {count} records, the file ends after {whole}")
    # Lists of varying length (polygons): record by record (the slow path, for polygon meshes only).
    out = {p: [] for p, _ in props}
    for i in range(count):
        for pname, t in props:
            if pos >= T.size:
                raise _Malformed(f"truncated: element '{name}' declares {count} records, the file ends after {i}")
            if isinstance(t, str):
                out[pname].append(T[pos])
                pos += 1
            else:
                k = T[pos]
                if not (k >= 0 and k == int(k)):
                    raise _Malformed(f"element '{name}' record {i}: list '{pname}' has length {k:g}, not a count")
                k = int(k)
                if pos + 1 + k > T.size:
                    raise _Malformed(
                        f"truncated: element '{name}' declares {count} records, the file ends inside record {i}")
                out[pname].append(T[pos + 1:pos + 1 + k])
                pos += 1 + k
    return {p: (out[p] if isinstance(t, tuple) else np.array(out[p])) for p, t in props}, pos


def _sized_element(props, count: int, left: int, name: str) -> dict | None:
    """Refuse an element whose ``count`` records cannot fit in the ``left`` bytes (before anything is allocated);
    the empty columns of an element of no record, else None."""
    least = sum(np.dtype(t).itemsize if isinstance(t, str) else np.dtype(t[0]).itemsize for _, t in props)
    if count * least > left:
        raise _Malformed(
            f"truncated: element '{name}' declares {count} records of at least {least} bytes, "
            f"but only {left} bytes are left"
        )
    if count == 0:
        return {p: (np.zeros(0, t) if isinstance(t, str) else np.zeros((0, 3), t[1])) for p, t in props}
    return None


def _ply_binary_element(data, offset, count, props, name, endian):
    # Sizes are checked before reading, so a count of 10^10 fails here instead of allocating.
    empty = _sized_element(props, count, len(data) - offset, name)
    if empty is not None:
        return empty, offset
    # Fast path: every list has the length of the first record's (all triangles, say): one structured
    # dtype over the bytes (np.frombuffer, no copy), the fields taken as views.
    fields, pos = [], offset
    for pname, t in props:
        if isinstance(t, str):
            fields.append((pname, endian + t))
            pos += np.dtype(t).itemsize
        else:
            if pos + np.dtype(t[0]).itemsize > len(data):
                raise _Malformed(f"truncated inside element '{name}'")
            k = int(np.frombuffer(data, endian + t[0], 1, pos)[0])
            fields.append((pname + "#count", endian + t[0]))
            fields.append((pname, endian + t[1], (k,)))
            pos += np.dtype(t[0]).itemsize + k * np.dtype(t[1]).itemsize
    dt = np.dtype(fields)
    lists = [p for p, t in props if not isinstance(t, str)]
    if count * dt.itemsize <= len(data) - offset:
        rec = np.frombuffer(data, dt, count, offset)
        if all((rec[p + "#count"] == dt[p].shape[0]).all() for p in lists):
            return {p: rec[p] for p, _ in props}, offset + count * dt.itemsize
    if not lists:
        raise _Malformed(f"truncated: element '{name}' needs {count * dt.itemsize} bytes, {len(data) - offset} left")
    # Slow path: lists of varying length (polygons), record by record.
    out = {p: [] for p, _ in props}
    pos = offset
    try:
        for _ in range(count):
            for pname, t in props:
                if isinstance(t, str):
                    out[pname].append(np.frombuffer(data, endian + t, 1, pos)[0])
                    pos += np.dtype(t).itemsize
                else:
                    k = int(np.frombuffer(data, endian + t[0], 1, pos)[0])
                    pos += np.dtype(t[0]).itemsize
                    out[pname].append(np.frombuffer(data, endian + t[1], k, pos))
                    pos += k * np.dtype(t[1]).itemsize
    except ValueError:
        raise _Malformed(f"truncated: the file ends inside element '{name}'") from None
    return {p: (out[p] if p in lists else np.array(out[p])) for p, _ in props}, pos


_TYPE_RANGE = {"u1": (0, 255), "i1": (-128, 127), "u2": (0, 65535), "i2": (-32768, 32767),
               "u4": (0, 2**32 - 1), "i4": (-(2**31), 2**31 - 1)}


def _ply_colours(vx: dict, types: dict, n: int) -> np.ndarray | None:
    """RGBA in [0, 1] from ``red green blue [alpha]`` (or ``diffuse_*``); out-of-range values are refused
    (never wrapped or clipped): integers must lie in 0..255, floats in [0, 1]."""
    names = next(([f"{p}red", f"{p}green", f"{p}blue"] for p in ("", "diffuse_") if f"{p}red" in vx), None)
    if not names:
        return None
    alpha = names[0].replace("red", "alpha")
    names = names + ([alpha] if alpha in vx else [])
    cols = []
    for c in names:
        t = types[c]
        A = np.asarray(vx[c], np.float64)
        if t.startswith(("u", "i")):
            lo, hi = 0, 255
        else:
            lo, hi = 0.0, 1.0
        bad = ~((A >= lo) & (A <= hi) & (np.mod(A, 1) == 0 if t.startswith(("u", "i")) else True))
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            kind = "an integer colour (0..255)" if t.startswith(("u", "i")) else "a float colour (0..1)"
            nbad = int(bad.sum())
            raise _Malformed(
                f"vertex {k}: {c} = {A[k]:g} is outside the range of {kind}; {nbad} "
                f"{'value' if nbad == 1 else 'values'} out of range in all (refused rather than wrapped or clipped)"
            )
        cols.append(A / 255.0 if t.startswith(("u", "i")) else A)
    if len(cols) == 3:
        cols.append(np.ones(n))
    return np.stack(cols, axis=1)


def _ply_extras(elements, values, triangles: bool) -> PlyExtras:
    """The file's properties and elements beside coordinates, triangles and colours (:class:`PlyExtras`)."""
    extras = PlyExtras()
    for name, count, props in elements:
        if name == "vertex":
            extras.normals = all(c in values[name] for c in ("nx", "ny", "nz"))
            extras.vertex = {p: (t, np.asarray(values[name][p]).astype(t)) for p, t in props
                             if isinstance(t, str) and p not in _RECOMPUTED}
            extras.elements.append((name, count, [], {}))
        elif name == "face":
            if triangles:
                extras.face = {p: (t, np.asarray(values[name][p]).astype(t)) for p, t in props if isinstance(t, str)}
            extras.elements.append((name, count, [], {}))
        else:
            extras.elements.append((name, count, props, values[name]))
    return extras


def _ply_mesh(elements, values, notes):
    V, F, colors, selection = _ply_arrays(elements, values, notes)
    idx = next((values["face"][k] for k in ("vertex_indices", "vertex_index") if k in values.get("face", {})), None)
    triangles = isinstance(idx, np.ndarray) and idx.ndim == 2 and idx.shape[1] == 3  # face i is triangle i
    return V, F, colors, selection, _ply_extras(elements, values, triangles)


def _ply_arrays(elements, values, notes):
    if "vertex" not in values:
        raise _Malformed("the PLY file has no 'vertex' element")
    vx = values["vertex"]
    if not all(c in vx for c in "xyz"):
        raise _Malformed("the 'vertex' element has no x, y, z properties")
    for c in "xyz":
        if not isinstance(vx[c], np.ndarray) or vx[c].ndim != 1:
            raise _Malformed(f"the 'vertex' property {c} is a list; coordinates must be numbers")
    if "#xyz" in vx:  # read from the file into one array already (_read_ply_file)
        V = vx["#xyz"]
    else:
        V = np.empty((len(vx["x"]), 3))
        for j, c in enumerate("xyz"):
            V[:, j] = vx[c]
    types = dict(next(e for e in elements if e[0] == "vertex")[2])
    colors = _ply_colours(vx, types, len(V))
    selection = None
    if "flags" in vx and isinstance(types["flags"], str) and types["flags"][0] in "iu":
        selection = (np.asarray(vx["flags"]).astype(np.int64) & 0x20) != 0  # MeshLab's SELECTED bit
    n = V.shape[0]
    if "face" not in values:
        return V, np.zeros((0, 3), np.int64), colors, selection
    fc = values["face"]
    key = next((k for k in ("vertex_indices", "vertex_index") if k in fc), None)
    if key is None:
        raise _Malformed("the 'face' element has no vertex_indices list")
    ftypes = dict(next(e for e in elements if e[0] == "face")[2])
    if isinstance(ftypes[key], str):
        raise _Malformed(f"the 'face' property {key} is a number; it must be a list of vertex indices")
    idx = fc[key]
    if isinstance(idx, np.ndarray):  # fixed-length fast path: (m, k)
        if idx.dtype.kind == "f" and not np.all(np.mod(idx, 1) == 0):
            r = int(np.flatnonzero((np.mod(idx, 1) != 0).any(axis=1))[0])
            raise _Malformed(f"face {r}: vertex indices must be integers, got {idx[r].tolist()}")
        ids = np.arange(idx.shape[0])
        if idx.shape[1] == 3:  # triangles: check the range before the int64 copy (chunked, bounded memory)
            for a in range(0, idx.shape[0], 1 << 20):
                _check_indices(idx[a:a + (1 << 20)], ids[a:a + (1 << 20)], n)
            return V, np.ascontiguousarray(idx, dtype=np.int64), colors, selection
        P = idx.astype(np.int64)
        _check_indices(P, ids, n)
        return V, _triangulate([(ids, P)], notes), colors, selection
    lengths = np.fromiter((len(p) for p in idx), dtype=np.int64, count=len(idx))
    groups = []
    for k in np.unique(lengths):
        ids = np.flatnonzero(lengths == k)
        P = np.array([idx[i] for i in ids], dtype=np.float64).reshape(len(ids), k)
        if not np.all(np.mod(P, 1) == 0):
            raise _Malformed(f"face {int(ids[0])}: vertex indices must be integers")
        P = P.astype(np.int64)
        _check_indices(P, ids, n)
        groups.append((ids, P))
    return V, _triangulate(groups, notes), colors, selection

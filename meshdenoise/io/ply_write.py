"""PLY writing: the vertex and face tables (binary little-endian or ASCII) and a read file's other elements written back."""

from __future__ import annotations

import sys

import numpy as np

from .meshfile import PlyExtras
from .tables import _colour_bytes


_PLY_TYPE_NAMES = {"i1": "char", "u1": "uchar", "i2": "short", "u2": "ushort", "i4": "int", "u4": "uint",
                   "f4": "float", "f8": "double"}
_ASCII_FORMAT = {"f4": "%.9g", "f8": "%.17g"}  # enough digits to read the same float back; integers: %d
# Records per piece of a vertex or face table: written through one reused buffer (a few MB), so that
# writing a 5M-vertex mesh holds no second copy of its arrays (the whole table as bytes took 250 MB there).
_CHUNK_RECORDS = 1 << 16


def _ply_columns(columns) -> tuple[list[str], np.dtype]:
    """Header lines and little-endian record dtype of scalar and fixed-length columns ``(name, type, width)``."""
    head, fields = [], []
    for name, t, width in columns:
        if width is None:
            head.append(f"property {_PLY_TYPE_NAMES[t]} {name}")
            fields.append((name, "<" + t))
        else:  # a list of fixed length: its count, then the items
            head.append(f"property list uchar {_PLY_TYPE_NAMES[t]} {name}")
            fields += [(name + "#count", "u1"), (name, "<" + t, (width,))]
    return head, np.dtype(fields)


def _ply_table_bytes(columns, data: dict, count: int, binary: bool) -> bytes:
    """Records of scalar and fixed-length list columns, binary little-endian or ASCII."""
    if binary:
        _, dt = _ply_columns(columns)
        rec = np.zeros(count, dt)
        for name, _, width in columns:
            rec[name] = data[name]
            if width is not None:
                rec[name + "#count"] = width
        return rec.tobytes()
    parts, fmts = [], []
    for name, t, width in columns:
        fmt = _ASCII_FORMAT.get(t, "%d")
        if width is not None:
            parts.append(np.full((count, 1), width, dtype=object))
            fmts.append("%d")
        A = np.asarray(data[name]).reshape(count, -1)
        parts.append(A.astype(object) if fmt != "%d" else A.astype(np.int64).astype(object))
        fmts += [fmt] * A.shape[1]
    if count == 0:
        return b""
    table = np.hstack(parts)
    return (((" ".join(fmts) + "\n") * count) % tuple(table.ravel().tolist())).encode()


def _write_ply_table(fh, columns, data: dict, count: int, binary: bool, xyz: np.ndarray | None = None) -> None:
    """Write the records of :func:`_ply_table_bytes` to ``fh`` piece by piece, never the whole table at once.

    ``xyz``: the (count, 3) array whose columns are ``x y z``, written as its own bytes (no copy at all)
    when the table is exactly those three little-endian doubles and the array is C-contiguous float64.
    """
    if (binary and xyz is not None and [(c[0], c[1], c[2]) for c in columns] == [("x", "f8", None), ("y", "f8", None),
                                                                                 ("z", "f8", None)]
            and xyz.dtype == np.float64 and xyz.flags.c_contiguous and sys.byteorder == "little"):
        fh.write(memoryview(xyz).cast("B"))
        return
    if not binary:
        for a in range(0, count, _CHUNK_RECORDS):
            k = min(_CHUNK_RECORDS, count - a)
            fh.write(_ply_table_bytes(columns, {name: data[name][a:a + k] for name, _, _ in columns}, k, binary=False))
        return
    _, dt = _ply_columns(columns)
    buf = np.zeros(min(count, _CHUNK_RECORDS), dt)
    for name, _, width in columns:
        if width is not None:
            buf[name + "#count"] = width
    for a in range(0, count, _CHUNK_RECORDS):
        k = min(_CHUNK_RECORDS, count - a)
        rec = buf[:k]
        for name, _, _ in columns:
            rec[name] = data[name][a:a + k]
        fh.write(rec.view(np.uint8))


def _ply_element_bytes(count: int, props, values: dict, binary: bool) -> tuple[list[str], bytes]:
    """An element read from a file (a camera, a range grid...) written back: header lines and data."""
    head = []
    for name, t in props:
        if isinstance(t, str):
            head.append(f"property {_PLY_TYPE_NAMES[t]} {name}")
        else:
            head.append(f"property list {_PLY_TYPE_NAMES[t[0]]} {_PLY_TYPE_NAMES[t[1]]} {name}")
    if all(isinstance(t, str) or (isinstance(values[p], np.ndarray) and values[p].ndim == 2) for p, t in props):
        fields = []  # every list of one length: one structured record per row
        for p, t in props:
            if isinstance(t, str):
                fields.append((p, "<" + t))
            else:
                fields += [(p + "#count", "<" + t[0]), (p, "<" + t[1], (values[p].shape[1],))]
        if not binary:  # ASCII has no count type: the vertex and face tables' writer
            columns = [(p, t, None) if isinstance(t, str) else (p, t[1], values[p].shape[1]) for p, t in props]
            return head, _ply_table_bytes(columns, values, count, binary=False)
        rec = np.zeros(count, np.dtype(fields))
        for p, t in props:
            rec[p] = values[p]
            if not isinstance(t, str):
                rec[p + "#count"] = values[p].shape[1]
        return head, rec.tobytes()
    else:  # lists of varying length (a range grid: 0 or 1 vertex per cell): record by record
        pieces = []
        for i in range(count):
            for p, t in props:
                if isinstance(t, str):
                    pieces.append((t, np.asarray([values[p][i]])))
                else:
                    items = np.asarray(values[p][i]).ravel()
                    pieces += [(t[0], np.asarray([items.size])), (t[1], items)]
            pieces.append(None)
        if binary:
            return head, b"".join(a.astype("<" + t).tobytes() for t, a in filter(None, pieces))
        lines, words = [], []
        for piece in pieces:
            if piece is None:
                lines.append(" ".join(words))
                words = []
            else:
                t, a = piece
                words += [_ASCII_FORMAT.get(t, "%d") % v for v in a.astype(t).tolist()]
        return head, "".join(line + "\n" for line in lines).encode()


def _write_ply(fh, V, F, C, binary, extras: PlyExtras | None = None, normals=None, coordinate="f8"):
    extras = extras.for_mesh(len(V), len(F)) if extras is not None else PlyExtras()
    if coordinate == "f4":  # float32 values: ASCII then writes the digits that read back as these floats
        V = V.astype(np.float32)
    vcols = [("x", coordinate, None), ("y", coordinate, None), ("z", coordinate, None)]
    vdata = {"x": V[:, 0], "y": V[:, 1], "z": V[:, 2]}
    if normals is None and extras.normals:  # the file had normals: the new coordinates'
        from ..geometry import vertex_normals

        normals = vertex_normals(V, F) if len(F) else np.zeros_like(V)
    if normals is not None:  # in the coordinates' type, as MeshLab writes them
        N = normals.astype(np.float32) if coordinate == "f4" else normals
        vcols += [("nx", coordinate, None), ("ny", coordinate, None), ("nz", coordinate, None)]
        vdata.update(nx=N[:, 0], ny=N[:, 1], nz=N[:, 2])
    if C is not None:
        cb = _colour_bytes(C)
        for j, c in enumerate(("red", "green", "blue", "alpha")):
            vcols.append((c, "u1", None))
            vdata[c] = cb[:, j]
    for name, (t, A) in extras.vertex.items():
        vcols.append((name, t, None))
        vdata[name] = A
    fcols = [("vertex_indices", "i4", 3)] + [(name, t, None) for name, (t, _) in extras.face.items()]
    fdata = {"vertex_indices": F, **{name: A for name, (_, A) in extras.face.items()}}
    layout = extras.elements or [("vertex", 0, [], {}), ("face", 0, [], {})]
    if not any(name == "face" for name, *_ in layout):
        layout = layout + [("face", 0, [], {})]
    head = ["ply", f"format {'binary_little_endian' if binary else 'ascii'} 1.0", "comment written by meshdenoise"]
    blocks = []  # what to write after the header: the vertex and face tables by name, other elements as bytes (small)
    for name, count, props, values in layout:
        if name == "vertex":
            head += [f"element vertex {len(V)}"] + _ply_columns(vcols)[0]
            blocks.append("vertex")
        elif name == "face":
            head += [f"element face {len(F)}"] + _ply_columns(fcols)[0]
            blocks.append("face")
        else:
            lines, data = _ply_element_bytes(count, props, values, binary)
            head += [f"element {name} {count}"] + lines
            blocks.append(data)
    head.append("end_header")
    fh.write(("\n".join(head) + "\n").encode())
    for block in blocks:
        if isinstance(block, str) and block == "vertex":
            _write_ply_table(fh, vcols, vdata, len(V), binary, xyz=V)
        elif isinstance(block, str):  # "face"
            _write_ply_table(fh, fcols, fdata, len(F), binary)
        else:
            fh.write(block)

"""STL: binary and ASCII reading (corners merged into shared vertices), writing."""

from __future__ import annotations

import re
import struct

import numpy as np

from .errors import _Malformed

_STL_ASCII_START = re.compile(rb"(?:\xef\xbb\xbf)?[ \t\r\n\f\v]*solid", re.I)


def _read_stl(data: bytes, notes: list[str]):
    rec_dtype = np.dtype([("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")])
    m = int(np.frombuffer(data, "<u4", 1, 80)[0]) if len(data) >= 84 else -1
    if m >= 0 and len(data) == 84 + 50 * m:
        rec = np.frombuffer(data, rec_dtype, m, 84)
        return _stl_mesh(rec["v"].astype(np.float64).reshape(-1, 3), notes) + (None,)
    if _STL_ASCII_START.match(data[:1024]) and b"\x00" not in data:
        text = data.decode("latin-1")
        if text.startswith("\xef\xbb\xbf"):
            notes.append("UTF-8 byte-order mark at the start of the file skipped")
            text = text[3:]
        return _read_stl_ascii(text, notes) + (None,)
    if m >= 0 and len(data) > 84 + 50 * m:
        extra = len(data) - 84 - 50 * m
        notes.append(
            f"{extra} extra bytes after the {m} triangles its header declares ignored (binary STL; "
            "the file is longer than its triangle count says)"
        )
        rec = np.frombuffer(data, rec_dtype, m, 84)
        return _stl_mesh(rec["v"].astype(np.float64).reshape(-1, 3), notes) + (None,)
    if m >= 0:
        raise _Malformed(
            f"not a valid STL file: as binary STL its header declares {m} triangles, which need "
            f"{84 + 50 * m} bytes, but the file has {len(data)} (truncated?); it is not ASCII STL either"
        )
    raise _Malformed(f"not an STL file: {len(data)} bytes, too short for binary STL and not ASCII STL ('solid ...')")


def _read_stl_ascii(text: str, notes: list[str]):
    toks = np.array(text.split())
    low = np.char.lower(toks)
    if not (low == "endsolid").any():
        raise _Malformed("truncated ASCII STL: no 'endsolid' line")
    facets = np.flatnonzero(low == "facet")
    ends = np.flatnonzero(low == "endfacet")
    verts = np.flatnonzero(low == "vertex")
    if len(facets) != len(ends) or len(verts) != 3 * len(facets):
        raise _Malformed(
            f"malformed ASCII STL: {len(facets)} 'facet', {len(ends)} 'endfacet' and {len(verts)} 'vertex' "
            "lines (each facet needs exactly 3 vertices)"
        )
    if len(facets) and not np.array_equal(np.bincount(np.searchsorted(facets, verts, side="right") - 1,
                                                      minlength=len(facets)), np.full(len(facets), 3)):
        raise _Malformed("malformed ASCII STL: a facet does not have exactly 3 vertices")
    if len(verts) and verts.max() + 3 >= len(toks):
        raise _Malformed("truncated ASCII STL")
    coords = toks[(verts[:, None] + np.arange(1, 4)).ravel()] if len(verts) else np.zeros(0, str)
    try:
        C = coords.astype(np.float64).reshape(-1, 3)
    except ValueError:
        raise _Malformed("malformed ASCII STL: a vertex line has a coordinate that is not a number") from None
    return _stl_mesh(C, notes)


def _stl_mesh(corners: np.ndarray, notes: list[str]):
    """Merge STL's per-triangle corners into shared vertices (exact match, first-appearance order)."""
    bad = ~np.isfinite(corners).all(axis=1)
    if bad.any():
        t = int(np.flatnonzero(bad)[0]) // 3
        raise _Malformed(f"triangle {t} has a NaN or infinite coordinate {corners[3 * t:3 * t + 3].tolist()}")
    if corners.shape[0] == 0:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
    uniq, first, inverse = np.unique(corners, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first)
    rank = np.empty_like(order)
    rank[order] = np.arange(order.size)
    notes.append(f"STL corners merged into shared vertices by exact position: {corners.shape[0]} -> {uniq.shape[0]}")
    return uniq[order], rank[inverse.ravel()].reshape(-1, 3).astype(np.int64)


def _write_stl(fh, V, F, C, binary, extras=None, normals=None, coordinate="f8"):  # extras: PLY only; face normals
    from ..geometry import face_normals

    N = np.nan_to_num(face_normals(V, F)) if len(F) else np.zeros((0, 3))
    if binary:
        rec = np.zeros(len(F), np.dtype([("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")]))
        rec["n"], rec["v"] = N, V[F]
        fh.write(b"binary STL written by meshdenoise".ljust(80, b" ") + struct.pack("<I", len(F)))
        fh.write(rec.tobytes())
        return
    table = np.hstack([N, V[F].reshape(-1, 9)])
    facet = ("facet normal %.9g %.9g %.9g\n outer loop\n" + "  vertex %.17g %.17g %.17g\n" * 3 + " endloop\nendfacet\n")
    fh.write(b"solid meshdenoise\n")
    fh.write(((facet * len(F)) % tuple(table.ravel().tolist())).encode())
    fh.write(b"endsolid meshdenoise\n")

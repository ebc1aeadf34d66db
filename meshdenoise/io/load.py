"""Reading any mesh file: the first bytes checked against the extension's format, then its reader (:func:`load_mesh`)."""

from __future__ import annotations

import os
import re
import struct
from pathlib import Path

import numpy as np

from ..arrays import MeshValidationError, check_mesh_arrays
from .errors import _check_extension, _Malformed, MeshFileError
from .meshfile import MeshFile
from .obj import _OBJ_IGNORED, _read_obj
from .off import _OFF_HEADER, _read_off
from .ply_read import _read_ply, _read_ply_file, _streamable
from .stl import _read_stl, _STL_ASCII_START
from .tables import _BLANK
from .topology import topology_notes


_SNIFF_BYTES = 1 << 16  # read first: enough to refuse garbage without loading a 200 MB file
_UTF8_BOM = b"\xef\xbb\xbf"
_OFF_FIRST_WORD = re.compile(rb"(?:[ \t\r\n\f\v]+|#[^\r\n]*)*([^\s#]+)")


def _sniff(ext: str, head: bytes, size: int, more: bool) -> bool:
    """Refuse a file from its first bytes (``head``, of ``size`` in all) when they already show it is not
    of its extension's format; returns whether it starts with a UTF-8 byte-order mark to skip."""
    if head.startswith((b"\xff\xfe", b"\xfe\xff")):
        raise _Malformed("the file is UTF-16 text (it starts with a UTF-16 byte-order mark); save it as UTF-8 or ASCII")
    if not more and _BLANK.fullmatch(head):
        return False  # empty or whitespace only: said by the caller
    if ext == ".stl":  # no BOM to strip: a binary STL header may start with any bytes
        binary_fits = size >= 84 and 84 + 50 * int.from_bytes(head[80:84], "little") <= size
        if binary_fits or (_STL_ASCII_START.match(head) and b"\x00" not in head):
            return False
        if size >= 84:
            m = int.from_bytes(head[80:84], "little")
            raise _Malformed(
                f"not a valid STL file: as binary STL its header declares {m} triangles, which need "
                f"{84 + 50 * m} bytes, but the file has {size} (truncated?); it is not ASCII STL either"
            )
        raise _Malformed(f"not an STL file: {size} bytes, too short for binary STL and not ASCII STL ('solid ...')")
    bom = head.startswith(_UTF8_BOM)
    h = head[len(_UTF8_BOM):] if bom else head
    if ext == ".ply":
        if not re.match(rb"ply\r?\n", h) and not (not more and _BLANK.fullmatch(h)):
            raise _Malformed("not a PLY file: it does not start with the line 'ply'")
        return bom
    what = "an OBJ" if ext == ".obj" else "an OFF"
    if b"\x00" in h:
        raise _Malformed(f"not {what} file: it contains binary data (NUL bytes) where text is expected")
    if ext == ".obj" and more:  # a big file: most lines of its first 64 KiB must be OBJ statements
        words = re.findall(rb"(?m)^[ \t]*([^\s#]+|#)", h[:h.rfind(b"\n") + 1] if b"\n" in h else b"")
        known = {w.encode() for w in _OBJ_IGNORED} | {b"v", b"f", b"l", b"p", b"#"}
        if sum(w in known for w in words) * 2 < len(words) or not words:
            shown = ", ".join(repr(w[:20].decode("latin-1")) for w in words[:3])
            raise _Malformed("not an OBJ file: most lines of its first 64 KiB are not OBJ statements (v, f, vt, #...)"
                            + (f" (it starts with {shown})" if shown else " (no complete line)"))
    if ext == ".off":
        m = _OFF_FIRST_WORD.match(h)
        if m and (m.end() < len(h) or not more):
            word = m.group(1).decode("latin-1")
            if not _OFF_HEADER.match(word):
                raise _Malformed(
                    f"not an OFF file: the first word is {word[:40]!r}, expected OFF, COFF, NOFF or STOFF")
    return bom


def load_mesh(path: str | os.PathLike) -> MeshFile:
    """Read a PLY (ASCII or binary), OBJ, OFF or STL (ASCII or binary) file.

    The file's vertex order is kept (STL, which has no shared vertices, gets its corners
    merged by exact coordinates in order of first appearance). Polygons are split into
    triangle fans. Vertex colours are read from PLY (``red green blue [alpha]``), COFF and
    OBJ (``v x y z r g b``); a MeshLab vertex selection from PLY ``flags``. A UTF-8
    byte-order mark is skipped; data after what the header declares is ignored with a note.

    Parameters
    ----------
    path : str or PathLike
        A ``.ply``, ``.obj``, ``.off`` or ``.stl`` file.

    Returns
    -------
    MeshFile
        ``V (n, 3) float64``, ``F (m, 3) int64`` (``m`` may be 0: a point cloud), colours
        and notes.

    Raises
    ------
    MeshFileError
        Naming the file and the problem: missing, empty, not the format of its extension,
        truncated, a face index outside the vertices, a NaN or infinite coordinate, a colour
        outside its range (refused, never wrapped or clipped), UTF-16 text.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> p = pathlib.Path(tempfile.mkdtemp()) / "quad.obj"
    >>> _ = p.write_text("v 0 0 0\\nv 1 0 0\\nv 1 1 0\\nv 0 1 0\\nf 1 2 3 4\\n")
    >>> m = load_mesh(p)
    >>> m.F.tolist(), m.notes
    ([[0, 1, 2], [0, 2, 3]], ['1 polygons with more than 3 vertices triangulated into fans (2 triangles in all)'])
    """
    path = Path(path)
    _check_extension(path)
    if not path.exists():
        raise MeshFileError(f"{path}: no such file")
    if not path.is_file():
        raise MeshFileError(f"{path}: not a regular file")
    ext = path.suffix.lower()
    notes: list[str] = []
    try:
        with open(path, "rb") as fh:
            # Sniff the first bytes before reading the rest: garbage is refused without loading it.
            head = fh.read(_SNIFF_BYTES)
            rest = fh.read(1) if len(head) == _SNIFF_BYTES else b""
            try:
                bom = _sniff(ext, head, os.fstat(fh.fileno()).st_size, bool(rest))
                if ext == ".ply" and rest and b"end_header" not in head:  # a long header: look a little further
                    if b"end_header" not in head + rest + fh.read((1 << 20) - len(head)):
                        raise _Malformed("the PLY header has no 'end_header' line in its first MiB (not a PLY file)")
            except _Malformed as exc:
                raise MeshFileError(f"{path}: {exc}") from None
            streamed = bool(rest) and ext == ".ply" and not bom and _streamable(head)
            if streamed:  # binary PLY: read into the arrays from the file, no copy of it in memory
                out = _parse(lambda: _read_ply_file(fh, os.fstat(fh.fileno()).st_size, notes), path, ext)
            elif rest:
                fh.seek(0)
                data = fh.read()
            else:
                data = head
            del head, rest
    except OSError as exc:
        raise MeshFileError(f"{path}: cannot be read ({exc.strerror or exc})") from None
    if not streamed:
        out = _read_bytes(data, bom, path, ext, notes)
        del data
    V, F, colors = out[:3]
    selection = out[3] if len(out) > 3 else None
    extras = out[4] if len(out) > 4 else None
    bad = np.flatnonzero(~np.isfinite(np.asarray(V, dtype=np.float64)).all(axis=1)) if len(V) else []
    if len(bad):
        raise MeshFileError(
            f"{path}: {len(bad)} {'vertex' if len(bad) == 1 else 'vertices'} with a NaN or infinite coordinate "
            f"(first: vertex {bad[0]} = {np.asarray(V)[bad[0]].tolist()})"
        )
    try:
        V, F = check_mesh_arrays(V, F, allow_no_faces=True)
    except (MeshValidationError, TypeError) as exc:
        raise MeshFileError(f"{path}: {exc}") from None
    notes += topology_notes(V, F)
    return MeshFile(V, F, colors, notes, path, selection, extras)


def _read_bytes(data: bytes, bom: bool, path: Path, ext: str, notes: list[str]):
    """The reader of ``ext`` on the file's bytes ``data``: what it returns, or :class:`MeshFileError` naming ``path``."""
    if not data or _BLANK.fullmatch(data):
        raise MeshFileError(f"{path}: the file is empty" + (" (whitespace only)" if data else ""))
    if bom:
        data = data[len(_UTF8_BOM):]
        notes.append("UTF-8 byte-order mark at the start of the file skipped")
    return _parse(lambda: _READERS[ext](data, notes), path, ext)


def _parse(read, path: Path, ext: str):
    """``read()``, a reader's result; its failures as :class:`MeshFileError` naming ``path``."""
    try:
        return read()
    except _Malformed as exc:
        raise MeshFileError(f"{path}: {exc}") from None
    except (ValueError, IndexError, struct.error, OverflowError, MemoryError) as exc:
        # Any other parse failure is still a malformed file: say so with the file name.
        raise MeshFileError(f"{path}: cannot be read as {ext[1:].upper()} ({exc})") from None


def load_arrays(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Read a mesh file into ``(V (n, 3) float64, F (m, 3) int64)``; see :func:`load_mesh`."""
    mesh = load_mesh(path)
    return mesh.V, mesh.F


_READERS = {".off": _read_off, ".obj": _read_obj, ".ply": _read_ply, ".stl": _read_stl}

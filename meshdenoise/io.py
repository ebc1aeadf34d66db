"""Reading and writing mesh files: strict readers, errors that name the file, atomic writes.

The readers are pure Python/numpy (no C++ loader), so a hostile or broken file can raise
:class:`MeshFileError` but cannot crash the process: pymeshlab's loaders silently accept
truncated STL and OFF files and out-of-range OBJ indices, drop NaN vertices and duplicate
faces, read an OFF file with comments as empty and refuse CR line endings (see
the README section "Robustness"). Header counts are checked against the file size before anything is
allocated. Unusual but legal input (polygons, CR or CRLF line endings, negative OBJ
indices, STL's unshared corners) is read and described in :attr:`MeshFile.notes`.

The first 64 KiB are checked before the rest is read, so garbage is refused without loading it.
Binary PLY is read through numpy structured dtypes and ASCII PLY (and plain OBJ/OFF) as one
number stream, without a Python object per line. What is accepted, refused and guaranteed:
docs/file-formats.md.

Writers are numpy too: PLY stores ``double`` coordinates (``float`` on request), OFF and OBJ 17
significant digits, so a write-read round trip is exact (binary STL stores float32 by definition).
A temporary file being written is removed on SIGTERM/SIGHUP (see :class:`atomic_path`).
"""

from __future__ import annotations

import os
import re
import signal
import struct
import tempfile
import threading
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .arrays import MeshValidationError, check_mesh_arrays

__all__ = [
    "MeshFile",
    "load_mesh",
    "save_mesh",
    "load_arrays",
    "save_arrays",
    "atomic_path",
    "MeshFileError",
    "PrecisionWarning",
    "SUPPORTED_EXTENSIONS",
    "STL_TOLERANCE",
    "topology_notes",
]

SUPPORTED_EXTENSIONS = (".ply", ".obj", ".off", ".stl")


#: Largest move, in mean edge lengths, that binary STL's float32 rounding may give a vertex before
#: :func:`save_mesh` warns (a georeferenced scan: coordinates near 1e6, millimetre detail).
STL_TOLERANCE = 0.01


class PrecisionWarning(UserWarning):
    """A file format cannot hold the coordinates as they are: binary STL's float32 moves vertices by more
    than :data:`STL_TOLERANCE` mean edge lengths. The message names the file and the largest move."""


class MeshFileError(ValueError):
    """A mesh file that cannot be read or written; the message names the file and the problem."""


class _Malformed(Exception):
    """Raised by a reader; :func:`load_mesh` prefixes the path."""


def _check_extension(path: Path) -> None:
    if path.suffix.lower() not in SUPPORTED_EXTENSIONS:
        raise MeshFileError(
            f"{path}: unsupported extension {path.suffix!r}; use one of {', '.join(SUPPORTED_EXTENSIONS)}"
        )


_COLOUR_NAMES = frozenset(f"{p}{c}" for p in ("", "diffuse_") for c in ("red", "green", "blue", "alpha"))
_RECOMPUTED = frozenset(("x", "y", "z", "nx", "ny", "nz")) | _COLOUR_NAMES


@dataclass
class PlyExtras:
    """What a PLY file holds beside coordinates, triangles and colours, kept to be written again.

    A scanner's PLY often carries per-vertex ``quality``/``confidence``/``intensity``, MeshLab's
    ``flags``, vertex normals and a ``camera`` element (the scan's view point). A filter that
    keeps the vertices and faces (every denoiser) keeps them valid, so :func:`save_mesh` writes
    them to a PLY: the properties as they were (same names and types), normals recomputed from
    the new coordinates, other elements verbatim. :meth:`for_mesh` drops what a change of the
    vertices or faces makes meaningless.

    Attributes
    ----------
    vertex, face : dict of str -> (str, ndarray (n,) or (m,))
        Scalar properties by name: (numpy type code such as ``"f4"``, values), in file order.
        Coordinates, normals and colours are not in ``vertex`` (written from the arrays).
        ``face`` is empty when the file's polygons were split into triangles.
    elements : list of (str, int, list, dict)
        Every element of the file in order, as ``(name, count, properties, values)``;
        ``vertex`` and ``face`` appear with ``properties`` and ``values`` empty (placeholders
        for their position).
    normals : bool
        The vertices had ``nx ny nz``.
    """

    vertex: dict = field(default_factory=dict)
    face: dict = field(default_factory=dict)
    elements: list = field(default_factory=list)
    normals: bool = False

    def other_elements(self) -> list:
        return [e for e in self.elements if e[0] not in ("vertex", "face")]

    def describe(self) -> list[str]:
        """Short names of what is carried, for messages: ``['vertex quality', 'camera', ...]``."""
        out = [f"vertex {k}" for k in self.vertex] + [f"face {k}" for k in self.face]
        out += ["vertex normals"] if self.normals else []
        return out + [name for name, *_ in self.other_elements()]

    def with_selection(self, selected: np.ndarray | None) -> "PlyExtras":
        """MeshLab's "selected" bit (0x20) of integer vertex ``flags`` set from ``selected`` (n,) bool (None: none)."""
        if "flags" not in self.vertex or self.vertex["flags"][0][0] not in "iu":
            return self
        t, flags = self.vertex["flags"]
        bit = np.asarray(0x20).astype(t)
        new = flags & ~bit if selected is None else np.where(np.asarray(selected, bool), flags | bit, flags & ~bit)
        return PlyExtras({**self.vertex, "flags": (t, new.astype(t))}, self.face, self.elements, self.normals)

    def with_quality(self, vertex: np.ndarray | None, face: np.ndarray | None) -> "PlyExtras":
        """Per-vertex and per-face ``quality`` (MeshLab's scalar) set to the arrays given (kept as read when None)."""
        out = {"vertex": dict(self.vertex), "face": dict(self.face)}
        for where, values in (("vertex", vertex), ("face", face)):
            if values is not None:
                t = out[where].get("quality", ("f4", None))[0]
                out[where]["quality"] = (t, np.asarray(values).astype(t))
        return PlyExtras(out["vertex"], out["face"], self.elements, self.normals)

    def for_mesh(self, n: int, m: int) -> "PlyExtras":
        """What stays valid for a mesh of ``n`` vertices and ``m`` faces (the same ones, if counts match).

        Vertex properties need ``n`` equal to theirs, face properties ``m``; with other
        vertices, other elements are kept only when they refer to no vertex (no list
        property, no property named ``vertex*``: a camera yes, a range grid or edges no).
        """
        nv = next((len(a) for _, a in self.vertex.values()), None)
        nf = next((len(a) for _, a in self.face.values()), None)
        same_vertices = nv is None or nv == n
        vertex = self.vertex if same_vertices else {}
        face = self.face if nf is None or nf == m else {}

        def refers_to_vertices(props) -> bool:
            return any(not isinstance(t, str) or name.startswith("vertex") for name, t in props)

        elements = [e for e in self.elements
                    if e[0] in ("vertex", "face") or same_vertices or not refers_to_vertices(e[2])]
        return PlyExtras(vertex, face, elements, self.normals)


@dataclass
class MeshFile:
    """A mesh read from a file.

    Attributes
    ----------
    V : ndarray, shape (n, 3), float64
    F : ndarray, shape (m, 3), int64
        Triangles; polygons of the file are split into fans ``(a, b, c), (a, c, d), ...``.
    vertex_colors : ndarray, shape (n, 4), float64 in [0, 1], or None
        RGBA, when the file has vertex colours.
    notes : list of str
        What was done to read an unusual but legal file (polygons triangulated, STL corners
        merged, CR line endings) and legal oddities worth knowing (unreferenced vertices,
        duplicate faces, non-manifold edges, no faces).
    path : Path
    selection : ndarray, shape (n,), bool, or None
        The MeshLab vertex selection, when the file stores it: a PLY whose vertices have the
        integer property ``flags`` (MeshLab's "Flags" save option; bit 0x20 is "selected").
        None for every other file.
    extras : PlyExtras or None
        A PLY file's other properties and elements (quality, flags, camera...), written again by
        :func:`save_mesh` to a PLY. None for every other format.
    """

    V: np.ndarray
    F: np.ndarray
    vertex_colors: np.ndarray | None = None
    notes: list[str] = field(default_factory=list)
    path: Path | None = None
    selection: np.ndarray | None = None
    extras: PlyExtras | None = None


# ---------------------------------------------------------------------------------- reading
_SNIFF_BYTES = 1 << 16  # read first: enough to refuse garbage without loading a 200 MB file
_UTF8_BOM = b"\xef\xbb\xbf"
_BLANK = re.compile(rb"[ \t\r\n\f\v]*")
_OFF_FIRST_WORD = re.compile(rb"(?:[ \t\r\n\f\v]+|#[^\r\n]*)*([^\s#]+)")
_STL_ASCII_START = re.compile(rb"(?:\xef\xbb\xbf)?[ \t\r\n\f\v]*solid", re.I)


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
            if rest:
                fh.seek(0)
                data = fh.read()
            else:
                data = head
            del head, rest
    except OSError as exc:
        raise MeshFileError(f"{path}: cannot be read ({exc.strerror or exc})") from None
    if not data or _BLANK.fullmatch(data):
        raise MeshFileError(f"{path}: the file is empty" + (" (whitespace only)" if data else ""))
    if bom:
        data = data[len(_UTF8_BOM):]
        notes.append("UTF-8 byte-order mark at the start of the file skipped")
    reader = _READERS[ext]
    try:
        out = reader(data, notes)
    except _Malformed as exc:
        raise MeshFileError(f"{path}: {exc}") from None
    except (ValueError, IndexError, struct.error, OverflowError, MemoryError) as exc:
        # Any other parse failure is still a malformed file: say so with the file name.
        raise MeshFileError(f"{path}: cannot be read as {ext[1:].upper()} ({exc})") from None
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


def load_arrays(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Read a mesh file into ``(V (n, 3) float64, F (m, 3) int64)``; see :func:`load_mesh`."""
    mesh = load_mesh(path)
    return mesh.V, mesh.F


def topology_notes(V: np.ndarray, F: np.ndarray) -> list[str]:
    """Legal oddities of a mesh, in words: no faces, unreferenced vertices, degenerate,
    duplicate faces, non-manifold edges. Empty for a clean manifold mesh.

    Examples
    --------
    >>> import numpy as np
    >>> for note in topology_notes(np.zeros((4, 3)), np.array([[0, 1, 2], [2, 1, 0]])):
    ...     print(note)
    1 unreferenced vertices (kept; filters leave them in place)
    1 duplicate faces (same vertices as an earlier face)
    """
    if F.shape[0] == 0:
        return [f"no faces: a point cloud of {V.shape[0]} vertices (filters need faces)"]
    notes = []
    n = V.shape[0]
    used = np.zeros(n, dtype=bool)
    used[F.ravel()] = True
    if not used.all():
        notes.append(f"{int((~used).sum())} unreferenced vertices (kept; filters leave them in place)")
    del used
    S = np.sort(F.astype(np.int32) if n < 2**31 else F, axis=1)  # int32: half the memory at millions of faces
    degenerate = int(((S[:, 0] == S[:, 1]) | (S[:, 1] == S[:, 2])).sum())
    if degenerate:
        notes.append(f"{degenerate} degenerate faces (a vertex repeated)")
    duplicates = _repeated_rows(S, n)
    if duplicates:
        notes.append(f"{duplicates} duplicate faces (same vertices as an earlier face)")
    # sorted edge keys (one int64 per side, degenerate sides left out); an edge on 3+ faces is a run of 3+
    keys = np.concatenate([S[:, 0].astype(np.int64) * n + S[:, 1], S[:, 1].astype(np.int64) * n + S[:, 2],
                           S[:, 0].astype(np.int64) * n + S[:, 2]])
    keep = np.concatenate([S[:, 0] != S[:, 1], S[:, 1] != S[:, 2], S[:, 0] != S[:, 2]])
    del S
    keys = keys[keep]
    del keep
    keys.sort()
    if keys.size > 2:
        first = np.empty(keys.size - 2, dtype=bool)  # k[i] starts a run ...
        first[0] = True
        np.not_equal(keys[1:-2], keys[:-3], out=first[1:])
        nonmanifold = int((first & (keys[2:] == keys[:-2])).sum())  # ... of length 3 or more
        if nonmanifold:
            notes.append(f"{nonmanifold} non-manifold edges (shared by more than two faces)")
    return notes


def _repeated_rows(S: np.ndarray, n: int) -> int:
    """Rows of ``S`` (m, 3) (values in 0..n-1) equal to an earlier row."""
    if float(n) ** 3 < 2.0**62:
        key = (S[:, 0].astype(np.int64) * n + S[:, 1]) * n + S[:, 2]
        key.sort()
        return int((key[1:] == key[:-1]).sum())
    order = np.lexsort((S[:, 2], S[:, 1], S[:, 0]))
    R = S[order]
    return int((R[1:] == R[:-1]).all(axis=1).sum())


def _fast_table(lines: list[str]) -> np.ndarray | None:
    """Lines of whitespace-separated numbers as a float64 (k, c) array by numpy's C parser;
    None when the lines do not all have the same count of numbers (the caller goes slow)."""
    if not lines:
        return None
    try:
        return np.loadtxt(lines, dtype=np.float64, ndmin=2, comments=None)
    except ValueError:
        return None


def _decode_text(data: bytes, what: str) -> str:
    if b"\x00" in data:
        raise _Malformed(f"not {what} file: it contains binary data (NUL bytes) where text is expected")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        return data.decode("latin-1")  # comments and names in a legacy encoding are harmless


def _lines(text: str, notes: list[str]) -> list[str]:
    if "\r" in text and "\n" not in text:
        notes.append("CR-only (classic Mac) line endings")
    return text.splitlines()


def _float_table(rows: list[list[str]], what: str, linenos=None, lineno_of=None) -> np.ndarray:
    """Rows of number tokens (all of one length) as a float64 array; the error names the line or row."""
    try:
        return np.array(rows, dtype=np.str_).astype(np.float64)
    except ValueError:
        for k, row in enumerate(rows):
            for tok in row:
                try:
                    float(tok)
                except ValueError:
                    if lineno_of is not None:
                        where = f"line {lineno_of(k)}"
                    else:
                        where = f"line {linenos[k]}" if linenos is not None else f"{what} {k}"
                    raise _Malformed(f"{where}: {tok[:40]!r} is not a number") from None
        raise


def _int_table(rows, what: str, linenos=None) -> np.ndarray:
    A = _float_table(rows, what, linenos)
    if A.size and not np.all(np.mod(A, 1) == 0):
        k = int(np.flatnonzero((np.mod(A, 1) != 0).any(axis=1))[0])
        where = f"line {linenos[k]}" if linenos is not None else f"{what} {k}"
        raise _Malformed(f"{where}: vertex indices must be integers, got {' '.join(rows[k])!r}")
    return A.astype(np.int64)


def _triangulate(groups: list[tuple[np.ndarray, np.ndarray]], notes: list[str]) -> np.ndarray:
    """Triangles from polygons given as ``(face ids (m,), indices (m, k))`` groups, in file order.

    A polygon ``(a, b, c, d, ...)`` becomes the fan ``(a, b, c), (a, c, d), ...``.
    """
    if len(groups) == 1 and groups[0][1].shape[1] == 3:  # all triangles, in file order: nothing to do
        ids, P = groups[0]
        if P.shape[0] == 0 or (ids[0] == 0 and ids[-1] == len(ids) - 1):
            return np.ascontiguousarray(P, dtype=np.int64)
    tris, keys = [np.zeros((0, 3), np.int64)], [np.zeros(0, np.int64)]
    n_poly = 0
    for ids, P in groups:
        k = P.shape[1]
        if k < 3:
            raise _Malformed(f"face {int(ids.min())} has {k} vertices: a face needs at least 3")
        T = np.stack([P[:, [0, j, j + 1]] for j in range(1, k - 1)], axis=1).reshape(-1, 3)
        tris.append(T)
        keys.append(np.repeat(ids, k - 2) * 1_000_000_000 + np.tile(np.arange(k - 2), len(ids)))
        if k > 3:
            n_poly += len(ids)
    T, key = np.concatenate(tris), np.concatenate(keys)
    T = T[np.argsort(key, kind="stable")]
    if n_poly:
        notes.append(
            f"{n_poly} polygons with more than 3 vertices triangulated into fans ({T.shape[0]} triangles in all)"
        )
    return T


def _check_indices(P: np.ndarray, ids: np.ndarray, n: int) -> None:
    bad = (P < 0) | (P >= n)
    if bad.any():
        r = int(np.flatnonzero(bad.any(axis=1))[0])
        face = ", ".join(f"{x:.15g}" for x in np.asarray(P[r], dtype=np.float64))
        raise _Malformed(
            f"face {int(ids[r])} = [{face}] references a vertex outside 0..{n - 1} (the file has {n} vertices)"
        )


# ------------------------------------------------------------------------------------ OFF
_OFF_HEADER = re.compile(r"^(ST)?(C)?(N)?(4)?(n)?OFF$")
_NAN_WORD = re.compile(rb"nan", re.I)


def _line_table(block: bytes) -> tuple[np.ndarray, np.ndarray] | None:
    """Lines of whitespace-separated numbers, parsed without a Python object per line.

    A NaN is appended to every line as an end-of-line marker and the whole block goes through
    numpy's C tokenizer once; the markers' positions give each line's count of numbers.
    Returns ``(numbers (t,), line ends (lines,))`` where ``line ends[i]`` is the marker index of
    line ``i`` (its numbers are the ones before it, after the previous marker), or None when the
    block cannot be read this way (a NaN or a word in it, a blank line, CR-only line ends):
    the caller then uses the line-by-line reader, which names the line and the problem.
    """
    if not block or _NAN_WORD.search(block) or re.search(rb"(?:^|\n)[ \t\r\f\v]*\n", block):
        return None
    marked = block.replace(b"\n", b" nan\n")
    if not block.endswith(b"\n"):
        marked += b" nan"
    try:
        T = np.fromstring(marked, dtype=np.float64, sep=" ")
    except ValueError:
        return None
    del marked
    ends = np.flatnonzero(np.isnan(T))
    return T, ends


def _vertex_and_face_rows(table, nv: int, nf: int, min_face_columns: int):
    """The ``nv`` vertex rows (3 numbers each) and ``nf`` face rows (at least ``min_face_columns``) of a
    number table, or ``None`` when the table does not have that shape (the line reader then says why)."""
    T, ends = table
    V = _rows_of(T, ends, 0, nv)
    Fr = _rows_of(T, ends, nv, nv + nf)
    if V is None or V.shape[1] != 3 or Fr is None or (nf and Fr.shape[1] < min_face_columns):
        return None
    return np.ascontiguousarray(V), Fr


def _rows_of(T: np.ndarray, ends: np.ndarray, a: int, b: int) -> np.ndarray | None:
    """Lines ``a..b-1`` of a :func:`_line_table` as a ``(b - a, k)`` array when all have k numbers, else None."""
    if b <= a:
        return np.zeros((0, 0))
    start = ends[a - 1] + 1 if a else 0
    k = int(ends[a] - start)
    if k <= 0 or ends[b - 1] - start + 1 != (b - a) * (k + 1):
        return None
    R = T[start:ends[b - 1] + 1].reshape(b - a, k + 1)
    if not np.isnan(R[:, k]).all():
        return None
    return R[:, :k]


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


# ------------------------------------------------------------------------------------ OBJ
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


# ------------------------------------------------------------------------------------ PLY
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


def _ply_binary_element(data, offset, count, props, name, endian):
    # Sizes are checked before reading, so a count of 10^10 fails here instead of allocating.
    least = sum(np.dtype(t).itemsize if isinstance(t, str) else np.dtype(t[0]).itemsize for _, t in props)
    if count * least > len(data) - offset:
        raise _Malformed(
            f"truncated: element '{name}' declares {count} records of at least {least} bytes, "
            f"but only {len(data) - offset} bytes are left"
        )
    if count == 0:
        return {p: (np.zeros(0, t) if isinstance(t, str) else np.zeros((0, 3), t[1])) for p, t in props}, offset
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


# ------------------------------------------------------------------------------------ STL
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


_READERS = {".off": _read_off, ".obj": _read_obj, ".ply": _read_ply, ".stl": _read_stl}


# ---------------------------------------------------------------------------------- writing
def _process_umask() -> int:
    mask = os.umask(0)  # the only portable way to read it is to set it, so read it once, at import
    os.umask(mask)
    return mask


_UMASK = _process_umask()


# Temporary files being written now. A handler for SIGTERM and SIGHUP (installed by the first write,
# in the main thread only) removes them before the signal's previous action: the default one (the
# process ends, as if the handler were not there) or the handler that was installed before ours.
# SIGINT needs nothing here: KeyboardInterrupt unwinds through atomic_path.__exit__. SIGKILL (kill -9)
# and power loss cannot be caught: they leave a hidden ``.<stem>.<random><suffix>`` file beside the
# destination (never the destination itself, which is only ever replaced by a complete file).
_IN_FLIGHT: set[Path] = set()
_PREVIOUS_HANDLERS: dict[int, object] = {}
_CLEANUP_SIGNALS = tuple(getattr(signal, name) for name in ("SIGTERM", "SIGHUP") if hasattr(signal, name))


def _remove_in_flight_and_resend(signum, frame) -> None:
    for tmp in list(_IN_FLIGHT):
        try:
            os.unlink(tmp)
        except OSError:
            pass
    _IN_FLIGHT.clear()
    previous = _PREVIOUS_HANDLERS.get(signum, signal.SIG_DFL)
    if callable(previous):
        previous(signum, frame)
        return
    signal.signal(signum, signal.SIG_DFL)  # the default action (terminate), as if we had not been here
    os.kill(os.getpid(), signum)


def _install_cleanup_handlers() -> None:
    if threading.current_thread() is not threading.main_thread():
        return  # signal handlers can only be set from the main thread
    for sig in _CLEANUP_SIGNALS:
        if sig in _PREVIOUS_HANDLERS:
            continue
        current = signal.getsignal(sig)
        if current is signal.SIG_IGN or current is None or current is _remove_in_flight_and_resend:
            continue  # ignored (the process goes on, so must its files) or set outside Python
        try:
            signal.signal(sig, _remove_in_flight_and_resend)
        except (ValueError, OSError):  # pragma: no cover - embedded interpreters
            continue
        _PREVIOUS_HANDLERS[sig] = current


class atomic_path:
    """Context manager giving a temporary path beside ``path``, renamed onto it only on success.

    Nothing is left behind on failure, and a reader never sees a half-written file: the
    temporary file is flushed to disk and then renamed (atomic on POSIX and Windows). A ``path``
    that is a folder, a device (``/dev/null``), a pipe or a socket is refused (``MeshFileError``):
    the rename would replace it. SIGTERM
    and SIGHUP during the write remove the temporary file, then take their previous action
    (by default: the process ends). Only what cannot be caught (SIGKILL, a power cut) can leave
    the hidden temporary ``.<stem>.<8 random characters><suffix>`` beside ``path``.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> target = pathlib.Path(tempfile.mkdtemp()) / "out.txt"
    >>> with atomic_path(target) as tmp:
    ...     _ = tmp.write_text("done")
    >>> target.read_text()
    'done'
    """

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)

    def __enter__(self) -> Path:
        if self.path.exists() and not self.path.is_file():  # renaming onto /dev/null would replace the device
            kind = "a folder" if self.path.is_dir() else "a device, pipe or socket"
            raise MeshFileError(f"{self.path}: cannot be written: it is {kind}, not a file")
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(prefix=f".{self.path.stem}.", suffix=self.path.suffix, dir=self.path.parent)
        except OSError as exc:
            raise MeshFileError(f"{self.path}: cannot be written ({exc.strerror or exc})") from None
        os.close(fd)
        self.tmp = Path(tmp)
        _install_cleanup_handlers()
        _IN_FLIGHT.add(self.tmp)
        return self.tmp

    def __exit__(self, exc_type, exc, tb) -> bool:
        try:
            return self._finish(exc_type, exc)
        finally:
            _IN_FLIGHT.discard(self.tmp)

    def _finish(self, exc_type, exc) -> bool:
        if exc_type is None and self.tmp.exists() and self.tmp.stat().st_size > 0:
            try:
                with open(self.tmp, "rb") as fh:
                    os.fsync(fh.fileno())
                # mkstemp makes private (0600) files; give the result the mode any other tool would:
                # the replaced file's, or 0666 minus the umask for a new one
                mode = self.path.stat().st_mode & 0o7777 if self.path.exists() else 0o666 & ~_UMASK
                os.chmod(self.tmp, mode)
                os.replace(self.tmp, self.path)
            except OSError as err:
                self.tmp.unlink(missing_ok=True)
                raise MeshFileError(f"{self.path}: cannot be written ({err.strerror or err})") from None
        else:
            self.tmp.unlink(missing_ok=True)
            if exc_type is None:
                raise MeshFileError(f"{self.path}: nothing was written")
            if issubclass(exc_type, OSError):
                raise MeshFileError(f"{self.path}: cannot be written ({exc.strerror or exc})") from None
        return False


def save_mesh(
    path: str | os.PathLike,
    V: np.ndarray,
    F: np.ndarray,
    vertex_colors: np.ndarray | None = None,
    *,
    binary: bool = True,
    extras: PlyExtras | None = None,
    vertex_normals: np.ndarray | None = None,
    precision: str = "float64",
) -> Path:
    """Write a mesh atomically (temporary file, then rename); the format comes from the extension.

    PLY (binary little-endian, or ASCII with ``binary=False``) stores ``double``
    coordinates (``float`` with ``precision="float32"``) and ``uchar`` RGBA colours; OFF (COFF with colours) and OBJ (``v x y z r g b``)
    store 17 significant digits, so reading the file back gives the same arrays. STL
    stores float32 corners (binary) or 17 digits (ASCII), and no colours. Nothing is left at ``path``
    if writing fails, and an existing file there is replaced only once the new one is complete.

    Parameters
    ----------
    path : str or PathLike
    V : array_like, shape (n, 3)
    F : array_like of int, shape (m, 3)
        ``m`` may be 0 (a point cloud), except for STL.
    vertex_colors : array_like, shape (n, 3) or (n, 4), in [0, 1], optional
    binary : bool
        PLY and STL only.
    extras : PlyExtras, optional
        A PLY file's other properties and elements (:attr:`MeshFile.extras`), written to a PLY
        (other formats cannot hold them): what stays valid for ``V`` and ``F``
        (:meth:`PlyExtras.for_mesh`), normals recomputed from ``V`` (unless ``vertex_normals`` are given).
    vertex_normals : array_like, shape (n, 3), optional
        Per-vertex normals written as they are: PLY ``nx ny nz`` (in the coordinates' type), OBJ
        ``vn`` lines (faces ``f a//a b//b c//c``). OFF and STL have no per-vertex normals: not written.
    precision : {"float64", "float32"}
        PLY's coordinate type: ``double`` (exact) or ``float`` (half the size, what MeshLab's float
        build and most viewers write). A :class:`PrecisionWarning` says when float32 moves a vertex by
        more than :data:`STL_TOLERANCE` mean edge lengths (a georeferenced scan), as for binary STL.

    Returns
    -------
    Path

    Raises
    ------
    MeshFileError
        Naming the file: bad arrays (NaN, bad indices), bad colours or normals, a point cloud as
        STL, ``precision="float32"`` for another format than PLY, or an OS error (permission, disk full).

    Examples
    --------
    >>> import tempfile, pathlib, numpy as np
    >>> p = pathlib.Path(tempfile.mkdtemp()) / "t.ply"
    >>> _ = save_mesh(p, np.eye(3), np.array([[0, 1, 2]]))
    >>> load_mesh(p).V.tolist()
    [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    """
    path = Path(path)
    _check_extension(path)
    try:
        V, F = check_mesh_arrays(V, F, allow_no_faces=True)
    except (MeshValidationError, TypeError) as exc:
        raise MeshFileError(f"{path}: cannot be written: {exc}") from None
    C = None
    if vertex_colors is not None:
        C = np.asarray(vertex_colors, dtype=np.float64)
        if C.shape not in ((V.shape[0], 3), (V.shape[0], 4)):
            raise MeshFileError(f"{path}: vertex_colors must have shape ({V.shape[0]}, 3 or 4), got {C.shape}")
        if not np.isfinite(C).all() or C.min() < 0 or C.max() > 1:
            raise MeshFileError(f"{path}: vertex_colors must lie in [0, 1], got values in [{C.min()}, {C.max()}]")
        if C.shape[1] == 3:
            C = np.hstack([C, np.ones((C.shape[0], 1))])
    ext = path.suffix.lower()
    if precision not in ("float64", "float32"):
        raise MeshFileError(f"{path}: precision must be 'float64' or 'float32', got {precision!r}")
    if precision == "float32" and ext != ".ply":
        raise MeshFileError(f"{path}: precision 'float32' is for PLY only (OBJ and OFF write 17 significant digits, "
                            "binary STL is always float32)")
    N = None
    if vertex_normals is not None:
        N = np.asarray(vertex_normals, dtype=np.float64)
        if N.shape != V.shape:
            raise MeshFileError(f"{path}: vertex_normals must have shape {V.shape}, got {N.shape}")
        if not np.isfinite(N).all():
            raise MeshFileError(f"{path}: vertex_normals must be finite")
    if ext == ".stl" and F.shape[0] == 0:
        raise MeshFileError(f"{path}: STL stores triangles only and this mesh has no faces; use .ply for a point cloud")
    if ext == ".stl" and binary:
        _warn_if_float32_moves(path, V, F)
    if ext == ".ply" and precision == "float32":
        _warn_if_float32_moves(path, V, F, "PLY (precision float32)", "save with precision float64")
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        more = (N, "f4" if precision == "float32" else "f8") if N is not None or precision == "float32" else ()
        _WRITERS[ext](fh, V, F, C, binary, extras, *more)
    return path


def float32_move(V: np.ndarray, F: np.ndarray) -> tuple[float, float]:
    """``(largest move, mean edge length)``: how far float32 rounding (binary STL) moves a vertex of a face of ``(V, F)``.

    >>> import numpy as np
    >>> V = np.array([[1e6, 0, 0], [1e6 + 1e-3, 0, 0], [1e6, 1e-3, 0]]) + 0.01
    >>> move, h = float32_move(V, np.array([[0, 1, 2]]))
    >>> bool(move > STL_TOLERANCE * h), bool(float32_move(V - 1e6, np.array([[0, 1, 2]]))[0] < STL_TOLERANCE * h)
    (True, False)
    """
    used = np.zeros(V.shape[0], dtype=bool)
    used[F.ravel()] = True
    U = V[used]
    move = float(np.sqrt((np.square(U - U.astype(np.float32).astype(np.float64))).sum(axis=1)).max()) if U.size else 0.0
    edges = [V[F[:, (k + 1) % 3]] - V[F[:, k]] for k in range(3)]
    h = float(np.mean([np.sqrt(np.square(e).sum(axis=1)).mean() for e in edges])) if F.size else 0.0
    return move, h


def _warn_if_float32_moves(path: Path, V: np.ndarray, F: np.ndarray, what: str = "binary STL",
                           keep: str = "write PLY (double) or ASCII STL") -> None:
    """Binary STL (or PLY asked for float32) stores float32: say so (:class:`PrecisionWarning`) when that moves a
    vertex by more than :data:`STL_TOLERANCE` mean edge lengths; the file is still written, as MeshLab writes it."""
    import warnings

    move, h = float32_move(V, F)
    if h > 0 and move > STL_TOLERANCE * h:
        warnings.warn(
            f"{path}: {what} stores float32 coordinates: vertices move by up to {move:.3g} "
            f"({move / h:.3g} mean edge lengths); {keep} to keep them",
            PrecisionWarning, stacklevel=3)


def save_arrays(path: str | os.PathLike, V: np.ndarray, F: np.ndarray, *, binary: bool = True) -> Path:
    """Write ``(V, F)`` to ``path`` (format from the extension) atomically; see :func:`save_mesh`."""
    return save_mesh(path, V, F, binary=binary)


def _rows_text(A: np.ndarray, fmt: str, prefix: str = "") -> bytes:
    if A.shape[0] == 0:
        return b""
    line = prefix + " ".join([fmt] * A.shape[1]) + "\n"
    return ((line * A.shape[0]) % tuple(A.ravel().tolist())).encode()


def _colour_bytes(C: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(C * 255.0), 0, 255).astype(np.uint8)


_PLY_TYPE_NAMES = {"i1": "char", "u1": "uchar", "i2": "short", "u2": "ushort", "i4": "int", "u4": "uint",
                   "f4": "float", "f8": "double"}
_ASCII_FORMAT = {"f4": "%.9g", "f8": "%.17g"}  # enough digits to read the same float back; integers: %d


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
        from .geometry import vertex_normals

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
    blocks = []
    for name, count, props, values in layout:
        if name == "vertex":
            head += [f"element vertex {len(V)}"] + _ply_columns(vcols)[0]
            blocks.append(_ply_table_bytes(vcols, vdata, len(V), binary))
        elif name == "face":
            head += [f"element face {len(F)}"] + _ply_columns(fcols)[0]
            blocks.append(_ply_table_bytes(fcols, fdata, len(F), binary))
        else:
            lines, data = _ply_element_bytes(count, props, values, binary)
            head += [f"element {name} {count}"] + lines
            blocks.append(data)
    head.append("end_header")
    fh.write(("\n".join(head) + "\n").encode())
    for block in blocks:
        fh.write(block)


def _write_off(fh, V, F, C, binary, extras=None, normals=None, coordinate="f8"):  # extras: PLY only; no normals
    fh.write(f"{'COFF' if C is not None else 'OFF'}\n{len(V)} {len(F)} 0\n".encode())
    if C is None:
        fh.write(_rows_text(V, "%.17g"))
    else:
        vals = np.empty((len(V), 7), dtype=object)
        vals[:, :3], vals[:, 3:] = V, _colour_bytes(C)
        fh.write((("%.17g %.17g %.17g %d %d %d %d\n" * len(V)) % tuple(vals.ravel().tolist())).encode())
    fh.write(_rows_text(np.hstack([np.full((len(F), 1), 3), F]), "%d"))


def _write_obj(fh, V, F, C, binary, extras=None, normals=None, coordinate="f8"):  # extras: PLY only
    fh.write(b"# written by meshdenoise\n")
    fh.write(_rows_text(V if C is None else np.hstack([V, C[:, :3]]), "%.17g", "v "))
    if normals is None:
        fh.write(_rows_text(F + 1, "%d", "f "))
        return
    fh.write(_rows_text(normals, "%.17g", "vn "))  # normal i is vertex i's: faces 'f a//a b//b c//c'
    if len(F):
        fh.write((("f %d//%d %d//%d %d//%d\n" * len(F)) % tuple(np.repeat(F + 1, 2, axis=1).ravel().tolist())).encode())


def _write_stl(fh, V, F, C, binary, extras=None, normals=None, coordinate="f8"):  # extras: PLY only; face normals
    from .geometry import face_normals

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


_WRITERS = {".off": _write_off, ".obj": _write_obj, ".ply": _write_ply, ".stl": _write_stl}

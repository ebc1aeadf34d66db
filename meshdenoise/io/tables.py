"""Number tables shared by the text readers (OFF, OBJ) and the polygon fans every reader makes; the text writers' rows."""

from __future__ import annotations

import re

import numpy as np

from .errors import _Malformed


_BLANK = re.compile(rb"[ \t\r\n\f\v]*")  # whitespace only (an empty file or element body)


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


def _rows_text(A: np.ndarray, fmt: str, prefix: str = "") -> bytes:
    if A.shape[0] == 0:
        return b""
    line = prefix + " ".join([fmt] * A.shape[1]) + "\n"
    return ((line * A.shape[0]) % tuple(A.ravel().tolist())).encode()


def _colour_bytes(C: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(C * 255.0), 0, 255).astype(np.uint8)

"""Legal oddities of a mesh read from a file, in words (:func:`topology_notes`): unreferenced vertices, duplicate faces..."""

from __future__ import annotations

import numpy as np


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

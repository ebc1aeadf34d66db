"""Legal oddities of a mesh read from a file, in words (:func:`topology_notes`): unreferenced vertices, duplicate faces..."""

from __future__ import annotations

import numpy as np

from ..meshinfo import repeated_faces, undirected_edges


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
    duplicates = repeated_faces(S, n)
    del S
    if duplicates:
        notes.append(f"{duplicates} duplicate faces (same vertices as an earlier face)")
    # an edge on 3+ face sides (degenerate sides left out), from the edges bucketed by their smaller vertex
    nonmanifold = int(np.count_nonzero(undirected_edges(F, n)[1] > 2))
    if nonmanifold:
        notes.append(f"{nonmanifold} non-manifold edges (shared by more than two faces)")
    return notes

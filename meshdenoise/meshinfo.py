"""Topology and size of a triangle mesh, for ``meshdenoise info``: all vectorised, no loop over vertices."""

from __future__ import annotations

import numpy as np

from .arrays import check_mesh_arrays
from .kernels import njit

__all__ = ["mesh_info", "undirected_edges", "repeated_faces"]


_CHUNK = 1 << 20  # faces per chunk of the per-face float work (bounded temporaries)


def _components(N: int, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Connected components of the undirected graph on nodes ``0..N-1`` with edges ``(a[i], b[i])``.

    Returns ``label (N,) int32``: the smallest node of each node's component. Min-label hooking
    with pointer jumping, all in numpy: memory is a few int32 arrays of the edge count (a sparse
    matrix and its transpose for scipy's routine would take several times more at millions of
    edges).

    Examples
    --------
    >>> _components(5, np.array([0, 3]), np.array([1, 4])).tolist()
    [0, 0, 2, 3, 3]
    """
    label = np.arange(N, dtype=np.int32)
    a = np.asarray(a, dtype=np.int32)
    b = np.asarray(b, dtype=np.int32)
    step = 1 << 22  # edges per chunk: the temporaries stay small whatever the graph's size
    while True:
        hooked = 0
        for c in range(0, a.size, step):
            la = label[a[c:c + step]]  # each label is a node of the same component, never a larger one
            lb = label[b[c:c + step]]
            differ = la != lb
            if not differ.any():
                continue
            la, lb = la[differ], lb[differ]
            hooked += la.size
            np.minimum.at(label, np.maximum(la, lb), np.minimum(la, lb))  # hook the larger onto the smaller
        if hooked == 0:  # every edge joins equal labels, all of them roots: done
            return label
        while True:  # pointer jumping: every node straight to its root
            nxt = label[label]
            if np.array_equal(nxt, label):
                break
            label = nxt
            del nxt


# --------------------------------------------------------------------------- edges by buckets, no global sort
@njit(cache=True, nogil=True)
def _bucket_sides(F, n, start):  # pragma: no cover - compiled
    """``start[v + 1]`` = the face sides ``(a, b)``, ``a != b``, whose smaller vertex is ``v``; then its running sum."""
    for f in range(F.shape[0]):
        for k in range(3):
            a, b = F[f, k], F[f, (k + 1) % 3]
            if a != b:
                start[min(a, b) + 1] += 1
    for v in range(n):
        start[v + 1] += start[v]


@njit(cache=True, nogil=True)
def _fill_buckets(F, start, other):  # pragma: no cover - compiled
    """Each side's larger vertex into its smaller vertex's bucket, each bucket sorted; returns the distinct count."""
    n = start.size - 1
    cursor = start[:-1].copy()
    for f in range(F.shape[0]):
        for k in range(3):
            a, b = F[f, k], F[f, (k + 1) % 3]
            if a != b:
                lo = min(a, b)
                other[cursor[lo]] = max(a, b)
                cursor[lo] += 1
    distinct = 0
    for v in range(n):
        s, e = start[v], start[v + 1]
        if e - s > 24:
            other[s:e].sort()
        else:  # a vertex has a handful of sides: insertion sort
            for i in range(s + 1, e):
                x = other[i]
                j = i - 1
                while j >= s and other[j] > x:
                    other[j + 1] = other[j]
                    j -= 1
                other[j + 1] = x
        for i in range(s, e):
            if i == s or other[i] != other[i - 1]:
                distinct += 1
    return distinct


@njit(cache=True, nogil=True)
def _bucket_edges(start, other, edges, counts):  # pragma: no cover - compiled
    """The distinct ``(v, other)`` pairs of the sorted buckets in order, and how many sides each has."""
    k = -1
    for v in range(start.size - 1):
        for i in range(start[v], start[v + 1]):
            if i == start[v] or other[i] != other[i - 1]:
                k += 1
                edges[k, 0] = v
                edges[k, 1] = other[i]
                counts[k] = 1
            else:
                counts[k] += 1


def undirected_edges(F: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """The unique undirected edges ``(e, 2)`` of the faces ``F`` on ``n`` vertices, ``edges[:, 0] < edges[:, 1]``,
    sorted by their first then second vertex, and how many face sides each has ``(e,) int32``.

    Sides ``(i, i)`` of degenerate faces are no edge. Edges int32 below 2^31 vertices. Built by putting each
    side into the bucket of its smaller vertex and sorting the buckets (a few entries each): O(m), with 4 or 8
    bytes per side, where sorting every side's key ``min * n + max`` took 2 s at 5M vertices and 16 bytes per side.

    Examples
    --------
    >>> import numpy as np
    >>> e, c = undirected_edges(np.array([[0, 1, 2], [0, 2, 3], [3, 3, 1]]), 4)
    >>> e.tolist(), c.tolist()
    ([[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]], [1, 2, 1, 1, 2, 1])
    """
    index = np.int32 if n < 2**31 - 1 else np.int64
    F = np.ascontiguousarray(F)
    if F.dtype not in (np.int32, np.int64):
        F = F.astype(np.int64)
    if F.size and (F.min() < 0 or F.max() >= n):
        raise IndexError(f"undirected_edges: face indices must lie in 0 .. {n - 1}, got {F.min()} .. {F.max()}")
    start = np.zeros(n + 1, dtype=np.int64)
    if F.shape[0] == 0 or n == 0:
        return np.zeros((0, 2), dtype=index), np.zeros(0, dtype=np.int32)
    _bucket_sides(F, n, start)
    other = np.empty(int(start[n]), dtype=index)
    distinct = _fill_buckets(F, start, other)
    edges = np.empty((distinct, 2), dtype=index)
    counts = np.empty(distinct, dtype=np.int32)
    _bucket_edges(start, other, edges, counts)
    return edges, counts


@njit(cache=True, nogil=True)
def _repeated_in_buckets(S, start, pair):  # pragma: no cover - compiled
    """Rows of ``S`` (each row sorted) equal to another: bucket rows by their first vertex, sort the buckets'
    ``(second, third)`` keys, count the repeats."""
    n = start.size - 1
    for f in range(S.shape[0]):
        start[S[f, 0] + 1] += 1
    for v in range(n):
        start[v + 1] += start[v]
    cursor = start[:-1].copy()
    for f in range(S.shape[0]):
        a = S[f, 0]
        pair[cursor[a]] = S[f, 1] * n + S[f, 2]
        cursor[a] += 1
    repeated = 0
    for v in range(n):
        s, e = start[v], start[v + 1]
        if e - s > 1:
            pair[s:e].sort()
            for i in range(s + 1, e):
                if pair[i] == pair[i - 1]:
                    repeated += 1
    return repeated


def repeated_faces(S: np.ndarray, n: int) -> int:
    """How many rows of ``S`` (m, 3), each sorted, values in ``0 .. n-1``, equal an earlier row (duplicate faces).

    Examples
    --------
    >>> import numpy as np
    >>> repeated_faces(np.array([[0, 1, 2], [0, 1, 2], [1, 2, 3], [0, 1, 2]]), 4)
    2
    """
    if S.shape[0] < 2:
        return 0
    if float(n) ** 2 >= 2.0**62:  # the (second, third) key would not fit an int64: rows sorted as they are
        R = S[np.lexsort((S[:, 2], S[:, 1], S[:, 0]))]
        return int((R[1:] == R[:-1]).all(axis=1).sum())
    return int(_repeated_in_buckets(np.ascontiguousarray(S), np.zeros(n + 1, dtype=np.int64),
                                    np.empty(S.shape[0], dtype=np.int64)))


def _side_keys(F: np.ndarray, n: int) -> np.ndarray:
    """``(m, 3) int64``: the undirected edge key ``min * n + max`` of each face side (side s: slots s, s+1)."""
    keys = np.empty((F.shape[0], 3), dtype=np.int64)
    for s in range(3):
        u, w = F[:, s], F[:, (s + 1) % 3]
        keys[:, s] = np.minimum(u, w) * n + np.maximum(u, w)  # 1-D keys: far faster than unique(axis=0)
    return keys


def _edge_table(F: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unique undirected edges ``(k, 2)`` (int32 below 2^31 vertices, sorted by key), the number of face
    sides on each ``(k,)``, and each face side's edge id ``(m, 3) int32`` (side ``s`` joins slots ``s``, ``s+1``).

    The keys are sorted in place and the side ids found by binary search chunk by chunk, so that
    the peak is about two int64 arrays of the side count, not the four of ``np.unique(return_inverse)``.
    """
    keys = _side_keys(F, n).reshape(-1)
    keys.sort()
    new = np.empty(keys.size, dtype=bool)
    new[0] = True
    np.not_equal(keys[1:], keys[:-1], out=new[1:])
    starts = np.flatnonzero(new)
    counts = np.diff(np.append(starts, keys.size))
    del starts
    uniq = keys[new]
    del keys, new
    side_edge = np.empty(F.shape, dtype=np.int32)
    for a in range(0, F.shape[0], _CHUNK):
        side_edge[a:a + _CHUNK] = np.searchsorted(uniq, _side_keys(F[a:a + _CHUNK], n))
    itype = np.int32 if n < 2**31 else np.int64
    edges = np.empty((uniq.size, 2), dtype=itype)
    edges[:, 0] = uniq // n
    edges[:, 1] = uniq % n
    return edges, counts, side_edge


def _fan_graph(F: np.ndarray, side_edge: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The half-edge graph whose components are the fans: one link ``(a, b)`` per corner (int32).

    Nodes are half-edges ``(edge e, endpoint v)``, numbered ``2 e + (v is the larger endpoint)``; the
    corner of face ``f`` at vertex ``v`` joins its two sides through ``v``. Two faces around ``v``
    sharing an edge through ``v`` share a node, so a vertex's fans are its nodes' components.
    """
    m = F.shape[0]
    a = np.empty(3 * m, dtype=np.int32)
    b = np.empty(3 * m, dtype=np.int32)
    for s in range(3):
        v, nxt, prv = F[:, s], F[:, (s + 1) % 3], F[:, (s + 2) % 3]
        a[s * m:(s + 1) * m] = 2 * side_edge[:, s] + (v > nxt)  # side s: (v, next)
        b[s * m:(s + 1) * m] = 2 * side_edge[:, (s + 2) % 3] + (v > prv)  # side s+2: (prev, v)
    return a, b


def _fans_per_vertex(a: np.ndarray, b: np.ndarray, edges: np.ndarray, n: int) -> np.ndarray:
    """Number of edge-connected fans of faces around each vertex (1 on a manifold vertex, 0 if
    unreferenced), from the graph of :func:`_fan_graph`."""
    N = 2 * edges.shape[0]
    used = np.zeros(N, dtype=bool)
    used[a] = True
    used[b] = True
    label = _components(N, a, b)
    fans = np.zeros(n, dtype=np.int64)
    for c in range(0, N, _CHUNK):  # a fan per root (a used node that is its own label), counted at its vertex
        root = used[c:c + _CHUNK] & (label[c:c + _CHUNK] == np.arange(c, min(c + _CHUNK, N), dtype=np.int32))
        node = np.flatnonzero(root) + c
        fans += np.bincount(edges[node >> 1, node & 1], minlength=n)
    return fans


def _finite_or_none(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def mesh_info(V: np.ndarray, F: np.ndarray) -> dict:
    """Counts and checks of a triangle mesh.

    Parameters
    ----------
    V : array_like, shape (n, 3)
    F : array_like, shape (m, 3)

    Returns
    -------
    dict
        ``vertices``, ``faces``, ``edges``, ``bbox_min``, ``bbox_max``, ``bbox_diagonal``,
        ``connected_components`` (of faces sharing vertices; unreferenced vertices not
        counted), ``unreferenced_vertices``, ``boundary_edges`` (on one face),
        ``boundary_loops`` (connected components of the boundary edges),
        ``non_manifold_edges`` (on three faces or more), ``non_manifold_vertices``
        (whose faces form more than one edge-connected fan), ``duplicate_vertices``
        (vertices at exactly the position of an earlier one), ``degenerate_faces``
        (zero area or a repeated vertex), ``closed`` (no boundary edge).
        Every float is finite (``bbox_diagonal`` is None when the diagonal exceeds the largest
        float), so ``json.dumps(info, allow_nan=False)`` always works.

    Examples
    --------
    >>> from meshdenoise.shapes import icosphere
    >>> info = mesh_info(*icosphere(1))
    >>> info["vertices"], info["faces"], info["boundary_loops"], info["closed"]
    (42, 80, 0, True)
    """
    V, F = check_mesh_arrays(V, F, allow_no_faces=True)
    n, m = V.shape[0], F.shape[0]
    info: dict = {"vertices": int(n), "faces": int(m)}
    if n:
        lo, hi = V.min(axis=0), V.max(axis=0)
        # scaled so that coordinates near the float limit do not overflow; None if the length itself does not fit
        scale = float(np.max(np.abs(np.concatenate([lo, hi]))))
        with np.errstate(over="ignore", invalid="ignore"):
            diag = float(np.linalg.norm(hi / scale - lo / scale)) * scale if scale > 0 else 0.0
        info.update(bbox_min=lo.tolist(), bbox_max=hi.tolist(), bbox_diagonal=_finite_or_none(diag))
    referenced = np.zeros(n, dtype=bool)
    referenced[F.reshape(-1)] = True
    info["unreferenced_vertices"] = int(n - referenced.sum())
    if m:
        edges, counts, side_edge = _edge_table(F, n)
        labels = _components(n, edges[:, 0], edges[:, 1])
        info["edges"] = int(len(edges))
        info["connected_components"] = int(np.unique(labels[referenced]).size)
        del labels
        border = edges[counts == 1]
        info["boundary_edges"] = int(len(border))
        if len(border):
            blabels = _components(n, border[:, 0], border[:, 1])
            info["boundary_loops"] = int(np.unique(blabels[np.unique(border)]).size)
            del blabels
        else:
            info["boundary_loops"] = 0
        info["non_manifold_edges"] = int((counts > 2).sum())
        del counts, border
        a, b = _fan_graph(F, side_edge)
        del side_edge
        info["non_manifold_vertices"] = int((_fans_per_vertex(a, b, edges, n) > 1).sum())
        del a, b, edges
        degenerate = 0
        # a power of two (exact) brings coordinates near the float limit down so that edges do not overflow
        big = float(np.abs(V).max()) if n else 0.0
        shrink = 2.0 ** -np.ceil(np.log2(big / 1e50)) if big > 1e50 else 1.0
        for a in range(0, m, _CHUNK):  # chunks: three (m, 3) float temporaries at once would be large
            Fc = F[a:a + _CHUNK]
            V0 = V[Fc[:, 0]] * shrink
            area2 = np.linalg.norm(np.cross(V[Fc[:, 1]] * shrink - V0, V[Fc[:, 2]] * shrink - V0), axis=1)
            repeated = (Fc[:, 0] == Fc[:, 1]) | (Fc[:, 1] == Fc[:, 2]) | (Fc[:, 0] == Fc[:, 2])
            degenerate += int(((area2 == 0) | repeated).sum())
        info["degenerate_faces"] = degenerate
    else:
        info.update(edges=0, connected_components=0, boundary_edges=0, boundary_loops=0,
                    non_manifold_edges=0, non_manifold_vertices=0, degenerate_faces=0)
    if n:
        order = np.lexsort(V.T[::-1])
        S = V[order]
        del order
        info["duplicate_vertices"] = int((S[1:] == S[:-1]).all(axis=1).sum())
    else:
        info["duplicate_vertices"] = 0
    info["closed"] = bool(m and info["boundary_edges"] == 0)
    return info

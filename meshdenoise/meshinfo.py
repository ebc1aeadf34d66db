"""Topology and size of a triangle mesh, for ``meshdenoise info``: all vectorised, no loop over vertices."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from .arrays import check_mesh_arrays

__all__ = ["mesh_info"]


def _edge_table(F: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unique undirected edges ``(k, 2)``, the number of faces on each, and each face side's edge id ``(m, 3)``."""
    sides = np.stack([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]], axis=1).reshape(-1, 2)
    sides.sort(axis=1)
    n = int(F.max()) + 1
    keys, inverse, counts = np.unique(sides[:, 0] * n + sides[:, 1], return_inverse=True, return_counts=True)
    edges = np.stack([keys // n, keys % n], axis=1)  # 1-D keys: far faster than unique(axis=0)
    return edges, counts, inverse.reshape(-1, 3)


def _fans_per_vertex(F: np.ndarray, side_edge: np.ndarray, n: int) -> np.ndarray:
    """Number of edge-connected fans of faces around each vertex (1 on a manifold vertex, 0 if unreferenced).

    Nodes are the corners (face, vertex); two corners of one vertex are joined when their
    faces share an edge through that vertex. A vertex's fans are its corners' components.
    """
    m = F.shape[0]
    corner = np.arange(3 * m).reshape(m, 3)  # corner id of (face f, slot s)
    # Side s of a face joins slots s and s+1; record (edge id, vertex, corner) for both ends.
    e = np.repeat(side_edge, 2, axis=1).reshape(-1)  # per (face, side, end)
    slots = np.array([[0, 1], [1, 2], [2, 0]])
    faces = np.repeat(np.arange(m), 6)
    slot = np.tile(slots.reshape(-1), m)
    vert = F[faces, slot]
    node = corner[faces, slot]
    # Sort by (edge, vertex): consecutive entries with the same key belong to faces sharing that edge.
    order = np.argsort(e * n + vert, kind="stable")
    e, vert, node = e[order], vert[order], node[order]
    same = (e[1:] == e[:-1]) & (vert[1:] == vert[:-1])
    a, b = node[:-1][same], node[1:][same]
    G = sp.coo_matrix((np.ones(a.size), (a, b)), shape=(3 * m, 3 * m))
    _, labels = connected_components(G, directed=False)
    corner_vertex = F.reshape(-1)
    pairs = np.unique(corner_vertex.astype(np.int64) * (3 * m) + labels)
    return np.bincount(pairs // (3 * m), minlength=n)


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
        info.update(bbox_min=lo.tolist(), bbox_max=hi.tolist(), bbox_diagonal=float(np.linalg.norm(hi - lo)))
    referenced = np.zeros(n, dtype=bool)
    referenced[F.reshape(-1)] = True
    info["unreferenced_vertices"] = int(n - referenced.sum())
    if m:
        edges, counts, side_edge = _edge_table(F)
        A = sp.coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n))
        n_comp, labels = connected_components(A, directed=False)
        info["edges"] = int(len(edges))
        info["connected_components"] = int(np.unique(labels[referenced]).size)
        border = edges[counts == 1]
        info["boundary_edges"] = int(len(border))
        if len(border):
            B = sp.coo_matrix((np.ones(len(border)), (border[:, 0], border[:, 1])), shape=(n, n))
            _, blabels = connected_components(B, directed=False)
            info["boundary_loops"] = int(np.unique(blabels[np.unique(border)]).size)
        else:
            info["boundary_loops"] = 0
        info["non_manifold_edges"] = int((counts > 2).sum())
        info["non_manifold_vertices"] = int((_fans_per_vertex(F, side_edge, n) > 1).sum())
        area2 = np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
        repeated = (F[:, 0] == F[:, 1]) | (F[:, 1] == F[:, 2]) | (F[:, 0] == F[:, 2])
        info["degenerate_faces"] = int(((area2 == 0) | repeated).sum())
    else:
        info.update(edges=0, connected_components=0, boundary_edges=0, boundary_loops=0,
                    non_manifold_edges=0, non_manifold_vertices=0, degenerate_faces=0)
    if n:
        order = np.lexsort(V.T[::-1])
        S = V[order]
        info["duplicate_vertices"] = int((S[1:] == S[:-1]).all(axis=1).sum())
    else:
        info["duplicate_vertices"] = 0
    info["closed"] = bool(m and info["boundary_edges"] == 0)
    return info

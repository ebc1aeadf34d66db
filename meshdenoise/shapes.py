"""Meshes the project generates itself: spheres, planes with boundary, tori, boxes.

Used by the tests (every filter runs on them when the third-party meshes are absent),
the examples and the benchmarks. All return ``(V (n, 3) float64, F (m, 3) int64)`` with
consistently oriented faces (outward normals for closed surfaces).
"""

from __future__ import annotations

import numpy as np

__all__ = ["icosphere", "grid", "torus", "box"]


def icosphere(subdivisions: int = 3, radius: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """A geodesic sphere: the icosahedron split ``subdivisions`` times, 10 * 4^s + 2 vertices.

    Examples
    --------
    >>> V, F = icosphere(2)
    >>> V.shape, F.shape
    ((162, 3), (320, 3))
    """
    if not isinstance(subdivisions, (int, np.integer)) or subdivisions < 0:
        raise ValueError(f"icosphere: subdivisions must be an int >= 0, got {subdivisions!r}")
    t = (1.0 + 5**0.5) / 2.0
    V = np.array(
        [[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t],
         [0, -1, -t], [0, 1, -t], [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]], dtype=np.float64)
    F = np.array(
        [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4], [11, 10, 2],
         [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9], [4, 9, 5],
         [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]], dtype=np.int64)
    V /= np.linalg.norm(V, axis=1, keepdims=True)
    for _ in range(int(subdivisions)):
        edges = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
        uniq, inverse = np.unique(edges, axis=0, return_inverse=True)
        mids = V[uniq].mean(axis=1)
        mids /= np.linalg.norm(mids, axis=1, keepdims=True)
        m = F.shape[0]
        e01, e12, e20 = (inverse[k * m:(k + 1) * m].ravel() + V.shape[0] for k in range(3))
        V = np.vstack([V, mids])
        F = np.vstack([
            np.stack([F[:, 0], e01, e20], 1), np.stack([F[:, 1], e12, e01], 1),
            np.stack([F[:, 2], e20, e12], 1), np.stack([e01, e12, e20], 1),
        ])
    return V * radius, F


def grid(nx: int = 10, ny: int = 10, size: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """A flat square in the z = 0 plane, ``nx`` x ``ny`` vertices, open (with a boundary).

    Examples
    --------
    >>> V, F = grid(3, 3)
    >>> V.shape, F.shape
    ((9, 3), (8, 3))
    """
    if nx < 2 or ny < 2:
        raise ValueError(f"grid: nx and ny must be >= 2, got {nx}, {ny}")
    x, y = np.meshgrid(np.linspace(0, size, nx), np.linspace(0, size, ny), indexing="xy")
    V = np.stack([x.ravel(), y.ravel(), np.zeros(nx * ny)], axis=1)
    idx = np.arange(nx * ny).reshape(ny, nx)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    F = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]).astype(np.int64)
    return V, F


def torus(n_major: int = 24, n_minor: int = 12, major: float = 1.0, minor: float = 0.35) -> tuple[np.ndarray, np.ndarray]:
    """A closed torus of genus 1 (``n_major * n_minor`` vertices).

    Examples
    --------
    >>> V, F = torus(8, 4)
    >>> V.shape, F.shape
    ((32, 3), (64, 3))
    """
    if n_major < 3 or n_minor < 3:
        raise ValueError(f"torus: n_major and n_minor must be >= 3, got {n_major}, {n_minor}")
    u = np.linspace(0, 2 * np.pi, n_major, endpoint=False)
    v = np.linspace(0, 2 * np.pi, n_minor, endpoint=False)
    uu, vv = np.meshgrid(u, v, indexing="ij")
    r = major + minor * np.cos(vv)
    V = np.stack([r * np.cos(uu), r * np.sin(uu), minor * np.sin(vv)], axis=-1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(n_major), np.arange(n_minor), indexing="ij")
    a = i * n_minor + j
    b = ((i + 1) % n_major) * n_minor + j
    c = ((i + 1) % n_major) * n_minor + (j + 1) % n_minor
    d = i * n_minor + (j + 1) % n_minor
    F = np.concatenate([np.stack([a.ravel(), b.ravel(), c.ravel()], 1), np.stack([a.ravel(), c.ravel(), d.ravel()], 1)])
    return V, F.astype(np.int64)


def box(n: int = 8, size: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """A closed cube surface with sharp edges, each face an ``n`` x ``n`` grid (shared edges merged).

    Examples
    --------
    >>> V, F = box(3)
    >>> V.shape, F.shape
    ((26, 3), (48, 3))
    """
    if n < 2:
        raise ValueError(f"box: n must be >= 2, got {n}")
    gv, gf = grid(n, n, 1.0)
    parts_v, parts_f, offset = [], [], 0
    # each side maps the unit square (u, v) into 3D; orientation is fixed below
    zero, one = (lambda p: np.zeros(len(p))), (lambda p: np.ones(len(p)))
    sides = [
        lambda p: np.stack([p[:, 0], p[:, 1], zero(p)], 1),
        lambda p: np.stack([p[:, 0], p[:, 1], one(p)], 1),
        lambda p: np.stack([p[:, 0], zero(p), p[:, 1]], 1),
        lambda p: np.stack([p[:, 0], one(p), p[:, 1]], 1),
        lambda p: np.stack([zero(p), p[:, 0], p[:, 1]], 1),
        lambda p: np.stack([one(p), p[:, 0], p[:, 1]], 1),
    ]
    for side in sides:
        parts_v.append(side(gv[:, :2]))
        parts_f.append(gf + offset)
        offset += gv.shape[0]
    V = np.vstack(parts_v)
    F = np.vstack(parts_f)
    key = np.round(V * (n - 1)).astype(np.int64)
    uniq, inverse = np.unique(key, axis=0, return_inverse=True)
    F = inverse.ravel()[F]
    V = uniq.astype(np.float64) / (n - 1)
    # orient every face outwards: flip those whose normal points towards the centre
    centre = np.full(3, 0.5)
    nrm = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    flip = np.einsum("ij,ij->i", nrm, V[F].mean(axis=1) - centre) < 0
    F[flip] = F[flip][:, [0, 2, 1]]
    return V * size, F

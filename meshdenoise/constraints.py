"""Options every filter shares: pinned vertices, a region that may move, volume preservation.

``pinned`` vertices never move; outside ``region`` nothing moves. Both become one mask
of *fixed* vertices that each filter imposes as Dirichlet data (iterative filters use an
operator whose fixed rows are identity rows; Sobolev solves the reduced system on the
free vertices), and the registry copies fixed coordinates back bit for bit.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .geometry import signed_volume

__all__ = ["fixed_mask", "vertex_mask", "restore_volume", "check_encloses_volume"]


def vertex_mask(spec: Any, n: int, what: str, ops=None, data=None) -> np.ndarray:
    """Turn a vertex specification into a boolean mask of length ``n``.

    ``spec`` is a boolean mask (n,), an array of vertex indices, ``"boundary"`` (vertices
    on a boundary edge) or ``"selection"`` (the current pymeshlab vertex selection).
    """
    if isinstance(spec, str):
        if spec == "boundary" and ops is not None:
            return ops.boundary_vertices.copy()
        if spec == "selection" and data is not None:
            sel = data.selection()
            if sel.shape != (n,):
                raise ValueError(f"{what}='selection': the selection has {sel.shape[0]} vertices, the mesh {n}")
            if not sel.any():  # pinning nothing, or letting nothing move, is never what was meant
                raise ValueError(f"{what}='selection': the mesh has no selected vertex")
            return sel
        allowed = "'boundary', 'selection'" if what == "pinned" else "'selection'"
        raise ValueError(f"{what}={spec!r} is not understood: use a boolean mask, vertex indices, or {allowed}")
    arr = np.asarray(spec)
    if arr.dtype == bool:
        if arr.shape != (n,):
            raise ValueError(f"{what}: a boolean mask must have one entry per vertex ({n}), got shape {arr.shape}")
        return arr.copy()
    if arr.size == 0:
        return np.zeros(n, dtype=bool)
    if not np.issubdtype(arr.dtype, np.integer) or arr.ndim != 1:
        raise TypeError(f"{what} must be a boolean mask, a 1-D array of vertex indices or a keyword; got {spec!r:.80}")
    bad = arr[(arr < 0) | (arr >= n)]
    if bad.size:  # a negative index would wrap around (-1: the last vertex): refused like any other out of range
        raise ValueError(f"{what}: vertex index {int(bad[0])} is out of range 0..{n - 1} "
                         f"({bad.size} of {arr.size} indices outside it; min {int(arr.min())}, max {int(arr.max())})")
    mask = np.zeros(n, dtype=bool)
    mask[arr] = True
    return mask


def fixed_mask(ops, pinned: Any, region: Any, data) -> np.ndarray | None:
    """The mask of vertices a filter must keep where they are, or ``None`` if all may move."""
    n = ops.n
    fixed = np.zeros(n, dtype=bool)
    if pinned is not None:
        fixed |= vertex_mask(pinned, n, "pinned", ops, data)
    if region is not None:
        if isinstance(region, str) and region == "boundary":
            raise ValueError("region='boundary' is not supported: use pinned='boundary' to keep the boundary fixed")
        fixed |= ~vertex_mask(region, n, "region", ops, data)
    return fixed if fixed.any() else None


def check_encloses_volume(V: np.ndarray, F: np.ndarray) -> float:
    """The signed volume :func:`restore_volume` keeps; ``ValueError`` when the mesh encloses none (flat or empty).

    >>> import numpy as np
    >>> check_encloses_volume(np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]), np.array([[0, 1, 2]]))
    Traceback (most recent call last):
    ...
    ValueError: preserve_volume: the input encloses no volume (flat or empty mesh); leave out preserve_volume
    """
    vol0 = signed_volume(V, F, V.mean(axis=0)) if len(V) else 0.0
    if not abs(vol0) >= 1e-300:
        raise ValueError("preserve_volume: the input encloses no volume (flat or empty mesh); leave out preserve_volume")
    return vol0


def _det_terms(a, b, c):
    return np.einsum("ij,ij->i", a, np.cross(b, c)).sum()


def restore_volume(V0: np.ndarray, V1: np.ndarray, F: np.ndarray, fixed: np.ndarray | None) -> np.ndarray:
    """Scale the movable vertices of ``V1`` about their centroid so the enclosed volume equals ``V0``'s.

    The volume of ``V(s) = c + s (V1 - c)`` on movable vertices (fixed ones unchanged) is
    a cubic in ``s``; we take its positive root closest to 1. On a closed mesh with no
    fixed vertex this is ``s = (vol0 / vol1)^(1/3)``. On an open mesh the volume is that
    of the cone from the input's vertex centroid to the surface, which depends on that
    choice of apex: a weaker guarantee, documented in the README.

    Raises
    ------
    ValueError
        If the filtered volume is zero or of the other sign, or no positive scale works.
    """
    origin = V0.mean(axis=0)
    vol0 = check_encloses_volume(V0, F)
    movable = np.ones(V0.shape[0], dtype=bool) if fixed is None else ~fixed
    if not movable.any():
        return V1
    c = V1[movable].mean(axis=0)
    P0 = np.where(movable[:, None], c, V1) - origin  # constant part of each vertex
    P1 = np.where(movable[:, None], V1 - c, 0.0)  # part multiplied by s
    a0, b0, c0 = (P0[F[:, k]] for k in range(3))
    a1, b1, c1 = (P1[F[:, k]] for k in range(3))
    k0 = _det_terms(a0, b0, c0)
    k1 = _det_terms(a1, b0, c0) + _det_terms(a0, b1, c0) + _det_terms(a0, b0, c1)
    k2 = _det_terms(a1, b1, c0) + _det_terms(a1, b0, c1) + _det_terms(a0, b1, c1)
    k3 = _det_terms(a1, b1, c1)
    coeffs = np.array([k3, k2, k1, k0 - 6.0 * vol0]) / 6.0
    roots = np.roots(coeffs) if np.any(coeffs[:3]) else np.array([])
    real = roots[np.abs(roots.imag) < 1e-9 * np.maximum(1.0, np.abs(roots.real))].real
    real = real[real > 0]
    if real.size == 0:
        raise ValueError(
            f"preserve_volume: no positive scale restores the volume {vol0:.6g} "
            f"(the filtered mesh encloses {k0 + k1 + k2 + k3:.6g} / 6)"
        )
    s = real[np.argmin(np.abs(real - 1.0))]
    for _ in range(3):  # Newton polish of the root
        f = np.polyval(coeffs, s)
        df = np.polyval(np.polyder(coeffs), s)
        if df == 0:
            break
        s -= f / df
    out = V1.copy()
    out[movable] = c + s * (V1[movable] - c)
    return out

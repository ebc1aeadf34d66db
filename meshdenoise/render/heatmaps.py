"""What the heat maps show: each vertex's error against a reference (or change from the first mesh), its colour.

Also the meshes drawn, read from any mesh type or file (:func:`_arrays`), and where the colour
bar tops (:func:`_default_vmax`, :func:`_bar_top`).
"""

from __future__ import annotations

import os
from typing import Any, Sequence

import numpy as np

from ..adapters import read_mesh
from ..io import load_mesh

__all__ = ["vertex_error", "error_colors", "ERROR_MODES"]

ERROR_MODES = ("auto", "vertex", "nearest")


def vertex_error(mesh: Any, reference: Any, mode: str = "auto") -> tuple[np.ndarray, str]:
    """Per-vertex error of ``mesh`` against ``reference``.

    Parameters
    ----------
    mesh, reference : a ``(V, F)`` tuple, any mesh type of :func:`meshdenoise.adapters.read_mesh`, or a file path
    mode : {'auto', 'vertex', 'nearest'}
        ``'vertex'``: :math:`e_i = \\|x_i - y_i\\|`, the displacement of vertex *i* from the
        reference's vertex *i* (the meshes must share vertex order, as noisy and denoised
        copies of one mesh do). ``'nearest'``: :math:`e_i = \\min_{y \\in S} \\|x_i - y\\|`, the
        distance to the nearest point of the reference surface *S* (Open3D's
        ``RaycastingScene.compute_distance``, in float32). ``'auto'``: ``'vertex'`` when both
        meshes have the same faces (hence the same vertex order), else ``'nearest'``.

    Returns
    -------
    error : ndarray, shape (n,), float64
    mode : str
        The mode used.

    Examples
    --------
    >>> import numpy as np
    >>> V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]); F = np.array([[0, 1, 2]])
    >>> err, how = vertex_error((V + [0, 0, 0.5], F), (V, F))
    >>> err.tolist(), how
    ([0.5, 0.5, 0.5], 'vertex')
    >>> err, how = vertex_error((V[[1, 2, 0]] + [0, 0, 0.25], F), (V, F), mode="nearest")
    >>> np.round(err, 6).tolist(), how
    ([0.25, 0.25, 0.25], 'nearest')
    """
    if mode not in ERROR_MODES:
        raise ValueError(f"error mode must be one of {ERROR_MODES}, got {mode!r}")
    V, F = _arrays(mesh, "mesh")
    Vr, Fr = _arrays(reference, "reference")
    if mode == "auto":
        mode = "vertex" if F.shape == Fr.shape and np.array_equal(F, Fr) else "nearest"
    if mode == "vertex":
        if V.shape != Vr.shape:
            raise ValueError(
                f"error mode 'vertex' needs the same vertices in the same order: the mesh has {V.shape[0]} "
                f"vertices, the reference {Vr.shape[0]}; use mode='nearest'"
            )
        return np.linalg.norm(V - Vr, axis=1), mode
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(Vr.astype(np.float32)), o3d.core.Tensor(Fr.astype(np.uint32)))
    dist = scene.compute_distance(o3d.core.Tensor(V.astype(np.float32))).numpy()
    return dist.astype(np.float64), mode


def error_colors(error: np.ndarray, vmax: float, cmap: str = "viridis") -> np.ndarray:
    """RGB colours ``(n, 3)`` in [0, 1] of errors on the colour bar from 0 to ``vmax``.

    Errors above ``vmax`` take the top colour; the colour bar then shows an arrow (it is
    drawn with ``extend='max'``), so a saturated picture is never mistaken for a scale.

    Examples
    --------
    >>> error_colors(np.array([0.0, 1.0]), vmax=1.0, cmap="gray").tolist()
    [[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]]
    """
    import matplotlib

    err = np.asarray(error, dtype=np.float64)
    if not np.isfinite(vmax) or vmax <= 0:
        raise ValueError(f"vmax must be a finite number > 0, got {vmax!r}")
    if err.size and (not np.isfinite(err).all() or err.min() < 0):
        raise ValueError("errors must be finite and >= 0")
    return matplotlib.colormaps[cmap](np.clip(err / vmax, 0.0, 1.0))[:, :3]


def _arrays(mesh: Any, what: str) -> tuple[np.ndarray, np.ndarray]:
    """(V, F) of a mesh object or file; a mesh without faces cannot be drawn."""
    if isinstance(mesh, (str, os.PathLike)):
        m = load_mesh(mesh)
        V, F = m.V, m.F
        if F.shape[0] == 0:
            raise ValueError(f"{mesh}: {what} has no faces, so there is no surface to render")
        return V, F
    data = read_mesh(mesh)
    return data.V, data.F


def _default_vmax(errors: Sequence[np.ndarray]) -> float:
    """The largest error shown; a tiny positive scale when all are zero (identical meshes)."""
    top = max((float(e.max()) for e in errors if e.size), default=0.0)
    return top if top > 0 else 1e-12


def _bar_top(values: Sequence[np.ndarray], percentile: float) -> float:
    """The ``percentile`` of all shown values; the maximum when that is 0; a tiny scale when all are 0."""
    every = np.concatenate([np.ravel(v) for v in values]) if values else np.zeros(0)
    if every.size == 0:
        return 1e-12
    top = float(np.percentile(every, percentile))
    if top <= 0:
        top = float(every.max())
    return top if top > 0 else 1e-12

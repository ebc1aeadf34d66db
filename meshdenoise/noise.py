"""The paper's noise model: Gaussian displacement along vertex normals."""

from __future__ import annotations

from typing import Any

import numpy as np

from .adapters import read_mesh
from .geometry import vertex_normals

__all__ = ["add_normal_noise"]


def add_normal_noise(mesh: Any, rho: float, seed: int | np.random.Generator | None = None) -> Any:
    """Displace every vertex along its normal by Gaussian noise of standard deviation ``rho``.

    .. math:: x_i = x^0_i + \\rho\\, \\varepsilon_i N_i, \\qquad \\varepsilon_i \\sim \\mathcal N(0, 1)

    with :math:`N_i` the normalised sum of the unit normals of the faces around vertex
    ``i`` (:func:`meshdenoise.geometry.vertex_normals`). ``rho`` is absolute (in the
    mesh's units). A vertex with a zero normal (isolated, or normals cancelling) is not
    moved. Returns the same mesh type as the input, like the filters (a MeshSet is
    changed in place).

    Parameters
    ----------
    mesh : (V, F) tuple, pymeshlab.MeshSet or Mesh, or open3d.geometry.TriangleMesh
    rho : float, >= 0
        Noise amplitude.
    seed : int or numpy.random.Generator, optional
        Same seed, same noise.

    Examples
    --------
    >>> import numpy as np
    >>> V = np.array([[0., 0, 0], [1, 0, 0], [0, 1, 0]])
    >>> Vn, _ = add_normal_noise((V, np.array([[0, 1, 2]])), rho=0.1, seed=0)
    >>> bool(np.allclose(Vn[:, :2], V[:, :2]))  # a flat triangle moves along z only
    True
    """
    if isinstance(rho, (bool, np.bool_)) or not isinstance(rho, (int, float, np.integer, np.floating)):
        raise TypeError(f"add_normal_noise: rho must be a number, got {rho!r}")
    if not (np.isfinite(rho) and rho >= 0):
        raise ValueError(f"add_normal_noise: parameter 'rho' = {rho!r} is out of range: rho >= 0")
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    data = read_mesh(mesh)
    N = vertex_normals(data.V, data.F)
    eps = rng.standard_normal(data.V.shape[0])
    return data.write(data.V + float(rho) * eps[:, None] * N)

"""The OT mesh denoiser: barycentric projection of the entropic self-transport plan (the ``sinkhorn`` filter's core)."""

from __future__ import annotations

import numbers

import numpy as np

from ..geometry import lumped_mass
from .checks import _mesh_arrays, _positive_float, _positive_int
from .kernels import MeshHeatKernel
from .scaling import symmetric_sinkhorn


def ot_denoise(
    V,
    F,
    t=10.0,
    iterations=3,
    laplacian="graph",
    measure="uniform",
    debias=True,
    steps=1,
    pinned=None,
    stopThr=1e-10,
    numItermax=500,
    cache=None,
):
    r"""OT mesh denoiser: barycentric projection of the entropic self-transport plan.

    One iteration, on the current vertex positions :math:`X` (n, 3):

    1. heat kernel :math:`G = (I + tL)^{-1}` (or its ``steps``-fold split
       :math:`(I + \tfrac{t}{s}L)^{-s}`; symmetric, positive, applied by
       a cached sparse Cholesky factor, never formed), :math:`L` the graph
       Laplacian :math:`D - W` or the cotangent Laplacian of :math:`X`;
    2. vertex measure :math:`m` (``"uniform"``: ones; ``"area"``: lumped
       vertex areas of :math:`X`, scaled to mean 1);
    3. symmetric Sinkhorn (:func:`symmetric_sinkhorn`): :math:`u` with
       :math:`u \odot G u = m`, so :math:`P = \mathrm{diag}(u) G \mathrm{diag}(u)`
       is the entropic OT plan of :math:`m` to itself (:math:`P1 = P^T1 = m`);
    4. barycentric projection :math:`T X = \mathrm{diag}(m)^{-1} P X`
       (each vertex moves to the :math:`P`-weighted mean of the others), and
       with ``debias`` the twicing correction

    .. math::
        X \leftarrow 2\,TX - T(TX) = X - (I - T)^2 X,

    which removes the first-order shrinkage (blur) of :math:`T`.
    Vertices in ``pinned`` are reset to their input position after each
    iteration; with ``measure="area"`` a vertex of zero area (isolated, or
    only in degenerate faces) carries no mass and stays put.
    Since :math:`T1 = 1` the result is translation equivariant.
    With ``measure="uniform"`` :math:`G1 = 1` already, so :math:`u = 1` and
    :math:`T = G` (implicit graph/cotangent smoothing); ``"area"`` gives a
    genuinely rescaled plan.

    Parameters
    ----------
    V : array_like, shape (n, 3)
        Noisy vertex positions.
    F : array_like of int, shape (m, 3)
        Triangles.
    t : float
        Diffusion time (> 0), in squared edge hops (both Laplacians are
        scale-free with the identity mass).
    iterations : int
        Number of iterations (>= 0).
    laplacian : {"graph", "cotangent"}
        Laplacian of the heat kernel.
    measure : {"uniform", "area"}
        Vertex measure :math:`m`.
    debias : bool
        Apply the twicing correction.
    steps : int
        Backward-Euler substeps of the heat kernel (:class:`MeshHeatKernel`).
    pinned : array_like of bool, shape (n,), optional
        Vertices that must not move.
    stopThr, numItermax
        Tolerance and iteration cap of the Sinkhorn scaling.
    cache : dict, optional
        Where the Cholesky factor of the graph kernel is kept between calls
        (it depends only on the topology and ``t``).

    Returns
    -------
    Y : ndarray, shape (n, 3)
        Denoised vertex positions.

    References
    ----------
    A. Vaillant-Tenzer, "Mesh Denoising", 2022 (OT section).  Solomon et al.,
    "Convolutional Wasserstein distances", 2015.  Landa, Coifman, Kluger,
    "Doubly stochastic normalization of the Gaussian kernel is robust to
    heteroskedastic noise", SIAM J. Math. Data Sci. 3(1), 2021.  J. Tukey,
    "Exploratory data analysis" (twicing), 1977.

    Examples
    --------
    >>> import numpy as np
    >>> V = np.array([[0., 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    >>> F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    >>> Y = ot_denoise(V, F, t=1.0, iterations=1)
    >>> np.allclose(Y.mean(0), V.mean(0))
    True
    """
    V, F = _mesh_arrays(V, F)
    t = _positive_float("t", t)
    if isinstance(iterations, bool) or not isinstance(iterations, numbers.Integral) or iterations < 0:
        raise ValueError(f"iterations must be an integer >= 0, got {iterations!r}")
    if laplacian not in ("graph", "cotangent"):
        raise ValueError(f"laplacian must be 'graph' or 'cotangent', got {laplacian!r}")
    if measure not in ("uniform", "area"):
        raise ValueError(f"measure must be 'uniform' or 'area', got {measure!r}")
    if not isinstance(debias, (bool, np.bool_)):
        raise TypeError(f"debias must be True or False, got {debias!r}")
    steps = _positive_int("steps", steps)
    n = V.shape[0]
    if pinned is not None:
        pinned = np.asarray(pinned)
        if pinned.shape != (n,) or pinned.dtype != bool:
            raise ValueError(f"pinned must be a bool array of shape ({n},), got {pinned.dtype} {pinned.shape}")
    if cache is None:
        cache = {}
    X0 = V
    X = V.copy()
    for _ in range(int(iterations)):
        if laplacian == "graph":
            key = ("ot_denoise.graph_heat", t, steps)
            if key not in cache:
                cache[key] = MeshHeatKernel(X, F, t, laplacian="graph", mass="uniform", steps=steps)
            K = cache[key]
        else:
            K = MeshHeatKernel(X, F, t, laplacian="cotangent", mass="uniform", steps=steps)
        if measure == "uniform":
            m = np.ones(n)
        else:
            m = lumped_mass(X, F)
            if not np.any(m > 0):
                raise ValueError("every vertex has zero area; use measure='uniform'")
            m = m / m[m > 0].mean()
        u, _ = symmetric_sinkhorn(K.solve, m, numItermax=numItermax, stopThr=stopThr)
        um = u[:, None]
        live = m > 0  # a vertex without mass has nothing to transport: it stays put
        inv_m = np.zeros((n, 1))
        inv_m[live, 0] = 1.0 / m[live]

        def T(Z):
            TZ = inv_m * (um * K.solve(um * Z))
            TZ[~live] = Z[~live]
            return TZ

        TX = T(X)
        X = 2.0 * TX - T(TX) if debias else TX
        if pinned is not None:
            X[pinned] = X0[pinned]
    return X

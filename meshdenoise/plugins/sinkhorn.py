"""OT denoising: barycentric projection of the entropic self-transport plan under a mesh heat kernel."""

from __future__ import annotations

from ..ot import ot_denoise
from ..registry import MAX_ITERATIONS, AutoRule, Param, register
from .sinkhorn_rule import SINKHORN_NORMALS, choose_sinkhorn

__all__ = ["sinkhorn"]


@register(
    "sinkhorn",
    auto=AutoRule(("t", "iterations"), choose_sinkhorn, normals="t", held_out=SINKHORN_NORMALS),
    summary="OT: move each vertex to its barycentric projection under the Sinkhorn-scaled heat-kernel plan",
    params=[
        Param("t", float, 10.0, low=0.0, low_open=True, help="diffusion time of the heat kernel (I + tL)^-1"),
        Param("iterations", int, 3, low=0, high=MAX_ITERATIONS, help="number of projections"),
        Param("laplacian", str, "graph", choices=("graph", "cotangent"), help="Laplacian of the heat kernel"),
        Param("measure", str, "uniform", choices=("uniform", "area"), help="vertex measure m of the plan"),
        Param("debias", bool, True, help="twicing X <- 2TX - T(TX) against shrinkage"),
        Param("steps", int, 1, low=1, high=1000, help="backward-Euler substeps of the heat kernel"),
    ],
    linear=False,
    translation_equivariant=True,
)
def sinkhorn(V, F, *, ops, pinned, t, iterations, laplacian, measure, debias, steps):
    """OT mesh denoiser (the paper's 4th method, with heat kernels on the mesh).

    One iteration, with :math:`X` the current positions (n, 3):

    .. math::
        G = (I + tL)^{-1}, \\qquad u \\odot G u = m, \\qquad
        P = \\mathrm{diag}(u)\\, G\\, \\mathrm{diag}(u), \\qquad
        T X = \\mathrm{diag}(m)^{-1} P X, \\qquad
        X \\leftarrow 2\\,TX - T(TX)

    :math:`L` is the graph Laplacian :math:`D - W` (or the cotangent Laplacian of
    :math:`X`), :math:`G` the heat kernel, applied through a sparse Cholesky factor
    cached per topology (never an (n, n) dense matrix), :math:`m` the vertex measure
    (ones, or the lumped areas of :math:`X` scaled to mean 1), :math:`u` the symmetric
    Sinkhorn scaling (pinned point :math:`u \\leftarrow \\sqrt{u \\odot m \\oslash G u}`),
    so :math:`P` is the entropic optimal transport plan of :math:`m` to itself for the
    cost :math:`-\\varepsilon\\log G` (:math:`P1 = P^T1 = m`), and :math:`TX` the
    barycentric projection: each vertex moves to the :math:`P`-weighted mean of the
    others. The last step (``debias=True``) is Tukey's twicing,
    :math:`X - (I - T)^2 X`, which cancels the first-order shrinkage of :math:`T`
    (``debias=False``: :math:`X \\leftarrow TX`).

    With ``measure="uniform"`` the heat kernel is already doubly stochastic
    (:math:`G1 = 1`), so :math:`u = 1` and :math:`T = G`; ``measure="area"`` makes the
    scaling non-trivial (it scores lower on the elephant, see the README, "Optimal transport"). The
    filter is translation equivariant (:math:`T1 = 1`) and, with the default uniform
    measure and graph Laplacian, linear.

    Choosing ``t`` for a scan: with noise of 0.1, 0.3 and 1 mean edge lengths along the normals the
    oracle chose ``t`` 0.13-0.28, 0.29-0.43 and 0.70-0.75 on a sphere and a torus
    (``benchmarks/results/parameter-scale.md``): about ``0.7 * sqrt(s)`` for noise of ``s`` edge lengths.

    Parameters
    ----------
    mesh : (V, F) tuple, pymeshlab.MeshSet or Mesh, or open3d.geometry.TriangleMesh
    t : float, > 0
        Diffusion time, in squared edge hops.
    iterations : int, >= 0
        Number of projections.
    laplacian : {"graph", "cotangent"}
        Laplacian of the heat kernel.
    measure : {"uniform", "area"}
        Vertex measure :math:`m`.
    debias : bool
        Twicing correction.
    steps : int, 1 <= steps <= 1000
        Backward-Euler substeps: :math:`G = (I + \\tfrac{t}{s}L)^{-s}`.
    pinned, region, preserve_volume, operators
        Options shared by every filter; see the README.

    Returns
    -------
    Same type as ``mesh``

    References
    ----------
    A. Vaillant-Tenzer, "Mesh Denoising", 2022 (optimal transport section).
    J. Solomon et al., "Convolutional Wasserstein distances", ACM TOG 34(4), 2015.
    B. Landa, R. Coifman, Y. Kluger, "Doubly stochastic normalization of the Gaussian
    kernel is robust to heteroskedastic noise", SIAM J. Math. Data Sci. 3(1), 2021.
    J. Tukey, "Exploratory Data Analysis", 1977 (twicing).

    Examples
    --------
    >>> import numpy as np, meshdenoise
    >>> from meshdenoise.shapes import icosphere
    >>> V, F = icosphere(3)
    >>> Vn, _ = meshdenoise.add_normal_noise((V, F), rho=0.05, seed=0)
    >>> V1, _ = meshdenoise.sinkhorn((Vn, F), t=1.0, iterations=1)
    >>> bool(meshdenoise.snr((V, F), (V1, F)) > meshdenoise.snr((V, F), (Vn, F)) + 5)
    True
    """
    return ot_denoise(
        V,
        F,
        t=t,
        iterations=iterations,
        laplacian=laplacian,
        measure=measure,
        debias=debias,
        steps=steps,
        pinned=pinned,
        cache=ops.cache,
    )

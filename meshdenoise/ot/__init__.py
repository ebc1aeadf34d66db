"""Entropic optimal transport: Sinkhorn, Wasserstein barycenters and mesh heat kernels.

This package implements, in plain numpy/scipy, the optimal-transport tools used by
the OT-based denoisers of ``meshdenoise`` (4th method of Vaillant-Tenzer, "Mesh
Denoising", 2022):

* :func:`sinkhorn` -- discrete entropic OT (scaling and log-domain solvers),
  same argument order and conventions as POT's ``ot.sinkhorn``;
* :func:`barycenter` -- entropic Wasserstein barycenter of histograms by
  iterative Bregman projections (as ``ot.bregman.barycenter``);
* :func:`convolutional_barycenter` -- the same barycenter where the Gibbs kernel
  is an *operator* (a callable), never a dense matrix (Solomon et al. 2015);
* :func:`convolutional_barycenter2d` -- the operator version on a 2D grid with a
  separable Gaussian kernel (as ``ot.bregman.convolutional_barycenter2d``);
* :class:`MeshHeatKernel` -- one backward-Euler heat step
  :math:`(M + tL)^{-1} M` on a triangle mesh through a cached sparse Cholesky
  factorisation (cholespy);
* :func:`symmetric_sinkhorn` and :func:`ot_denoise` -- the symmetric scaling of
  a kernel and the OT mesh denoiser built on it.

The modules: :mod:`~meshdenoise.ot.scaling` (the two Sinkhorn scalings),
:mod:`~meshdenoise.ot.barycenters` (the three barycenters),
:mod:`~meshdenoise.ot.kernels` (the 2D Gaussian and the mesh heat kernel),
:mod:`~meshdenoise.ot.denoise` (the denoiser) and :mod:`~meshdenoise.ot.checks`
(the arguments' checks they share).

References
----------
.. [1] M. Cuturi, "Sinkhorn distances: lightspeed computation of optimal
   transport", NIPS 2013.
.. [2] J.-D. Benamou, G. Carlier, M. Cuturi, L. Nenna, G. Peyre, "Iterative
   Bregman projections for regularized transportation problems", SIAM J. Sci.
   Comput. 37(2), 2015.
.. [3] J. Solomon, F. de Goes, G. Peyre, M. Cuturi, A. Butscher, A. Nguyen,
   T. Du, L. Guibas, "Convolutional Wasserstein distances: efficient optimal
   transportation on geometric domains", ACM TOG 34(4), 2015.
.. [4] L. Vaillant-Tenzer, "Mesh Denoising", 2022.
"""

from __future__ import annotations

from .barycenters import barycenter, convolutional_barycenter, convolutional_barycenter2d
from .denoise import ot_denoise
from .kernels import MeshHeatKernel, gaussian_kernel2d
from .scaling import sinkhorn, symmetric_sinkhorn

__all__ = [
    "sinkhorn",
    "barycenter",
    "convolutional_barycenter",
    "convolutional_barycenter2d",
    "gaussian_kernel2d",
    "MeshHeatKernel",
    "symmetric_sinkhorn",
    "ot_denoise",
]

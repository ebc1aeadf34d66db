"""Entropic Wasserstein barycenters by iterative Bregman projections (Benamou et al. 2015).

* :func:`barycenter` -- histograms with a cost matrix (as ``ot.bregman.barycenter``);
* :func:`convolutional_barycenter` -- the Gibbs kernel as an *operator* (a callable), never a dense
  matrix (Solomon et al. 2015);
* :func:`convolutional_barycenter2d` -- images on a 2D grid with the separable Gaussian kernel (as
  ``ot.bregman.convolutional_barycenter2d``), scaling or log-domain iterations.
"""

from __future__ import annotations

import itertools
import warnings

import numpy as np

from .checks import _check_method, _float_array, _histogram, _positive_float, _positive_int, _weights
from .kernels import _log_gaussian_kernel2d, gaussian_kernel2d


def barycenter(A, M, reg, weights=None, numItermax=1000, stopThr=1e-9, log=False, warn=True):
    r"""Entropic Wasserstein barycenter of histograms (iterative Bregman projections).

    Finds :math:`\arg\min_p \sum_k w_k W_\mathrm{reg}(p, a_k)` with the
    algorithm of Benamou et al. (2015).  With :math:`K = e^{-M/\mathrm{reg}}`
    and plans :math:`\gamma_k = \mathrm{diag}(v_k) K \mathrm{diag}(u_k)`
    (rows: the histogram :math:`a_k`, columns: the barycenter), iterate

    .. math::
        v_k \leftarrow a_k \oslash K u_k,\qquad
        p \leftarrow \prod_k \big(u_k \odot K^T v_k\big)^{w_k},\qquad
        u_k \leftarrow p \oslash K^T v_k .

    Stops when :math:`\sum_i \mathrm{std}_k\big(u_k \odot K^T v_k\big)_i < \mathrm{stopThr}`
    (the barycenter marginals of all plans agree), checked every 10 iterations.

    Parameters
    ----------
    A : array_like, shape (dim, n_hists)
        Histograms in the columns (non-negative, each summing to the same mass).
    M : array_like, shape (dim, dim)
        Cost matrix.
    reg : float
        Entropic regularisation, > 0.
    weights : array_like, shape (n_hists,), optional
        Barycentric weights on the simplex; uniform by default.
    numItermax : int
        Maximum number of iterations.
    stopThr : float
        Tolerance (>= 0).
    log : bool
        Also return a dict with ``err`` and ``niter``.
    warn : bool
        Emit a ``UserWarning`` if ``numItermax`` is reached.

    Returns
    -------
    p : ndarray, shape (dim,)
        The barycenter.
    log : dict
        Only if ``log=True``.

    References
    ----------
    Benamou, Carlier, Cuturi, Nenna, Peyre, "Iterative Bregman projections for
    regularized transportation problems", SIAM J. Sci. Comput. 37(2), 2015.

    Examples
    --------
    >>> import numpy as np
    >>> x = np.linspace(0, 1, 51)
    >>> M = (x[:, None] - x[None, :]) ** 2
    >>> A = np.stack([np.exp(-(x - .25) ** 2 / .005), np.exp(-(x - .75) ** 2 / .005)], 1)
    >>> A /= A.sum(0)
    >>> p = barycenter(A, M, 1e-3)
    >>> round(float(p.sum()), 6), int(np.argmax(p))
    (1.0, 25)
    """
    A = _histogram("A", A, (2,))
    M = _float_array("M", M, (2,))
    dim, k = A.shape
    if M.shape != (dim, dim):
        raise ValueError(f"M must have shape ({dim}, {dim}) to match A {A.shape}, got {M.shape}")
    reg = _positive_float("reg", reg)
    K = np.exp(-M / reg)
    return _ibp(lambda x: K @ x, lambda x: K.T @ x, A, _weights(weights, k), numItermax, stopThr, log, warn)


def _ibp(Kop, KTop, A, w, numItermax, stopThr, log, warn, stab=1e-300):
    """Iterative Bregman projections on the scalings (A: (dim, k) histograms), run by :func:`_projections`."""

    def rounds():
        u = np.ones_like(A)
        p_last = None
        for it in itertools.count():
            v = A / Kop(u)
            KTv = KTop(v)
            marg = u * KTv
            p = np.exp(np.log(np.maximum(marg, stab)) @ w)
            u = p[:, None] / KTv
            if not (np.all(np.isfinite(p)) and np.all(np.isfinite(u))):
                warnings.warn(
                    f"barycenter: numerical under/overflow at iteration {it} (reg too small for the scaling "
                    "iterations); returning the last finite iterate -- increase reg, or use "
                    "method='sinkhorn_log' where available",
                    UserWarning,
                    stacklevel=5,
                )
                yield (p_last if p_last is not None else p), None
                return
            p_last = p
            yield p, lambda: marg

    return _projections(rounds(), numItermax, stopThr, log, warn, over="ignore")


def _projections(rounds, numItermax, stopThr, log, warn, **errstate):
    """The loop both iterations share: ``rounds`` yields ``(p, marginals)`` a round, ``marginals()`` the plans'
    barycenter marginals (dim, k), read every 10th round: the run stops when their spread across the plans,
    :math:`\\sum_i \\mathrm{std}_k`, is under ``stopThr`` (or warns after ``numItermax`` rounds). A round whose
    ``marginals`` is ``None`` ends the run with its ``p`` (the round has warned why)."""
    numItermax = _positive_int("numItermax", numItermax)
    stopThr = _positive_float("stopThr", stopThr, allow_zero=True)
    errs = []
    converged = False
    with np.errstate(divide="ignore", invalid="ignore", **errstate):
        for it, (p, marginals) in zip(range(numItermax), rounds):
            if marginals is None:
                converged = True  # already warned
                break
            if it % 10 == 9:
                err = float(np.sum(np.std(marginals(), axis=1)))
                errs.append(err)
                if err < stopThr:
                    converged = True
                    break
    if not converged and warn:
        warnings.warn(
            f"barycenter did not converge in numItermax={numItermax} iterations "
            f"(error {errs[-1] if errs else float('nan'):.3e} > stopThr={stopThr:g}): increase numItermax or reg",
            UserWarning,
            stacklevel=4,
        )
    if log:
        return p, {"err": errs, "niter": it}
    return p


def convolutional_barycenter(A, kernel, weights=None, area=None, numItermax=10000, stopThr=1e-9, log=False, warn=True):
    r"""Entropic Wasserstein barycenter where the Gibbs kernel is an operator.

    Same iterative Bregman projections as :func:`barycenter`, but the kernel
    is only ever *applied* (Solomon et al. 2015): on images a separable
    Gaussian, on meshes a heat kernel such as :class:`MeshHeatKernel`.  The
    kernel must be symmetric with respect to the ``area`` measure: with
    :math:`a` = ``area`` the matrix :math:`\mathcal{K}x = \mathrm{kernel}(x / a)`
    must be symmetric (true for :math:`(M+tL)^{-1}M` with ``area`` the
    lumped masses; for ``area=None`` the kernel itself must be symmetric).
    With :math:`\mathcal{K}`, the histograms :math:`a_k` (masses per vertex or
    pixel) and weights :math:`w_k`:

    .. math::
        v_k \leftarrow a_k \oslash \mathcal{K} u_k,\qquad
        p \leftarrow \prod_k \big(u_k \odot \mathcal{K} v_k\big)^{w_k},\qquad
        u_k \leftarrow p \oslash \mathcal{K} v_k .

    Parameters
    ----------
    A : array_like, shape (n, n_hists)
        Histograms (masses, non-negative) in the columns.
    kernel : callable
        ``kernel(X)`` applies the (symmetric w.r.t. ``area``) kernel to an
        array ``X`` of shape (n, n_hists) and returns the same shape.
    weights : array_like, shape (n_hists,), optional
        Barycentric weights on the simplex; uniform by default.
    area : array_like, shape (n,), optional
        Positive vertex areas (the reference measure); None means all ones.
    numItermax : int
        Maximum number of iterations.
    stopThr : float
        Tolerance on :math:`\sum_i \mathrm{std}_k (u_k \odot \mathcal{K} v_k)_i`.
    log : bool
        Also return a dict with ``err`` and ``niter``.
    warn : bool
        Emit a ``UserWarning`` if ``numItermax`` is reached.

    Returns
    -------
    p : ndarray, shape (n,)
        The barycenter (a histogram of masses).
    log : dict
        Only if ``log=True``.

    References
    ----------
    Solomon et al., "Convolutional Wasserstein distances", ACM TOG 34(4), 2015.

    Examples
    --------
    >>> import numpy as np
    >>> x = np.linspace(0, 1, 40)
    >>> K = np.exp(-(x[:, None] - x[None, :]) ** 2 / 1e-2)
    >>> A = np.stack([np.exp(-(x - .2) ** 2 / .002), np.exp(-(x - .8) ** 2 / .002)], 1)
    >>> A /= A.sum(0)
    >>> p = convolutional_barycenter(A, lambda X: K @ X)
    >>> int(np.argmax(p)) in (19, 20)
    True
    """
    if not callable(kernel):
        raise TypeError(f"kernel must be a callable applying the kernel, got {kernel!r}")
    A = _histogram("A", A, (2,))
    n, k = A.shape
    w = _weights(weights, k)
    if area is None:
        Kop = kernel
    else:
        area = _float_array("area", area, (1,))
        if area.shape != (n,):
            raise ValueError(f"area must have shape ({n},), got {area.shape}")
        if np.any(area <= 0):
            raise ValueError(f"area must be positive, got min {area.min()!r}")
        inv = (1.0 / area)[:, None]

        def Kop(X):
            return kernel(X * inv)

    test = Kop(np.ones((n, k)))
    if np.shape(test) != (n, k):
        raise ValueError(f"kernel must map shape {(n, k)} to itself, got {np.shape(test)}")
    return _ibp(Kop, Kop, A, w, numItermax, stopThr, log, warn)


def convolutional_barycenter2d(
    A, reg, weights=None, method="sinkhorn", numItermax=10000, stopThr=1e-9, log=False, warn=True
):
    r"""Entropic Wasserstein barycenter of 2D images with a separable Gaussian kernel.

    Same conventions as POT's ``ot.bregman.convolutional_barycenter2d``: the
    images live on :math:`[0,1]^2`, the Gibbs kernel is
    :math:`e^{-\|x-y\|^2/\mathrm{reg}}` applied separably
    (:func:`gaussian_kernel2d`), and the iteration is that of
    :func:`convolutional_barycenter`:

    .. math::
        v_k \leftarrow a_k \oslash K u_k,\qquad
        p \leftarrow \prod_k \big(u_k \odot K v_k\big)^{w_k},\qquad
        u_k \leftarrow p \oslash K v_k .

    Parameters
    ----------
    A : array_like, shape (n_hists, w, h)
        Images (non-negative, each summing to the same mass).
    reg : float
        Entropic regularisation / squared kernel width, > 0.
    weights : array_like, shape (n_hists,), optional
        Barycentric weights; uniform by default.
    method : {"sinkhorn", "sinkhorn_log"}
        Scaling iterations, or the same iterations on the logarithms of the
        scalings with the kernel applied by separable log-sum-exp (stable for
        small ``reg``, slower: :math:`O(wh(w+h))` exponentials per application).
    numItermax : int
        Maximum number of iterations.
    stopThr : float
        Tolerance (>= 0).
    log : bool
        Also return a dict with ``err`` and ``niter``.
    warn : bool
        Emit a ``UserWarning`` if ``numItermax`` is reached.

    Returns
    -------
    p : ndarray, shape (w, h)
        The barycenter image.
    log : dict
        Only if ``log=True``.

    References
    ----------
    Solomon et al., "Convolutional Wasserstein distances", ACM TOG 34(4), 2015.

    Examples
    --------
    >>> import numpy as np
    >>> A = np.zeros((2, 20, 20)); A[0, 4:8, 4:8] = 1; A[1, 12:16, 12:16] = 1
    >>> A /= A.sum((1, 2), keepdims=True)
    >>> p = convolutional_barycenter2d(A, 4e-3)
    >>> p.shape, round(float(p.sum()), 6)
    ((20, 20), 1.0)
    """
    method = _check_method(method)
    A = _histogram("A", A, (3,))
    k, w, h = A.shape
    if method == "sinkhorn":
        K = gaussian_kernel2d((w, h), reg)
        res = convolutional_barycenter(
            A.reshape(k, w * h).T, K, weights, numItermax=numItermax, stopThr=stopThr, log=log, warn=warn
        )
    else:
        reg = _positive_float("reg", reg)
        res = _ibp_log(_log_gaussian_kernel2d(w, h, reg), A.reshape(k, w * h).T, _weights(weights, k),
                       numItermax, stopThr, log, warn)
    if log:
        return res[0].reshape(w, h), res[1]
    return res.reshape(w, h)


def _ibp_log(logK, A, w, numItermax, stopThr, log, warn):
    """Iterative Bregman projections on the log-scalings (symmetric log-kernel operator), run by :func:`_projections`."""

    def rounds():
        with np.errstate(divide="ignore"):
            logA = np.log(A)
        logu = np.zeros_like(A)
        while True:
            logv = logA - logK(logu)
            logKv = logK(logv)
            logmarg = logu + logKv
            logp = logmarg @ w
            logu = logp[:, None] - logKv
            yield np.exp(logp), lambda: np.exp(logmarg)

    return _projections(rounds(), numItermax, stopThr, log, warn)

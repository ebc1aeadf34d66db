"""Sinkhorn scaling: the entropic transport plan between two histograms, and of one measure to itself.

* :func:`sinkhorn` -- discrete entropic OT (scaling and log-domain solvers), same argument order and
  conventions as POT's ``ot.sinkhorn``;
* :func:`symmetric_sinkhorn` -- the symmetric scaling :math:`u \\odot G u = m` of a symmetric kernel
  operator (the plan of :func:`meshdenoise.ot.ot_denoise`).
"""

from __future__ import annotations

import warnings

import numpy as np
from scipy.special import logsumexp

from .checks import _HINT, _check_method, _float_array, _histogram, _positive_float, _positive_int, _safe_log


def sinkhorn(a, b, M, reg, method="sinkhorn", numItermax=1000, stopThr=1e-9, log=False, warn=True):
    r"""Entropic optimal transport plan between two histograms (Sinkhorn-Knopp).

    Solves

    .. math::
        \gamma = \arg\min_{\gamma \ge 0,\ \gamma 1 = a,\ \gamma^T 1 = b}
        \langle \gamma, M\rangle_F + \mathrm{reg} \sum_{ij} \gamma_{ij}\log\gamma_{ij}

    whose solution is :math:`\gamma = \mathrm{diag}(u) K \mathrm{diag}(v)` with
    :math:`K = e^{-M/\mathrm{reg}}`, found by alternate scaling

    .. math::
        v \leftarrow b \oslash K^T u, \qquad u \leftarrow a \oslash K v .

    ``method="sinkhorn_log"`` runs the same iteration on the dual potentials
    :math:`f = \mathrm{reg}\log u`, :math:`g = \mathrm{reg}\log v` with
    log-sum-exp,

    .. math::
        g_j \leftarrow \mathrm{reg}\log b_j - \mathrm{reg}\,\mathrm{LSE}_i\big((f_i - M_{ij})/\mathrm{reg}\big),\quad
        f_i \leftarrow \mathrm{reg}\log a_i - \mathrm{reg}\,\mathrm{LSE}_j\big((g_j - M_{ij})/\mathrm{reg}\big),

    which stays finite for small ``reg`` where :math:`K` underflows.
    Iterations stop when the marginal error :math:`\|\gamma^T 1 - b\|_2`
    (checked every 10 iterations) is below ``stopThr``.

    Parameters
    ----------
    a : array_like, shape (n,)
        Source histogram (non-negative).  An empty list means uniform.
    b : array_like, shape (m,)
        Target histogram (non-negative, same total mass as ``a``).  An empty
        list means uniform.
    M : array_like, shape (n, m)
        Cost matrix.
    reg : float
        Entropic regularisation, > 0.
    method : {"sinkhorn", "sinkhorn_log"}
        Plain scaling or log-domain stabilised iterations.
    numItermax : int
        Maximum number of iterations (>= 1).
    stopThr : float
        Tolerance on the marginal error (>= 0).
    log : bool
        If True also return a dict with ``err``, ``niter``, ``u``, ``v``
        (or ``log_u``, ``log_v`` for the log method).
    warn : bool
        Emit a ``UserWarning`` when ``numItermax`` is reached.

    Returns
    -------
    gamma : ndarray, shape (n, m)
        Transport plan.
    log : dict
        Only if ``log=True``.

    Raises
    ------
    ValueError, TypeError
        On invalid inputs (shapes, negative masses, unequal total masses,
        non-positive ``reg``, unknown method).

    References
    ----------
    Cuturi, "Sinkhorn distances", NIPS 2013.  Schmitzer, "Stabilized sparse
    scaling algorithms for entropy regularized transport problems", 2019.

    Examples
    --------
    >>> import numpy as np
    >>> P = sinkhorn([.5, .5], [.5, .5], [[0., 1.], [1., 0.]], 1.0)
    >>> np.round(P, 8)
    array([[0.36552929, 0.13447071],
           [0.13447071, 0.36552929]])
    """
    method = _check_method(method)
    M = _float_array("M", M, (2,))
    n, m = M.shape
    a = np.full(n, 1.0 / n) if np.size(a) == 0 else _histogram("a", a)
    b = np.full(m, 1.0 / m) if np.size(b) == 0 else _histogram("b", b)
    if a.shape != (n,) or b.shape != (m,):
        raise ValueError(f"shapes do not match: a {a.shape}, b {b.shape}, M {M.shape}")
    if not np.isclose(a.sum(), b.sum(), rtol=1e-6, atol=1e-12):
        raise ValueError(f"a and b must have the same total mass, got {a.sum()!r} and {b.sum()!r}")
    reg = _positive_float("reg", reg)
    numItermax = _positive_int("numItermax", numItermax)
    stopThr = _positive_float("stopThr", stopThr, allow_zero=True)

    errs = []
    converged = False
    if method == "sinkhorn":
        K = np.exp(-M / reg)
        u = np.full(n, 1.0 / n)
        v = np.full(m, 1.0 / m)
        with np.errstate(divide="ignore", invalid="ignore"):
            for it in range(numItermax):
                Ktu = K.T @ u
                v_new = b / Ktu
                u_new = a / (K @ v_new)
                if not (np.all(np.isfinite(u_new)) and np.all(np.isfinite(v_new))):
                    warnings.warn(
                        f"sinkhorn: numerical overflow/underflow at iteration {it} (reg={reg!r} too small "
                        f"for the scaling method); returning the last finite iterate -- {_HINT}",
                        UserWarning,
                        stacklevel=2,
                    )
                    break
                u, v = u_new, v_new
                if it % 10 == 0:
                    err = float(np.linalg.norm(v * (K.T @ u) - b))
                    errs.append(err)
                    if err < stopThr:
                        converged = True
                        break
        gamma = u[:, None] * K * v[None, :]
        extra = {"u": u, "v": v}
    else:
        la, lb = _safe_log(a), _safe_log(b)
        f = np.zeros(n)
        g = np.zeros(m)
        for it in range(numItermax):
            g = reg * lb - reg * logsumexp((f[:, None] - M) / reg, axis=0)
            f = reg * la - reg * logsumexp((g[None, :] - M) / reg, axis=1)
            if it % 10 == 0:
                logP = (f[:, None] + g[None, :] - M) / reg
                err = float(np.linalg.norm(np.exp(logsumexp(logP, axis=0)) - b))
                errs.append(err)
                if err < stopThr:
                    converged = True
                    break
        gamma = np.exp((f[:, None] + g[None, :] - M) / reg)
        extra = {"log_u": f / reg, "log_v": g / reg}
    if not converged and warn and it == numItermax - 1:
        warnings.warn(
            f"sinkhorn did not converge in numItermax={numItermax} iterations "
            f"(marginal error {errs[-1] if errs else float('nan'):.3e} > stopThr={stopThr:g}): {_HINT}",
            UserWarning,
            stacklevel=2,
        )
    if log:
        return gamma, {"err": errs, "niter": it, **extra}
    return gamma


def symmetric_sinkhorn(kernel, m, numItermax=500, stopThr=1e-10, u0=None, warn=True):
    r"""Symmetric Sinkhorn scaling of a symmetric positive kernel operator.

    Finds :math:`u > 0` such that the symmetric plan
    :math:`P = \mathrm{diag}(u)\, G\, \mathrm{diag}(u)` has both marginals
    equal to :math:`m`, i.e. :math:`u \odot G u = m`, by the damped
    (geometric-mean) fixed point of Knight (2008) / Feydy et al. (2019)

    .. math::
        u \leftarrow \sqrt{u \odot m \oslash G u},

    stopping when :math:`\|u \odot G u - m\|_1 / \|m\|_1 < \mathrm{stopThr}`.
    This is the entropic OT plan from the measure :math:`m` to itself for the
    cost :math:`-\varepsilon \log G` (for a heat kernel, Varadhan: the squared
    geodesic distance).

    Parameters
    ----------
    kernel : callable
        ``kernel(x)`` applies the symmetric kernel :math:`G` to x, shape (n,).
    m : array_like, shape (n,)
        Non-negative target marginal (not all zero); where :math:`m_i = 0`,
        :math:`u_i = 0`.
    numItermax : int
        Maximum number of iterations.
    stopThr : float
        Tolerance on the relative marginal error.
    u0 : array_like, shape (n,), optional
        Starting scaling (default :math:`\sqrt{m}`).
    warn : bool
        Emit a ``UserWarning`` when ``numItermax`` is reached.

    Returns
    -------
    u : ndarray, shape (n,)
        The scaling.
    info : dict
        ``niter`` and ``err``.

    Raises
    ------
    ValueError
        If ``m`` has a negative entry or is all zero, or the kernel maps a
        positive vector to one with a non-positive entry on the support of m (the kernel is not positive, e.g. a
        cotangent heat kernel on a mesh with very obtuse triangles).

    References
    ----------
    P. Knight, "The Sinkhorn-Knopp algorithm: convergence and applications",
    SIAM J. Matrix Anal. Appl. 30(1), 2008.  J. Feydy et al., "Interpolating
    between optimal transport and MMD using Sinkhorn divergences", AISTATS 2019.

    Examples
    --------
    >>> import numpy as np
    >>> G = np.array([[2., 1.], [1., 3.]])
    >>> u, info = symmetric_sinkhorn(lambda x: G @ x, np.array([1., 1.]))
    >>> np.allclose(u * (G @ u), 1.0)
    True
    """
    if not callable(kernel):
        raise TypeError(f"kernel must be a callable, got {kernel!r}")
    m = _float_array("m", m, (1,))
    if m.size == 0 or np.any(m < 0) or not np.any(m > 0):
        raise ValueError(f"m must be non-negative and not all zero, got min {m.min() if m.size else None!r}")
    support = m > 0
    numItermax = _positive_int("numItermax", numItermax)
    stopThr = _positive_float("stopThr", stopThr, allow_zero=True)
    u = np.sqrt(m) if u0 is None else np.where(support, _float_array("u0", u0, (1,)), 0.0)
    msum = m.sum()
    err = np.inf
    for it in range(numItermax):
        Gu = kernel(u)
        if np.any(Gu[support] <= 0):
            bad = int(np.flatnonzero(support)[np.argmin(Gu[support])])
            raise ValueError(
                f"the kernel is not positive: (G u)[{bad}] = {Gu[bad]!r} for positive u; "
                "use laplacian='graph' or a smaller t"
            )
        err = float(np.abs(u * Gu - m).sum() / msum)
        if err < stopThr:
            break
        u_new = np.zeros_like(m)
        u_new[support] = np.sqrt(u[support] * m[support] / Gu[support])
        u = u_new
    else:
        if warn:
            warnings.warn(
                f"symmetric_sinkhorn did not converge in numItermax={numItermax} iterations "
                f"(marginal error {err:.3e} > stopThr={stopThr:g}): increase numItermax or t",
                UserWarning,
                stacklevel=2,
            )
    return u, {"niter": it, "err": err}

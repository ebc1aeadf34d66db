"""Heat diffusion on the random-walk Laplacian I - D^-1 W: explicit Euler, or exp(-T (I - D^-1 W)) X by Chebyshev."""

from __future__ import annotations

import math

import numpy as np
from scipy.special import ive

from ..gpu import BACKENDS, Backend, get_backend
from ..operators import Operators
from ..registry import Param, register
from .filtering import run_linear_steps, step_matrix, use_locality_order

__all__ = ["heat", "heat_steps", "stable_tau", "chebyshev_coefficients", "chebyshev_heat"]

METHODS = ("euler", "chebyshev")


def stable_tau(ops: Operators) -> float:
    """The largest stable Euler step ``2 / lambda_max(I - D^-1 W)`` for this topology (at least 1)."""
    lam = ops.lambda_max()
    return math.inf if lam == 0 else 2.0 / lam


def heat_steps(tau: float, time: float) -> int:
    """Number of Euler steps for ``time``: ``ceil(time / tau)`` (0 for time 0)."""
    # the tolerance keeps time = k * tau from becoming k + 1 steps through rounding
    return max(0, math.ceil(time / tau - 1e-9))


def _check_tau(ops: Operators, tau: float) -> None:
    # The eigenvalues of I - D^-1 W lie in [0, 2]: every tau <= 1 is stable without computing them.
    if tau <= 1.0:
        return
    limit = stable_tau(ops)
    if tau > limit * (1 + 1e-9):
        raise ValueError(
            f"parameter 'tau' = {tau!r} is out of the stable range 0 < tau <= 2 / lambda_max = {limit:.6g} "
            f"for this mesh (lambda_max(I - D^-1 W) = {ops.lambda_max():.6g}): explicit Euler would diverge. "
            "Use a smaller tau; the same time T needs only ceil(T / tau) steps."
        )


def chebyshev_coefficients(time: float, tol: float) -> np.ndarray:
    r"""Coefficients :math:`a_k` with :math:`e^{-T x} \approx \sum_{k \le K} a_k T_k(1 - x)` on :math:`[0, 2]`.

    From :math:`e^{-T(1 - y)} = e^{-T} I_0(T) + 2 \sum_{k \ge 1} e^{-T} I_k(T)\, T_k(y)`
    (modified Bessel functions; ``scipy.special.ive`` gives :math:`e^{-T} I_k(T)` without
    overflow), truncated at the first ``K`` whose dropped tail
    :math:`2 \sum_{k > K} e^{-T} I_k(T)` is at most ``tol``; that tail bounds the error
    uniformly on :math:`[0, 2]` since :math:`|T_k| \le 1` there. The tail is then added to
    :math:`a_0` so that :math:`\sum a_k = 1`: the polynomial is exactly 1 at ``x = 0``,
    so translations (the constant vector) pass through unchanged.

    Examples
    --------
    >>> a = chebyshev_coefficients(40.0, 1e-7)
    >>> len(a), round(float(a.sum()), 12)
    (35, 1.0)
    """
    if time == 0:
        return np.ones(1)
    kmax = int(math.ceil(time + 12.0 * math.sqrt(time) + 30))
    c = ive(np.arange(kmax + 1), time)
    tails = 2.0 * np.cumsum(c[::-1])[::-1]  # tails[k] = 2 sum_{j >= k} c_j
    K = int(np.argmax(np.append(tails[1:], 0.0) <= tol))
    a = 2.0 * c[: K + 1]
    a[0] = c[0]
    a[0] += 1.0 - a.sum()
    return a


def chebyshev_heat(
    P, X: np.ndarray, time: float, tol: float = 1e-7, backend: str | Backend = "cpu"
) -> np.ndarray:
    r"""``exp(-T (I - P)) X`` for a matrix ``P`` with spectrum in [-1, 1] (``D^-1 W``, fixed rows as identity).

    .. math:: e^{-T(I - P)} X \approx \sum_{k=0}^{K} a_k U_k, \qquad U_0 = X,\; U_1 = P X,\;
              U_{k+1} = 2 P U_k - U_{k-1}

    (:func:`chebyshev_coefficients`; :math:`U_k = T_k(P) X`). ``P = D^{-1} W`` is similar
    to the symmetric :math:`D^{-1/2} W D^{-1/2}`, whose eigenvalues lie in [-1, 1], so the
    error is at most ``tol`` times :math:`\sqrt{d_{max}/d_{min}}\,\|X\|`. One sparse product
    and one ``axpy`` per degree, three coordinate buffers: the recurrence runs in place
    by keeping :math:`\pm U_k` and adding :math:`\pm 2 P U_k` into the older buffer.
    """
    be = get_backend(backend) if isinstance(backend, str) else backend
    a = chebyshev_coefficients(float(time), float(tol))
    X0 = be.asarray(X)
    if len(a) == 1:
        return np.array(be.to_numpy(X0), dtype=np.float64)
    Pd = be.matrix(P)
    two_p = {1.0: be.scaled(Pd, 2.0), -1.0: be.scaled(Pd, -2.0)}
    res = be.zeros_like(X0)
    be.axpy(a[0], X0, res)
    older = X0  # holds sign[k-1] * U_{k-1}; X0 is ours to overwrite
    newer = be.spmm(Pd, X0)  # U_1
    be.axpy(a[1], newer, res)
    sign = [1.0, 1.0]  # sign[k] of the stored U_k: period 1, 1, -1, -1 lets the kernel only add
    for k in range(1, len(a) - 1):
        s_next = -sign[k - 1]
        be.spmm(two_p[s_next * sign[k]], newer, out=older, accumulate=True)  # = s_next * U_{k+1}
        be.axpy(s_next * a[k + 1], older, res)
        sign.append(s_next)
        older, newer = newer, older
    return np.array(be.to_numpy(res), dtype=np.float64)


@register(
    "heat",
    summary="Heat diffusion to time T by explicit Euler: X <- X - tau (I - D^-1 W) X, ceil(T/tau) steps",
    params=[
        Param("tau", float, 0.5, low=0.0, high=2.0, low_open=True, help="Euler step (stable up to 2/lambda_max)"),
        Param("time", float, 10.0, low=0.0, help="diffusion time T"),
        Param(
            "method",
            str,
            "euler",
            choices=METHODS,
            help="euler: ceil(T/tau) explicit steps; chebyshev: exp(-T (I - D^-1 W)) X at exactly T (tau unused)",
        ),
        Param(
            "tol",
            float,
            1e-7,
            low=0.0,
            high=0.1,
            low_open=True,
            help="method='chebyshev': largest error of the polynomial replacing exp on the spectrum",
        ),
        Param("backend", str, "cpu", choices=BACKENDS, help="where the sparse products run (see meshdenoise.gpu)"),
    ],
    linear=True,
)
def heat(V, F, *, ops, fixed, tau, time, method, tol, backend):
    """Heat diffusion by explicit Euler steps (the paper's second method).

    .. math:: X^{(t+1)} = X^{(t)} - \\tau \\left(I - D^{-1} W\\right) X^{(t)}, \\qquad t = 0, \\dots, \\lceil T / \\tau \\rceil - 1

    Each step has length ``tau``, so the run ends at time :math:`\\lceil T/\\tau \\rceil \\tau`
    (``T`` rounded up to a whole number of steps). The scheme is stable when
    :math:`\\tau \\lambda_{max}(I - D^{-1}W) \\le 2`; every ``tau <= 1`` is stable, and a
    larger ``tau`` is checked against the mesh's largest eigenvalue (computed once per
    topology by Lanczos and cached): an unstable ``tau`` such as the paper's 1.42 on the
    elephant raises ``ValueError`` instead of returning garbage.

    With ``method="chebyshev"`` the exact solution of :math:`\\dot X = -(I - D^{-1}W) X`
    at time ``T`` (not rounded to steps) is approximated by a Chebyshev polynomial in
    :math:`D^{-1}W` (:func:`chebyshev_heat`) whose degree grows like
    :math:`\\sqrt{T \\log(1/\\mathrm{tol})}` instead of :math:`T/\\tau`: 34 products instead of
    80 at ``T = 40, tau = 0.5``. ``tau`` is then unused. Pinned vertices are Dirichlet
    data in both methods (identity rows of :math:`D^{-1}W`).

    Parameters
    ----------
    mesh : (V, F) tuple, pymeshlab.MeshSet or Mesh, or open3d.geometry.TriangleMesh
    tau : float, 0 < tau <= 2 / lambda_max
        Euler step.
    time : float, >= 0
        Diffusion time T.
    method : {"euler", "chebyshev"}
        Explicit Euler steps (the paper's scheme) or the Chebyshev approximation of the
        exact exponential.
    tol : float in (0, 0.1]
        ``method="chebyshev"`` only: bound on the polynomial's error on the spectrum.
    backend : {"cpu", "scipy", "cupy", "torch"}
        Where the sparse products run; see :mod:`meshdenoise.gpu`.
    pinned, region, preserve_volume, operators
        Options shared by every filter; see the README.

    Returns
    -------
    Same type as ``mesh``

    References
    ----------
    A. Vaillant-Tenzer, "Mesh Denoising", 2022, section on the heat equation.

    Examples
    --------
    >>> import numpy as np
    >>> V = np.array([[0., 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    >>> F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    >>> V1, _ = heat((V, F), tau=0.5, time=1.0)  # two steps: x <- x/3 + 2/3 mean(x), so 0 -> 1/6 -> 2/9
    >>> V1[0]
    array([0.22222222, 0.22222222, 0.22222222])
    """
    if method == "chebyshev":
        if not use_locality_order(ops, len(chebyshev_coefficients(time, tol))):
            return chebyshev_heat(ops.with_fixed_rows(ops.P, fixed, "P"), V, time, tol, backend)
        order = ops.locality_order  # same computation on relabelled vertices: fewer cache misses
        P = ops.with_fixed_rows(ops.permuted(ops.P, "uniform-True"), None if fixed is None else fixed[order], "permuted-uniform-True")
        Y = chebyshev_heat(P, V[order], time, tol, backend)
        result = np.empty_like(Y)
        result[order] = Y
        return result
    _check_tau(ops, tau)
    steps = heat_steps(tau, time)
    if steps == 0:
        return np.array(V, dtype=np.float64)
    permuted = use_locality_order(ops, steps)
    M = step_matrix(ops, "uniform", tau, fixed, permuted=permuted)
    return run_linear_steps(M, V, steps, backend, ops.locality_order if permuted else None)

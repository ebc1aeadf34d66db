"""Heat diffusion on the random-walk Laplacian I - D^-1 W: explicit Euler, or exp(-T (I - D^-1 W)) X by Chebyshev."""

from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sp
from scipy.special import ive

from ..gpu import BACKENDS, Backend, get_backend
from ..operators import Operators, mask_key
from ..registry import MAX_ITERATIONS, AutoRule, Param, ParameterError, register
from .filtering import LocalityConfig, run_linear_steps, step_matrix, use_locality_order
from .heat_rule import HEAT_NORMALS, choose_heat

__all__ = ["heat", "heat_steps", "stable_tau", "chebyshev_coefficients", "chebyshev_heat", "ChebyshevHeat"]

METHODS = ("euler", "chebyshev")


def stable_tau(ops: Operators) -> float:
    """The largest stable Euler step ``2 / lambda_max(I - D^-1 W)`` for this topology (at least 1)."""
    lam = ops.lambda_max()
    return math.inf if lam == 0 else 2.0 / lam


def heat_steps(tau: float, time: float) -> int:
    """Number of Euler steps for ``time``: ``ceil(time / tau)`` (0 for time 0)."""
    # the tolerance keeps time = k * tau from becoming k + 1 steps through rounding
    ratio = time / tau
    if not ratio <= MAX_ITERATIONS:  # also inf (tau = 1e-300) and nan
        raise ParameterError(
            f"parameters 'time' = {time!r} and 'tau' = {tau!r} give ceil(time / tau) = {ratio:.3g} Euler steps, "
            f"more than the limit {MAX_ITERATIONS}: use a larger tau, a shorter time or method: chebyshev"
        )
    return max(0, math.ceil(ratio - 1e-9))


def _check_tau(ops: Operators, tau: float) -> None:
    # The eigenvalues of I - D^-1 W lie in [0, 2]: every tau <= 1 is stable without computing them.
    if tau <= 1.0:
        return
    limit = stable_tau(ops)
    if tau > limit * (1 + 1e-9):
        raise ParameterError(
            f"parameter 'tau' = {tau!r} is out of the stable range 0 < tau <= 2 / lambda_max = {limit:.6g} "
            f"for this mesh (lambda_max(I - D^-1 W) = {ops.lambda_max():.6g}): explicit Euler would diverge. "
            "Use a smaller tau; the same time T needs only ceil(T / tau) steps."
        )


# The default keeps exp's frequency response to within 1e-3: Euler with tau = 0.5, the paper's
# scheme, is 3.4e-3 away from it at T = 40, so the default is the more faithful of the two.
DEFAULT_TOL = 1e-3


def chebyshev_coefficients(time: float, tol: float, upper: float = 2.0) -> np.ndarray:
    r"""Coefficients :math:`a_k` with :math:`e^{-T x} \approx \sum_{k \le K} a_k T_k(1 - 2x/b)` on :math:`[0, b]`.

    With :math:`y = 1 - 2x/b` and :math:`T' = T b / 2`,
    :math:`e^{-T x} = e^{-T'(1 - y)} = e^{-T'} I_0(T') + 2 \sum_{k \ge 1} e^{-T'} I_k(T')\, T_k(y)`
    (modified Bessel functions; ``scipy.special.ive`` gives :math:`e^{-T'} I_k(T')` without
    overflow), truncated at the first ``K`` whose dropped tail
    :math:`s = 2 \sum_{k > K} e^{-T'} I_k(T')` is at most ``tol / 2``. The tail is then
    added to :math:`a_0` so that :math:`\sum a_k = 1`: the polynomial is exactly 1 at
    ``x = 0``, so translations (the constant vector) pass through unchanged. Since
    :math:`|T_k| \le 1` on the interval, the error is at most :math:`2 s \le` ``tol``
    uniformly on :math:`[0, b]`. The degree grows like :math:`\sqrt{T b \log(1/\mathrm{tol})}`:
    a smaller interval ``b = upper`` needs fewer terms.

    Examples
    --------
    >>> a = chebyshev_coefficients(40.0, 1e-7)
    >>> len(a), round(float(a.sum()), 12)
    (36, 1.0)
    >>> len(chebyshev_coefficients(40.0, 1e-7, upper=1.5))  # a closed mesh's interval
    32
    """
    if not 0.0 < upper <= 2.0:
        raise ValueError(f"upper = {upper!r} must lie in (0, 2]: the spectrum of I - D^-1 W is inside [0, 2]")
    t = time * upper / 2.0
    if t == 0:
        return np.ones(1)
    if not t <= MAX_ITERATIONS:  # the series needs about t terms
        raise ParameterError(
            f"parameter 'time' = {time!r} needs about {t:.3g} Chebyshev terms, more than the limit {MAX_ITERATIONS}"
        )
    kmax = int(math.ceil(t + 12.0 * math.sqrt(t) + 30))
    c = ive(np.arange(kmax + 1), t)
    tails = 2.0 * np.cumsum(c[::-1])[::-1]  # tails[k] = 2 sum_{j >= k} c_j
    K = int(np.argmax(np.append(tails[1:], 0.0) <= tol / 2))
    a = 2.0 * c[: K + 1]
    a[0] = c[0]
    a[0] += 1.0 - a.sum()
    return a


class ChebyshevHeat:
    r"""``exp(-T (I - P)) X`` for any ``X`` and ``T``, by a Chebyshev series in ``P``; reusable.

    ``P`` is ``D^-1 W`` (pinned rows as identity rows allowed) and ``upper`` an upper bound
    on the spectrum of ``I - P`` (:attr:`~meshdenoise.operators.Operators.lambda_max_bound`).
    With :math:`M = I - \tfrac{2}{b}(I - P)`, whose spectrum lies in [-1, 1],

    .. math:: e^{-T(I - P)} X \approx \sum_{k=0}^{K} a_k U_k, \qquad U_0 = X,\; U_1 = M X,\;
              U_{k+1} = 2 M U_k - U_{k-1}

    (:func:`chebyshev_coefficients`; :math:`U_k = T_k(M) X`). ``P`` is similar to the
    symmetric :math:`D^{-1/2} W D^{-1/2}`, so the error is at most ``tol`` times
    :math:`\sqrt{d_{max}/d_{min}}\,\|X - \bar X\|` (the constant part is exact).
    One sparse product per degree and one pass over the sum per two degrees, three
    coordinate buffers: the recurrence runs in place by keeping :math:`\pm U_k` and adding
    :math:`\pm 2 M U_k` into the older buffer. The object holds :math:`\pm 2M` on the backend, built once.

    Examples
    --------
    >>> import numpy as np, scipy.sparse as sp, scipy.linalg as sl
    >>> P = sp.csr_matrix((np.ones(6) / 2, [1, 2, 0, 2, 0, 1], [0, 2, 4, 6]), shape=(3, 3))  # a triangle
    >>> X = np.array([[1.0], [0.0], [0.0]])
    >>> Y = ChebyshevHeat(P, upper=1.5)(X, time=2.0, tol=1e-12)
    >>> bool(np.allclose(Y, sl.expm(-2.0 * (np.eye(3) - P.toarray())) @ X, atol=1e-12))
    True
    """

    def __init__(self, P, upper: float = 2.0, backend: str | Backend = "cpu"):
        if not 0.0 < upper <= 2.0:
            raise ValueError(f"upper = {upper!r} must lie in (0, 2]: the spectrum of I - D^-1 W is inside [0, 2]")
        self.backend = be = get_backend(backend) if isinstance(backend, str) else backend
        self.upper = float(upper)
        P = sp.csr_matrix(P, dtype=np.float64)
        # 2M = 2(1 - 2/b) I + (4/b) P: the interval map folded into the one matrix of each product
        two_m = (4.0 / self.upper) * P
        if self.upper != 2.0:
            two_m = two_m + sp.diags(np.full(P.shape[0], 2.0 - 4.0 / self.upper))
        two_m = sp.csr_matrix(two_m)
        two_m.sort_indices()
        self._two_m = {1.0: be.matrix(two_m)}
        self._two_m[-1.0] = be.scaled(self._two_m[1.0], -1.0)  # shares the index arrays

    def __call__(self, X: np.ndarray, time: float, tol: float = DEFAULT_TOL, *, overwrite_x: bool = False) -> np.ndarray:
        """The series at ``time`` to ``tol`` on ``X`` (n, k); ``overwrite_x=True`` lets it use ``X`` as scratch."""
        be = self.backend
        a = chebyshev_coefficients(float(time), float(tol), self.upper)
        X0 = be.asarray_owned(X) if overwrite_x else be.asarray(X)
        if len(a) == 1:
            return be.to_new_numpy(X0)
        res = be.zeros_like(X0)
        older = X0  # holds sign[k-1] * U_{k-1}; X0 is ours to overwrite
        newer = be.spmm(self._two_m[1.0], X0)  # 2 U_1: no third matrix kept for one product
        be.axpy2(a[0], X0, a[1] / 2, newer, res)
        be.axpy(-0.5, newer, newer)
        sign = [1.0, 1.0]  # sign[k] of the stored U_k: period 1, 1, -1, -1 lets the kernel only add
        pending = None  # a term left for the next pass over res: one pass adds two terms
        for k in range(1, len(a) - 1):
            s_next = -sign[k - 1]
            be.spmm(self._two_m[s_next * sign[k]], newer, out=older, accumulate=True)  # = s_next * U_{k+1}
            if pending is None:
                pending = s_next * a[k + 1]  # stays intact in `newer` after the swap below
            else:
                be.axpy2(pending, newer, s_next * a[k + 1], older, res)
                pending = None
            sign.append(s_next)
            older, newer = newer, older
        if pending is not None:
            be.axpy(pending, newer, res)
        return be.to_new_numpy(res)


def chebyshev_heat(
    P, X: np.ndarray, time: float, tol: float = DEFAULT_TOL, backend: str | Backend = "cpu", upper: float = 2.0
) -> np.ndarray:
    r"""``exp(-T (I - P)) X`` for a matrix ``P`` with the spectrum of ``I - P`` in ``[0, upper]``.

    One-off form of :class:`ChebyshevHeat` (which keeps its matrices for further calls).

    Examples
    --------
    >>> import numpy as np, scipy.sparse as sp
    >>> P = sp.csr_matrix((np.ones(6) / 2, [1, 2, 0, 2, 0, 1], [0, 2, 4, 6]), shape=(3, 3))
    >>> chebyshev_heat(P, np.ones((3, 1)), time=5.0).ravel()  # constants are pinned points
    array([1., 1., 1.])
    """
    return ChebyshevHeat(P, upper, backend)(X, time, tol)


@register(
    "heat",
    auto=AutoRule(("tau", "time"), choose_heat, normals="time", held_out=HEAT_NORMALS),
    summary="Heat diffusion to time T: Euler X <- X - tau (I - D^-1 W) X, ceil(T/tau) steps, or exp(-T (I - D^-1 W)) X by Chebyshev",
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
            DEFAULT_TOL,
            low=0.0,
            high=0.1,
            low_open=True,
            help="method='chebyshev': largest error of the polynomial replacing exp on the spectrum",
        ),
        Param("backend", str, "cpu", choices=BACKENDS, help="where the sparse products run (see meshdenoise.gpu)"),
    ],
    linear=True,
)
def heat(V, F, *, ops, pinned, tau, time, method, tol, backend, config=None):
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
    :math:`D^{-1}W` (:class:`ChebyshevHeat`) on the interval :math:`[0, b]` that holds the
    spectrum of :math:`I - D^{-1}W`, with ``b`` the bound
    :attr:`~meshdenoise.operators.Operators.lambda_max_bound` (1.5 on a closed mesh). Its degree
    grows like :math:`\\sqrt{T b \\log(1/\\mathrm{tol})}` instead of :math:`T/\\tau`: 19 products
    instead of 80 at ``T = 40, tau = 0.5``. ``tau`` is then unused. ``tol`` bounds the
    difference between the polynomial and :math:`e^{-T\\lambda}` on the spectrum (the
    filter's frequency response); the default 1e-3 is closer to the exact exponential than
    Euler with ``tau = 0.5`` (3.4e-3 away at ``T = 40``). The matrices are cached with the
    operators, so later calls on the same faces start at once. Pinned vertices are
    Dirichlet data in both methods (identity rows of :math:`D^{-1}W`).

    Choosing ``time`` for a scan: with noise of 0.1, 0.3 and 1 mean edge lengths along the
    normals the oracle chose ``time`` 0.5, 1-1.5 and 3 on a sphere, a torus and the bunny
    (``benchmarks/results/parameter-scale.md``): about three times the noise in edge lengths, at
    least 0.5.

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
        ``method="chebyshev"`` only: bound on the polynomial's error on the spectrum
        (default 1e-3; each factor of 10 smaller costs about two more products at ``T = 40``).
    backend : {"cpu", "scipy", "cupy", "torch"}
        Where the sparse products run; see :mod:`meshdenoise.gpu`.
    pinned, region, preserve_volume, operators
        Options shared by every filter; see the README.
    config : LocalityConfig, optional
        The array core's (``get_filter("heat").core``) relabelled path by size (``filtering``'s settings); ``None``:
        its default.

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
        return _chebyshev_with_cache(ops, V, pinned, time, tol, backend, config)
    _check_tau(ops, tau)
    steps = heat_steps(tau, time)
    if steps == 0:
        return np.array(V, dtype=np.float64)
    permuted = use_locality_order(ops, steps, config)
    M = step_matrix(ops, "uniform", tau, pinned, permuted=permuted)
    return run_linear_steps(M, V, steps, backend, ops.locality_order if permuted else None)


def _chebyshev_with_cache(ops: Operators, V: np.ndarray, pinned, time: float, tol: float, backend,
                          config: LocalityConfig | None = None) -> np.ndarray:
    """Chebyshev heat with its matrices cached on the operators (per pinned mask and backend)."""
    upper = ops.lambda_max_bound
    if upper == 0.0:  # no edges: nothing diffuses
        return np.array(V, dtype=np.float64)
    permuted = use_locality_order(ops, len(chebyshev_coefficients(time, tol, upper)), config)
    be_name = backend if isinstance(backend, str) else backend.name
    key = ("chebyshev_heat", permuted, mask_key(pinned), be_name)
    if key not in ops.cache:
        if permuted:  # same computation on relabelled vertices: fewer cache misses
            order = ops.locality_order
            P = ops.permuted(ops.P, "uniform-True")
            P = ops.with_pinned_rows(P, None if pinned is None else pinned[order], "permuted-uniform-True")
        else:
            P = ops.with_pinned_rows(ops.P, pinned, "P")
        ops.cache[key] = ChebyshevHeat(P, upper, backend)
    run = ops.cache[key]
    if not permuted:
        return run(V, time, tol)
    return ops.restore_rows(run(ops.reorder_rows(V), time, tol, overwrite_x=True))

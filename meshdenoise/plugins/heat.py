"""Heat diffusion: explicit Euler on the random-walk Laplacian I - D^-1 W."""

from __future__ import annotations

import math

import numpy as np

from ..operators import Operators
from ..registry import Param, register
from .filtering import smoothing_steps

__all__ = ["heat", "heat_steps", "stable_tau"]


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


@register(
    "heat",
    summary="Heat diffusion to time T by explicit Euler: X <- X - tau (I - D^-1 W) X, ceil(T/tau) steps",
    params=[
        Param("tau", float, 0.5, low=0.0, high=2.0, low_open=True, help="Euler step (stable up to 2/lambda_max)"),
        Param("time", float, 10.0, low=0.0, help="diffusion time T"),
    ],
    linear=True,
)
def heat(V, F, *, ops, fixed, tau, time):
    """Heat diffusion by explicit Euler steps (the paper's second method).

    .. math:: X^{(t+1)} = X^{(t)} - \\tau \\left(I - D^{-1} W\\right) X^{(t)}, \\qquad t = 0, \\dots, \\lceil T / \\tau \\rceil - 1

    Each step has length ``tau``, so the run ends at time :math:`\\lceil T/\\tau \\rceil \\tau`
    (``T`` rounded up to a whole number of steps). The scheme is stable when
    :math:`\\tau \\lambda_{max}(I - D^{-1}W) \\le 2`; every ``tau <= 1`` is stable, and a
    larger ``tau`` is checked against the mesh's largest eigenvalue (computed once per
    topology by Lanczos and cached): an unstable ``tau`` such as the paper's 1.42 on the
    elephant raises ``ValueError`` instead of returning garbage.

    Parameters
    ----------
    mesh : (V, F) tuple, pymeshlab.MeshSet or Mesh, or open3d.geometry.TriangleMesh
    tau : float, 0 < tau <= 2 / lambda_max
        Euler step.
    time : float, >= 0
        Diffusion time T.
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
    _check_tau(ops, tau)
    steps = smoothing_steps(V, ops, weights="uniform", lam=tau, fixed=fixed)
    X = np.array(V, dtype=np.float64)
    for _ in range(heat_steps(tau, time)):
        X = next(steps)
    return X

"""Risk estimates for choosing a smoother's parameters: SURE, GCV, Hutchinson trace probes.

Generic machinery: nothing here knows a filter. A rule (registered with its filter, see
:func:`meshdenoise.registry.register`) evaluates candidate parameters as :class:`Point`
objects and scores them with a :class:`Criterion`: SURE or GCV without the clean mesh,
or the true squared error against it (``"oracle"``, for benchmarks).

For a linear smoother :math:`\\hat X = H X` (the same ``n x n`` matrix on the three
coordinate columns) and noise :math:`E` with independent per-vertex covariance
:math:`\\Sigma_i = \\rho^2 N_i N_i^T` (the paper's model: unit-variance Gaussian along
the unit normal), expanding :math:`\\|HX - X^0\\|^2 = \\|HX - X + E\\|^2` gives Stein's
unbiased risk estimate (Stein 1981; for linear smoothers no Gaussianity is needed)

.. math:: \\mathrm{SURE}(H) = \\|H X - X\\|_F^2 - n \\rho^2 + 2 \\rho^2\\, \\mathrm{tr}(H),
          \\qquad \\mathbb E\\, \\mathrm{SURE}(H) = \\mathbb E \\|H X - X^0\\|_F^2,

because :math:`\\mathbb E \\langle E, H E\\rangle = \\sum_i H_{ii}\\, \\mathrm{tr}\\,\\Sigma_i = \\rho^2 \\mathrm{tr}(H)`.
The SNR is a decreasing function of :math:`\\|\\hat X - X^0\\|_F`, so minimising SURE
maximises the expected SNR. ``tr(H)`` is estimated by Hutchinson's estimator
:math:`\\mathrm{tr}(H) \\approx \\frac1m \\sum_k z_k^T H z_k` with Rademacher probes
:math:`z_k`, carried along the run: the probes go through the same sparse steps (or the
same Cholesky solves) as the coordinates, so the whole SURE curve of ``filtering`` /
``heat`` / ``taubin`` costs one run. Small meshes (``n <= EXACT_TRACE_MAX``) use the
identity as probe block, which gives the exact trace.

Generalised cross-validation (Craven and Wahba 1979),
:math:`\\mathrm{GCV}(H) = n \\|HX - X\\|_F^2 / (n - \\mathrm{tr} H)^2`, needs no noise
level and is offered as ``criterion="gcv"``; it assumes noise in all ``3n`` coordinates,
while the model's noise is along the normals only, and on a noisy sphere it picks a
Sobolev ``mu`` 3.4 dB worse than SURE's (tests/test_auto.py): SURE is the default.

For a nonlinear filter :math:`f`, the divergence term is estimated by Monte-Carlo
SURE (Ramani, Blu and Unser 2008): with :math:`b_i = \\rho z_i N_i`,
:math:`\\mathbb E\\, b^T (f(X + \\delta b) - f(X)) / \\delta \\to \\mathrm{tr}(\\Sigma J_f)`,
two filter runs per candidate.

References
----------
C. Stein, "Estimation of the mean of a multivariate normal distribution", Ann. Stat. 1981.
P. Craven, G. Wahba, "Smoothing noisy data with spline functions", Numer. Math. 1979.
M. F. Hutchinson, "A stochastic estimator of the trace of the influence matrix", 1990.
S. Ramani, T. Blu, M. Unser, "Monte-Carlo SURE", IEEE TIP 2008.
D. L. Donoho, I. M. Johnstone, "Ideal spatial adaptation by wavelet shrinkage", 1994 (MAD).
"""

from __future__ import annotations

import math
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass, field
from typing import Any, Iterator

import numpy as np

__all__ = ["sure", "gcv", "probe_block", "noise_colouring", "active_colouring", "colour_probes", "Point", "Criterion",
           "EXACT_TRACE_MAX", "N_PROBES", "MC_SURE_STEP", "MC_SURE_STEP_CORRELATED", "mc_sure_step"]

EXACT_TRACE_MAX = 800  # up to this many vertices the trace is exact (identity probes)
N_PROBES = 24  # Rademacher probes otherwise: trace error ~ sqrt(2 ||H||_F^2 / 24), negligible next to n rho^2
MC_SURE_STEP = 0.1  # finite-difference step of Monte-Carlo SURE, in units of rho
# under correlated noise a nonlinear filter's response to a 0.1 rho probe missed 10-12 % of the realised
# covariance of the noise (two_stage on the bunny with scanner noise, docs/automatic-parameters.md): one rho
MC_SURE_STEP_CORRELATED = 1.0


def mc_sure_step(rho: float, correlated: bool) -> float:
    """The finite-difference step of Monte-Carlo SURE (Ramani et al. 2008) for a nonlinear filter.

    Parameters
    ----------
    rho : float
        The noise level (standard deviation per coordinate along the probe directions), >= 0.
    correlated : bool
        Whether the noise is spatially correlated (the probes are coloured like it).

    Returns
    -------
    float
        ``MC_SURE_STEP * rho`` for independent noise, ``MC_SURE_STEP_CORRELATED * rho`` for correlated
        noise, where the smaller step reads the filter's divergence short.

    Examples
    --------
    >>> mc_sure_step(0.5, False), mc_sure_step(0.5, True)
    (0.05, 0.5)
    """
    if not (math.isfinite(rho) and rho >= 0):
        raise ValueError(f"mc_sure_step: rho must be finite and >= 0, got {rho!r}")
    return (MC_SURE_STEP_CORRELATED if correlated else MC_SURE_STEP) * float(rho)


@dataclass
class Point:
    """One evaluated candidate: its parameter value, :math:`\\|f(X) - X\\|_F^2`, the trace (or
    divergence) term, the filtered coordinates ``X`` (n, 3) and, once scored, its ``score``."""

    value: float
    residual_sq: float
    trace: float
    X: np.ndarray = field(repr=False)
    score: float = math.inf


@dataclass(frozen=True)
class Criterion:
    """How a :class:`Point` is scored: ``"sure"`` (needs ``rho``), ``"gcv"`` or ``"oracle"`` (needs ``reference``).

    Examples
    --------
    >>> import numpy as np
    >>> p = Point(0, residual_sq=0.0, trace=10.0, X=np.zeros((10, 3)))
    >>> Criterion("sure").score(p, n=10, rho=1.0), Criterion("oracle", np.ones((10, 3))).score(p, 10, None)
    (10.0, 30.0)
    """

    name: str
    reference: np.ndarray | None = field(default=None, repr=False, compare=False)

    def __post_init__(self) -> None:
        if self.name not in ("sure", "gcv", "oracle"):
            raise ValueError(f"criterion must be 'sure', 'gcv' or 'oracle', got {self.name!r}")
        if (self.name == "oracle") != (self.reference is not None):
            raise ValueError("criterion 'oracle' needs a reference (the clean mesh), and only it takes one")

    @property
    def oracle(self) -> bool:
        return self.name == "oracle"

    def score(self, p: Point, n: int, rho: float | None) -> float:
        """The score of ``p`` (smaller is better) for a smoother of ``n`` vertices and noise ``rho``."""
        if self.reference is not None:
            return float(np.sum((p.X - self.reference) ** 2))
        if self.name == "sure":
            return sure(p.residual_sq, p.trace, n, rho)
        return gcv(p.residual_sq, p.trace, n)


def as_criterion(criterion: "Criterion | str") -> Criterion:
    """``criterion`` as a :class:`Criterion` (a name is ``"sure"`` or ``"gcv"``)."""
    return criterion if isinstance(criterion, Criterion) else Criterion(criterion)


def sure(residual_sq: float, trace: float, n: int, rho: float) -> float:
    """Stein's unbiased estimate of :math:`\\|HX - X^0\\|_F^2` for a linear smoother.

    .. math:: \\mathrm{SURE} = \\|HX - X\\|_F^2 - n\\rho^2 + 2\\rho^2\\, \\mathrm{tr}(H)

    Parameters
    ----------
    residual_sq : float
        :math:`\\|HX - X\\|_F^2` (all three coordinates).
    trace : float
        :math:`\\mathrm{tr}(H)` of the ``n x n`` smoother.
    n : int
        Number of vertices.
    rho : float
        Noise level (standard deviation of the normal displacement).

    Examples
    --------
    >>> sure(residual_sq=0.0, trace=10.0, n=10, rho=1.0)  # H = I: the noise itself, n rho^2
    10.0
    """
    return float(residual_sq - n * rho**2 + 2.0 * rho**2 * trace)


def gcv(residual_sq: float, trace: float, n: int) -> float:
    """Generalised cross-validation score :math:`n \\|HX - X\\|_F^2 / (n - \\mathrm{tr} H)^2`.

    Examples
    --------
    >>> gcv(residual_sq=4.0, trace=8.0, n=10)
    10.0
    """
    denom = (n - trace) ** 2
    return float("inf") if denom <= 0 else float(n * residual_sq / denom)


_COLOURING: ContextVar[Any] = ContextVar("meshdenoise_noise_colouring", default=None)


@contextmanager
def noise_colouring(model: Any) -> Iterator[None]:
    """Within this block, :func:`probe_block` colours its probes by ``model`` (a
    :class:`~meshdenoise.tuning.covariance.NoiseModel`, or ``None`` / an independent model: no colouring).

    :func:`~meshdenoise.tuning.choose.choose_parameters` runs a filter's rule inside it, so
    that every rule built on the shared probes (the iterative paths, the shifted solves,
    their traces) scores SURE with :math:`\\mathrm{tr}(H\\Sigma)` without code of its own.
    """
    token = _COLOURING.set(model if model is not None and getattr(model, "correlated", False) else None)
    try:
        yield
    finally:
        _COLOURING.reset(token)


def active_colouring() -> Any:
    """The correlated noise model :func:`noise_colouring` made active, or ``None``."""
    return _COLOURING.get()


def colour_probes(Z: np.ndarray, s: float, model: Any = None) -> np.ndarray:
    """``Z`` (n, m) coloured by ``model`` (default: the active one); ``Z`` itself when there is none.

    For Monte-Carlo SURE probes drawn by a rule itself (``b = z N``: colour ``z``).
    """
    model = model if model is not None else _COLOURING.get()
    if model is None or not getattr(model, "correlated", False):
        return Z
    if model.V is not None and model.V.shape[0] != Z.shape[0]:
        raise ValueError(f"colour_probes: the noise model has {model.V.shape[0]} vertices, the probes {Z.shape[0]} rows")
    return model.colour(Z, s)


def probe_block(n: int, exact: bool | None = None, n_probes: int = N_PROBES, seed: int = 0,
                colour: Any = None) -> tuple[np.ndarray, float]:
    """Trace probes ``Z`` (n, m) and the scale ``s`` such that ``tr(H Sigma) ~ s * sum(Z * (H Z))``.

    Exact (``Z = I``, ``s = 1``) when ``exact`` is True, or when it is None and
    ``n <= EXACT_TRACE_MAX``; otherwise ``n_probes`` Rademacher columns, ``s = 1/m``
    (Hutchinson: :math:`\\mathbb E z^T H z = \\mathrm{tr} H` for :math:`z_i = \\pm 1`).
    :math:`\\Sigma = I` (independent noise) unless a correlated noise model is given
    (``colour``) or active (:func:`noise_colouring`): then the probes are
    :math:`\\Sigma^{1/2} Z` (:meth:`~meshdenoise.tuning.covariance.NoiseModel.colour`), and
    :math:`\\mathbb E\\, z^T H z = \\mathrm{tr}(\\Sigma^{1/2} H \\Sigma^{1/2}) = \\mathrm{tr}(H\\Sigma)`.

    Examples
    --------
    >>> import numpy as np
    >>> H = np.arange(16.0).reshape(4, 4)
    >>> Z, s = probe_block(4)
    >>> float(s * np.sum(Z * (H @ Z)))  # exact on a small matrix: 0 + 5 + 10 + 15
    30.0
    """
    if exact is None:
        exact = n <= EXACT_TRACE_MAX
    if exact:
        Z, s = np.eye(n), 1.0
    else:
        rng = np.random.default_rng(seed)
        Z, s = rng.choice([-1.0, 1.0], size=(n, n_probes)), 1.0 / n_probes
    return colour_probes(Z, s, colour), s

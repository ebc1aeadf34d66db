"""Recorrupted pairs: a risk estimate for any filter from the noisy mesh alone (Pang et al. 2021).

Generic machinery: nothing here knows a filter. Given noisy positions :math:`Y = X^0 + E` and a
draw :math:`Z` from the same noise model as :math:`E` (independent of it), the pair

.. math:: Y^+ = Y + a Z, \\qquad Y^- = Y - Z / a

has noises :math:`E + aZ` and :math:`E - Z/a` whose cross-covariance is
:math:`\\Sigma - \\Sigma = 0`; for Gaussian noise they are independent. Filtering :math:`Y^+` and
scoring against :math:`Y^-` then estimates the filter's risk at the inflated noise level
:math:`\\sqrt{1 + a^2}\\, \\rho` without the clean mesh:

* **positions**: :math:`\\mathbb E \\|f(Y^+) - Y^-\\|^2 = \\mathbb E \\|f(Y^+) - X^0\\|^2 +
  \\mathbb E \\|E - Z/a\\|^2`, the second term the same for every candidate
  (:math:`(1 + a^{-2})` times the noise energy; :func:`position_risk` removes it);
* **face normals**: the unnormalised face normal :math:`c_f(X) = (x_b - x_a) \\times (x_c - x_a)`
  is bilinear in the positions, and with independent zero-mean noise on the corners its
  expectation is the clean one, :math:`\\mathbb E\\, c_f(Y^-) = c_f(X^0)` (the terms
  :math:`e_b \\times e_c` have mean 0; :math:`e_a \\times e_a = 0`). So

  .. math:: \\mathbb E\\, \\Big[-\\sum_f w_f\\, u_f(f(Y^+)) \\cdot c_f(Y^-)\\Big]
            = -\\sum_f w_f\\, |c_f(X^0)|\\ \\mathbb E \\cos\\theta_f,

  :math:`u_f` the unit face normal of the filtered mesh and :math:`\\theta_f` its angle to the
  clean face normal: with :math:`w_f \\approx 1 / |c_f(X^0)|` (a fixed reference's face areas)
  an unbiased ranking of candidates by the mean of :math:`1 - \\cos\\theta_f`, the squared
  chord between the normals. Correlated noise leaves :math:`\\mathbb E\\, e_b \\times e_c =
  C_{bc}\\, N_b \\times N_c` (small when neighbouring normals are near parallel).

The recorruption is the caller's noise model: ``sampler(rng)`` returns one draw :math:`Z`
(n, 3). :func:`recorrupted_scores` averages ``draws`` independent pairs: the estimate of one
pair carries the variance of one noise realisation at the inflated level.

References
----------
T. Pang, H. Zheng, Y. Quan, H. Ji, "Recorrupted-to-Recorrupted: Unsupervised Deep Learning for
Image Denoising", CVPR 2021.
J. Moran, A. Meiring, J. Holloway, "Noisier2Noise: Learning to Denoise from Unpaired Noisy Data",
CVPR 2020.
"""

from __future__ import annotations

from typing import Callable, Iterable, Sequence

import numpy as np

from ..geometry import face_normals

__all__ = ["recorrupt", "cross_normals", "position_score", "normal_score", "position_risk", "recorrupted_scores"]


def recorrupt(Y: np.ndarray, Z: np.ndarray, a: float) -> tuple[np.ndarray, np.ndarray]:
    """The recorrupted pair :math:`(Y + aZ,\\ Y - Z/a)`, each shape (n, 3), of noisy positions ``Y`` and a noise draw ``Z`` (n, 3).

    Raises
    ------
    ValueError
        When ``a`` is not a positive finite number or the shapes differ.
    """
    a = float(a)
    if not np.isfinite(a) or a <= 0:
        raise ValueError(f"recorrupt: a must be positive and finite, got {a!r}")
    Y = np.asarray(Y, dtype=np.float64)
    Z = np.asarray(Z, dtype=np.float64)
    if Y.shape != Z.shape:
        raise ValueError(f"recorrupt: Y {Y.shape} and Z {Z.shape} differ in shape")
    return Y + a * Z, Y - Z / a


def cross_normals(X: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Unnormalised face normals :math:`(x_b - x_a) \\times (x_c - x_a)` (twice the area times the unit normal), shape (m, 3)."""
    X = np.asarray(X, dtype=np.float64)
    F = np.asarray(F)
    P0 = X[F[:, 0]]
    return np.cross(X[F[:, 1]] - P0, X[F[:, 2]] - P0)


def position_score(X: np.ndarray, target: np.ndarray, rows: np.ndarray | None = None) -> float:
    """:math:`\\|X - Y^-\\|_F^2` over ``rows`` (bool or int index into the n vertices; all when None); ``X``, ``target`` (n, 3)."""
    D = np.asarray(X, dtype=np.float64) - np.asarray(target, dtype=np.float64)
    if rows is not None:
        D = D[rows]
    return float(np.sum(D * D))


def normal_score(X: np.ndarray, F: np.ndarray, target_cross: np.ndarray, faces: np.ndarray | None = None,
                 weights: np.ndarray | None = None) -> float:
    """:math:`-\\sum_f w_f\\, u_f(X) \\cdot c_f(Y^-)`: lower is better.

    Parameters
    ----------
    X : ndarray, shape (n, 3)
        The filtered positions (of :math:`Y^+`).
    F : ndarray of int, shape (m, 3)
        Faces.
    target_cross : ndarray, shape (k, 3)
        :func:`cross_normals` of :math:`Y^-` on ``F[faces]``.
    faces : ndarray of bool, shape (m,), optional
        The faces scored (all when None).
    weights : ndarray, shape (k,), optional
        :math:`w_f` (1 when None); the reciprocal of a fixed reference's :func:`cross_normals`
        lengths makes the score a mean of :math:`-\\cos\\theta_f` (see the module's text).
    """
    U = face_normals(X, F)
    if faces is not None:
        U = U[faces]
    d = np.einsum("ij,ij->i", U, np.asarray(target_cross, dtype=np.float64))
    if weights is not None:
        d = d * weights
    return -float(np.sum(d))


def position_risk(score: float | np.ndarray, noise_energy: float, a: float) -> float | np.ndarray:
    """The risk :math:`\\mathbb E \\|f(Y^+) - X^0\\|^2` estimated from :func:`position_score`: ``score`` less :math:`(1 + a^{-2})` ``noise_energy``.

    ``noise_energy``: :math:`\\mathbb E \\|E\\|^2` over the scored rows (for the normal-noise model,
    :math:`\\rho^2` times their count).
    """
    return score - (1.0 + 1.0 / float(a) ** 2) * float(noise_energy)


def recorrupted_scores(run: Callable[[np.ndarray], Iterable[np.ndarray]], Y: np.ndarray,
                       sampler: Callable[[np.random.Generator], np.ndarray],
                       score: Callable[[np.ndarray, np.ndarray], float | Sequence[float]], a: float = 1.0,
                       draws: int = 1, seed: int = 0, length: int | None = None) -> np.ndarray:
    """Scores of a filter's outputs on recorrupted pairs, shape (draws, K), or (draws, K, S) for S scores per output.

    Parameters
    ----------
    run : callable
        ``run(Yplus)`` yields K filtered versions of ``Yplus`` (n, 3) (e.g. along the outer
        iterations of one run; one for a single output).
    Y : ndarray, shape (n, 3)
        The noisy positions.
    sampler : callable
        ``sampler(rng)`` returns one draw (n, 3) of the noise model (``rng`` a
        :class:`numpy.random.Generator`).
    score : callable
        ``score(X, Yminus)`` of one output and the pair's target: e.g.
        ``lambda X, T: position_score(X, T, rows)`` or, for face normals,
        ``lambda X, T: normal_score(X, F, cross_normals(T, F)[faces], faces, w)``; a sequence of
        S floats gives S scores of each output from one run.
    a : float
        The recorruption's strength (the estimate's noise level is :math:`\\sqrt{1 + a^2}\\,\\rho`).
    draws : int
        Independent pairs (rows of the result), from ``np.random.default_rng(seed)``.
    length : int, optional
        Read at most this many outputs of each run; runs of different lengths are cut to the shortest.

    Raises
    ------
    ValueError
        When ``draws`` < 1 or a run yields nothing.
    """
    if int(draws) < 1:
        raise ValueError(f"recorrupted_scores: draws must be at least 1, got {draws!r}")
    rng = np.random.default_rng(seed)
    rows = []
    for _ in range(int(draws)):
        plus, minus = recorrupt(Y, sampler(rng), a)
        values = []
        for X in run(plus):
            values.append(score(X, minus))
            if length is not None and len(values) >= length:
                break
        if not values:
            raise ValueError("recorrupted_scores: the run yielded no output")
        rows.append(values)
    K = min(len(r) for r in rows)
    return np.array([r[:K] for r in rows], dtype=np.float64)

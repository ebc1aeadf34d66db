"""Quality measures of a denoised mesh against a reference."""

from __future__ import annotations

from typing import Any

import numpy as np

from .adapters import mesh_kind, to_arrays
from .arrays import check_vertices

__all__ = ["snr", "coordinates", "METRICS", "compute_metrics"]


def coordinates(mesh: Any) -> np.ndarray:
    """Vertex coordinates ``(n, 3) float64`` of any supported mesh, or of a bare ``(n, 3)`` array."""
    if isinstance(mesh, np.ndarray) or (isinstance(mesh, (list, tuple)) and len(mesh) != 2):
        return check_vertices(mesh)
    try:
        mesh_kind(mesh)
    except TypeError:
        return check_vertices(mesh)
    return to_arrays(mesh, allow_no_faces=True)[0]


def snr(reference: Any, candidate: Any) -> float:
    """Signal-to-noise ratio of ``candidate`` against ``reference``, in dB.

    .. math:: \\mathrm{SNR}(X, Y) = -20 \\log_{10} \\frac{\\|X - Y\\|_F}{\\|Y\\|_F}

    with :math:`Y` the reference (clean) coordinates and :math:`X` the candidate's, the
    same vertices in the same order. ``inf`` when they are identical. Either argument
    may be any supported mesh type or an ``(n, 3)`` array.

    Raises
    ------
    ValueError
        Different vertex counts, or a reference with all coordinates zero.

    Examples
    --------
    >>> import numpy as np
    >>> Y = np.array([[1.0, 0, 0], [0, 1.0, 0]])
    >>> round(snr(Y, Y * 1.1), 6)  # ||X - Y|| / ||Y|| = 0.1
    20.0
    >>> snr(Y, Y)
    inf
    """
    Y = coordinates(reference)
    X = coordinates(candidate)
    if X.shape != Y.shape:
        raise ValueError(f"snr: the candidate has {X.shape[0]} vertices, the reference {Y.shape[0]}")
    ref = np.linalg.norm(Y)
    if ref == 0:
        raise ValueError("snr: the reference has all coordinates zero, so its norm is 0")
    err = np.linalg.norm(X - Y)
    if err == 0:
        return float("inf")
    return float(-20.0 * np.log10(err / ref))


# name -> function(reference, candidate) -> float. Every entry is available by name in the API,
# the YAML `metrics` step and the results tables.
METRICS: dict = {"snr": snr}


def compute_metrics(reference: Any, candidate: Any, names: list[str] | None = None) -> dict[str, float]:
    """The named metrics (all of :data:`METRICS` by default) of ``candidate`` against ``reference``.

    Examples
    --------
    >>> import numpy as np
    >>> Y = np.array([[1.0, 0, 0], [0, 1.0, 0]])
    >>> compute_metrics(Y, Y * 1.1, ["snr"])
    {'snr': 20.0...}
    """
    chosen = list(METRICS) if names is None else names
    unknown = [n for n in chosen if n not in METRICS]
    if unknown:
        raise ValueError(f"unknown metric(s) {unknown}; known: {', '.join(METRICS)}")
    return {n: METRICS[n](reference, candidate) for n in chosen}

from . import quality_metrics  # noqa: E402,F401  (registers normal error, distances and volume change in METRICS)

"""A tuning walk's records: the residual and trace terms of a state in one pass over its rows."""

from __future__ import annotations

import sys

import numpy as np
from numba import prange

from .threads import njit


# --------------------------------------------------------------------------- walk records
CURVE_CHUNK = 1 << 14  # rows per partial sum: fixed, so the sums do not depend on the thread count


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def _curve_partials(Y, V, Z, out):  # pragma: no cover - compiled
    n, c = V.shape
    p = Z.shape[1]
    for b in prange(out.shape[0]):
        r = 0.0
        t = 0.0
        for i in range(b * CURVE_CHUNK, min(n, (b + 1) * CURVE_CHUNK)):
            for j in range(c):
                d = Y[i, j] - V[i, j]
                r += d * d
            for j in range(p):
                t += Z[i, j] * Y[i, c + j]
        out[b, 0] = r
        out[b, 1] = t


def curve_terms(Y: np.ndarray, V: np.ndarray, Z: np.ndarray) -> tuple[float, float]:
    """``sum((Y[:, :c] - V)**2)`` and ``sum(Z * Y[:, c:])`` in one pass over the rows, no temporaries.

    ``Y`` (n, c + p) the state of a walk (its coordinates, then its probes), ``V`` (n, c), ``Z``
    (n, p), all C-contiguous float64. Partial sums over fixed blocks of :data:`CURVE_CHUNK` rows,
    added in block order: the same numbers on any number of threads (they differ from numpy's
    ``einsum`` in the last places only).
    """
    n, c = V.shape
    if Y.shape != (n, c + Z.shape[1]) or Z.shape[0] != n:
        raise ValueError(f"curve_terms: Y {Y.shape}, V {V.shape} and Z {Z.shape} do not match")
    Y, V, Z = (np.ascontiguousarray(a, dtype=np.float64) for a in (Y, V, Z))
    sys.modules[__package__].set_threads()  # the package's: where callers (and tests) replace it
    out = np.empty(((n + CURVE_CHUNK - 1) // CURVE_CHUNK, 2))
    _curve_partials(Y, V, Z, out)
    return float(out[:, 0].sum()), float(out[:, 1].sum())

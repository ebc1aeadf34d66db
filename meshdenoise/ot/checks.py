"""Checks of the optimal-transport functions' arguments, shared by the modules of :mod:`meshdenoise.ot`.

Each raises ``TypeError`` or ``ValueError`` naming the bad argument and its value, and returns the value
converted (``float``, ``int``, a float64 array).
"""

from __future__ import annotations

import numbers

import numpy as np

# what the scaling iterations' warnings advise when they stop without converging or overflow
_HINT = "increase numItermax or reg, or use method='sinkhorn_log'"


def _positive_float(name, value, allow_zero=False):
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(f"{name} must be a real number, got {value!r} ({type(value).__name__})")
    value = float(value)
    if not np.isfinite(value) or value < 0 or (value == 0 and not allow_zero):
        bound = ">= 0" if allow_zero else "> 0"
        raise ValueError(f"{name} must be finite and {bound}, got {value!r}")
    return value


def _positive_int(name, value):
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise TypeError(f"{name} must be an integer, got {value!r} ({type(value).__name__})")
    if value < 1:
        raise ValueError(f"{name} must be >= 1, got {value!r}")
    return int(value)


def _float_array(name, value, ndim):
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"{name} must be a real array, got {value!r}") from exc
    if arr.ndim not in ndim:
        raise ValueError(f"{name} must have {' or '.join(map(str, ndim))} dimension(s), got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains non-finite values: {arr!r}")
    return arr


def _histogram(name, value, ndim=(1,)):
    arr = _float_array(name, value, ndim)
    if arr.size == 0:
        raise ValueError(f"{name} is empty")
    if np.any(arr < 0):
        raise ValueError(f"{name} has negative entries (min {arr.min()!r})")
    return arr


def _weights(weights, k):
    if weights is None:
        return np.full(k, 1.0 / k)
    w = _float_array("weights", weights, (1,))
    if w.shape != (k,):
        raise ValueError(f"weights must have shape ({k},), got shape {w.shape}")
    if np.any(w < 0) or not np.isclose(w.sum(), 1.0, rtol=0, atol=1e-8):
        raise ValueError(f"weights must be non-negative and sum to 1, got {w!r}")
    return w


def _check_method(method):
    if not isinstance(method, str):
        raise TypeError(f"method must be a string, got {method!r}")
    if method.lower() not in ("sinkhorn", "sinkhorn_log"):
        raise ValueError(f"method must be 'sinkhorn' or 'sinkhorn_log', got {method!r}")
    return method.lower()



def _safe_log(x):
    with np.errstate(divide="ignore"):
        return np.log(x)



def _mesh_arrays(V, F):
    V = _float_array("V", V, (2,))
    if V.shape[1] != 3 or V.shape[0] == 0:
        raise ValueError(f"V must have shape (n, 3), got {V.shape}")
    Fa = np.asarray(F)
    if Fa.ndim != 2 or Fa.shape[1] != 3 or Fa.shape[0] == 0:
        raise ValueError(f"F must have shape (m, 3), got {Fa.shape}")
    if not np.issubdtype(Fa.dtype, np.integer):
        raise TypeError(f"F must be an integer array, got dtype {Fa.dtype}")
    Fa = Fa.astype(np.int64)
    if Fa.min() < 0 or Fa.max() >= V.shape[0]:
        raise ValueError(f"F indexes vertices outside [0, {V.shape[0]}): min {Fa.min()}, max {Fa.max()}")
    return V, Fa


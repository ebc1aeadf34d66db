"""Wall-clock times of the best settings: median of repeats in this process, no SNR bookkeeping inside."""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from ..metrics import snr
from ..plugins.sobolev import SobolevSolver
from ..registry import get_filter
from .batch import NoisyBatch
from .result import SearchResult

__all__ = ["median_seconds", "time_best", "time_curve", "TIME_CURVES"]


def median_seconds(fn: Callable[[int], object], min_repeats: int = 3, max_repeats: int = 25, budget: float = 0.5) -> tuple[float, int]:
    """Median wall time of ``fn(i)`` over repeats ``i = 0, 1, ...``: at least ``min_repeats``, then until ``budget`` seconds.

    Examples
    --------
    >>> seconds, repeats = median_seconds(lambda i: sum(range(100)), budget=0.0)
    >>> repeats, seconds > 0
    (3, True)"""
    times = []
    start = time.perf_counter()
    while len(times) < min_repeats or (len(times) < max_repeats and time.perf_counter() - start < budget):
        t0 = time.perf_counter()
        fn(len(times))
        times.append(time.perf_counter() - t0)
    return float(np.median(times)), len(times)


def _cold_sobolev(batch: NoisyBatch, params: dict) -> Callable[[int], object]:
    # A fresh factorisation every call: what the first call on a new mesh (or a new mu) costs.
    return lambda i: SobolevSolver(batch.ops, params["mu"]).solve(batch.noisy(i % batch.n_seeds)) if params["mu"] else None


# Method -> builder of a "first call" timer, for filters whose warm call reuses a cached factorisation.
COLD_TIMERS: dict[str, Callable[[NoisyBatch, dict], Callable[[int], object]]] = {"sobolev": _cold_sobolev}


def time_best(result: SearchResult, batch: NoisyBatch, budget: float = 0.5) -> dict:
    """Time the registered filter at ``result``'s best setting on the noisy meshes, and cross-check its SNR.

    The filter is called through its public function with the cached operators (as a
    user calling it twice on one mesh would), cycling over the seeds' noisy meshes. A
    warm-up call fills the caches; its SNR on seed 0 must equal the searched value to
    1e-6 dB, a check that the search computed what the filter does.

    Returns ``{"seconds", "repeats", "seconds_cold", "check_snr"}`` (``seconds_cold``:
    with the factorisation, for filters in :data:`COLD_TIMERS`, else ``None``).
    """
    spec = get_filter(result.method)
    params = result.best_params
    meshes = [(np.array(batch.noisy(s)), batch.F) for s in range(batch.n_seeds)]
    Y, _ = spec.public(meshes[0], operators=batch.ops, **params)
    check = snr(batch.V, Y)
    expected = result.snr[result.best_index, 0]
    if not abs(check - expected) <= 1e-6 * max(1.0, abs(expected)):
        raise RuntimeError(
            f"reproduce: {result.method} {params} on {batch.mesh} rho={batch.rho} seed {batch.seeds[0]} scores "
            f"{check:.9f} dB when run, but the search computed {expected:.9f} dB"
        )
    seconds, repeats = median_seconds(
        lambda i: spec.public(meshes[i % len(meshes)], operators=batch.ops, **params), budget=budget
    )
    cold = None
    if result.method in COLD_TIMERS:
        cold, _ = median_seconds(COLD_TIMERS[result.method](batch, params), budget=budget)
    return {"seconds": seconds, "repeats": repeats, "seconds_cold": cold, "check_snr": check}


# Method -> (parameter plotted, values, other parameters from the best setting or fixed)
TIME_CURVES: dict[str, tuple[str, tuple]] = {
    "filtering": ("iterations", (1, 2, 5, 10, 20, 50, 100)),
    "heat": ("time", (0.5, 1, 2, 5, 10, 20, 50)),
    "sobolev": ("mu", (0.01, 0.1, 1.0, 10.0, 100.0)),
}


def time_curve(method: str, batch: NoisyBatch, best_params: dict, budget: float = 0.2) -> dict:
    """Median time of ``method`` at each value of its :data:`TIME_CURVES` parameter (others at ``best_params``).

    Returns ``{"param", "values", "seconds", "seconds_cold"}``; heat keeps the best tau and
    drops the times that would need more than 2000 steps.
    """
    param, values = TIME_CURVES[method]
    spec = get_filter(method)
    mesh = (np.array(batch.noisy(0)), batch.F)
    warm, cold = [], []
    if method == "heat":  # a tiny best tau would make the longest times cost minutes: keep runs under 2000 steps
        values = tuple(v for v in values if v / best_params["tau"] <= 2000) or values[:1]
    for v in values:
        params = {**best_params, param: v}
        spec.public(mesh, operators=batch.ops, **params)
        warm.append(median_seconds(lambda i: spec.public(mesh, operators=batch.ops, **params), budget=budget)[0])
        if method in COLD_TIMERS:
            cold.append(median_seconds(COLD_TIMERS[method](batch, params), budget=budget)[0])
    return {"param": param, "values": list(values), "seconds": warm, "seconds_cold": cold or None}

"""Filtering and fixed-step heat searches: SNR read after every step of one run per step size."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from ..plugins.filtering import smoothing_steps
from ..tuning.search import past_minimum
from .batch import NoisyBatch
from .result import SearchResult

__all__ = ["search_filtering", "snr_along_run", "run_until_past_peak"]


def snr_along_run(batch: NoisyBatch, steps: Iterator[np.ndarray], n_steps: int) -> np.ndarray:
    """SNR per seed after 0, 1, ..., ``n_steps`` steps of ``steps``, shape (n_steps + 1, S)."""
    out = np.empty((n_steps + 1, batch.n_seeds))
    out[0] = batch.noisy_snr()
    for k in range(1, n_steps + 1):
        out[k] = batch.snr_stack(next(steps))
    return out


def run_until_past_peak(batch: NoisyBatch, steps: Iterator[np.ndarray], max_steps: int) -> tuple[np.ndarray, bool]:
    """SNR per seed along ``steps`` until past the best mean SNR (the tuning walks' rule,
    :func:`~meshdenoise.tuning.search.past_minimum`: twice the best step count and 20 more).

    Returns the (k + 1, S) SNR array and whether ``max_steps`` stopped the run first.
    """
    rows = [batch.noisy_snr()]
    best_k, best = 0, rows[0].mean()
    k = 0
    while k < max_steps:
        k += 1
        rows.append(batch.snr_stack(next(steps)))
        if rows[-1].mean() > best:
            best_k, best = k, rows[-1].mean()
        if past_minimum(k, best_k):
            return np.array(rows), False
    return np.array(rows), True


def search_filtering(batch: NoisyBatch, max_iterations: int = 5000) -> SearchResult:
    """Best number of averaging steps ``X <- D^-1 W X``, reading the SNR after each step of a single run.

    All seeds are smoothed together (one sparse product per step on the stacked (n, 3 S)
    coordinates). The run stops at twice the best step count so far plus 20 (:func:`~meshdenoise.tuning.search.past_minimum`).

    Examples
    --------
    >>> from meshdenoise.reproduce.batch import make_batch
    >>> from meshdenoise.shapes import icosphere
    >>> r = search_filtering(make_batch("sphere", *icosphere(3), rho=0.05, seeds=(0,)))
    >>> r.best_params["iterations"] >= 1 and r.best_snr > float(r.snr[0, 0])  # row 0: the noisy input
    True
    """
    snr, capped = run_until_past_peak(batch, smoothing_steps(batch.X, batch.ops), max_iterations)
    params = [{"iterations": k} for k in range(snr.shape[0])]
    notes = [f"stopped at {max_iterations} iterations before the SNR peaked"] if capped else []
    return SearchResult(
        "filtering", batch.mesh, batch.rho, params, snr,
        figure_data={"iterations": np.arange(snr.shape[0]), "snr": snr},
        notes=notes, how="SNR after every step of one run (all seeds stacked)",
    )

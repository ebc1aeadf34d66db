"""Filtering and fixed-step heat searches: SNR read after every step of one run per step size."""

from __future__ import annotations

import itertools
from collections.abc import Iterator

import numpy as np

from ..plugins.filtering import smoothing_steps
from ..tuning.walk import walk
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
    """SNR per seed along ``steps`` until past the best mean SNR, shape (k + 1, S), and whether ``max_steps`` came first.

    The oracle search of the tuning floor (:func:`~meshdenoise.tuning.walk.walk`, its one
    stopping rule: twice the best step count and 20 more), scored by the mean SNR over the
    seeds against the clean mesh; every state's SNRs are kept for the table and the figures.
    """
    rows: list[np.ndarray] = []

    def score(Y: np.ndarray) -> float:
        rows.append(batch.snr_stack(Y))
        return -float(rows[-1].mean())

    found = walk(itertools.chain([batch.X], steps), score, max_steps=max_steps)
    return np.array(rows), not found.complete


def search_filtering(batch: NoisyBatch, max_iterations: int = 5000) -> SearchResult:
    """Best number of averaging steps ``X <- D^-1 W X``, reading the SNR after each step of a single run.

    All seeds are smoothed together (one sparse product per step on the stacked (n, 3 S)
    coordinates). The run stops at twice the best step count so far plus 20 (the one walk of the
    tuning floor, :func:`~meshdenoise.tuning.walk.walk`, scored by the mean SNR over the seeds).

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

"""Heat search over the paper's step grid and the diffusion time, along one run (or one Chebyshev basis) per step."""

from __future__ import annotations

import math

import numpy as np

from ..plugins.filtering import smoothing_steps
from ..plugins.heat import stable_tau
from .batch import NoisyBatch
from .chebyshev import heat_snr_chebyshev
from .filtering_search import run_until_past_peak, snr_along_run
from .paper import TAU_GRID
from .result import SearchResult

__all__ = ["search_heat"]


def search_heat(
    batch: NoisyBatch,
    taus: np.ndarray = TAU_GRID,
    direct_steps: int = 150,
    time_points: int = 400,
    max_steps: int = 5000,
) -> SearchResult:
    """Best ``(tau, T)`` for heat diffusion: every stable ``tau`` of the grid, ``T = k tau`` up to a common ``T_max``.

    Our heat runs ``k = ceil(T / tau)`` Euler steps, so the reachable times are the
    multiples ``k tau``. The largest stable ``tau`` runs first, until twice its best step
    count: that fixes ``T_max``. Every other ``tau`` needing at most ``direct_steps``
    steps to reach ``T_max`` is run directly (SNR after every step); smaller steps are
    evaluated exactly (to 1e-12) after each of their first ``direct_steps`` steps and at
    ``time_points`` times up to ``T_max`` through one Chebyshev basis
    (:mod:`.chebyshev`). Steps above the stability bound ``2 / lambda_max(I - D^-1 W)``
    diverge and are skipped; the result's notes list them.

    Examples
    --------
    >>> from meshdenoise.reproduce.batch import make_batch
    >>> from meshdenoise.shapes import icosphere
    >>> r = search_heat(make_batch("sphere", *icosphere(1), rho=0.05, seeds=(0,)), taus=np.array([0.1, 0.5, 1.9]))
    >>> r.notes[0].startswith("tau 1.9 skipped: above the stability bound")
    True
    >>> sorted(float(t) for t in r.figure_data["curves"])
    [0.1, 0.5]
    """
    ops = batch.ops
    bound = stable_tau(ops)
    taus = np.sort(np.asarray(taus, dtype=np.float64))
    stable, unstable = taus[taus <= bound * (1 + 1e-12)], taus[taus > bound * (1 + 1e-12)]
    if stable.size == 0:
        raise ValueError(f"heat search: no tau of the grid is below the stability bound {bound:.4g}")
    notes = []
    if unstable.size:
        notes.append(
            "tau " + ", ".join(f"{t:.3g}" for t in unstable) + f" skipped: above the stability bound "
            f"2 / lambda_max(I - D^-1 W) = {bound:.4g} of this mesh, explicit Euler diverges"
        )
    curves: dict[float, tuple[np.ndarray, np.ndarray]] = {}  # tau -> (times, snr (len, S))
    first = stable[-1]
    snr, capped = run_until_past_peak(batch, smoothing_steps(batch.X, ops, lam=first), max_steps)
    if capped:
        notes.append(f"tau {first:.3g} stopped at {max_steps} steps before the SNR peaked")
    t_max = (snr.shape[0] - 1) * first
    curves[first] = (np.arange(snr.shape[0]) * first, snr)
    chebyshev_taus, chebyshev_ks = [], []
    for tau in stable[:-1]:
        n_steps = math.ceil(t_max / tau - 1e-9)
        if n_steps <= direct_steps:
            curves[tau] = (np.arange(n_steps + 1) * tau, snr_along_run(batch, smoothing_steps(batch.X, ops, lam=tau), n_steps))
        else:
            # every one of the first direct_steps steps (an optimum at a small T is not missed), then an even T grid
            grid = np.ceil(np.linspace(0.0, t_max, time_points + 1) / tau - 1e-9).astype(np.int64)
            ks = np.unique(np.concatenate([np.arange(direct_steps + 1), grid]))
            chebyshev_taus.append(np.full(ks.size, tau))
            chebyshev_ks.append(ks)
    how = f"SNR after every step of one run per tau (direct up to {direct_steps} steps)"
    if chebyshev_taus:
        values, degree = heat_snr_chebyshev(batch, np.concatenate(chebyshev_taus), np.concatenate(chebyshev_ks))
        start = 0
        for tt, ks in zip(chebyshev_taus, chebyshev_ks):
            curves[float(tt[0])] = (ks * tt[0], values[start : start + ks.size])
            start += ks.size
        small = sorted(float(t[0]) for t in chebyshev_taus)
        how += (
            f"; tau <= {small[-1]:.3g} after each of the first {direct_steps} steps and at {time_points} times up to "
            f"T_max = {t_max:.3g}, through one Chebyshev basis of degree {degree} "
            "(coefficients dropped below 1e-13)"
        )
    params, rows = [], []
    for tau in sorted(curves):
        times, values = curves[tau]
        steps = np.rint(times / tau).astype(np.int64)
        params += [{"tau": float(tau), "time": float(k * tau)} for k in steps]
        rows.append(values)
    result = SearchResult(
        "heat", batch.mesh, batch.rho, params, np.vstack(rows),
        figure_data={"curves": curves, "unstable": unstable, "bound": bound, "t_max": t_max},
        notes=notes, how=how,
    )
    best = result.best_params
    if best["time"] > 0.9 * t_max:
        result.notes.append(f"best T = {best['time']:.3g} lies near the end of the searched range T <= {t_max:.3g}")
    return result

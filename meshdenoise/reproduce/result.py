"""The outcome of one parameter search: SNR of every tried setting for every noise seed."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["SearchResult"]


@dataclass
class SearchResult:
    """SNR (dB) of ``params[i]`` on seed ``s`` is ``snr[i, s]``; the best setting maximises the seed mean.

    Attributes
    ----------
    method : str
        Registered filter name.
    mesh : str
    rho : float
    params : list of dict
        The settings tried, each a keyword dict for the registered filter.
    snr : ndarray, shape (len(params), S)
    figure_data : dict
        Curves for the figures, method-specific.
    notes : list of str
        What the reader of table.md must know (skipped unstable steps, best at the grid's edge...).
    how : str
        How the SNR values were computed (one line, for table.md and results.json).
    """

    method: str
    mesh: str
    rho: float
    params: list[dict]
    snr: np.ndarray
    figure_data: dict = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    how: str = ""

    def __post_init__(self):
        self.snr = np.asarray(self.snr, dtype=np.float64)
        if self.snr.ndim != 2 or self.snr.shape[0] != len(self.params):
            raise ValueError(
                f"SearchResult {self.method} {self.mesh} rho={self.rho}: snr has shape {self.snr.shape}, "
                f"expected ({len(self.params)}, seeds)"
            )

    @property
    def best_index(self) -> int:
        """Index of the setting with the highest mean SNR over seeds (the first one on ties)."""
        return int(np.argmax(self.snr.mean(axis=1)))

    @property
    def best_params(self) -> dict:
        return dict(self.params[self.best_index])

    @property
    def best_snr(self) -> float:
        """Mean over seeds of the SNR of the best setting."""
        return float(self.snr[self.best_index].mean())

    @property
    def best_snr_std(self) -> float:
        """Sample standard deviation over seeds of the SNR of the best setting (0 for one seed)."""
        row = self.snr[self.best_index]
        return float(row.std(ddof=1)) if row.size > 1 else 0.0

    @property
    def per_seed_best_snr(self) -> float:
        """Mean over seeds of each seed's own best SNR (the paper's one-draw protocol, repeated)."""
        return float(self.snr.max(axis=0).mean())

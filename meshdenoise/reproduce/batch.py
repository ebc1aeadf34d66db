"""Noisy copies of one clean mesh, stacked as columns so that one sparse product smooths every seed."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ..noise import add_normal_noise
from ..operators import Operators, get_operators

__all__ = ["NoisyBatch", "make_batch"]


@dataclass
class NoisyBatch:
    """The noisy versions of one clean mesh at one noise level, one per seed.

    Attributes
    ----------
    mesh : str
        Mesh key (``"elephant"``, ``"nefertiti"``).
    rho : float
        Noise amplitude.
    V : ndarray, shape (n, 3)
        Clean coordinates (the SNR reference).
    F : ndarray, shape (m, 3)
    ops : Operators
    seeds : tuple of int
    X : ndarray, shape (n, 3 S)
        Noisy coordinates of seed ``s`` in columns ``3 s .. 3 s + 2``.
    """

    mesh: str
    rho: float
    V: np.ndarray
    F: np.ndarray
    ops: Operators
    seeds: tuple[int, ...]
    X: np.ndarray

    @property
    def n_seeds(self) -> int:
        return len(self.seeds)

    def noisy(self, s: int) -> np.ndarray:
        """Noisy coordinates (n, 3) of the ``s``-th seed."""
        return self.X[:, 3 * s : 3 * s + 3]

    def snr_stack(self, Y: np.ndarray) -> np.ndarray:
        """SNR in dB of each seed's block of ``Y`` (n, 3 S) against the clean mesh, shape (S,).

        .. math:: \\mathrm{SNR}_s = -10 \\log_{10} \\frac{\\|Y_s - V\\|_F^2}{\\|V\\|_F^2}
        """
        err = Y - self._clean_tiled
        err *= err
        return snr_from_squared_error(err.sum(axis=0).reshape(self.n_seeds, 3).sum(axis=1), self.clean_norm2)

    @cached_property
    def _clean_tiled(self) -> np.ndarray:
        return np.tile(self.V, (1, self.n_seeds))

    @cached_property
    def clean_norm2(self) -> float:
        """``||V||_F^2``."""
        return float(np.einsum("ij,ij->", self.V, self.V))

    def noisy_snr(self) -> np.ndarray:
        """SNR of the noisy input of each seed, shape (S,)."""
        return self.snr_stack(self.X)


def snr_from_squared_error(err2: np.ndarray, ref2: float) -> np.ndarray:
    """``-10 log10(err2 / ref2)`` (``inf`` where the error is 0)."""
    err2 = np.asarray(err2, dtype=np.float64)
    with np.errstate(divide="ignore"):
        return -10.0 * np.log10(err2 / ref2)


def make_batch(mesh: str, V: np.ndarray, F: np.ndarray, rho: float, seeds: tuple[int, ...]) -> NoisyBatch:
    """Add the paper's normal noise (:func:`meshdenoise.add_normal_noise`) once per seed and stack the copies.

    Examples
    --------
    >>> from meshdenoise import snr
    >>> from meshdenoise.shapes import icosphere
    >>> V, F = icosphere(1)
    >>> b = make_batch("sphere", V, F, rho=0.05, seeds=(0, 1))
    >>> b.X.shape
    (42, 6)
    >>> bool(np.isclose(b.noisy_snr()[1], snr(V, b.noisy(1))))
    True"""
    if not seeds:
        raise ValueError(f"make_batch: at least one seed is needed for {mesh} rho={rho}, got seeds={seeds!r}")
    X = np.hstack([add_normal_noise((V, F), rho, seed)[0] for seed in seeds])
    return NoisyBatch(mesh, float(rho), V, F, get_operators(F, V.shape[0]), tuple(int(s) for s in seeds), X)

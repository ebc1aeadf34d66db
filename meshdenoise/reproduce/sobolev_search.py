"""Sobolev search over mu: one eigendecomposition for small meshes, one factorisation per mu for large ones."""

from __future__ import annotations

import numpy as np

from ..solvers import shifted_solver
from .batch import NoisyBatch, snr_from_squared_error
from .paper import MU_GRID
from .result import SearchResult

__all__ = ["search_sobolev", "cholmod_available", "DENSE_LIMIT"]

DENSE_LIMIT = 3000  # vertices: up to here one dense eigh of L (O(n^3)) serves every mu exactly


def _spectral_snr(batches: list[NoisyBatch], mus: np.ndarray) -> list[np.ndarray]:
    """Exact SNR for every mu from ``L = U diag(lambda) U^T``: ``Y(mu) = U diag(1 / (1 + mu lambda)) U^T X``.

    ``U`` is orthogonal, so ``||Y - V|| = ||diag(1 / (1 + mu lambda)) U^T X - U^T V||``.
    """
    lam, U = np.linalg.eigh(batches[0].ops.L.toarray())
    lam = np.maximum(lam, 0.0)  # L is positive semi-definite; rounding may give -1e-15
    gain = 1.0 / (1.0 + np.outer(mus, lam))  # (M, n)
    out = []
    for b in batches:
        n, S = b.V.shape[0], b.n_seeds
        Z = (U.T @ b.X).reshape(n, S, 3)
        Vhat = U.T @ b.V
        err = gain[:, :, None, None] * Z[None] - Vhat[None, :, None, :]
        out.append(snr_from_squared_error(np.einsum("mnsk,mnsk->ms", err, err), b.clean_norm2))
    return out


def _factor_snr(batches: list[NoisyBatch], mus: np.ndarray, advance=None) -> list[np.ndarray]:
    """SNR for every mu by one sparse Cholesky of ``I + mu L`` per mu, solved for all seeds and noise levels at once."""
    X = np.hstack([b.X for b in batches])
    widths = np.cumsum([0] + [b.X.shape[1] for b in batches])
    out = [np.empty((mus.size, b.n_seeds)) for b in batches]
    for i, mu in enumerate(mus):
        Y = X if mu == 0 else shifted_solver(batches[0].ops, mu).solve(X)
        for j, b in enumerate(batches):
            out[j][i] = b.snr_stack(Y[:, widths[j] : widths[j + 1]])
        if advance is not None:
            advance(1.0 / mus.size)
    return out


def cholmod_available() -> bool:
    """Whether scikit-sparse's CHOLMOD (the ``cholmod`` extra) is installed."""
    try:
        import sksparse.cholmod  # noqa: F401
    except ImportError:
        return False
    return True


def _cholmod_snr(batches: list[NoisyBatch], mus: np.ndarray, advance=None) -> list[np.ndarray]:
    """SNR for every mu with CHOLMOD: one symbolic analysis of ``I + mu L``, then a numeric factorisation per mu.

    The sparsity pattern of ``I + mu L`` does not depend on ``mu > 0``, so the fill-reducing
    ordering and the elimination tree are computed once and reused. (A sweep over many mu:
    :func:`~meshdenoise.solvers.shifted_solver` builds one cholespy factor per mu, with no
    symbolic reuse; tests/test_reproduce.py checks the two agree to 1e-9 dB.)
    """
    from sksparse.cholmod import analyze

    from ..solvers import shifted_matrix

    ops = batches[0].ops
    factor = analyze(shifted_matrix(ops, 1.0).tocsc())
    X = np.hstack([b.X for b in batches])
    widths = np.cumsum([0] + [b.X.shape[1] for b in batches])
    out = [np.empty((mus.size, b.n_seeds)) for b in batches]
    for i, mu in enumerate(mus):
        if mu == 0:
            Y = X
        else:
            factor.cholesky_inplace(shifted_matrix(ops, mu).tocsc())
            Y = factor(X)
        for j, b in enumerate(batches):
            out[j][i] = b.snr_stack(Y[:, widths[j] : widths[j + 1]])
        if advance is not None:
            advance(1.0 / mus.size)
    return out


def search_sobolev(
    batches: list[NoisyBatch],
    mus: np.ndarray = MU_GRID,
    dense_limit: int = DENSE_LIMIT,
    advance=None,
    cholmod: bool | None = None,
) -> list[SearchResult]:
    """Best ``mu`` of ``(I + mu L) Y = X`` for each noise level of one mesh (``batches`` share the topology).

    Small meshes (``n <= dense_limit``): one dense eigendecomposition of ``L`` is reused
    for every mu, seed and noise level, and the SNR is exact for every mu. Large meshes:
    with scikit-sparse installed (``cholmod``, default when available) CHOLMOD analyses the
    pattern of ``I + mu L`` once and only refactorises numerically for each mu; without it,
    cholespy redoes its symbolic analysis for each matrix, so each mu costs one analysis
    and factorisation (the package's one solver of ``I + mu L``,
    :func:`~meshdenoise.solvers.shifted_solver`).
    Either way one factorisation serves every seed and noise level (one multi-column solve).

    Examples
    --------
    >>> from meshdenoise.reproduce.batch import make_batch
    >>> from meshdenoise.shapes import icosphere
    >>> (r,) = search_sobolev([make_batch("sphere", *icosphere(1), rho=0.05, seeds=(0,))], np.array([0.0, 0.1, 1.0]))
    >>> r.params[0], r.snr.shape
    ({'mu': 0.0}, (3, 1))
    """
    mus = np.asarray(mus, dtype=np.float64)
    n = batches[0].V.shape[0]
    if any(b.ops is not batches[0].ops for b in batches):
        raise ValueError("search_sobolev: the batches must share one mesh topology")
    if n <= dense_limit:
        values = _spectral_snr(batches, mus)
        how = f"exact for every mu from one dense eigendecomposition of L ({n} vertices)"
    elif cholmod if cholmod is not None else cholmod_available():
        values = _cholmod_snr(batches, mus, advance)
        how = (
            "CHOLMOD: one symbolic analysis of I + mu L reused for every mu, one numeric factorisation per mu, "
            f"shared by all {sum(b.n_seeds for b in batches)} noisy meshes"
        )
    else:
        values = _factor_snr(batches, mus, advance)
        how = f"one sparse Cholesky (cholespy) of I + mu L per mu, shared by all {sum(b.n_seeds for b in batches)} noisy meshes"
    results = []
    for b, snr in zip(batches, values):
        r = SearchResult(
            "sobolev", b.mesh, b.rho, [{"mu": float(m)} for m in mus], snr,
            figure_data={"mu": mus, "snr": snr}, how=how,
        )
        if r.best_index == mus.size - 1:
            r.notes.append(f"best mu = {mus[-1]:g} is the largest of the grid")
        results.append(r)
    return results

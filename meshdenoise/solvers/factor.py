"""Factorised solves of symmetric positive definite systems with Dirichlet (pinned) rows.

:class:`DirichletSystem` holds the reduced system on the free rows; :class:`SPDSolver` factorises it once by
sparse Cholesky: CHOLMOD (scikit-sparse, the ``cholmod`` extra) with one symbolic analysis per sparsity pattern
kept (:func:`clear_symbolic`), else cholespy. Which back end, and up to which sizes, is a
:class:`~meshdenoise.solvers.config.SolverConfig`'s.
"""

from __future__ import annotations

import hashlib
import threading
from collections import OrderedDict
from typing import Any, Callable

import numpy as np
import scipy.sparse as sp
from cholespy import CholeskySolverD, MatrixType

from ..cache import FACTOR_BYTES_PER_NNZ, nbytes
from ..operators import on_clear_cache
from .config import CHOLMOD, SolverConfig, resolve

__all__ = ["DirichletSystem", "SPDSolver", "CHOLMOD", "clear_symbolic"]


class DirichletSystem:
    """``A Y = X`` on the free rows of a symmetric positive definite ``A``, with ``Y = X`` on pinned rows.

    Holds the reduced matrix :math:`A_{ff}` (sorted CSR, attribute ``A``) and the coupling
    :math:`A_{fp}` that moves the pinned values to the right-hand side,
    :math:`A_{ff} Y_f = X_f - A_{fp} X_p`; every :math:`A_{ff}` of an SPD ``A`` is SPD.
    Subclasses solve the reduced system (a factorisation, or conjugate gradients).
    """

    def __init__(self, A: sp.spmatrix, pinned: np.ndarray | None = None):
        A = sp.csr_matrix(A, dtype=np.float64)
        self.n = A.shape[0]
        self.pinned = None if pinned is None or not pinned.any() else pinned.copy()
        if self.pinned is None:
            self.free = None
        else:
            self.free = np.flatnonzero(~self.pinned)
            self._pinned_rows = np.flatnonzero(self.pinned)
            A_free = A[self.free]
            self._coupling = A_free[:, self._pinned_rows]  # moves the pinned values to the right-hand side
            A = sp.csr_matrix(A_free[:, self.free])
        A.sort_indices()
        self.A = A
        self.size = A.shape[0]

    @property
    def nbytes(self) -> int:
        """Approximate memory held (matrices; a factorisation is estimated from its matrix)."""
        return nbytes(self.A) + nbytes(getattr(self, "_coupling", None))

    def _columns(self, X: np.ndarray) -> np.ndarray:
        """``X`` as float64 ``(n, k)``, checked against the system's size."""
        X = np.asarray(X, dtype=np.float64)
        if X.shape[0] != self.n:
            raise ValueError(f"{type(self).__name__}.solve: X has {X.shape[0]} rows, the system {self.n}")
        return X.reshape(self.n, -1)

    def _reduce(self, X2: np.ndarray, order: str = "C") -> np.ndarray:
        """The right-hand side of the reduced system: a new array in ``order`` (solvers may write into it)."""
        if self.free is None:
            return np.array(X2, dtype=np.float64, order=order)
        return np.asarray(X2[self.free] - self._coupling @ X2[self._pinned_rows], order=order)

    def _start(self, x0: np.ndarray | None, X: np.ndarray) -> np.ndarray | None:
        """An iterative solve's start on the reduced system: the free rows of ``x0`` (a guess shaped like the right-hand
        side ``X``), or ``None`` without one."""
        if x0 is None:
            return None
        start = self._columns(x0)
        if start.shape != self._columns(X).shape:
            raise ValueError(f"{type(self).__name__}.solve: x0 has shape {np.shape(x0)}, X {np.shape(X)}")
        return start if self.free is None else start[self.free]

    def _expand(self, X2: np.ndarray, out: np.ndarray) -> np.ndarray:
        """The full solution: ``out`` on the free rows, the pinned rows of ``X2`` bit for bit."""
        if self.free is None:
            return out
        Y = X2.copy()
        Y[self.free] = out
        return Y


_quiet_lock = threading.Lock()
_quiet: dict = {"depth": 0, "saved": {}, "tmps": {}}  # the one redirection of descriptors 1 and 2, shared by threads


def _without_cholmod_warnings(build: Callable[[], Any]) -> Any:
    """``build()`` with CHOLMOD's own C-level warning lines kept off the terminal.

    A failed factorisation (``ValueError: Matrix is not positive definite!``) is reported
    by our error message, which names the filter and its parameters; CHOLMOD also prints
    ``CHOLMOD warning: not positive definite ...`` through C's buffered ``stdout``. File
    descriptors 1 and 2 are sent to temporary files while the factor is built (C's buffers
    flushed before they are restored), then everything else written there meanwhile (other
    threads' output) is written back. Descriptors belong to the process: threads building at
    once share one redirection, made by the first to enter and undone by the last to leave
    (each saving and restoring its own would leave them on a deleted temporary file).
    """
    import ctypes
    import os
    import sys
    import tempfile

    with _quiet_lock:
        if _quiet["depth"] == 0:
            try:
                sys.stdout.flush()
                sys.stderr.flush()
                saved = {fd: os.dup(fd) for fd in (1, 2)}
            except (OSError, ValueError, AttributeError):  # no usable descriptors (embedded interpreters): build as is
                saved = None
            if saved is not None:
                tmps = {fd: tempfile.TemporaryFile() for fd in (1, 2)}
                for fd, tmp in tmps.items():
                    os.dup2(tmp.fileno(), fd)
                _quiet.update(saved=saved, tmps=tmps)
        _quiet["depth"] += 1
    try:
        return build()
    finally:
        with _quiet_lock:
            _quiet["depth"] -= 1
            if _quiet["depth"] == 0 and _quiet["saved"]:  # the last one out undoes the redirection, if one was made
                try:
                    ctypes.CDLL(None).fflush(None)  # C's buffered output into the temporary files first
                except (OSError, AttributeError):
                    pass
                saved, tmps = _quiet["saved"], _quiet["tmps"]
                _quiet.update(saved={}, tmps={})
                for fd, tmp in tmps.items():
                    os.dup2(saved[fd], fd)
                    os.close(saved[fd])
                    tmp.seek(0)
                    kept = [line for line in tmp.read().splitlines(keepends=True) if not line.startswith(b"CHOLMOD warning")]
                    tmp.close()
                    if kept:
                        os.write(fd, b"".join(kept))


_symbolic: OrderedDict = OrderedDict()  # pattern -> analysis, at most SolverConfig.symbolic_max kept
_symbolic_lock = threading.Lock()


def clear_symbolic() -> None:
    """Forget the stored symbolic analyses of :class:`SPDSolver` (CHOLMOD's orderings of each sparsity pattern)."""
    with _symbolic_lock:
        _symbolic.clear()


on_clear_cache(clear_symbolic)  # operators.clear_cache forgets them too


def _cholmod_factor(A: sp.csr_matrix, config: SolverConfig | None = None) -> Any:
    """A numeric CHOLMOD factor of the symmetric positive definite ``A`` (sorted CSR), its symbolic analysis
    (simplicial ``L D L^T``) computed once per sparsity pattern and reused.

    The automatic rules factorise ``I + mu L^p`` for many ``mu`` on one pattern: only the numeric step is
    repeated (bunny scanner, 28,088 vertices, idle: ``I + c L`` 131 -> 37 ms, the two-ring factor of
    ``I + mu L^3`` 410 -> 243 ms against cholespy, which orders every matrix again; the solves cost the same;
    a factor used once costs about the same either way: the analysis is 88 and 164 ms). Up to
    :attr:`SolverConfig.cholmod_metis_max_rows` rows METIS orders the pattern; above, METIS's analysis costs more than it saves
    (face000's 85,182 vertices: 0.27 s for a one-ring matrix whose numeric factor takes 0.12 s) and CHOLMOD's default
    orders it (AMD, with METIS tried when AMD's fill is large): a one-ring factor 0.41 -> 0.18 s at 85k rows,
    0.62 -> 0.36 at 100k, 0.97 -> 0.77 at 139k against cholespy, two-ring factors 0.97 to 1.21 times cholespy's,
    solves 5 to 28 % slower (``benchmarks/factor_backend.py``). Up to :attr:`SolverConfig.cholmod_max_rows` rows only, the same
    back end for a matrix whatever was factorised before: at 400k rows cholespy's factor is the faster (3.4 against
    4.4 s) and at 1.6M too (docs/benchmarks.md). A simplicial ``L D L^T`` does not fail on an indefinite matrix: a
    pivot ``D <= 0`` is reported as cholespy reports it.
    """
    from sksparse.cholmod import analyze

    config = resolve(config)
    pattern = hashlib.blake2b(f"{A.shape[0]} {A.indptr.dtype} {A.indices.dtype}".encode(), digest_size=20)
    pattern.update(np.ascontiguousarray(A.indptr))  # the buffers themselves: no converted copy
    pattern.update(np.ascontiguousarray(A.indices))
    key = pattern.digest()  # the pattern's content, not its arrays: nothing of size n kept but the analysis
    C = sp.csc_matrix((A.data, A.indices, A.indptr), shape=A.shape)  # a symmetric matrix's CSR is its CSC
    with _symbolic_lock:
        symbolic = _symbolic.get(key)
        if symbolic is not None:
            _symbolic.move_to_end(key)
    if symbolic is None:
        order = "metis" if A.shape[0] <= config.cholmod_metis_max_rows else "default"
        symbolic = analyze(C, mode="simplicial", ordering_method=order)
        with _symbolic_lock:
            _symbolic[key] = symbolic
            while len(_symbolic) > config.symbolic_max:
                _symbolic.popitem(last=False)
    factor = symbolic.cholesky(C)
    if not np.all(factor.D() > 0):
        raise ValueError("Matrix is not positive definite!")  # as cholespy says it
    return factor


class SPDSolver(DirichletSystem):
    """A sparse Cholesky factorisation of SPD ``A``, reduced to free rows when some are pinned.

    Solves ``A Y = X`` on the free rows with ``Y = X`` on the pinned ones, i.e. the reduced
    system :math:`A_{ff} Y_f = X_f - A_{fp} X_p`. With scikit-sparse installed (the ``cholmod``
    extra; ``make`` installs it) and up to :attr:`SolverConfig.cholmod_max_rows` rows by CHOLMOD with one symbolic
    analysis per sparsity pattern (:func:`_cholmod_factor`: a parameter search's many weights), else
    by cholespy; ``config`` (a :class:`~meshdenoise.solvers.config.SolverConfig`, default
    :data:`~meshdenoise.solvers.config.DEFAULT`) says which and up to which sizes.

    Examples
    --------
    >>> import numpy as np, scipy.sparse as sp
    >>> A = sp.csr_matrix(np.array([[2.0, -1, 0], [-1, 2, -1], [0, -1, 2]]))
    >>> SPDSolver(A, np.array([False, True, False])).solve(np.array([[1.0], [5.0], [1.0]])).ravel()
    array([3., 5., 3.])
    """

    def __init__(self, A: sp.spmatrix, pinned: np.ndarray | None = None, *, config: SolverConfig | None = None):
        super().__init__(A, pinned)
        config = resolve(config)
        A = self.A
        self._solver = self._factor = None
        if not self.size:
            return
        if config.cholmod and self.size <= config.cholmod_max_rows:
            self._factor = _cholmod_factor(A, config)
        else:
            self._solver = _without_cholmod_warnings(lambda: CholeskySolverD(
                self.size, A.indptr.astype(np.int32), A.indices.astype(np.int32), A.data.astype(np.float64),
                MatrixType.CSR,
            ))

    @property
    def nbytes(self) -> int:
        """Approximate memory held: the reduced matrix plus an estimate of its Cholesky factor
        (not reported by the solvers: :data:`~meshdenoise.cache.FACTOR_BYTES_PER_NNZ` per nonzero)."""
        return super().nbytes + FACTOR_BYTES_PER_NNZ * int(self.A.nnz)

    def solve(self, X: np.ndarray) -> np.ndarray:
        """``Y`` of the shape of ``X`` (n,) or (n, k), with ``(A Y)_f = X_f`` and ``Y_p = X_p``."""
        X2 = self._columns(X)
        # CHOLMOD solves column-major right-hand sides (scikit-sparse converts any other): one copy fewer, the same
        # bits (51 columns at 28k rows: 37 -> 32 ms)
        rhs = self._reduce(X2, order="F" if self._factor is not None else "C")
        if self._factor is not None:
            out = np.ascontiguousarray(self._factor(rhs), dtype=np.float64)
        else:
            out = np.empty_like(rhs)
            if self._solver is not None:
                self._solver.solve(rhs, out)
        return self._expand(X2, out).reshape(np.shape(X))

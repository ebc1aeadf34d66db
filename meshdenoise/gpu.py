"""Array backends for the linear filters: the CPU default, a plain-scipy reference, CuPy and torch.

The iterative linear filters (``filtering`` with a fixed weight matrix, ``heat`` by Euler
or Chebyshev) only need four operations on an ``(n, 3)`` block of coordinates:
upload a CSR matrix, ``Y <- A X`` / ``Y <- Y + A X``, ``Y <- Y + a X`` and download.
They are written once against :class:`Backend`, so the same code runs on

- ``"cpu"`` (default): scipy's compiled CSR kernel threaded over row blocks
  (:func:`meshdenoise.operators.spmm`) and BLAS ``daxpy``, no temporaries;
- ``"scipy"``: the same algorithm through the public ``A @ X`` and numpy arithmetic, a
  slow reference that lets CI test the backend-generic code path without a GPU;
- ``"cupy"``: ``cupyx.scipy.sparse.csr_matrix`` on a CUDA GPU;
- ``"torch"``: ``torch.sparse_csr_tensor`` on ``cuda`` when available (else torch's CPU).

CuPy and torch are optional and never imported unless asked for; asking for one that
is missing (or without a GPU, for CuPy) raises a ``ValueError`` that says what to
install. Everything stays float64.
"""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np
import scipy.sparse as sp

from .operators import spmm

__all__ = ["Backend", "BACKENDS", "get_backend"]

BACKENDS = ("cpu", "scipy", "cupy", "torch")


class Backend:
    """The CPU backend, and the interface the others follow.

    Examples
    --------
    >>> import numpy as np, scipy.sparse as sp
    >>> be = get_backend("cpu")
    >>> A = be.matrix(sp.csr_matrix(np.array([[0.0, 1.0], [1.0, 0.0]])))
    >>> X = be.asarray(np.array([[1.0, 2.0], [3.0, 4.0]]))
    >>> be.to_numpy(be.spmm(A, X))
    array([[3., 4.],
           [1., 2.]])
    """

    name = "cpu"

    def matrix(self, A: sp.csr_matrix) -> Any:
        """The backend's copy of a CSR float64 matrix."""
        A = sp.csr_matrix(A, dtype=np.float64)
        if A.indptr.dtype != A.indices.dtype:
            A.indptr = A.indptr.astype(A.indices.dtype)
        return A

    def scaled(self, M: Any, factor: float) -> Any:
        """``factor * M`` with the same sparsity (shares the index arrays where it can)."""
        return sp.csr_matrix((M.data * factor, M.indices, M.indptr), shape=M.shape)

    def asarray(self, X: np.ndarray) -> Any:
        """A C-contiguous float64 copy of ``X`` owned by the backend."""
        return np.array(X, dtype=np.float64, order="C")

    def to_numpy(self, X: Any) -> np.ndarray:
        return np.asarray(X)

    def zeros_like(self, X: Any) -> Any:
        return np.zeros_like(X)

    def asarray_owned(self, X: np.ndarray) -> Any:
        """:meth:`asarray` for a numpy array the caller hands over: used as is when it can be (no copy)."""
        if X.dtype == np.float64 and X.flags.c_contiguous and X.flags.writeable:
            return X
        return self.asarray(X)

    def to_new_numpy(self, X: Any) -> np.ndarray:
        """A float64 numpy array of ``X`` for a buffer the caller gives up (no copy when ``X`` is one)."""
        return np.asarray(X, dtype=np.float64)

    def spmm(self, M: Any, X: Any, out: Any = None, accumulate: bool = False) -> Any:
        """``out <- M X`` (or ``out <- out + M X``); a new array when ``out`` is None."""
        return spmm(M, X, out, accumulate=accumulate)

    def axpy(self, a: float, X: Any, Y: Any) -> None:
        """``Y <- Y + a X`` in place."""
        _axpy_blocked(a, X.reshape(-1), Y.reshape(-1))

    def axpy2(self, a: float, X: Any, b: float, Z: Any, Y: Any) -> None:
        """``Y <- Y + a X + b Z`` in place, in one pass over ``Y`` where the backend can."""
        _axpy2_blocked(a, X.reshape(-1), b, Z.reshape(-1), Y.reshape(-1))


class ScipyBackend(Backend):
    """The generic path through scipy's public API and numpy arithmetic (the test reference)."""

    name = "scipy"

    # generic array arithmetic (``@``, ``+=``): also what CuPy uses, which subclasses this backend
    def spmm(self, M, X, out=None, accumulate=False):
        Y = M @ X
        if out is None:
            return Y
        if accumulate:
            out += Y
        else:
            out[...] = Y
        return out

    def axpy(self, a, X, Y):
        Y += a * X

    def axpy2(self, a, X, b, Z, Y):
        Y += a * X
        Y += b * Z


class CupyBackend(ScipyBackend):
    """CuPy on the current CUDA device (``cupyx.scipy.sparse.csr_matrix`` times dense)."""

    name = "cupy"

    def __init__(self):
        try:
            import cupy
            import cupyx.scipy.sparse as csp

            cupy.cuda.runtime.getDeviceCount()
        except Exception as exc:  # ImportError, or CUDA missing at run time
            raise ValueError(
                f"backend='cupy' needs CuPy and a CUDA GPU ({type(exc).__name__}: {exc}); "
                "install the cupy-cudaXXx wheel matching your CUDA, or use backend='cpu'"
            ) from exc
        self.cp, self.csp = cupy, csp

    def matrix(self, A):
        return self.csp.csr_matrix(Backend.matrix(self, A))

    def scaled(self, M, factor):
        return self.csp.csr_matrix((M.data * factor, M.indices, M.indptr), shape=M.shape)

    def asarray(self, X):
        return self.cp.array(np.asarray(X, dtype=np.float64), order="C")

    def to_numpy(self, X):
        return self.cp.asnumpy(X)

    def zeros_like(self, X):
        return self.cp.zeros_like(X)

    def asarray_owned(self, X):
        return self.asarray(X)

    def to_new_numpy(self, X):
        return np.array(self.to_numpy(X), dtype=np.float64)


class TorchBackend(Backend):
    """torch sparse CSR on ``cuda`` when available, else on the CPU."""

    name = "torch"

    def __init__(self):
        try:
            import torch
        except Exception as exc:
            raise ValueError(
                f"backend='torch' needs PyTorch ({type(exc).__name__}: {exc}); install torch, or use backend='cpu'"
            ) from exc
        self.torch = torch
        self.device = "cuda" if torch.cuda.is_available() else "cpu"

    def matrix(self, A):
        A = Backend.matrix(self, A)
        t = self.torch
        with warnings.catch_warnings():  # torch flags CSR as beta at every construction; ours is canonical
            warnings.filterwarnings("ignore", message="Sparse CSR tensor support is in beta", category=UserWarning)
            return t.sparse_csr_tensor(
                t.from_numpy(A.indptr.astype(np.int64)),
                t.from_numpy(A.indices.astype(np.int64)),
                t.from_numpy(A.data),
                size=A.shape,
                dtype=t.float64,
                device=self.device,
                check_invariants=False,  # scipy's sorted CSR; said explicitly so torch does not warn
            )

    def scaled(self, M, factor):
        return M * factor

    def asarray(self, X):
        return self.torch.tensor(np.asarray(X, dtype=np.float64), device=self.device)

    def to_numpy(self, X):
        return X.detach().cpu().numpy()

    def zeros_like(self, X):
        return self.torch.zeros_like(X)

    def asarray_owned(self, X):
        return self.asarray(X)

    def to_new_numpy(self, X):
        return np.array(self.to_numpy(X), dtype=np.float64)

    def spmm(self, M, X, out=None, accumulate=False):
        Y = M @ X
        if out is None:
            return Y
        if accumulate:
            out.add_(Y)
        else:
            out.copy_(Y)
        return out

    def axpy(self, a, X, Y):
        Y.add_(X, alpha=a)

    def axpy2(self, a, X, b, Z, Y):
        Y.add_(X, alpha=a)
        Y.add_(Z, alpha=b)


_AXPY_BLOCK = 1 << 15  # 256 KiB of float64: the scratch for a * x stays in cache


def _axpy_blocked(a: float, x: np.ndarray, y: np.ndarray) -> None:
    """``y += a x`` over cache-sized blocks: memory traffic of one pass, no full-size temporary.

    (BLAS ``daxpy`` would do the same, but OpenBLAS threads it and on a busy machine its
    spinning threads made it 100 times slower than this.)
    """
    tmp = np.empty(min(_AXPY_BLOCK, x.size))
    for i in range(0, x.size, _AXPY_BLOCK):
        xs = x[i : i + _AXPY_BLOCK]
        t = tmp[: xs.size]
        np.multiply(xs, a, out=t)
        ys = y[i : i + _AXPY_BLOCK]
        np.add(ys, t, out=ys)


def _axpy2_blocked(a: float, x: np.ndarray, b: float, z: np.ndarray, y: np.ndarray) -> None:
    """``y += a x + b z`` over cache-sized blocks: four streams instead of the six of two ``axpy``."""
    tmp = np.empty(min(_AXPY_BLOCK, x.size))
    tmp2 = np.empty_like(tmp)
    for i in range(0, x.size, _AXPY_BLOCK):
        xs = x[i : i + _AXPY_BLOCK]
        t = tmp[: xs.size]
        t2 = tmp2[: xs.size]
        np.multiply(xs, a, out=t)
        np.multiply(z[i : i + _AXPY_BLOCK], b, out=t2)
        t += t2
        ys = y[i : i + _AXPY_BLOCK]
        np.add(ys, t, out=ys)


_instances: dict[str, Backend] = {}


def get_backend(name: str = "cpu") -> Backend:
    """The backend called ``name`` (one of :data:`BACKENDS`), created once.

    Raises
    ------
    ValueError
        An unknown name, or CuPy / torch not installed (or no CUDA GPU for CuPy).

    Examples
    --------
    >>> get_backend("scipy").name
    'scipy'
    """
    if name not in BACKENDS:
        raise ValueError(f"backend = {name!r} is unknown: one of {', '.join(repr(b) for b in BACKENDS)}")
    if name not in _instances:
        cls = {"cpu": Backend, "scipy": ScipyBackend, "cupy": CupyBackend, "torch": TorchBackend}[name]
        _instances[name] = cls()
    return _instances[name]

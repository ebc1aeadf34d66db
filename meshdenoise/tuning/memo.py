"""The tuning memo: repeated solves and filter runs of the automatic and oracle searches, bounded in bytes.

A benchmark asks for the automatic and the oracle choice on the same noisy mesh; both
searches evaluate many identical points (same matrix, same right-hand side, same
parameter). Keys are content digests (never ``id()``); the store is a
:class:`~meshdenoise.cache.ByteLRU` of at most :data:`MEMO_BYTES`, emptied by
``MEMO.clear()`` or :func:`meshdenoise.cache.clear_caches`.
"""

from __future__ import annotations

import hashlib
from typing import Any

import numpy as np
import scipy.sparse as sp

from ..cache import ByteLRU, on_clear

__all__ = ["MEMO", "MEMO_BYTES", "digest", "release_before_filter"]

MEMO_BYTES = 256 << 20
MEMO = ByteLRU(MEMO_BYTES)
on_clear(lambda: MEMO.clear())  # meshdenoise.cache.clear_caches empties it too


def release_before_filter() -> None:
    """Empty the memo between a choice and the filter run it chose (``denoise``, the CLI, pipelines).

    No filter reads the memo, and the input's entries are useless once the filter has
    moved the vertices; at scan size they are the largest thing left from the choice (a
    1.6M-vertex averaging curve: the coordinates, 10 probes and their state, 255 MB) and
    would sit beside the filter's own buffers at its peak. :func:`choose_parameters` alone
    keeps them, for a second search on the same mesh (a benchmark's oracle). In a batch run on
    threads another mesh's search may lose its entries here: it computes them again, the same
    numbers (every entry is a deterministic function of its key).
    """
    MEMO.clear()


def _feed(h: Any, a: np.ndarray) -> None:
    """Shape, dtype and the bytes of ``a`` into the hash ``h``, read in place (no copy of a contiguous array)."""
    a = np.ascontiguousarray(a)
    h.update(f"{a.shape}{a.dtype.str}".encode())
    h.update(a.reshape(-1).view(np.uint8) if a.size else b"")


def digest(*parts: Any) -> str:
    """A content hash (SHA-256) of arrays, sparse matrices and plain values (their ``repr``).

    Every byte of every array counts, read in place: at scan size the memo keys hash the faces,
    the coordinates and the probes (170 MB at 1.6M vertices), and a copy of each (``tobytes``) plus
    BLAKE2b, 1.2 GB/s here, took 0.3 s per key where SHA-256 (the processor's own instructions,
    2 GB/s here) in place takes 0.08 s. No sampling: two inputs differing in one value are two keys.

    Examples
    --------
    >>> import numpy as np
    >>> digest(np.zeros(3), 1.5) == digest(np.zeros(3), 1.5) != digest(np.ones(3), 1.5)
    True
    >>> digest(np.zeros(3)) != digest(np.zeros(3, dtype=np.int64)) != digest(np.zeros((3, 1)))
    True
    """
    h = hashlib.sha256()
    for part in parts:
        if sp.issparse(part):
            part = sp.csr_matrix(part)
            h.update(b"csr" + repr(part.shape).encode())
            for a in (part.indptr, part.indices, part.data):
                _feed(h, a)
        elif isinstance(part, np.ndarray):
            _feed(h, part)
        else:
            h.update(repr(part).encode())
        h.update(b"|")  # parts apart: (a, b) and (ab,) are two keys
    return h.hexdigest()[:32]

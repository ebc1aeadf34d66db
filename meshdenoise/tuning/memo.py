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

from ..cache import ByteLRU

__all__ = ["MEMO", "MEMO_BYTES", "digest"]

MEMO_BYTES = 256 << 20
MEMO = ByteLRU(MEMO_BYTES)


def digest(*parts: Any) -> str:
    """A content hash of arrays, sparse matrices and plain values (their ``repr``).

    Examples
    --------
    >>> import numpy as np
    >>> digest(np.zeros(3), 1.5) == digest(np.zeros(3), 1.5) != digest(np.ones(3), 1.5)
    True
    """
    h = hashlib.blake2b(digest_size=16)
    for part in parts:
        if sp.issparse(part):
            part = sp.csr_matrix(part)
            for a in (part.indptr, part.indices, part.data):
                h.update(np.ascontiguousarray(a).tobytes())
        elif isinstance(part, np.ndarray):
            h.update(str(part.shape).encode() + np.ascontiguousarray(part).tobytes())
        else:
            h.update(repr(part).encode())
    return h.hexdigest()

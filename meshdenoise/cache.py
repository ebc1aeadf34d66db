"""Bounded caches: a least-recently-used store with a byte limit and ``clear()``.

The package keeps two module-level caches, both instances of :class:`ByteLRU`:
the operators of recent topologies (:func:`meshdenoise.operators.get_operators`, with the
factorisations stored on them) and the tuning memo of repeated solves
(:mod:`meshdenoise.tuning.memo`). :func:`clear_caches` empties both; their limits are
attributes (``max_bytes``) a caller may change. Everything else reusable lives on
objects the caller holds and drops (an :class:`~meshdenoise.operators.Operators`, a
solver).
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from typing import Any, Callable, Hashable

import numpy as np
import scipy.sparse as sp

__all__ = ["ByteLRU", "nbytes", "clear_caches", "on_clear"]

# an estimate for a factor whose size the library does not report: bytes per nonzero of the
# factorised matrix (cholespy/CHOLMOD fill on mesh Laplacians is 5 to 10 times nnz(A), 12 B each)
FACTOR_BYTES_PER_NNZ = 120


def nbytes(value: Any, _depth: int = 0) -> int:
    """Approximate memory held by ``value``: arrays, sparse matrices, containers, objects with ``nbytes``
    or with attributes (their ``vars()``, a few levels deep).

    Examples
    --------
    >>> import numpy as np
    >>> nbytes({"a": np.zeros(10), "b": [np.zeros(5, dtype=np.int32)]})
    100
    """
    if _depth > 6 or value is None:
        return 0
    if isinstance(value, np.ndarray):
        return int(value.nbytes) if value.base is None else 0  # views belong to their base
    if sp.issparse(value):
        m = value.tocsr() if not hasattr(value, "data") else value
        return sum(int(getattr(m, a).nbytes) for a in ("data", "indices", "indptr", "row", "col") if hasattr(m, a))
    own = getattr(type(value), "nbytes", None)
    if isinstance(own, property):
        return int(value.nbytes)
    if isinstance(value, dict):
        return sum(nbytes(v, _depth + 1) for v in value.values())
    if isinstance(value, (list, tuple)):
        return sum(nbytes(v, _depth + 1) for v in value)
    if hasattr(value, "__dict__") and not isinstance(value, type):
        return nbytes(vars(value), _depth + 1)  # a helper object stored on a topology (face adjacency, ...)
    return 0


class ByteLRU:
    """A thread-safe least-recently-used map whose entries' total size stays under ``max_bytes``.

    Entries may grow after insertion (a list of iterates, an object with lazy members):
    sizes are measured again whenever something is stored. The most recent entry is kept
    even if it alone exceeds the limit (it is what the caller is using).

    Parameters
    ----------
    max_bytes : int
        The limit; 0 stores nothing past the current entry.
    size : callable, optional
        Size of one value in bytes (default :func:`nbytes`).

    Examples
    --------
    >>> import numpy as np
    >>> c = ByteLRU(max_bytes=1000)
    >>> _ = c.get("a", lambda: np.zeros(100))  # 800 B
    >>> _ = c.get("b", lambda: np.zeros(100))  # 1600 B in all: "a" goes
    >>> list(c), c.total_bytes()
    (['b'], 800)
    >>> c.discard("b"); c.discard("b"); len(c)
    0
    """

    def __init__(self, max_bytes: int, size: Callable[[Any], int] = nbytes):
        if max_bytes < 0:
            raise ValueError(f"ByteLRU: max_bytes must be >= 0, got {max_bytes!r}")
        self.max_bytes = int(max_bytes)
        self._size = size
        self._data: OrderedDict[Hashable, Any] = OrderedDict()
        self._lock = threading.RLock()

    def __len__(self) -> int:
        return len(self._data)

    def __iter__(self):
        return iter(list(self._data))

    def __contains__(self, key: Hashable) -> bool:
        return key in self._data

    def lookup(self, key: Hashable) -> Any:
        """The value stored under ``key`` (now most recent), or ``None``."""
        with self._lock:
            if key not in self._data:
                return None
            self._data.move_to_end(key)
            return self._data[key]

    def put(self, key: Hashable, value: Any) -> Any:
        """Store ``value`` as the most recent entry, then evict the oldest until under the limit."""
        with self._lock:
            self._data[key] = value
            self._data.move_to_end(key)
            self._evict()
            return value

    def get(self, key: Hashable, compute: Callable[[], Any]) -> Any:
        """The value under ``key``, computed by ``compute()`` and stored on a miss."""
        hit = self.lookup(key)
        if hit is not None or key in self._data:
            return hit
        return self.put(key, compute())

    def discard(self, key: Hashable) -> None:
        """Forget the entry under ``key`` (nothing when there is none)."""
        with self._lock:
            self._data.pop(key, None)

    def total_bytes(self) -> int:
        """The entries' current total size in bytes."""
        with self._lock:
            return sum(self._size(v) for v in self._data.values())

    def trim(self) -> None:
        """Evict the oldest entries until under ``max_bytes`` (after an entry grew in place)."""
        with self._lock:
            self._evict()

    def clear(self) -> None:
        """Forget every entry."""
        with self._lock:
            self._data.clear()

    def _evict(self) -> None:
        sizes = {k: self._size(v) for k, v in self._data.items()}
        total = sum(sizes.values())
        while total > self.max_bytes and len(self._data) > 1:
            key, _ = self._data.popitem(last=False)
            total -= sizes[key]


_CLEARS: list[Callable[[], None]] = []


def on_clear(clear: Callable[[], None]) -> Callable[[], None]:
    """Have :func:`clear_caches` call ``clear`` too: each module keeping a module-level cache registers its own
    clear at import (:func:`meshdenoise.operators.clear_cache`, the tuning memo's), so this module names none."""
    _CLEARS.append(clear)
    return clear


def clear_caches() -> None:
    """Empty every module-level cache of the package (operators with their factors, tuning memo)."""
    for clear in list(_CLEARS):
        clear()

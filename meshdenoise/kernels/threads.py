"""Threads and numba's set-up for the compiled kernels: OpenMP first, a cache place, thread counts and limits.

Imported first by every kernel module (:func:`njit` is numba's, with ``cache=True`` dropped where no place can
hold the cache), so numba's threading layer and ``OMP_WAIT_POLICY`` are set before any kernel is compiled.
"""

from __future__ import annotations

import os
import sys
import threading
from contextlib import contextmanager
from typing import Callable, Iterator, Sequence, TypeVar

# Idle OpenMP threads sleep instead of spinning. On a busy machine (2 cores shared by many
# jobs) spinning doubled the CPU time of a two_stage run and made 2 threads slower than 1;
# passive waiting costs a few microseconds per parallel loop here, each loop taking
# milliseconds. Read when OpenMP starts, so set before numba loads it; a user's value wins.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numba  # noqa: E402
from numba import njit as _numba_njit  # noqa: E402

# OpenMP first: numba would otherwise try an old TBB (Open3D's) first and warn about its version.
# Both are safe to call from several threads at once, unlike the workqueue fallback.
numba.config.THREADING_LAYER_PRIORITY = ["omp", "tbb", "workqueue"]


def _cache_probe() -> None:
    """A function of this file: numba's cache locators are asked where this file's kernels would be cached."""


def _private_cache_dir() -> str | None:
    """``<temp>/meshdenoise-numba-<uid>``, made private (0700) and checked to be ours (another user's folder there
    could hold cache files that run as code); a new unique folder when it is not; ``None`` when none can be made."""
    import stat
    import tempfile

    if hasattr(os, "getuid"):
        path = os.path.join(tempfile.gettempdir(), f"meshdenoise-numba-{os.getuid()}")
        try:
            os.makedirs(path, mode=0o700, exist_ok=True)
            info = os.lstat(path)
            if stat.S_ISDIR(info.st_mode) and info.st_uid == os.getuid() and not info.st_mode & 0o022:
                return path
        except OSError:
            pass
    try:
        return tempfile.mkdtemp(prefix="meshdenoise-numba-")
    except OSError:
        return None


def _find_cache_place() -> bool:
    """Whether numba can cache this package's kernels on disk, choosing a place if it cannot by itself.

    numba caches beside the sources (``__pycache__``), else in the user's cache folder (``~/.cache/numba``),
    else in ``NUMBA_CACHE_DIR`` when set; with none writable (installed read-only, HOME not writable) every
    ``cache=True`` kernel raised ``RuntimeError: cannot cache function ...: no locator available`` at import.
    Then, unless the user set ``NUMBA_CACHE_DIR``, a private folder of the temporary directory
    (:func:`_private_cache_dir`) becomes numba's cache folder; failing that the kernels are compiled in every
    process (no cache, :data:`CACHE` False).
    """
    from numba.core.caching import FunctionCache

    try:
        FunctionCache(_cache_probe)
        return True
    except RuntimeError:
        pass
    if numba.config.CACHE_DIR:  # the user's own choice, unusable: no cache rather than another place
        return False
    place = _private_cache_dir()
    if place is None:
        return False
    numba.config.CACHE_DIR = place
    try:
        FunctionCache(_cache_probe)
        return True
    except RuntimeError:
        numba.config.CACHE_DIR = ""
        return False


#: Whether the kernels are cached on disk (:func:`_find_cache_place`): ``cache=True`` of :func:`njit` is dropped if not.
CACHE = _find_cache_place()


def njit(*args, **kwargs):
    """numba's ``njit``, with ``cache=True`` dropped when no place can hold the cache (:data:`CACHE`)."""
    if not CACHE:
        kwargs.pop("cache", None)
    return _numba_njit(*args, **kwargs)

T = TypeVar("T")
R = TypeVar("R")



_limits = threading.local()  # the calling Python thread's own cap on threads (single_threaded sets it)


def thread_limit() -> int | None:
    """The calling Python thread's cap on the threads of its products and kernels, None when uncapped
    (:func:`single_threaded` sets it for runs going side by side)."""
    return getattr(_limits, "limit", None)


def spmm_threads() -> int:
    """Threads :func:`meshdenoise.operators.spmm` uses on large products: ``$MESHDENOISE_THREADS``, else the CPU
    count (at most 8)."""
    env = os.environ.get("MESHDENOISE_THREADS")
    if env:
        try:
            value = int(env)
        except ValueError:
            raise ValueError(f"MESHDENOISE_THREADS = {env!r} is not a whole number of threads") from None
        if value < 1:
            raise ValueError(f"MESHDENOISE_THREADS = {env!r} must be at least 1")
        return value
    return max(1, min(os.cpu_count() or 1, 8))


def set_threads() -> int:
    """Use :func:`spmm_threads` threads (at most numba's pool size, and at most
    the calling thread's :func:`single_threaded` limit); returns the count."""

    k = max(1, min(spmm_threads(), numba.config.NUMBA_NUM_THREADS, thread_limit() or 1 << 30))
    numba.set_num_threads(k)  # numba's count is the calling thread's own
    return k


@contextmanager
def single_threaded() -> Iterator[None]:
    """Inside the block, kernels and sparse products (:func:`~meshdenoise.operators.spmm`) started from this Python
    thread run on one thread (:func:`set_threads`, :func:`thread_limit`)."""
    old = getattr(_limits, "limit", None)
    _limits.limit = 1
    try:
        yield
    finally:
        _limits.limit = old
        set_threads()


@contextmanager
def every_thread() -> Iterator[None]:
    """Inside the block, this Python thread's kernels and products use every thread again (lifts
    :func:`single_threaded`): for work that other threads are waiting for (a shared colouring)."""
    old = getattr(_limits, "limit", None)
    _limits.limit = None
    try:
        yield
    finally:
        _limits.limit = old
        set_threads()


CONCURRENT_BELOW = 10_000  # vertices: runs of smaller meshes go side by side (run_concurrently), larger one after another


def run_concurrently(fn: Callable[[T], R], items: Sequence[T], vertices: int = 0) -> list[R]:
    """``[fn(x) for x in items]``, computed on :func:`spmm_threads` Python threads.

    For many independent runs on a small mesh (a tuning rule's candidates on its sampled
    region): each run's kernels are then single-threaded (:func:`single_threaded`), so the
    runs, not the loops inside them, share the cores. A parallel loop over a few thousand
    faces costs about as much in waking and joining threads as in work (``fit_vertices`` on
    3,000 vertices: 2 threads slower than 1), while whole runs side by side need no joining
    until they end. Runs on meshes of ``vertices`` >= :data:`CONCURRENT_BELOW` go one after
    another, each on every thread: there a run's own loops scale, and 3 runs on 2 threads
    side by side wait for the third (``two_stage`` with 2 probes, 2 cores idle: 0.85 of the
    loop's time at 3,176 vertices, 0.97 at 7,352, 1.07 at 13,256, 1.17 at 37,448). Every kernel
    computes each output element on one thread in a fixed order, so the results are the same
    bits as a loop's. The first exception raised is re-raised.
    """
    from concurrent.futures import ThreadPoolExecutor

    items = list(items)
    workers = min(spmm_threads(), numba.config.NUMBA_NUM_THREADS, len(items))
    # the package's value: where callers (and tests) set it, meshdenoise.kernels.CONCURRENT_BELOW
    if workers <= 1 or vertices >= getattr(sys.modules.get(__package__), "CONCURRENT_BELOW", CONCURRENT_BELOW):
        return [fn(x) for x in items]

    def one(x: T) -> R:
        with single_threaded():
            return fn(x)

    with ThreadPoolExecutor(max_workers=workers, thread_name_prefix="meshdenoise-runs") as pool:
        return list(pool.map(one, items))




def compiled_here(dispatchers: Sequence[object] | None = None) -> bool:
    """Whether numba's cache holds compiled kernels of this installation: the index file of at least one of
    ``dispatchers`` (default: the compiled kernels of this package's modules) exists.

    False on a new clone's first run (the cache lives beside the sources, or in ``NUMBA_CACHE_DIR``): every kernel
    then compiles on its first call, which the command line says (face000's default from a fresh clone: 31 kernels,
    0.4 to 1.1 s each, 17.6 s against about 4 s once cached). True when no cache's place can be read (a numba
    without one): no note rather than a wrong one.
    """
    if dispatchers is None:  # every compiled kernel of the package's modules
        dispatchers = [f for name, module in list(sys.modules.items()) if name.startswith(__package__ + ".")
                       for f in vars(module).values()
                       if hasattr(f, "py_func") and getattr(f, "_cache", None) is not None]
    paths = []
    for dispatcher in dispatchers:
        try:
            paths.append(dispatcher._cache._cache_file._index_path)
        except AttributeError:
            continue
    return not paths or any(os.path.exists(path) for path in paths)

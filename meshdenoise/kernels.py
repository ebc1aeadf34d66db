"""Compiled (numba) kernels of the nonlinear filters: two-stage normal filtering and Open3D-weight Taubin.

The linear filters are sparse products (:func:`meshdenoise.operators.spmm`); the nonlinear
ones recompute their weights from the current coordinates at every pass, which in numpy
means arrays of one value per face pair or per edge (tens of millions at scan size) and a
sort per pass. Here each pass is one loop over faces (or vertices) in CSR order, threaded
with numba's ``prange`` over rows, writing into preallocated buffers: no per-pass
allocation, no sort, no Python loop over elements.

Every kernel sums in the same order as the numpy/scipy code it replaces (CSR rows in
index order, products ``a * x`` added to a zero start), so results agree with it to a few
units in the last place. Compiled code is cached on disk (``cache=True``): the first call
in a fresh install compiles (a few seconds), later processes load it. Where numba finds no
writable place (a read-only install with a read-only HOME) the cache moves to a private
temporary folder, or is left out (:func:`_find_cache_place`); importing never fails for it.

Index arrays: ``indptr`` int64, ``indices`` int32 (int64 above 2^31 entries).
"""

from __future__ import annotations

import os
import threading
from contextlib import contextmanager
from typing import Callable, Iterator, Sequence, TypeVar

# Idle OpenMP threads sleep instead of spinning. On a busy machine (2 cores shared by many
# jobs) spinning doubled the CPU time of a two_stage run and made 2 threads slower than 1;
# passive waiting costs a few microseconds per parallel loop here, each loop taking
# milliseconds. Read when OpenMP starts, so set before numba loads it; a user's value wins.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numba  # noqa: E402
import numpy as np  # noqa: E402
from numba import njit as _numba_njit  # noqa: E402
from numba import prange, types  # noqa: E402
from numba.extending import intrinsic  # noqa: E402

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

__all__ = [
    "set_threads",
    "single_threaded",
    "every_thread",
    "run_concurrently",
    "face_geometry",
    "normal_turns",
    "centroid_spacing_sums",
    "spatial_weights",
    "patch_scores",
    "pick_guidance",
    "bilateral_pass",
    "bilateral_spatial_pass",
    "csr_matmat",
    "csr_matmat3",
    "cg_product",
    "cg_step",
    "cg_direction",
    "fit_vertices",
    "restore_tangential",
    "unit_into",
    "face_neighbour_lists",
    "patch_edge_lists",
    "inverse_distance_pass",
    "curve_terms",
    "projected_divergence_terms",
    "compiled_here",
]


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
    if workers <= 1 or vertices >= CONCURRENT_BELOW:
        return [fn(x) for x in items]

    def one(x: T) -> R:
        with single_threaded():
            return fn(x)

    with ThreadPoolExecutor(max_workers=workers, thread_name_prefix="meshdenoise-runs") as pool:
        return list(pool.map(one, items))


# --------------------------------------------------------------------------- small helpers
@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def unit_into(out, i, s0, s1, s2):  # pragma: no cover - compiled
    """Row ``out[i] = (s0, s1, s2) / norm``, zero for a zero vector; returns the norm.

    The division by ``np.sqrt`` of the sum of squares is numpy's arithmetic for
    ``v / np.linalg.norm(v)`` on one row, so the kernels agree with the numpy code bit for bit.
    """
    norm = np.sqrt(s0 * s0 + s1 * s1 + s2 * s2)
    if norm > 0:
        out[i, 0] = s0 / norm
        out[i, 1] = s1 / norm
        out[i, 2] = s2 / norm
    else:
        out[i, 0] = 0.0
        out[i, 1] = 0.0
        out[i, 2] = 0.0
    return norm


# exp on a block of non-positive arguments: libm's exp, called per pair, was 60 % of a guided normal-filtering pass
# (face000, 2.1M face pairs: 13.7 ms a pass against 5.4 ms with no exp); this loop has no call, no branch and no
# float-to-int64 conversion (which AVX2 lacks: with one the loop ran one argument at a time), so it runs as vector
# instructions, within 1 ulp of numpy's exp (tests/test_two_stage_kernel.py)
EXP_LOG2E = 1.4426950408889634
EXP_LN2_HI = 6.93147180369123816490e-01  # ln 2 in two parts (fdlibm's): k * EXP_LN2_HI is exact for |k| < 2^11
EXP_LN2_LO = 1.90821492927058770002e-10
EXP_FLOOR = -700.0  # below this exp is under 1e-304: 0
EXP_SHIFT = 6755399441055744.0  # 1.5 * 2^52: y + EXP_SHIFT - EXP_SHIFT is y rounded to an integer, for |y| < 2^51
EXP_BLOCK = 256  # rows of face pairs whose arguments are gathered, then exponentiated, at a time


@intrinsic
def _as_double(typingctx, bits):
    """The float64 whose bits are the int64 ``bits`` (a bit cast, which numba's scalars lack)."""
    if bits != types.int64:
        return None

    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], context.get_value_type(types.float64))

    return types.float64(types.int64), codegen


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def exp_one(x):  # pragma: no cover - compiled
    r"""``exp(x)`` for ``x <= 0``, 0 below :data:`EXP_FLOOR`: vector code when inlined into a loop.

    :math:`e^x = 2^k e^r` with :math:`k = \mathrm{round}(x / \ln 2)`, :math:`|r| \le \ln 2 / 2`
    (Cody and Waite's reduction), :math:`e^r` by its Taylor polynomial of degree 13 (truncation
    under 5e-18 relative, Horner's scheme), times :math:`2^k` made from its bits (exact: the
    result is normal, :math:`k \ge -1010`).
    """
    small = x < EXP_FLOOR
    x = 0.0 if small else x
    shifted = x * EXP_LOG2E + EXP_SHIFT
    k = shifted - EXP_SHIFT
    r = (x - k * EXP_LN2_HI) - k * EXP_LN2_LO
    p = 1.0 / 6227020800.0  # 1/13!
    p = p * r + 1.0 / 479001600.0
    p = p * r + 1.0 / 39916800.0
    p = p * r + 1.0 / 3628800.0
    p = p * r + 1.0 / 362880.0
    p = p * r + 1.0 / 40320.0
    p = p * r + 1.0 / 5040.0
    p = p * r + 1.0 / 720.0
    p = p * r + 1.0 / 120.0
    p = p * r + 1.0 / 24.0
    p = p * r + 1.0 / 6.0
    p = p * r + 0.5
    p = p * r + 1.0
    p = p * r + 1.0
    two_k = _as_double((np.int64(np.int32(k)) + 1023) << 52)  # int32 first: AVX2 converts doubles to int32 only
    return 0.0 if small else p * two_k


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def exp_nonpositive(buf, count):  # pragma: no cover - compiled
    """``buf[t] = exp(buf[t])`` for ``t < count`` and ``buf[t] <= 0`` (:func:`exp_one`; 0 below :data:`EXP_FLOOR`)."""
    for t in range(count):
        buf[t] = exp_one(buf[t])


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def exp_nonpositive2(a, b, count):  # pragma: no cover - compiled
    """:func:`exp_nonpositive` of two buffers in one loop: two independent chains of the polynomial per step.

    Horner's polynomial is a chain of 26 dependent operations; a core whose scheduler holds about one
    step of the vector loop waits on it (Zen 1: 7 ns an argument, against 4 for a shallower scheme).
    Two chains per step overlap, with the same arithmetic per argument, so the same bits.
    """
    for t in range(count):
        x = exp_one(a[t])
        y = exp_one(b[t])
        a[t] = x
        b[t] = y


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def face_cross(X, a, b, c):  # pragma: no cover - compiled
    """``cross(X[b] - X[a], X[c] - X[a])`` as three floats, numpy's ``cross`` arithmetic."""
    u0 = X[b, 0] - X[a, 0]
    u1 = X[b, 1] - X[a, 1]
    u2 = X[b, 2] - X[a, 2]
    v0 = X[c, 0] - X[a, 0]
    v1 = X[c, 1] - X[a, 1]
    v2 = X[c, 2] - X[a, 2]
    return u1 * v2 - u2 * v1, u2 * v0 - u0 * v2, u0 * v1 - u1 * v0


# --------------------------------------------------------------------------- face geometry
@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def face_geometry(X, F, N, A, C):  # pragma: no cover - compiled
    """Unit normals ``N`` (m, 3), areas ``A`` (m,) and centroids ``C`` (m, 3) of the faces, in place.

    Same arithmetic as :func:`meshdenoise.geometry.face_normals` (numpy's ``cross``, then
    division by the norm; zero for a zero-area face), ``face_areas`` and ``X[F].mean(1)``.
    """
    m = F.shape[0]
    for f in prange(m):
        a, b, c = F[f, 0], F[f, 1], F[f, 2]
        n0, n1, n2 = face_cross(X, a, b, c)
        A[f] = 0.5 * unit_into(N, f, n0, n1, n2)
        for d in range(3):
            C[f, d] = (X[a, d] + X[b, d] + X[c, d]) / 3.0


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def normal_turns(D, F, e1, e2, n, inv, out):  # pragma: no cover - compiled
    """The turn of each unit face normal under the vertex displacement ``D`` (n, 3), into ``out`` (m, 3).

    :class:`meshdenoise.tuning.normal_risk.NormalJacobian`'s product :math:`J d` in one pass over the faces:
    :math:`((d_1 - d_0) \\times e_2 + e_1 \\times (d_2 - d_0))` without its part along the unit normal
    ``n``, times ``inv`` (1 / twice the area; 0 for a zero-area face). Same products and sums as
    the numpy code (:func:`meshdenoise.geometry.cross_rows`), so the same rounding.
    """
    m = F.shape[0]
    for f in prange(m):
        a, b, c = F[f, 0], F[f, 1], F[f, 2]
        u0, u1, u2 = D[b, 0] - D[a, 0], D[b, 1] - D[a, 1], D[b, 2] - D[a, 2]
        w0, w1, w2 = D[c, 0] - D[a, 0], D[c, 1] - D[a, 1], D[c, 2] - D[a, 2]
        p0, p1, p2 = e1[f, 0], e1[f, 1], e1[f, 2]
        q0, q1, q2 = e2[f, 0], e2[f, 1], e2[f, 2]
        c0 = (u1 * q2 - u2 * q1) + (p1 * w2 - p2 * w1)
        c1 = (u2 * q0 - u0 * q2) + (p2 * w0 - p0 * w2)
        c2 = (u0 * q1 - u1 * q0) + (p0 * w1 - p1 * w0)
        t = n[f, 0] * c0 + n[f, 1] * c1 + n[f, 2] * c2
        out[f, 0] = (c0 - n[f, 0] * t) * inv[f]
        out[f, 1] = (c1 - n[f, 1] * t) * inv[f]
        out[f, 2] = (c2 - n[f, 2] * t) * inv[f]


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def normal_turns_many(D, F, e1, e2, n, inv, out):  # pragma: no cover - compiled
    """:func:`normal_turns` of ``P`` displacements at once: ``D`` (n, P, 3) into ``out`` (m, P, 3), the same
    products and sums per displacement (one pass over the faces instead of ``P`` calls: the exact traces'
    probes on a small mesh are one per vertex)."""
    m, P = F.shape[0], D.shape[1]
    for f in prange(m):
        a, b, c = F[f, 0], F[f, 1], F[f, 2]
        p0, p1, p2 = e1[f, 0], e1[f, 1], e1[f, 2]
        q0, q1, q2 = e2[f, 0], e2[f, 1], e2[f, 2]
        for k in range(P):
            u0, u1, u2 = D[b, k, 0] - D[a, k, 0], D[b, k, 1] - D[a, k, 1], D[b, k, 2] - D[a, k, 2]
            w0, w1, w2 = D[c, k, 0] - D[a, k, 0], D[c, k, 1] - D[a, k, 1], D[c, k, 2] - D[a, k, 2]
            c0 = (u1 * q2 - u2 * q1) + (p1 * w2 - p2 * w1)
            c1 = (u2 * q0 - u0 * q2) + (p2 * w0 - p0 * w2)
            c2 = (u0 * q1 - u1 * q0) + (p0 * w1 - p1 * w0)
            t = n[f, 0] * c0 + n[f, 1] * c1 + n[f, 2] * c2
            out[f, k, 0] = (c0 - n[f, 0] * t) * inv[f]
            out[f, k, 1] = (c1 - n[f, 1] * t) * inv[f]
            out[f, k, 2] = (c2 - n[f, 2] * t) * inv[f]


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def normal_turns_adjoint_many(W, F, e1, e2, n, inv, out):  # pragma: no cover - compiled
    """The adjoint of :func:`normal_turns_many`: ``W`` (m, P, 3) turns into ``out`` (n, P, 3), zeroed by the caller.
    Per face :math:`\\hat w = (w - n (n \\cdot w)) / \\|c\\|`, :math:`g_1 = e_2 \\times \\hat w`,
    :math:`g_2 = \\hat w \\times e_1`, added to corners 1 and 2 and subtracted from corner 0. Threads over the
    displacements (each writes its own slice of ``out``: no two threads add to one number), faces in order."""
    m, P = F.shape[0], W.shape[1]
    for k in prange(P):
        for f in range(m):
            s = inv[f]
            t = n[f, 0] * W[f, k, 0] + n[f, 1] * W[f, k, 1] + n[f, 2] * W[f, k, 2]
            w0, w1, w2 = (W[f, k, 0] - n[f, 0] * t) * s, (W[f, k, 1] - n[f, 1] * t) * s, (W[f, k, 2] - n[f, 2] * t) * s
            p0, p1, p2 = e1[f, 0], e1[f, 1], e1[f, 2]
            q0, q1, q2 = e2[f, 0], e2[f, 1], e2[f, 2]
            g0, g1, g2 = q1 * w2 - q2 * w1, q2 * w0 - q0 * w2, q0 * w1 - q1 * w0  # e2 x w
            h0, h1, h2 = w1 * p2 - w2 * p1, w2 * p0 - w0 * p2, w0 * p1 - w1 * p0  # w x e1
            a, b, c = F[f, 0], F[f, 1], F[f, 2]
            out[a, k, 0] -= g0 + h0
            out[a, k, 1] -= g1 + h1
            out[a, k, 2] -= g2 + h2
            out[b, k, 0] += g0
            out[b, k, 1] += g1
            out[b, k, 2] += g2
            out[c, k, 0] += h0
            out[c, k, 1] += h1
            out[c, k, 2] += h2


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def centroid_spacing_sums(C, indptr, indices, out):  # pragma: no cover - compiled
    """Per face ``i``: the sum of ``|c_i - c_j|`` over its neighbours ``j != i`` into ``out`` (m,); returns their count.

    The pair ``(i, i)`` adds ``sqrt(0) = 0`` to a non-negative sum, which leaves it unchanged: no branch on
    ``j == i`` in the loop (the same sums), and the count is the pairs ``j != i``.
    """
    m = C.shape[0]
    count = 0
    for i in prange(m):
        s = 0.0
        c0 = C[i, 0]
        c1 = C[i, 1]
        c2 = C[i, 2]
        self_pairs = 0
        for k in range(indptr[i], indptr[i + 1]):
            j = indices[k]
            d0 = c0 - C[j, 0]
            d1 = c1 - C[j, 1]
            d2 = c2 - C[j, 2]
            s += np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
            self_pairs += j == i
        out[i] = s
        count += indptr[i + 1] - indptr[i] - self_pairs
    return count


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def gaussian_block(X, indptr, indices, denom, lo, hi, out):  # pragma: no cover - compiled
    """``out[k - indptr[lo]] = exp(-|x_i - x_j|^2 / denom)`` for the pairs ``k = (i, j)`` of rows ``lo`` to ``hi - 1``
    of the CSR pattern, ``X`` (m, 3). The exponents first, then their exponentials at once
    (:func:`exp_nonpositive`; exp(-0) is 1 exactly)."""
    base = indptr[lo]
    for i in range(lo, hi):
        x0 = X[i, 0]
        x1 = X[i, 1]
        x2 = X[i, 2]
        for k in range(indptr[i], indptr[i + 1]):
            j = indices[k]
            d0 = x0 - X[j, 0]
            d1 = x1 - X[j, 1]
            d2 = x2 - X[j, 2]
            out[k - base] = -(d0 * d0 + d1 * d1 + d2 * d2) / denom
    exp_nonpositive(out, indptr[hi] - base)


@njit(cache=True, nogil=True, error_model="numpy")
def _block_pairs(indptr, blocks):  # pragma: no cover - compiled
    """The most face pairs in any :data:`EXP_BLOCK` rows: the size of a block's scratch."""
    m = indptr.shape[0] - 1
    most = 0
    for b in range(blocks):
        lo = b * EXP_BLOCK
        most = max(most, indptr[min(m, lo + EXP_BLOCK)] - indptr[lo])
    return most


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def spatial_weights(C, A, indptr, indices, denom, S):  # pragma: no cover - compiled
    """``S[k] = A_j exp(-|c_i - c_j|^2 / denom)`` for every pair ``k = (i, j)`` of the CSR pattern.

    The exponentials by blocks of :data:`EXP_BLOCK` rows, in ``S`` itself (:func:`gaussian_block`), each
    then times ``A_j`` while the block is in cache.
    """
    m = C.shape[0]
    for b in prange((m + EXP_BLOCK - 1) // EXP_BLOCK):
        lo = b * EXP_BLOCK
        hi = min(m, lo + EXP_BLOCK)
        start, stop = indptr[lo], indptr[hi]
        gaussian_block(C, indptr, indices, denom, lo, hi, S[start:stop])
        for k in range(start, stop):
            S[k] *= A[indices[k]]


# --------------------------------------------------------------------------- sparse products
@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def csr_matmat(indptr, indices, data, X, Y, accumulate):  # pragma: no cover - compiled
    """``Y = A X`` (``Y += A X`` with ``accumulate``) for CSR ``A`` and C-contiguous ``X`` (p, k), ``Y`` (n, k).

    Each row's sum runs over its non-zeros in storage order from 0 (or from ``Y``'s value), as
    scipy's ``csr_matvecs`` does, so the result is the same bits; the rows are shared by numba's
    threads (no Python thread hand-off: a 24-column product of the bunny's 200k non-zeros took
    0.38 ms on 2 threads against 0.76 ms through scipy's kernel on two Python threads), and each
    row's columns are one vector loop.
    """
    n = Y.shape[0]
    k = X.shape[1]
    for i in prange(n):
        if not accumulate:
            for c in range(k):
                Y[i, c] = 0.0
        add_row_product(indptr, indices, data, X, Y, i)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def add_row_product(indptr, indices, data, X, Y, i):  # pragma: no cover - compiled
    """``Y[i] += A[i] X``: row ``i`` of CSR ``A`` times ``X``, its non-zeros in storage order (scipy's order)."""
    k = X.shape[1]
    for t in range(indptr[i], indptr[i + 1]):
        a = data[t]
        j = indices[t]
        for c in range(k):
            Y[i, c] += a * X[j, c]


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def csr_matmat3(indptr, indices, data, X, Y, accumulate):  # pragma: no cover - compiled
    """:func:`csr_matmat` for three columns (coordinates), the sums in registers: the same bits."""
    n = Y.shape[0]
    for i in prange(n):
        s0 = Y[i, 0] if accumulate else 0.0
        s1 = Y[i, 1] if accumulate else 0.0
        s2 = Y[i, 2] if accumulate else 0.0
        for t in range(indptr[i], indptr[i + 1]):
            a = data[t]
            j = indices[t]
            s0 += a * X[j, 0]
            s1 += a * X[j, 1]
            s2 += a * X[j, 2]
        Y[i, 0] = s0
        Y[i, 1] = s1
        Y[i, 2] = s2


# --------------------------------------------------------------------------- block conjugate gradients
CG_BLOCK = 2048  # rows per partial sum of block_cg's dot products: their order is fixed whatever the thread count


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def cg_product(indptr, indices, data, P, Q, partial):  # pragma: no cover - compiled
    """``Q = A P`` (rows summed as :func:`csr_matmat` sums them) and ``partial[b, c]``, the sum of ``P[i, c] Q[i, c]``
    over the rows ``i`` of block ``b`` (:data:`CG_BLOCK` rows), in row order."""
    n = Q.shape[0]
    k = Q.shape[1]
    for b in prange(partial.shape[0]):
        for c in range(k):
            partial[b, c] = 0.0
        for i in range(b * CG_BLOCK, min(n, (b + 1) * CG_BLOCK)):
            for c in range(k):
                Q[i, c] = 0.0
            add_row_product(indptr, indices, data, P, Q, i)
            for c in range(k):
                partial[b, c] += P[i, c] * Q[i, c]


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def cg_step(X, R, P, Q, alpha, dinv, partial_rr, partial_rz):  # pragma: no cover - compiled
    """``X += alpha P``, ``R -= alpha Q`` (per column), and per block of :data:`CG_BLOCK` rows the sums of ``R^2``
    and of ``R (R dinv)`` (the new residual's norm and its product with the preconditioned residual)."""
    n = X.shape[0]
    k = X.shape[1]
    for b in prange(partial_rr.shape[0]):
        for c in range(k):
            partial_rr[b, c] = 0.0
            partial_rz[b, c] = 0.0
        for i in range(b * CG_BLOCK, min(n, (b + 1) * CG_BLOCK)):
            d = dinv[i]
            for c in range(k):
                X[i, c] += P[i, c] * alpha[c]
                r = R[i, c] - Q[i, c] * alpha[c]
                R[i, c] = r
                partial_rr[b, c] += r * r
                partial_rz[b, c] += r * (r * d)


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def cg_direction(P, R, dinv, beta):  # pragma: no cover - compiled
    """``P = beta P + R dinv`` (per column): the next search direction from the preconditioned residual."""
    n = P.shape[0]
    k = P.shape[1]
    for b in prange((n + CG_BLOCK - 1) // CG_BLOCK):
        for i in range(b * CG_BLOCK, min(n, (b + 1) * CG_BLOCK)):
            d = dinv[i]
            for c in range(k):
                P[i, c] = P[i, c] * beta[c] + R[i, c] * d


# --------------------------------------------------------------------------- guided filter
@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def lanczos_product(indptr, indices, data, Q, W, U, partial_a, partial_d):  # pragma: no cover - compiled
    """``W = M Q`` (rows summed as :func:`csr_matmat` sums them); per block of :data:`CG_BLOCK` rows ``partial_a[b, c]``,
    the sum of ``Q[i, c] W[i, c]``, and ``partial_d[f, b, c]``, of ``U[f, i, c] Q[i, c]`` (the duals' projections)."""
    n = Q.shape[0]
    k = Q.shape[1]
    duals = U.shape[0]
    for b in prange(partial_a.shape[0]):
        for c in range(k):
            partial_a[b, c] = 0.0
        for f in range(duals):
            for c in range(k):
                partial_d[f, b, c] = 0.0
        for i in range(b * CG_BLOCK, min(n, (b + 1) * CG_BLOCK)):
            for c in range(k):
                W[i, c] = 0.0
            add_row_product(indptr, indices, data, Q, W, i)
            for c in range(k):
                partial_a[b, c] += Q[i, c] * W[i, c]
            for f in range(duals):
                for c in range(k):
                    partial_d[f, b, c] += U[f, i, c] * Q[i, c]


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def lanczos_update(Q, Qp, W, alpha, beta_prev, partial_b):  # pragma: no cover - compiled
    """``W = W - Q alpha - Qp beta_prev`` (per column) and per block of :data:`CG_BLOCK` rows the sum of ``W^2``."""
    n = Q.shape[0]
    k = Q.shape[1]
    for b in prange(partial_b.shape[0]):
        for c in range(k):
            partial_b[b, c] = 0.0
        for i in range(b * CG_BLOCK, min(n, (b + 1) * CG_BLOCK)):
            for c in range(k):
                w = W[i, c] - Q[i, c] * alpha[c] - Qp[i, c] * beta_prev[c]
                W[i, c] = w
                partial_b[b, c] += w * w


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def lanczos_accumulate(Q, Y, out):  # pragma: no cover - compiled
    """``out[m] += Q Y[m]`` (per column) for every set ``m`` of coefficients: several functions' second pass at once."""
    n = Q.shape[0]
    k = Q.shape[1]
    sets = Y.shape[0]
    for i in prange(n):
        for m in range(sets):
            for c in range(k):
                out[m, i, c] += Q[i, c] * Y[m, c]


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def lanczos_next_row(indptr, indices, data, Q, Qp, alpha, beta_prev, inv, Qn, i, w):  # pragma: no cover - compiled
    """Row ``i`` of the next basis vectors, ``((M Q - Q alpha) - Qp beta_prev) inv``, into ``Qn`` (``Qp`` itself
    allowed: its row is read before written); ``w`` (k,) scratch."""
    k = Q.shape[1]
    for c in range(k):
        w[c] = 0.0
    for t in range(indptr[i], indptr[i + 1]):
        a = data[t]
        j = indices[t]
        for c in range(k):
            w[c] += a * Q[j, c]
    for c in range(k):
        Qn[i, c] = ((w[c] - Q[i, c] * alpha[c]) - Qp[i, c] * beta_prev[c]) * inv[c]


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def lanczos_regenerate(indptr, indices, data, Q, Qp, alpha, beta_prev, inv, Y, out):  # pragma: no cover - compiled
    """One step of a second pass, in one sweep of the rows: ``out[m] += Q Y[m]`` (per column, as
    :func:`lanczos_accumulate`), then the next basis vectors into ``Qp``, in place: ``((M Q - Q alpha) - Qp beta_prev)
    inv`` with the first pass's ``alpha`` and ``inv = 1 / beta`` (the arithmetic of :func:`lanczos_product`,
    :func:`lanczos_update` and :func:`lanczos_scale`, so the same basis to the bit, with no sums and a third of the
    memory traffic). Row ``i`` reads ``Qp[i]`` before writing it and ``Q`` only: safe on any number of threads."""
    n = Q.shape[0]
    k = Q.shape[1]
    sets = Y.shape[0]
    for b in prange((n + CG_BLOCK - 1) // CG_BLOCK):
        w = np.empty(k)
        for i in range(b * CG_BLOCK, min(n, (b + 1) * CG_BLOCK)):
            for m in range(sets):
                for c in range(k):
                    out[m, i, c] += Q[i, c] * Y[m, c]
            lanczos_next_row(indptr, indices, data, Q, Qp, alpha, beta_prev, inv, Qp, i, w)


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def lanczos_next(indptr, indices, data, Q, Qp, alpha, beta_prev, inv, Qn):  # pragma: no cover - compiled
    """:func:`lanczos_regenerate`'s recurrence alone, the next basis vectors into ``Qn`` (another buffer:
    ``((M Q - Q alpha) - Qp beta_prev) inv``, the same arithmetic, the same bits)."""
    n = Q.shape[0]
    k = Q.shape[1]
    for b in prange((n + CG_BLOCK - 1) // CG_BLOCK):
        w = np.empty(k)
        for i in range(b * CG_BLOCK, min(n, (b + 1) * CG_BLOCK)):
            lanczos_next_row(indptr, indices, data, Q, Qp, alpha, beta_prev, inv, Qn, i, w)


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def lanczos_accumulate_steps(ring, slots, Y, out):  # pragma: no cover - compiled
    """``out[m] += sum_s ring[slots[s]] Y[s, m]`` (per column), the steps ``s`` added in order: the numbers of one
    :func:`lanczos_regenerate` accumulation per step, with ``out`` read and written once for all of them."""
    n = out.shape[1]
    k = out.shape[2]
    sets = out.shape[0]
    steps = slots.shape[0]
    for b in prange((n + CG_BLOCK - 1) // CG_BLOCK):
        acc = np.empty((sets, k))
        for i in range(b * CG_BLOCK, min(n, (b + 1) * CG_BLOCK)):
            for m in range(sets):
                for c in range(k):
                    acc[m, c] = out[m, i, c]
            for s in range(steps):  # each step's row once (contiguous), its additions in step order
                r = slots[s]
                for m in range(sets):
                    for c in range(k):
                        acc[m, c] += ring[r, i, c] * Y[s, m, c]
            for m in range(sets):
                for c in range(k):
                    out[m, i, c] = acc[m, c]


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def lanczos_scale(W, inv, out):  # pragma: no cover - compiled
    """``out = W inv`` (per column): the next basis vectors."""
    n = W.shape[0]
    k = W.shape[1]
    for i in prange(n):
        for c in range(k):
            out[i, c] = W[i, c] * inv[c]


@njit(cache=True, nogil=True, error_model="numpy")
def shifted_tridiagonal_solves(alpha, beta, sizes, mu, order, out):  # pragma: no cover - compiled
    """``out[:k_j, j] = (I + mu T_j^p)^{-1} e_1``, ``T_j`` the symmetric tridiagonal of column ``j``'s first ``k_j =
    sizes[j]`` steps (diagonal ``alpha[:k_j, j]``, off-diagonal ``beta[:k_j - 1, j]``), zero below ``k_j``.

    ``1 + mu x^p = mu prod_m (x - z_m)`` over its roots ``z_m = a exp(i pi (2m + 1) / p)``, ``a = mu^(-1/p)``: one
    Thomas recurrence per root, in turn (a product of inverses, no sum: partial fractions cancel to 1e-9 where the
    result is small), each without pivoting (``T - z I`` has a definite imaginary part, or is SPD for the real root
    ``-a``); the result is real up to rounding, its real part kept. ``out`` (kmax, c), written."""
    kmax = out.shape[0]
    c = out.shape[1]
    a = mu ** (-1.0 / order)
    w = np.empty(kmax, dtype=np.complex128)
    cp = np.empty(kmax, dtype=np.complex128)
    for j in range(c):
        k = sizes[j]
        for i in range(kmax):
            out[i, j] = 0.0
        if k == 0:
            continue
        for i in range(k):
            w[i] = 0.0
        w[0] = 1.0
        for m in range(order):
            angle = np.pi * (2 * m + 1) / order
            z = complex(a * np.cos(angle), a * np.sin(angle))
            if 2 * m + 1 == order:
                z = complex(-a, 0.0)  # exactly real
            d = alpha[0, j] - z
            cp[0] = beta[0, j] / d if k > 1 else 0.0
            w[0] = w[0] / d
            for i in range(1, k):
                d = (alpha[i, j] - z) - beta[i - 1, j] * cp[i - 1]
                cp[i] = beta[i, j] / d if i < k - 1 else 0.0
                w[i] = (w[i] - beta[i - 1, j] * w[i - 1]) / d
            for i in range(k - 2, -1, -1):
                w[i] = w[i] - cp[i] * w[i + 1]
        for i in range(k):
            out[i, j] = w[i].real / mu


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def patch_scores(N, A, indptr, indices, edge_a, edge_b, patch_ptr, patch_edge, g, H, phi):  # pragma: no cover
    """Mean normal ``g`` (m, 3) and inconsistency ``H`` (m,) of every patch (Zhang et al. 2015).

    ``g_j = unit(sum_k A_k n_k)`` over the faces ``k`` of patch ``j`` (its CSR row),
    ``H_j = max_k |n_k - g_j| * max_e phi_e / (1e-9 + sum_e phi_e)`` over the face pairs
    ``e`` sharing an edge inside the patch (``patch_edge``, rows ``patch_ptr``), with
    ``phi_e = |n_a - n_b|`` written to ``phi`` (E,).
    """
    m = N.shape[0]
    for e in prange(edge_a.shape[0]):
        a, b = edge_a[e], edge_b[e]
        d0 = N[a, 0] - N[b, 0]
        d1 = N[a, 1] - N[b, 1]
        d2 = N[a, 2] - N[b, 2]
        phi[e] = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
    for j in prange(m):
        s0 = 0.0
        s1 = 0.0
        s2 = 0.0
        for k in range(indptr[j], indptr[j + 1]):
            q = indices[k]
            w = A[q]
            s0 += w * N[q, 0]
            s1 += w * N[q, 1]
            s2 += w * N[q, 2]
        unit_into(g, j, s0, s1, s2)
        s0 = g[j, 0]
        s1 = g[j, 1]
        s2 = g[j, 2]
        spread2 = 0.0  # sqrt is monotone and correctly rounded: sqrt(max r^2) == max sqrt(r^2)
        for k in range(indptr[j], indptr[j + 1]):
            q = indices[k]
            d0 = N[q, 0] - s0
            d1 = N[q, 1] - s1
            d2 = N[q, 2] - s2
            r2 = d0 * d0 + d1 * d1 + d2 * d2
            if r2 > spread2:
                spread2 = r2
        spread = np.sqrt(spread2)
        largest = 0.0
        total = 0.0
        for t in range(patch_ptr[j], patch_ptr[j + 1]):
            p = phi[patch_edge[t]]
            if p > largest:
                largest = p
            total += p
        H[j] = spread * largest / (1e-9 + total)


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def pick_guidance(H, factor, g, indptr, indices, label, shift, key, G):  # pragma: no cover - compiled
    """``G_i = g_j`` for the patch ``j`` around face ``i`` with the least ``rint(H_j * factor)``, ties to the least ``label[j]``.

    ``label`` (m,) is the faces' index in the caller's order (the identity when the faces are
    not relabelled). Each patch's quantised score and label are packed into one integer,
    ``key[j] = rint(H_j * factor) << shift | label[j]`` (``key`` (m,) int64 scratch; ``shift``
    bits hold every label, and the scores are at most 2^30): comparing keys is comparing
    scores, then labels, and a loop of integer minima runs without branches (twice as fast
    as comparing the two in turn).
    """
    m = g.shape[0]
    for j in prange(m):
        key[j] = (np.int64(np.rint(H[j] * factor)) << shift) | label[j]
    for i in prange(m):
        best = indices[indptr[i]]
        best_key = key[best]
        for k in range(indptr[i] + 1, indptr[i + 1]):
            j = indices[k]
            candidate = key[j]
            better = candidate < best_key
            best = j if better else best
            best_key = candidate if better else best_key
        G[i, 0] = g[best, 0]
        G[i, 1] = g[best, 1]
        G[i, 2] = g[best, 2]


EXP_CHUNK = 8  # blocks of EXP_BLOCK rows per thread's task: one scratch allocation serves them all


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def bilateral_pass(N, G, S, indptr, indices, denom, out):  # pragma: no cover - compiled
    """One Jacobi pass ``out_i = unit(sum_j S_ij exp(-|G_i - G_j|^2 / denom) n_j)``.

    By blocks of :data:`EXP_BLOCK` rows: the block's exponents, then their exponentials at once
    (:func:`exp_nonpositive`), then the sums (each row's in the pattern's order, as before).
    """
    m = N.shape[0]
    blocks = (m + EXP_BLOCK - 1) // EXP_BLOCK
    size = _block_pairs(indptr, blocks)
    for chunk in prange((blocks + EXP_CHUNK - 1) // EXP_CHUNK):
        w = np.empty(size)
        for b in range(chunk * EXP_CHUNK, min(blocks, (chunk + 1) * EXP_CHUNK)):
            lo = b * EXP_BLOCK
            hi = min(m, lo + EXP_BLOCK)
            base = indptr[lo]
            gaussian_block(G, indptr, indices, denom, lo, hi, w)
            for i in range(lo, hi):
                s0 = 0.0
                s1 = 0.0
                s2 = 0.0
                for k in range(indptr[i], indptr[i + 1]):
                    j = indices[k]
                    wk = S[k] * w[k - base]
                    s0 += wk * N[j, 0]
                    s1 += wk * N[j, 1]
                    s2 += wk * N[j, 2]
                unit_into(out, i, s0, s1, s2)


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def bilateral_spatial_pass(N, G, C, A, indptr, indices, denom_s, denom_r, out):  # pragma: no cover - compiled
    """:func:`spatial_weights` and :func:`bilateral_pass` in one sweep of the face pairs, the weights never stored.

    ``out_i = unit(sum_j (A_j exp(-|c_i - c_j|^2 / denom_s)) exp(-|G_i - G_j|^2 / denom_r) n_j)``: the same
    products in the same order as the two kernels, so the same bits, without writing and reading back
    ``S`` (8 bytes a pair) or reading the pattern twice. For a run of one normal-filtering pass per
    outer iteration (the default's), where ``S`` is used once.
    """
    m = N.shape[0]
    blocks = (m + EXP_BLOCK - 1) // EXP_BLOCK
    size = _block_pairs(indptr, blocks)
    for chunk in prange((blocks + EXP_CHUNK - 1) // EXP_CHUNK):
        ws = np.empty(size)
        wr = np.empty(size)
        for b in range(chunk * EXP_CHUNK, min(blocks, (chunk + 1) * EXP_CHUNK)):
            lo = b * EXP_BLOCK
            hi = min(m, lo + EXP_BLOCK)
            base = indptr[lo]
            for i in range(lo, hi):  # both exponents of the block's pairs, in one sweep of their indices
                c0 = C[i, 0]
                c1 = C[i, 1]
                c2 = C[i, 2]
                g0 = G[i, 0]
                g1 = G[i, 1]
                g2 = G[i, 2]
                for k in range(indptr[i], indptr[i + 1]):
                    j = indices[k]
                    d0 = c0 - C[j, 0]
                    d1 = c1 - C[j, 1]
                    d2 = c2 - C[j, 2]
                    ws[k - base] = -(d0 * d0 + d1 * d1 + d2 * d2) / denom_s
                    e0 = g0 - G[j, 0]
                    e1 = g1 - G[j, 1]
                    e2 = g2 - G[j, 2]
                    wr[k - base] = -(e0 * e0 + e1 * e1 + e2 * e2) / denom_r
            exp_nonpositive2(ws, wr, indptr[hi] - base)
            for i in range(lo, hi):
                s0 = 0.0
                s1 = 0.0
                s2 = 0.0
                for k in range(indptr[i], indptr[i + 1]):
                    j = indices[k]
                    wk = (ws[k - base] * A[j]) * wr[k - base]
                    s0 += wk * N[j, 0]
                    s1 += wk * N[j, 1]
                    s2 += wk * N[j, 2]
                unit_into(out, i, s0, s1, s2)


# --------------------------------------------------------------------------- vertex update
@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def fit_vertices(X, F, N, corner_ptr, corners, scale, iterations, C):  # pragma: no cover - compiled
    """``iterations`` Jacobi steps ``x_i += scale_i sum_{corners c of i} n_f (n_f . (c_f - x_i))``, in place on ``X``.

    ``corners`` lists, per vertex (rows ``corner_ptr``), its corner indices ``3 f + k`` in
    increasing order; ``C`` (m, 3) is scratch for the centroids.
    """
    m = F.shape[0]
    n = X.shape[0]
    for _ in range(iterations):
        for f in prange(m):
            a, b, c = F[f, 0], F[f, 1], F[f, 2]
            for d in range(3):
                C[f, d] = (X[a, d] + X[b, d] + X[c, d]) / 3.0
        for v in prange(n):  # each vertex reads only its own x and the centroids: in place is Jacobi
            x0 = X[v, 0]
            x1 = X[v, 1]
            x2 = X[v, 2]
            a0 = 0.0
            a1 = 0.0
            a2 = 0.0
            for t in range(corner_ptr[v], corner_ptr[v + 1]):
                f = corners[t] // 3
                s = N[f, 0] * (C[f, 0] - x0) + N[f, 1] * (C[f, 1] - x1) + N[f, 2] * (C[f, 2] - x2)
                a0 += N[f, 0] * s
                a1 += N[f, 1] * s
                a2 += N[f, 2] * s
            X[v, 0] = x0 + scale[v] * a0
            X[v, 1] = x1 + scale[v] * a1
            X[v, 2] = x2 + scale[v] * a2


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def restore_tangential(X, Y, N, corner_ptr, corners):  # pragma: no cover - compiled
    """``x_i += (I - u_i u_i^T)(y_i - x_i)`` in place, ``u_i = unit(sum_{corners of i} n_f)``.

    Each vertex takes back the tangential part of its move from ``Y`` (n, 3), keeping the
    part along its normal ``u_i`` (the normalised sum of the unit face normals ``N`` (m, 3)
    around it, :func:`meshdenoise.geometry.vertex_normals`); a vertex whose normal is zero
    (on no face, or normals cancelling) does not move.
    """
    n = X.shape[0]
    for v in prange(n):
        s0 = 0.0
        s1 = 0.0
        s2 = 0.0
        for t in range(corner_ptr[v], corner_ptr[v + 1]):
            f = corners[t] // 3
            s0 += N[f, 0]
            s1 += N[f, 1]
            s2 += N[f, 2]
        norm = np.sqrt(s0 * s0 + s1 * s1 + s2 * s2)
        if norm > 0:
            u0 = s0 / norm
            u1 = s1 / norm
            u2 = s2 / norm
            r0 = Y[v, 0] - X[v, 0]
            r1 = Y[v, 1] - X[v, 1]
            r2 = Y[v, 2] - X[v, 2]
            along = r0 * u0 + r1 * u1 + r2 * u2
            X[v, 0] += r0 - along * u0
            X[v, 1] += r1 - along * u1
            X[v, 2] += r2 - along * u2


# --------------------------------------------------------------------------- topology
@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def _merge3_count(F, vf_ptr, vf, counts, dummy):  # pragma: no cover - compiled
    m = F.shape[0]
    for f in prange(m):
        counts[f] = _merge3(F, vf_ptr, vf, f, dummy, False)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _merge3(F, vf_ptr, vf, f, out, write):  # pragma: no cover - compiled
    """Sorted union of the (sorted) face lists of the corners of face ``f``; its size, written to ``out`` if asked."""
    a, b, c = F[f, 0], F[f, 1], F[f, 2]
    pa, ea = vf_ptr[a], vf_ptr[a + 1]
    pb, eb = vf_ptr[b], vf_ptr[b + 1]
    pc, ec = vf_ptr[c], vf_ptr[c + 1]
    if b == a:
        pb = eb
    if c == a or c == b:
        pc = ec
    big = np.iinfo(np.int64).max
    size = 0
    last = -1
    while pa < ea or pb < eb or pc < ec:
        x = vf[pa] if pa < ea else big
        y = vf[pb] if pb < eb else big
        z = vf[pc] if pc < ec else big
        v = min(x, min(y, z))
        if v == x:
            pa += 1
        if v == y:
            pb += 1
        if v == z:
            pc += 1
        if v != last:
            if write:
                out[size] = v
            size += 1
            last = v
    return size


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def _merge3_fill(F, vf_ptr, vf, indptr, indices):  # pragma: no cover - compiled
    m = F.shape[0]
    for f in prange(m):
        _merge3(F, vf_ptr, vf, f, indices[indptr[f] : indptr[f + 1]], True)


@njit(cache=True, nogil=True, error_model="numpy")
def _counting_sort(groups, ptr, members):  # pragma: no cover - compiled
    """``members[ptr[g]:ptr[g + 1]]`` = the positions ``t`` with ``groups[t] == g``, increasing (``ptr`` given)."""
    at = ptr[:-1].copy()
    for t in range(groups.shape[0]):
        g = groups[t]
        members[at[g]] = t
        at[g] += 1


def _csr_of_groups(groups: np.ndarray, size: int, index_dtype) -> tuple[np.ndarray, np.ndarray]:
    """Rows ``0..size-1`` listing the positions ``t`` with ``groups[t] == row``, in increasing ``t``.

    ``members`` is ``np.argsort(groups, kind="stable")``, by a counting sort (one pass; the
    stable argsort of 9.6M corners took about a second at 1.6M vertices).
    """
    counts = np.bincount(groups, minlength=size)
    ptr = np.zeros(size + 1, dtype=np.int64)
    np.cumsum(counts, out=ptr[1:])
    members = np.empty(groups.shape[0], dtype=index_dtype)
    _counting_sort(np.ascontiguousarray(groups), ptr, members)
    return ptr, members


@njit(cache=True, nogil=True, error_model="numpy")
def _sort_rows(ptr, order, other):  # pragma: no cover - compiled
    """Each row ``ptr[v]:ptr[v + 1]`` of ``(other, order)`` sorted by ``other``, stably (insertion sort: rows are short)."""
    for v in range(ptr.shape[0] - 1):
        for i in range(ptr[v] + 1, ptr[v + 1]):
            h, s = other[i], order[i]
            j = i - 1
            while j >= ptr[v] and other[j] > h:  # strict: equal keys keep their order
                other[j + 1] = other[j]
                order[j + 1] = order[j]
                j -= 1
            other[j + 1] = h
            order[j + 1] = s


@njit(cache=True, nogil=True, error_model="numpy")
def _consecutive_pairs(ptr, order, other, first, second):  # pragma: no cover - compiled
    """Faces of consecutive sorted sides of the same edge; returns how many (``first`` empty: count only)."""
    count = 0
    write = first.shape[0] > 0
    for v in range(ptr.shape[0] - 1):
        for i in range(ptr[v], ptr[v + 1] - 1):
            if other[i] == other[i + 1]:
                if write:
                    first[count] = order[i] // 3
                    second[count] = order[i + 1] // 3
                count += 1
    return count


def edge_side_pairs(F: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Faces sharing an edge: consecutive face sides of the same undirected edge, in (edge, side) order.

    The face sides ``3 f + k`` (from ``F[f, k]`` to ``F[f, (k + 1) % 3]``) sorted stably by the
    key ``min * n + max`` of their endpoints; each pair of consecutive sides with the same key
    gives ``(f, g)``: each manifold edge once, an edge of ``s`` sides ``s - 1`` times. The same
    arrays as ``np.argsort(key, kind="stable")`` and a comparison of neighbours, without the
    sort (2 s at 1.6M vertices) and its five ``(3 m,)`` int64 temporaries.

    Returns ``first``, ``second`` (E,) int64 face indices.
    """
    F = np.ascontiguousarray(F)
    G = np.roll(F, -1, axis=1)  # side k runs from F[:, k] to G[:, k]
    ptr, order = _csr_of_groups(np.minimum(F, G).ravel(), n, np.int64)  # sides by smaller endpoint, stably
    other = np.maximum(F, G).ravel()[order]  # ... then each row by the larger one
    del G
    _sort_rows(ptr, order, other)
    empty = np.empty(0, dtype=np.int64)
    count = _consecutive_pairs(ptr, order, other, empty, empty)
    first, second = np.empty(count, dtype=np.int64), np.empty(count, dtype=np.int64)
    _consecutive_pairs(ptr, order, other, first, second)
    return first, second


def face_neighbour_lists(F: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """For each face, the sorted faces sharing at least one vertex with it (itself included), as CSR.

    Returns ``indptr`` (m + 1,) int64 and ``indices`` (nnz,) int32 (int64 for huge meshes):
    the pattern of ``M^T M`` for the vertex-face incidence ``M``, without forming it.
    """
    F = np.array(F, dtype=np.int64, order="C")  # one compiled variant: writable int64
    m = F.shape[0]
    index_dtype = np.int32 if max(m, n) < 2**31 - 1 else np.int64
    vf_ptr, vf = _csr_of_groups(F.ravel(), n, np.int64)
    vf //= 3  # corner -> face; sorted per vertex, a face twice for a degenerate one (merged away)
    vf = vf.astype(index_dtype)
    counts = np.zeros(m, dtype=np.int64)
    _merge3_count(F, vf_ptr, vf, counts, np.empty(0, dtype=index_dtype))
    indptr = np.zeros(m + 1, dtype=np.int64)
    np.cumsum(counts, out=indptr[1:])
    indices = np.empty(int(indptr[-1]), dtype=index_dtype)
    _merge3_fill(F, vf_ptr, vf, indptr, indices)
    return indptr, indices


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def _patch_edges(indptr, indices, a_ptr, a_edges, a_other, patch_ptr, patch_edge, write):  # pragma: no cover
    m = indptr.shape[0] - 1
    for j in prange(m):
        lo, hi = indptr[j], indptr[j + 1]
        size = 0
        start = patch_ptr[j] if write else 0
        for k in range(lo, hi):
            a = indices[k]
            for t in range(a_ptr[a], a_ptr[a + 1]):
                e = a_edges[t]
                b = a_other[t]
                # b in this patch? (binary search in the sorted row)
                l, h = lo, hi
                while l < h:
                    mid = (l + h) >> 1
                    if indices[mid] < b:
                        l = mid + 1
                    else:
                        h = mid
                if l < hi and indices[l] == b:
                    if write:
                        # insertion into the sorted run patch_edge[start : start + size]
                        p = start + size
                        while p > start and patch_edge[p - 1] > e:
                            patch_edge[p] = patch_edge[p - 1]
                            p -= 1
                        patch_edge[p] = e
                    size += 1
        if not write:
            patch_ptr[j + 1] = size


def patch_edge_lists(
    indptr: np.ndarray, indices: np.ndarray, edge_a: np.ndarray, edge_b: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """For each patch ``j`` (CSR row of faces), the edge pairs ``e`` with both faces in it, increasing, as CSR."""
    m = indptr.shape[0] - 1
    index_dtype = np.int32 if edge_a.size < 2**31 - 1 else np.int64
    a_ptr, a_edges = _csr_of_groups(edge_a, m, np.int64)
    a_other = edge_b[a_edges].astype(indices.dtype)  # the other face of each edge pair, beside it
    a_edges = a_edges.astype(index_dtype)
    patch_ptr = np.zeros(m + 1, dtype=np.int64)
    _patch_edges(indptr, indices, a_ptr, a_edges, a_other, patch_ptr, np.empty(0, dtype=index_dtype), False)
    np.cumsum(patch_ptr, out=patch_ptr)
    patch_edge = np.empty(int(patch_ptr[-1]), dtype=index_dtype)
    _patch_edges(indptr, indices, a_ptr, a_edges, a_other, patch_ptr, patch_edge, True)
    return patch_ptr, patch_edge


# --------------------------------------------------------------------------- Open3D Taubin
@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def inverse_distance_pass(X, indptr, indices, fixed, f, Y):  # pragma: no cover - compiled
    """``Y = X + f (A X - X)`` with Open3D's weights ``A_ij ∝ 1 / (|x_i - x_j| + 1e-12)`` (rows normalised).

    A fixed vertex (``fixed[i]``) or one without neighbours keeps its position exactly.
    """
    n = X.shape[0]
    for i in prange(n):
        lo, hi = indptr[i], indptr[i + 1]
        x0 = X[i, 0]
        x1 = X[i, 1]
        x2 = X[i, 2]
        s = 0.0
        if not fixed[i]:
            for k in range(lo, hi):
                j = indices[k]
                d0 = x0 - X[j, 0]
                d1 = x1 - X[j, 1]
                d2 = x2 - X[j, 2]
                s += 1.0 / (np.sqrt(d0 * d0 + d1 * d1 + d2 * d2) + 1e-12)
        if s == 0.0:
            Y[i, 0] = x0
            Y[i, 1] = x1
            Y[i, 2] = x2
            continue
        inv = 1.0 / s
        a0 = 0.0
        a1 = 0.0
        a2 = 0.0
        for k in range(lo, hi):
            j = indices[k]
            d0 = x0 - X[j, 0]
            d1 = x1 - X[j, 1]
            d2 = x2 - X[j, 2]
            c = inv * (1.0 / (np.sqrt(d0 * d0 + d1 * d1 + d2 * d2) + 1e-12))
            a0 += c * X[j, 0]
            a1 += c * X[j, 1]
            a2 += c * X[j, 2]
        Y[i, 0] = x0 + f * (a0 - x0)
        Y[i, 1] = x1 + f * (a1 - x1)
        Y[i, 2] = x2 + f * (a2 - x2)


# --------------------------------------------------------------------------- walk records
CURVE_CHUNK = 1 << 14  # rows per partial sum: fixed, so the sums do not depend on the thread count


@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def _curve_partials(Y, V, Z, out):  # pragma: no cover - compiled
    n, c = V.shape
    p = Z.shape[1]
    for b in prange(out.shape[0]):
        r = 0.0
        t = 0.0
        for i in range(b * CURVE_CHUNK, min(n, (b + 1) * CURVE_CHUNK)):
            for j in range(c):
                d = Y[i, j] - V[i, j]
                r += d * d
            for j in range(p):
                t += Z[i, j] * Y[i, c + j]
        out[b, 0] = r
        out[b, 1] = t


def curve_terms(Y: np.ndarray, V: np.ndarray, Z: np.ndarray) -> tuple[float, float]:
    """``sum((Y[:, :c] - V)**2)`` and ``sum(Z * Y[:, c:])`` in one pass over the rows, no temporaries.

    ``Y`` (n, c + p) the state of a walk (its coordinates, then its probes), ``V`` (n, c), ``Z``
    (n, p), all C-contiguous float64. Partial sums over fixed blocks of :data:`CURVE_CHUNK` rows,
    added in block order: the same numbers on any number of threads (they differ from numpy's
    ``einsum`` in the last places only).
    """
    n, c = V.shape
    if Y.shape != (n, c + Z.shape[1]) or Z.shape[0] != n:
        raise ValueError(f"curve_terms: Y {Y.shape}, V {V.shape} and Z {Z.shape} do not match")
    Y, V, Z = (np.ascontiguousarray(a, dtype=np.float64) for a in (Y, V, Z))
    set_threads()
    out = np.empty(((n + CURVE_CHUNK - 1) // CURVE_CHUNK, 2))
    _curve_partials(Y, V, Z, out)
    return float(out[:, 0].sum()), float(out[:, 1].sum())


# --------------------------------------------------------------------------- sobolev_normal's divergence
@njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def projected_divergence_terms(V, F, Y, X, O, B, t, delta, k0, out):  # pragma: no cover - compiled
    """``out[j] = b * (proj(V + delta b, Y + delta o) - X)`` for probe ``k = k0 + j`` (``b``, ``o``: columns
    ``3k .. 3k + 2`` of ``B`` and ``O``), one probe per thread.

    ``proj(X0, Yb) = X0 + n n^T D + t (I - n n^T) D``, ``D = Yb - X0``, ``n`` the area-weighted unit vertex
    normals of ``Yb``: numpy's arithmetic in :func:`meshdenoise.geometry.area_normals` (cross products
    summed onto the corners in ``np.bincount``'s order: first corners, then second, then third) and
    :func:`meshdenoise.plugins.sobolev_normal.project_update`, so the same numbers bit for bit.
    """
    n = V.shape[0]
    m = F.shape[0]
    for j in prange(out.shape[0]):
        k = k0 + j
        Yb = np.empty((n, 3))
        for i in range(n):
            for d in range(3):
                Yb[i, d] = Y[i, d] + delta * O[i, 3 * k + d]
        C = np.empty((m, 3))
        for f in range(m):
            c0, c1, c2 = face_cross(Yb, F[f, 0], F[f, 1], F[f, 2])
            C[f, 0] = c0
            C[f, 1] = c1
            C[f, 2] = c2
        S = np.zeros((n, 3))
        for corner in range(3):
            for f in range(m):
                v = F[f, corner]
                S[v, 0] += C[f, 0]
                S[v, 1] += C[f, 1]
                S[v, 2] += C[f, 2]
        N = np.empty((n, 3))
        for i in range(n):
            unit_into(N, i, S[i, 0], S[i, 1], S[i, 2])
            x0 = V[i, 0] + delta * B[i, 3 * k]
            x1 = V[i, 1] + delta * B[i, 3 * k + 1]
            x2 = V[i, 2] + delta * B[i, 3 * k + 2]
            d0 = Yb[i, 0] - x0
            d1 = Yb[i, 1] - x1
            d2 = Yb[i, 2] - x2
            dot = (d0 * N[i, 0] + d2 * N[i, 2]) + d1 * N[i, 1]  # numpy's einsum('ij,ij->i') order here (two lanes)
            p0 = dot * N[i, 0]
            p1 = dot * N[i, 1]
            p2 = dot * N[i, 2]
            out[j, i, 0] = B[i, 3 * k] * ((x0 + p0) + t * (d0 - p0) - X[i, 0])
            out[j, i, 1] = B[i, 3 * k + 1] * ((x1 + p1) + t * (d1 - p1) - X[i, 1])
            out[j, i, 2] = B[i, 3 * k + 2] * ((x2 + p2) + t * (d2 - p2) - X[i, 2])



def compiled_here(dispatchers: Sequence[object] | None = None) -> bool:
    """Whether numba's cache holds compiled kernels of this installation: the index file of at least one of
    ``dispatchers`` (default: this module's compiled kernels) exists.

    False on a new clone's first run (the cache lives beside the sources, or in ``NUMBA_CACHE_DIR``): every kernel
    then compiles on its first call, which the command line says (face000's default from a fresh clone: 31 kernels,
    0.4 to 1.1 s each, 17.6 s against about 4 s once cached). True when no cache's place can be read (a numba
    without one): no note rather than a wrong one.
    """
    if dispatchers is None:
        dispatchers = [f for f in globals().values() if hasattr(f, "py_func") and getattr(f, "_cache", None) is not None]
    paths = []
    for dispatcher in dispatchers:
        try:
            paths.append(dispatcher._cache._cache_file._index_path)
        except AttributeError:
            continue
    return not paths or any(os.path.exists(path) for path in paths)

"""Row-sized helpers inlined into the kernels: unit vectors, the vectorised exponential, a face's cross product."""

from __future__ import annotations

import numpy as np
from numba import types
from numba.extending import intrinsic

from .threads import njit


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
    result is normal, :math:`k \ge -1010`). Inlined into a kernel compiled with FMA contraction
    (:data:`meshdenoise.kernels.bilateral.PAIR_MATH`) each Horner step is one FMA, half the
    operations of the chain that bounds the loop; within 1 ulp of numpy's either way
    (tests/test_two_stage_kernel.py, tests/test_kernel_exp.py).
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
def face_cross(X, a, b, c):  # pragma: no cover - compiled
    """``cross(X[b] - X[a], X[c] - X[a])`` as three floats, numpy's ``cross`` arithmetic."""
    u0 = X[b, 0] - X[a, 0]
    u1 = X[b, 1] - X[a, 1]
    u2 = X[b, 2] - X[a, 2]
    v0 = X[c, 0] - X[a, 0]
    v1 = X[c, 1] - X[a, 1]
    v2 = X[c, 2] - X[a, 2]
    return u1 * v2 - u2 * v1, u2 * v0 - u0 * v2, u0 * v1 - u1 * v0

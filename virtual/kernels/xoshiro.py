"""xoshiro256+ kernels: one stream advanced in place, or 64 lanes side by side; and 64 lanes of
xoshiro128+ (float32 uniforms) for the float32 block kernel.

The states come from :func:`virtual.rng.stream_states` / :func:`virtual.rng.lane_states`
(numpy's SeedSequence does the seeding); these kernels only advance four 64-bit words.
"""

from __future__ import annotations

import numpy as np
from numba import int32, int64, uint32, uint64

from virtual.kernels import jit

__all__ = ["LANES", "next_uint64", "next_double", "fill_uniforms", "fill_uniforms32"]

from virtual.kernel_codes import LANES

_TO_DOUBLE = 1.0 / 9007199254740992.0  # 2**-53


@jit(inline="llvm")
def _rotl(x, k):
    return (x << uint64(k)) | (x >> uint64(64 - k))



@jit(inline="llvm")
def next_uint64(s):
    """Advance the xoshiro256+ state ``s`` (uint64[4]) in place; return 64 random bits."""
    r = s[0] + s[3]
    t = s[1] << uint64(17)
    s[2] ^= s[0]
    s[3] ^= s[1]
    s[1] ^= s[2]
    s[0] ^= s[3]
    s[2] ^= t
    s[3] = _rotl(s[3], 45)
    return r



@jit(inline="llvm")
def next_double(s):
    """Uniform double in [0, 1) from the top 53 bits (the low bits of xoshiro256+ are weak)."""
    return (next_uint64(s) >> uint64(11)) * _TO_DOUBLE



@jit(inline="llvm")
def _step(s0, s1, s2, s3):
    """One xoshiro256+ step of a lane held in registers: ``(uniform, s0, s1, s2, s3)``."""
    r = s0 + s3
    t = s1 << uint64(17)
    s2 ^= s0
    s3 ^= s1
    s1 ^= s2
    s0 ^= s3
    s2 ^= t
    s3 = _rotl(s3, 45)
    return int64(r >> uint64(11)) * _TO_DOUBLE, s0, s1, s2, s3


#: Rows a lane's state makes per load and store in the fills: every row stored and reloaded it
#: (the lane loop innermost, for the vectors), which made the fill 2.3-2.8x slower on AVX-512.
#: The fills are called, not inlined: once per block of rays, and every kernel that inlined its
#: unrolled loops took seconds longer to compile.
_ROWS_PER_PASS = 4


@jit(inline="always")
def _fill_rows(lanes, out, step):
    """The fills' loop: column ``l`` of ``out`` from lane ``l``, ``step`` (a lane's state in
    registers -> ``(uniform, state)``) applied four rows per load of the states."""
    n_lanes = lanes.shape[1]
    rows = out.shape[0]
    j = 0
    while j < rows:
        if j + _ROWS_PER_PASS <= rows:
            r0 = out[j]
            r1 = out[j + 1]
            r2 = out[j + 2]
            r3 = out[j + 3]
            for lane in range(n_lanes):
                s0 = lanes[0, lane]
                s1 = lanes[1, lane]
                s2 = lanes[2, lane]
                s3 = lanes[3, lane]
                r0[lane], s0, s1, s2, s3 = step(s0, s1, s2, s3)
                r1[lane], s0, s1, s2, s3 = step(s0, s1, s2, s3)
                r2[lane], s0, s1, s2, s3 = step(s0, s1, s2, s3)
                r3[lane], s0, s1, s2, s3 = step(s0, s1, s2, s3)
                lanes[0, lane] = s0
                lanes[1, lane] = s1
                lanes[2, lane] = s2
                lanes[3, lane] = s3
            j += _ROWS_PER_PASS
        else:
            r0 = out[j]
            for lane in range(n_lanes):
                r0[lane], lanes[0, lane], lanes[1, lane], lanes[2, lane], lanes[3, lane] = step(
                    lanes[0, lane], lanes[1, lane], lanes[2, lane], lanes[3, lane])
            j += 1


@jit(family="xoshiro")
def fill_uniforms(lanes, out):
    """Fill ``out`` (float64[rows, LANES]) with uniforms in [0, 1): column ``l`` comes from lane
    ``l`` of ``lanes`` (uint64[4, LANES], advanced in place), row by row.

    The lane loop is innermost and branch-free, so LLVM vectorizes it (8 lanes per AVX-512
    instruction): 4x the throughput of one stream drawn number by number. Each pass makes four
    rows from one load of the states (the same numbers as row by row).
    """
    _fill_rows(lanes, out, _step)


_TO_FLOAT32 = np.float32(2.0 ** -24)
_U8, _U9, _U11, _U21 = uint32(8), uint32(9), uint32(11), uint32(21)


@jit(inline="llvm")
def _step32(s0, s1, s2, s3):
    """One xoshiro128+ step of a lane held in registers: ``(uniform, s0, s1, s2, s3)``, the
    uniform from bits 8-31 of the 32-bit sum. Every step is cast back to uint32 (numba widens
    uint32 arithmetic to 64 bits, which would halve the lanes per vector instruction)."""
    r = uint32(s0 + s3)
    t = uint32(s1 << _U9)
    s2 = uint32(s2 ^ s0)
    s3 = uint32(s3 ^ s1)
    s1 = uint32(s1 ^ s2)
    s0 = uint32(s0 ^ s3)
    s2 = uint32(s2 ^ t)
    s3 = uint32(uint32(s3 << _U11) | uint32(s3 >> _U21))
    return np.float32(int32(uint32(r >> _U8))) * _TO_FLOAT32, s0, s1, s2, s3


@jit(family="xoshiro")
def fill_uniforms32(lanes, out):
    """Fill ``out`` (float32[rows, LANES]) with uniforms k 2^-24 in [0, 1) from xoshiro128+
    (Blackman & Vigna): column ``l`` from lane ``l`` of ``lanes`` (uint32[4, LANES], advanced in
    place), the top 24 bits of each 32-bit output; four rows per load of the states, as
    :func:`fill_uniforms`."""
    _fill_rows(lanes, out, _step32)

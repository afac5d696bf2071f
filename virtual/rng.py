"""Counter-free, splittable random streams for numba kernels.

Each chunk of rays gets its own xoshiro256+ stream (Blackman & Vigna 2018) whose 256-bit state
comes from ``numpy.random.SeedSequence(seed).spawn(...)``: numpy does the seeding and the
stream independence, the kernel only advances four 64-bit words. numba's own ``np.random``
is MT19937 behind a call per number (about 9x slower here, see benchmarks/) and cannot be
split per chunk, and numpy's bit generators cannot be inlined into a kernel. A result thus
depends on the seed and the chunking, never on the thread count.
"""

from __future__ import annotations

import numpy as np
from numba import njit, uint64

__all__ = ["stream_states", "next_double", "next_uint64"]

_TO_DOUBLE = 1.0 / 9007199254740992.0  # 2**-53


@njit(inline="always", cache=True)
def _rotl(x, k):
    return (x << uint64(k)) | (x >> uint64(64 - k))


@njit(inline="always", cache=True)
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


@njit(inline="always", cache=True)
def next_double(s):
    """Uniform double in [0, 1) from the top 53 bits (the low bits of xoshiro256+ are weak)."""
    return (next_uint64(s) >> uint64(11)) * _TO_DOUBLE


def stream_states(seed: int | np.random.SeedSequence, n_streams: int) -> np.ndarray:
    """``(n_streams, 4)`` uint64 xoshiro states, independent children of ``seed``.

    A state of all zeros is a fixed point of xoshiro; SeedSequence output is never all zero
    in practice, but it is checked.
    """
    ss = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
    children = ss.spawn(n_streams)
    states = np.empty((n_streams, 4), dtype=np.uint64)
    for i, child in enumerate(children):
        st = child.generate_state(4, dtype=np.uint64)
        if not st.any():
            st[0] = 1
        states[i] = st
    return states

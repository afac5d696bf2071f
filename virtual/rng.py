"""Counter-free, splittable random streams for numba kernels.

Each chunk of rays gets its own xoshiro256+ stream (Blackman & Vigna 2018) whose 256-bit state
comes from ``numpy.random.SeedSequence(seed).spawn(...)``: numpy does the seeding and the
stream independence, the kernel only advances four 64-bit words. numba's own ``np.random``
is MT19937 behind a call per number (about 9x slower here, see benchmarks/) and cannot be
split per chunk, and numpy's bit generators cannot be inlined into a kernel. A result thus
depends on the seed and the chunking, never on the thread count.

This module owns the seeding (:func:`stream_states`, :func:`lane_states`); the kernels that
advance the states are :mod:`virtual.kernels.xoshiro` (``next_double``, ``next_uint64``,
``fill_uniforms``); ``LANES`` is in :mod:`virtual.kernel_codes`. Seeding needs no numba.
"""

from __future__ import annotations

import numpy as np
from virtual.kernel_codes import LANES

__all__ = ["stream_states", "lane_states", "lane_states32"]


def lane_states(seed: int | np.random.SeedSequence, n_streams: int, lanes: int = LANES,
                dtype: type = np.uint64) -> np.ndarray:
    """``(n_streams, 4, lanes)`` uint64 (or ``dtype``): for each chunk, ``lanes`` xoshiro states drawn from one
    independent child of ``seed``.

    A state of all zeros is a fixed point of xoshiro; SeedSequence output is never all zero
    in practice, but it is checked.
    """
    ss = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
    states = np.empty((n_streams, 4, lanes), dtype=dtype)
    for i, child in enumerate(ss.spawn(n_streams)):
        st = child.generate_state(4 * lanes, dtype=dtype).reshape(lanes, 4)
        st[~st.any(axis=1), 0] = 1
        states[i] = st.T
    return states


def lane_states32(seed: int | np.random.SeedSequence, n_streams: int, lanes: int = LANES) -> np.ndarray:
    """``(n_streams, 4, lanes)`` uint32 xoshiro128+ states for the float32 block kernel
    (:func:`virtual.kernels.xoshiro.fill_uniforms32`), seeded like :func:`lane_states`."""
    return lane_states(seed, n_streams, lanes, np.uint32)


def stream_states(seed: int | np.random.SeedSequence, n_streams: int) -> np.ndarray:
    """``(n_streams, 4)`` uint64 xoshiro states, independent children of ``seed``: one lane
    per chunk (:func:`lane_states`)."""
    return np.ascontiguousarray(lane_states(seed, n_streams, 1)[:, :, 0])

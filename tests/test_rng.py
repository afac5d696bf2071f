"""The xoshiro256+ streams: reference values, independence of chunks, uniformity."""

import numpy as np
from virtual.kernels import jit
from scipy import stats

from virtual.kernels.xoshiro import LANES, fill_uniforms, next_double, next_uint64
from virtual.rng import lane_states, stream_states

MASK = (1 << 64) - 1


def _reference_xoshiro256plus(state, n):
    """Blackman & Vigna's reference algorithm, in plain Python integers."""
    s = [int(v) for v in state]
    out = []
    for _ in range(n):
        r = (s[0] + s[3]) & MASK
        t = (s[1] << 17) & MASK
        s[2], s[3] = s[2] ^ s[0], s[3] ^ s[1]
        s[1], s[0] = s[1] ^ s[2], s[0] ^ s[3]  # with the new s[2], s[3], as in the C source
        s[2] ^= t
        s[3] = ((s[3] << 45) | (s[3] >> 19)) & MASK
        out.append(r)
    return out


@jit
def _draw_u64(state, n):
    s = state.copy()
    out = np.empty(n, dtype=np.uint64)
    for i in range(n):
        out[i] = next_uint64(s)
    return out


@jit
def _draw_double(state, n):
    s = state.copy()
    out = np.empty(n)
    for i in range(n):
        out[i] = next_double(s)
    return out


def test_kernel_generator_matches_the_reference_algorithm():
    st = stream_states(12345, 3)
    for row in st:
        assert [int(v) for v in _draw_u64(row, 50)] == _reference_xoshiro256plus(row, 50)


def test_streams_depend_on_seed_only_and_differ_between_chunks():
    a, b = stream_states(7, 4), stream_states(7, 4)
    assert np.array_equal(a, b)
    assert len({tuple(r) for r in a}) == 4
    assert not np.array_equal(stream_states(8, 4), a)


def test_doubles_are_uniform_in_unit_interval():
    u = _draw_double(stream_states(1, 1)[0], 200_000)
    assert u.min() >= 0.0 and u.max() < 1.0
    # Kolmogorov-Smirnov at alpha = 1e-3: a correct generator fails 1 time in 1000
    assert stats.kstest(u, "uniform").pvalue > 1e-3


# --- lanes: the block kernel's vectorized generator -------------------------------------------------


@jit
def _fill(lanes, rows):
    out = np.empty((rows, lanes.shape[1]))
    fill_uniforms(lanes, out)
    return out


def test_each_lane_is_the_scalar_stream_of_its_state():
    # fill_uniforms is vectorized across lanes; column l must be exactly the sequence that the
    # scalar next_double draws from lane l's state (so the lanes inherit the reference tests).
    lanes = lane_states(2024, 3)[1]
    assert lanes.shape == (4, LANES) and lanes.dtype == np.uint64
    u = _fill(lanes.copy(), 50)
    for lane in (0, 1, 17, LANES - 1):
        np.testing.assert_array_equal(u[:, lane], _draw_double(np.ascontiguousarray(lanes[:, lane]), 50))


def test_lanes_are_distinct_deterministic_children_of_the_seed():
    a, b = lane_states(7, 4), lane_states(7, 4)
    np.testing.assert_array_equal(a, b)
    words = a.transpose(0, 2, 1).reshape(-1, 4)
    assert len({tuple(w) for w in words}) == words.shape[0]  # no two lanes share a state
    assert not np.array_equal(lane_states(8, 4), a)


def test_lane_uniforms_are_uniform():
    # 64 lanes x 4096 rows = 262,144 uniforms in 64 equal bins: chi-square at alpha = 1e-3.
    u = _fill(lane_states(5, 1)[0].copy(), 4096).ravel()
    assert u.min() >= 0.0 and u.max() < 1.0
    counts = np.bincount((u * 64).astype(np.int64), minlength=64)
    assert stats.chisquare(counts).pvalue > 1e-3

"""The ray-counting engine: numba kernels, int64 counts, one random stream per chunk.

A measurement of ``N`` rays is split into a number of chunks that depends only on ``N``; chunk
``c`` draws from its own xoshiro stream, a child of the measurement's ``SeedSequence``. Chunks run
in parallel (``prange``) and each writes only its own row of counts, so the result is identical
for a given seed whatever the thread count, and memory does not grow with ``N``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit, prange

from virtual.beam import emit
from virtual.collector import patch_of
from virtual.rng import stream_states
from virtual.specimens import scatter

__all__ = [
    "chunking",
    "measurement_seed",
    "spectro_counts",
    "SPECTRO_BINS",
    "SpectroTally",
    "single_chunk_threads",
    "gonio_counts",
    "multinomial_counts",
]

#: Rays per chunk aimed at; enough to amortise a chunk's set-up, small enough to balance 2 cores.
CHUNK_RAYS = 1 << 20
MAX_CHUNKS = 1024

# spectrophotometer bins
BIN_REFLECTED, BIN_TRANSMITTED, BIN_ABSORBED, BIN_MISSED, BIN_CONE = range(5)
SPECTRO_BINS = ("reflected", "transmitted", "absorbed", "missed", "cone")


def chunking(n_rays: int) -> np.ndarray:
    """Rays per chunk (int64), a function of ``n_rays`` only, never of the thread count."""
    if n_rays < 0:
        raise ValueError(f"n_rays must be >= 0, got {n_rays}")
    n_chunks = max(1, min(MAX_CHUNKS, -(-n_rays // CHUNK_RAYS)))
    sizes = np.full(n_chunks, n_rays // n_chunks, dtype=np.int64)
    sizes[: n_rays % n_chunks] += 1
    return sizes


def measurement_seed(seed: int, *key: int) -> np.random.SeedSequence:
    """The SeedSequence of one measurement: the root seed and an integer key (e.g. the
    wavelength in pm, the incidence in millidegrees, a sweep task's key). Equal keys give equal
    streams, so the same wavelength measured in two runs draws the same rays."""
    return np.random.SeedSequence(int(seed), spawn_key=tuple(int(k) for k in key))


@njit(parallel=True, cache=True, fastmath=True)
def _spectro_kernel(model, params, beam_kind, disk, b, cone, sizes, states):
    n_chunks = sizes.shape[0]
    out = np.zeros((n_chunks, 5), dtype=np.int64)
    for c in prange(n_chunks):
        s = states[c].copy()
        refl = np.int64(0)
        trans = np.int64(0)
        absorbed = np.int64(0)
        missed = np.int64(0)
        in_cone = np.int64(0)
        for _ in range(sizes[c]):
            wx, wy, wz, hit = emit(beam_kind, disk, b, s)
            if not hit:
                missed += 1
                continue
            ox, oy, oz, alive = scatter(model, params, wx, wy, wz, s)
            if not alive:
                absorbed += 1
                continue
            if oz * wz > 0.0:
                refl += 1
            else:
                trans += 1
            if ox * cone[0] + oy * cone[1] + oz * cone[2] >= cone[3]:
                in_cone += 1
        out[c, 0] = refl
        out[c, 1] = trans
        out[c, 2] = absorbed
        out[c, 3] = missed
        out[c, 4] = in_cone
    return out


@dataclass(frozen=True)
class SpectroTally:
    """Counts of one spectrophotometric measurement at one wavelength."""

    N: int
    reflected: int
    transmitted: int
    absorbed: int
    missed: int
    cone: int

    @property
    def hits(self) -> int:
        """Rays that reached the specimen's front face (the estimates' denominator)."""
        return self.N - self.missed


class single_chunk_threads:
    """Context manager: run numba kernels on one thread when ``n_rays`` fits one chunk.

    A measurement of at most :data:`virtual.engine.CHUNK_RAYS` rays is one chunk, i.e. one
    task of the parallel loop, so extra threads only add their wake-up (several ms per launch on
    a loaded 2-core machine -- 16x the kernel time of an adaptive rule's small batches). Results
    never depend on the thread count.
    """

    def __init__(self, n_rays: int) -> None:
        self.n_rays = int(n_rays)
        self.previous: int | None = None

    def __enter__(self) -> "single_chunk_threads":
        import numba

        if self.n_rays <= CHUNK_RAYS:
            self.previous = numba.get_num_threads()
            numba.set_num_threads(1)
        return self

    def __exit__(self, *exc: object) -> None:
        if self.previous is not None:
            import numba

            numba.set_num_threads(self.previous)


NO_CONE = np.array([0.0, 0.0, 1.0, 2.0])  # cos >= 2 never happens: no cone tally


def spectro_counts(model: int, params: np.ndarray, beam_kind: int, disk: int, beam_args: np.ndarray,
                   n_rays: int, seq: np.random.SeedSequence, cone: np.ndarray = NO_CONE) -> SpectroTally:
    """Shoot ``n_rays`` rays at a specimen and count where they go.

    ``cone`` = (cx, cy, cz, cos_half_angle): rays leaving within that cone are also counted
    (a bidirectional detector's field of view, or a gloss trap).
    """
    sizes = chunking(n_rays)
    states = stream_states(seq, sizes.shape[0])
    with single_chunk_threads(n_rays):
        out = _spectro_kernel(np.int64(model), np.ascontiguousarray(params, dtype=np.float64),
                              np.int64(beam_kind), np.int64(disk),
                              np.ascontiguousarray(beam_args, dtype=np.float64),
                              np.ascontiguousarray(cone, dtype=np.float64), sizes, states)
    tot = out.sum(axis=0)
    return SpectroTally(int(n_rays), *(int(v) for v in tot))


# --- goniophotometer: counts per collector patch ------------------------------------------------

@njit(parallel=True, cache=True, fastmath=True)
def _gonio_kernel(model, params, beam_kind, disk, b, cargs, n_bins, sizes, states):
    n_chunks = sizes.shape[0]
    out = np.zeros((n_chunks, n_bins + 2), dtype=np.int64)
    for c in prange(n_chunks):
        s = states[c].copy()
        hist = np.zeros(n_bins + 2, dtype=np.int64)  # chunk-private: no false sharing
        for _ in range(sizes[c]):
            wx, wy, wz, hit = emit(beam_kind, disk, b, s)
            if not hit:
                hist[n_bins + 1] += 1
                continue
            ox, oy, oz, alive = scatter(model, params, wx, wy, wz, s)
            if not alive:
                hist[n_bins] += 1
                continue
            hist[patch_of(ox, oy, oz, cargs[0], cargs[1], cargs[2], cargs[3], cargs[4])] += 1
        out[c] = hist
    return out


def gonio_counts(model: int, params: np.ndarray, beam_kind: int, disk: int, beam_args: np.ndarray,
                 collector_args: tuple, n_rays: int, seq: np.random.SeedSequence) -> np.ndarray:
    """Counts per collector bin (upper patches, lower patches), then absorbed, then missed.

    ``collector_args`` is :meth:`virtual.collector.Collector.kernel_args`. Memory is
    O(chunks x bins), independent of ``n_rays``.
    """
    n_bins = 2 * int(collector_args[1]) * int(collector_args[2])  # (scheme, n_theta, n_phi, ...)
    sizes = chunking(n_rays)
    states = stream_states(seq, sizes.shape[0])
    with single_chunk_threads(n_rays):
        out = _gonio_kernel(np.int64(model), np.ascontiguousarray(params, dtype=np.float64),
                            np.int64(beam_kind), np.int64(disk), np.ascontiguousarray(beam_args, dtype=np.float64),
                            tuple(collector_args), np.int64(n_bins), sizes, states)
    return out.sum(axis=0)


def multinomial_counts(probabilities: np.ndarray, n_rays: int, seq: np.random.SeedSequence) -> np.ndarray:
    """The exact fast path: ``n_rays`` rays' counts over bins with known probabilities, drawn as
    one multinomial -- the same distribution as counting the rays one by one, at O(bins) cost.

    ``probabilities`` must be finite, >= 0 and sum to 1 within 1e-9 (renormalised exactly).
    """
    p = np.asarray(probabilities, dtype=np.float64)
    total = p.sum()
    if not np.all(np.isfinite(p)) or np.any(p < 0) or abs(total - 1.0) > 1e-9:
        raise ValueError(f"bin probabilities must be >= 0 and sum to 1 (sum = {total!r})")
    return np.random.default_rng(seq).multinomial(int(n_rays), p / total).astype(np.int64)

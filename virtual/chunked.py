"""A measurement's chunks run side by side: the kernels' chunk functions, compiled without the
GIL, called from as many Python threads as numba's thread count.

Each chunk draws from its own stream(s) and writes only its own row of the output, so the counts
depend on the seed and the chunking, never on the thread count or the order the threads finish.
numba's ``prange`` would do the same, but its parallel-loop passes cost every kernel a long
compile (about a quarter of the kernels' compile time); a thread pool costs a few microseconds
per chunk of a million rays.

The functions here keep the names and arguments of the parallel kernels they replace.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from typing import Any, Callable

import numba
import numpy as np

from virtual.kernels.block32 import gonio_block32_chunk
from virtual.kernels.block32_coat import gonio_coat32_chunk
from virtual.kernels.ray_loop import gonio_fx_chunk, spectro_fx_chunk, spectro_points_chunk
from virtual.kernels.block_coat import gonio_coat_chunk
from virtual.kernels.block64 import ggx_spectral_chunk, gonio_block_chunk, lambert_spectral_chunk
from virtual.kernels.spectral32 import ggx_spectral32_chunk, lambert_spectral32_chunk

__all__ = ["run_chunks", "gonio_block32_kernel", "gonio_coat32_kernel", "gonio_block_kernel", "gonio_coat_kernel", "lambert_spectral_kernel",
           "ggx_spectral_kernel", "lambert_spectral32_kernel", "ggx_spectral32_kernel", "spectro_fx_kernel",
           "gonio_fx_kernel", "spectro_points_kernel"]


def run_chunks(chunk: Callable[..., None], n_chunks: int, args_of: Callable[[int], tuple]) -> None:
    """``chunk(*args_of(c))`` for every chunk c, on up to ``numba.get_num_threads()`` threads
    (in this thread when one suffices). ``args_of`` runs here, in order; a chunk's exception is
    raised here."""
    threads = min(numba.get_num_threads(), n_chunks)
    if threads <= 1:
        for c in range(n_chunks):
            chunk(*args_of(c))
        return
    with ThreadPoolExecutor(max_workers=threads) as pool:
        for future in [pool.submit(chunk, *args_of(c)) for c in range(n_chunks)]:
            future.result()


def _tuple(a: np.ndarray) -> tuple:
    """An array's values as a tuple of its own scalar type (the chunks keep tuples in registers)."""
    return tuple(a.dtype.type(v) for v in a)


def gonio_block32_kernel(model: Any, params: np.ndarray, conical: bool, beam_args: np.ndarray, cargs: tuple,
                         margins: np.ndarray, n_bins: Any, sizes: np.ndarray, lanes: np.ndarray,
                         states: np.ndarray) -> np.ndarray:
    """Counts per chunk of the float32 block kernel (rows summed by the caller): float64 ``params``
    (6) and ``beam_args`` (15), passed in float32 and, for the rays the kernel decides again, in
    float64; float32 ``margins``, uint32 ``lanes``, uint64 ``states``."""
    out = np.zeros((sizes.shape[0], int(n_bins) + 2), dtype=np.int64)
    p64, b64 = _tuple(np.asarray(params[:6], dtype=np.float64)), _tuple(np.asarray(beam_args, dtype=np.float64))
    p, b = _tuple(np.asarray(params[:6], dtype=np.float32)), _tuple(np.asarray(beam_args, dtype=np.float32))
    run_chunks(gonio_block32_chunk, sizes.shape[0],
               lambda c: (model, p, p64, bool(conical), b, b64, cargs, margins[0], margins[1], n_bins, sizes[c],
                          lanes[c].copy(), states[c].copy(), out[c]))
    return out


def gonio_coat32_kernel(model: Any, params: np.ndarray, conical: bool, beam_args: np.ndarray, cargs: tuple,
                        margins: np.ndarray, n_bins: Any, sizes: np.ndarray, lanes: np.ndarray,
                        states: np.ndarray) -> np.ndarray:
    """Counts per chunk of the coated families' float32 block kernel
    (:mod:`virtual.kernels.block32_coat`): the whole float64 ``params`` vector (zero-padded to at
    least six; its first six passed in float32 too), 15 ``beam_args``."""
    out = np.zeros((sizes.shape[0], int(n_bins) + 2), dtype=np.int64)
    p64 = np.ascontiguousarray(params, dtype=np.float64)
    p, b = _tuple(p64[:6].astype(np.float32)), _tuple(np.asarray(beam_args, dtype=np.float32))
    b64 = _tuple(np.asarray(beam_args, dtype=np.float64))
    run_chunks(gonio_coat32_chunk, sizes.shape[0],
               lambda c: (model, p, p64, bool(conical), b, b64, cargs, margins[0], margins[1], n_bins, sizes[c],
                          lanes[c].copy(), states[c].copy(), out[c]))
    return out


def gonio_block_kernel(model: Any, params: np.ndarray, beam_kind: Any, beam_args: np.ndarray, cargs: tuple,
                       margins: Any, n_bins: Any, sizes: np.ndarray, lanes: np.ndarray,
                       states: np.ndarray) -> np.ndarray:
    """Counts per chunk of the float64 block kernel (six ``params``, 15 ``beam_args``)."""
    out = np.zeros((sizes.shape[0], int(n_bins) + 2), dtype=np.int64)
    p, b = _tuple(params[:6]), _tuple(beam_args)
    m0, m1 = np.float64(margins[0]), np.float64(margins[1])
    run_chunks(gonio_block_chunk, sizes.shape[0],
               lambda c: (model, p, beam_kind, b, cargs, m0, m1, n_bins, sizes[c], lanes[c].copy(), states[c].copy(),
                          out[c]))
    return out


def gonio_coat_kernel(model: Any, params: np.ndarray, beam_kind: Any, beam_args: np.ndarray, cargs: tuple,
                      margins: Any, n_bins: Any, sizes: np.ndarray, lanes: np.ndarray, states: np.ndarray) -> np.ndarray:
    """Counts per chunk of the coated families' block kernel (:mod:`virtual.kernels.block_coat`):
    the whole float64 ``params`` vector (zero-padded to at least six), 15 ``beam_args``."""
    out = np.zeros((sizes.shape[0], int(n_bins) + 2), dtype=np.int64)
    tab = np.ascontiguousarray(params, dtype=np.float64)
    p, b = _tuple(tab[:6]), _tuple(beam_args)
    m0, m1 = np.float64(margins[0]), np.float64(margins[1])
    run_chunks(gonio_coat_chunk, sizes.shape[0],
               lambda c: (model, p, tab, beam_kind, b, cargs, m0, m1, n_bins, sizes[c], lanes[c].copy(),
                          states[c].copy(), out[c]))
    return out


def lambert_spectral_kernel(thr: np.ndarray, beam_kind: Any, beam_args: np.ndarray, cargs: tuple, margins: Any,
                            n_patches: Any, sizes: np.ndarray, lanes: np.ndarray) -> tuple[np.ndarray, int]:
    """The float64 Lambertian batch: counts ``(n_thr + 1, n_patches)`` of hit rays by (cell of
    u0, upper patch), summed over chunks, and the missed rays."""
    n = sizes.shape[0]
    cells = np.zeros((n, thr.shape[0] + 1, int(n_patches)), dtype=np.int64)
    miss = np.zeros((n, 1), dtype=np.int64)
    b = _tuple(beam_args)
    m0, m1 = np.float64(margins[0]), np.float64(margins[1])
    run_chunks(lambert_spectral_chunk, n,
               lambda c: (thr, beam_kind, b, cargs, m0, m1, sizes[c], lanes[c].copy(), cells[c], miss[c]))
    return cells.sum(axis=0), int(miss.sum())


def ggx_spectral_kernel(ax: float, ay: float, separable: float, etas: np.ndarray, ks: np.ndarray, beam_kind: Any,
                        beam_args: np.ndarray, cargs: tuple, margins: Any, n_bins: Any, sizes: np.ndarray,
                        lanes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The float64 GGX batch: survivor counts ``(n_bins, W)`` and (hits, missed), summed over chunks."""
    n = sizes.shape[0]
    hist = np.zeros((n, int(n_bins), etas.shape[0]), dtype=np.int64)
    tallies = np.zeros((n, 2), dtype=np.int64)
    b = _tuple(beam_args)
    m0, m1 = np.float64(margins[0]), np.float64(margins[1])
    run_chunks(ggx_spectral_chunk, n,
               lambda c: (float(ax), float(ay), float(separable), etas, ks, beam_kind, b, cargs, m0, m1, sizes[c],
                          lanes[c].copy(), hist[c], tallies[c]))
    return hist.sum(axis=0), tallies.sum(axis=0)


def chunk_key(lanes: np.ndarray) -> np.uint64:
    """A chunk's 64-bit key for :func:`~virtual.kernels.refine.ray_bits`: two words of its
    first xoshiro128+ lane's initial state (seeded per chunk by the SeedSequence)."""
    return np.uint64((int(lanes[0, 0]) << 32) | int(lanes[1, 0]))


def lambert_spectral32_kernel(thr: np.ndarray, conical: bool, beam_args: np.ndarray, cargs: tuple,
                              margins: np.ndarray, n_patches: Any, sizes: np.ndarray,
                              lanes: np.ndarray) -> tuple[np.ndarray, int]:
    """The float32 Lambertian batch (float64 sorted ``thr``; float32 ``beam_args``, ``margins``;
    uint32 ``lanes``): counts ``(n_thr + 1, n_patches)`` and the missed rays, summed over chunks."""
    n, n_cells = sizes.shape[0], thr.shape[0] + 1
    cells = np.zeros((n, n_cells * int(n_patches)), dtype=np.int32)  # <= 2^20 rays per chunk: no overflow
    tallies = np.zeros((n, 1), dtype=np.int64)
    b = _tuple(beam_args)
    thr = np.ascontiguousarray(thr, dtype=np.float64)
    floors = (np.floor(thr * 2.0 ** 24) * 2.0 ** -24).astype(np.float32)  # exact: multiples of 2^-24 up to 1
    run_chunks(lambert_spectral32_chunk, n,
               lambda c: (thr, floors, bool(conical), b, cargs, margins[0], margins[1], n_patches, sizes[c],
                          lanes[c].copy(), chunk_key(lanes[c]), cells[c], tallies[c]))
    return cells.sum(axis=0, dtype=np.int64).reshape(n_cells, int(n_patches)), int(tallies.sum())


def ggx_spectral32_kernel(params: np.ndarray, etas: np.ndarray, ks: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                          conical: bool, beam_args: np.ndarray, cargs: tuple, margins: np.ndarray, n_bins: Any,
                          sizes: np.ndarray, lanes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The float32 GGX batch (``params`` = alpha_x, alpha_y, separable): survivor counts
    ``(n_bins, wp)`` and (hits, missed), summed over chunks."""
    n, wp = sizes.shape[0], lo.shape[1]
    hist = np.zeros((n, int(n_bins) * wp), dtype=np.int32)  # <= 2^20 rays per chunk: no overflow
    tallies = np.zeros((n, 2), dtype=np.int64)
    p, b = _tuple(params[:3]), _tuple(beam_args)
    run_chunks(ggx_spectral32_chunk, n,
               lambda c: (p, etas, ks, lo, hi, bool(conical), b, cargs, margins[0], margins[1], sizes[c],
                          lanes[c].copy(), chunk_key(lanes[c]), hist[c], tallies[c]))
    return hist.sum(axis=0, dtype=np.int64).reshape(int(n_bins), wp), tallies.sum(axis=0)


def spectro_fx_kernel(model: Any, ptab: np.ndarray, cdf: np.ndarray, beam_kind: Any, disk: Any, b: np.ndarray,
                      bp: np.ndarray, cone: np.ndarray, flags: Any, e: np.ndarray, sizes: np.ndarray,
                      states: np.ndarray) -> np.ndarray:
    """Tallies per chunk of the ray-by-ray spectrophotometer (:data:`virtual.effects.SPECTRO_FX_COLUMNS`)."""
    out = np.zeros((sizes.shape[0], 7), dtype=np.int64)
    run_chunks(spectro_fx_chunk, sizes.shape[0],
               lambda c: (model, ptab, cdf, beam_kind, disk, b, bp, cone, flags, e, sizes[c], states[c].copy(), out[c]))
    return out


def gonio_fx_kernel(model: Any, ptab: np.ndarray, cdf: np.ndarray, beam_kind: Any, disk: Any, b: np.ndarray,
                    bp: np.ndarray, cargs: tuple, n_bins: Any, flags: Any, e: np.ndarray, det: np.ndarray,
                    sizes: np.ndarray, states: np.ndarray) -> np.ndarray:
    """Counts per chunk of the ray-by-ray goniophotometer (patches, absorbed, missed, detectors)."""
    out = np.zeros((sizes.shape[0], int(n_bins) + 2 + det.shape[0]), dtype=np.int64)
    run_chunks(gonio_fx_chunk, sizes.shape[0],
               lambda c: (model, ptab, cdf, beam_kind, disk, b, bp, cargs, n_bins, flags, e, det, sizes[c],
                          states[c].copy(), out[c]))
    return out


def spectro_points_kernel(model: Any, params: np.ndarray, b: np.ndarray, pts: np.ndarray, starts: np.ndarray,
                          states: np.ndarray) -> np.ndarray:
    """Tallies per chunk (reflected, transmitted, absorbed, missed, 0) of rays through given points:
    chunk c takes ``pts[starts[c]:starts[c + 1]]``."""
    n = starts.shape[0] - 1
    out = np.zeros((n, 5), dtype=np.int64)
    run_chunks(spectro_points_chunk, n,
               lambda c: (model, params, b, pts, starts[c], starts[c + 1], states[c].copy(), out[c]))
    return out

"""The bare counting kernels: every chunk draws its own stream and writes only its own row.

* ray by ray (``spectro_kernel``, ``gonio_kernel``): each ray is emitted, scattered and counted
  before the next; any specimen, any disk sampling;
* block (``gonio_block_kernel``): rays go through in blocks of :data:`BLOCK_RAYS`; the block's
  uniforms are drawn first, 64 lanes side by side, then one branch-free loop emits (polar
  disks), scatters (:func:`~virtual.kernels.scatter.scatter_given`) and bins
  (:func:`~virtual.kernels.collector.guess_bin`) every ray, then a short scalar loop settles
  the rare uncertain bin with the exact :func:`~virtual.kernels.collector.patch_of`.

The Python wrappers (chunking, seeding, choosing a kernel) are :mod:`virtual.engine`.
"""

from __future__ import annotations

import numpy as np
from numba import prange

from virtual.kernels import jit
from virtual.kernels.beam import BEAM_CONICAL, emit, emit_given
from virtual.kernels.collector import SCHEME_EQUAL_ANGLE, SCHEME_EQUAL_PSA, SCHEME_EQUAL_SOLID_ANGLE, guess_bin, patch_of
from virtual.kernels.rng import LANES, fill_uniforms
from virtual.kernels.scatter import GIVEN_UNIFORMS, MODEL_GGX, MODEL_LAMBERT, scatter, scatter_given

__all__ = ["BLOCK_RAYS", "BEAM_UNIFORMS", "spectro_kernel", "gonio_kernel", "gonio_block_kernel"]

#: Rays per block of the block kernel: its 7 uniforms and 4 outputs per ray (88 KiB) stay in L2.
BLOCK_RAYS = 1024
BEAM_UNIFORMS = 4  # two polar disk points


@jit(parallel=True, fastmath=True)
def spectro_kernel(model, params, beam_kind, disk, b, cone, sizes, states):
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



@jit(parallel=True, fastmath=True)
def gonio_kernel(model, params, beam_kind, disk, b, cargs, n_bins, sizes, states):
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



@jit(fastmath=True, error_model="numpy")
def gonio_block_chunk(model, p, beam_kind, b, cargs, ring_margin, sector_margin, n_bins, n_rays, lane, hist):
    """One chunk of the block kernel: ``n_rays`` rays from the xoshiro lanes ``lane`` (advanced in
    place) added to ``hist``.

    Compiled on its own, not inlined into the parallel loop: numba's parfor lowering would hoist
    the block buffers out of the loop and compile the body with other flags, and the loops would
    no longer vectorize. ``error_model="numpy"``: a float division must not test its divisor and
    raise (a branch per division also stops vectorization); the formulas guard their divisors.
    ``p`` and ``b`` are tuples: loads from an array that the loop might write (for all LLVM
    knows) would be repeated every iteration.
    """
    nb = BLOCK_RAYS
    n_beam = BEAM_UNIFORMS if beam_kind == BEAM_CONICAL else 0
    ublock = np.empty(((n_beam + GIVEN_UNIFORMS) * nb // LANES, LANES))
    u = ublock.reshape(ublock.size)
    s0 = n_beam * nb  # the scatterer's uniforms follow the beam's
    bo = nb if n_beam > 0 else 0  # a collimated beam reads none: any valid index will do
    scheme, n_theta, n_phi, sin2_edges, phi_cs = cargs
    code = np.empty(nb, dtype=np.int64)
    vx = np.empty(nb)
    vy = np.empty(nb)
    vz = np.empty(nb)
    # Absorbed and missed rays are spread over 8 bins each (by i mod 8), summed at the end: when
    # most rays are absorbed, one bin would chain every increment on the previous one's store.
    h = np.zeros(n_bins + 16, dtype=np.int64)
    absorbed = n_bins
    missed = n_bins + 8
    left = n_rays
    while left > 0:
        m = min(left, nb)
        fill_uniforms(lane, ublock)
        # Each loop below is branch-free, so LLVM vectorizes it: a loop-invariant choice (the
        # model, the scheme) picks one copy of a loop, never a branch inside one.
        if model == MODEL_LAMBERT:
            for i in range(nb):
                wx, wy, wz, hit = emit_given(beam_kind, b, u[i], u[bo + i], u[2 * bo + i], u[3 * bo + i])
                vx[i], vy[i], vz[i], alive = scatter_given(MODEL_LAMBERT, p, wx, wy, wz, u[s0 + i],
                                                           u[s0 + nb + i], u[s0 + 2 * nb + i])
                code[i] = -2 if (alive & hit) else ((absorbed if hit else missed) + (i & 7))
        else:
            for i in range(nb):
                wx, wy, wz, hit = emit_given(beam_kind, b, u[i], u[bo + i], u[2 * bo + i], u[3 * bo + i])
                vx[i], vy[i], vz[i], alive = scatter_given(MODEL_GGX, p, wx, wy, wz, u[s0 + i],
                                                           u[s0 + nb + i], u[s0 + 2 * nb + i])
                code[i] = -2 if (alive & hit) else ((absorbed if hit else missed) + (i & 7))
        if scheme == SCHEME_EQUAL_PSA:
            for i in range(nb):
                g = guess_bin(vx[i], vy[i], vz[i], SCHEME_EQUAL_PSA, n_theta, n_phi, ring_margin, sector_margin)
                code[i] = g if code[i] == -2 else code[i]
        elif scheme == SCHEME_EQUAL_SOLID_ANGLE:
            for i in range(nb):
                g = guess_bin(vx[i], vy[i], vz[i], SCHEME_EQUAL_SOLID_ANGLE, n_theta, n_phi, ring_margin,
                              sector_margin)
                code[i] = g if code[i] == -2 else code[i]
        else:
            for i in range(nb):
                g = guess_bin(vx[i], vy[i], vz[i], SCHEME_EQUAL_ANGLE, n_theta, n_phi, ring_margin, sector_margin)
                code[i] = g if code[i] == -2 else code[i]
        for i in range(m):
            k = code[i]
            if k < 0:  # too near an edge (or the pole, or the horizon) for the guess: exact lookup
                k = patch_of(vx[i], vy[i], vz[i], scheme, n_theta, n_phi, sin2_edges, phi_cs)
            h[k] += 1
        left -= m
    for k in range(n_bins):
        hist[k] += h[k]
    for k in range(8):
        hist[n_bins] += h[absorbed + k]
        hist[n_bins + 1] += h[missed + k]



@jit(parallel=True)
def gonio_block_kernel(model, params, beam_kind, beam_args, cargs, margins, n_bins, sizes, lanes):
    p = (params[0], params[1], params[2], params[3], params[4])  # GGX: alpha_x, alpha_y, eta, k, separable
    b = (beam_args[0], beam_args[1], beam_args[2], beam_args[3], beam_args[4], beam_args[5], beam_args[6],
         beam_args[7], beam_args[8], beam_args[9], beam_args[10], beam_args[11], beam_args[12], beam_args[13],
         beam_args[14])
    n_chunks = sizes.shape[0]
    out = np.zeros((n_chunks, n_bins + 2), dtype=np.int64)
    for c in prange(n_chunks):
        hist = np.zeros(n_bins + 2, dtype=np.int64)
        gonio_block_chunk(model, p, beam_kind, b, cargs, margins[0], margins[1], n_bins, sizes[c], lanes[c].copy(),
                           hist)
        out[c] = hist
    return out

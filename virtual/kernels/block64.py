"""The block counting kernels: every chunk draws its own stream and writes only its own row.

(The ray-by-ray kernels, which emit, scatter and count each ray before the next, for any specimen
and any disk sampling, are :mod:`virtual.kernels.ray_loop`'s: with no effect flag set they are the
bare kernels, drawing exactly the same numbers -- one compiled kernel per instrument, not two.)

* block (``gonio_block_chunk``): rays go through in blocks of :data:`BLOCK_RAYS`; the block's
  uniforms are drawn first, 64 lanes side by side, then one branch-free loop emits (polar
  disks), scatters (:func:`~virtual.kernels.scatter.scatter_given`) and bins
  (:func:`~virtual.kernels.patch_lookup.guess_bin`) every ray, then a short scalar loop settles
  the rare uncertain bin with the exact :func:`~virtual.kernels.patch_lookup.patch_of`.

The Python wrappers (chunking, seeding, choosing a kernel) are :mod:`virtual.engine`.
"""

from __future__ import annotations

import numpy as np

from virtual.kernels import jit
from virtual.kernels.emit import BEAM_CONICAL, emit_given
from virtual.kernels.patch_lookup import SCHEME_EQUAL_ANGLE, SCHEME_EQUAL_PSA, SCHEME_EQUAL_SOLID_ANGLE, guess_bin, patch_of
from virtual.kernels.xoshiro import LANES, fill_uniforms
from virtual.kernels.ggx import fresnel_conductor_ratio
from virtual.kernels.law_dispatch import law_block64, law_uniforms
from virtual.kernels.warps import sincos_2pi, warp_cosine_hemisphere
from virtual.kernels.branchfree import (GIVEN4_UNIFORMS, PLASTIC_UNIFORMS, plastic_diffuse_redo, plastic_given,
                                        scatter_given4)
from virtual.kernels.scatter import (GIVEN_UNIFORMS, MODEL_DIELECTRIC, MODEL_GGX, MODEL_PLASTIC, ggx_given_parts,
                                     scatter_given)

__all__ = ["BLOCK_RAYS", "BEAM_UNIFORMS", "BLOCK_MODELS", "BLOCK_PARAMS", "gonio_block_chunk", "lambert_spectral_chunk",
           "ggx_spectral_chunk"]

from virtual.kernel_codes import BEAM_UNIFORMS, BLOCK_MODELS, BLOCK_PARAMS, BLOCK_RAYS


@jit(inline="always")
def guess_bins(code, x, y, z, n, scheme, n_theta, n_phi, ring_margin, sector_margin):
    """``code[i] = guess_bin(x[i], y[i], z[i], ...)`` for i < n, one loop per scheme so that the
    scheme is a constant inside each loop and the loop vectorizes; -1 where the exact lookup must
    decide."""
    if scheme == SCHEME_EQUAL_PSA:
        for i in range(n):
            code[i] = guess_bin(x[i], y[i], z[i], SCHEME_EQUAL_PSA, n_theta, n_phi, ring_margin, sector_margin)
    elif scheme == SCHEME_EQUAL_SOLID_ANGLE:
        for i in range(n):
            code[i] = guess_bin(x[i], y[i], z[i], SCHEME_EQUAL_SOLID_ANGLE, n_theta, n_phi, ring_margin, sector_margin)
    else:
        for i in range(n):
            code[i] = guess_bin(x[i], y[i], z[i], SCHEME_EQUAL_ANGLE, n_theta, n_phi, ring_margin, sector_margin)


@jit(inline="llvm")
def block_buffers(nb, n_bins):
    """A block's scratch: ``code`` (int64), its directions ``vx, vy, vz``, the compacted survivors'
    ``cx, cy, cz``, and the chunk's private counts ``h``: the bins, then absorbed and missed rays
    spread over 8 bins each (by i mod 8; when most rays are absorbed, one bin would chain every
    increment on the previous one's store), then 8 dump bins for :func:`bin_block`."""
    return (np.empty(nb, dtype=np.int64), np.empty(nb), np.empty(nb), np.empty(nb), np.empty(nb), np.empty(nb),
            np.empty(nb), np.zeros(n_bins + 24, dtype=np.int64))


@jit(inline="always")
def bin_block(code, vx, vy, vz, cx, cy, cz, m, h, dump, cargs, ring_margin, sector_margin):
    """Count the block's ``m`` rays into ``h``: ``code[i]`` is -2 for a survivor, else its
    absorbed/missed bin. Compaction: the surviving rays' directions move to the front of
    ``cx, cy, cz`` (branch-free: every ray is written, the write position advances only for a
    survivor); the others are counted now (absorbed/missed bins, or a dump bin for a survivor).
    Only survivors are binned -- a GGX dielectric absorbs 96 % of its rays, a Lambertian of
    albedo 0.5 half of them."""
    scheme, n_theta, n_phi, sin2_edges, phi_cs = cargs
    j = 0
    for i in range(m):
        k = code[i]
        live = k == -2
        cx[j] = vx[i]
        cy[j] = vy[i]
        cz[j] = vz[i]
        h[dump + (i & 7) if live else k] += 1
        j += live
    guess_bins(code, cx, cy, cz, j, scheme, n_theta, n_phi, ring_margin, sector_margin)
    for i in range(j):
        k = code[i]
        if k < 0:  # too near an edge (or the pole, or the horizon) for the guess: exact lookup
            k = patch_of(cx[i], cy[i], cz[i], scheme, n_theta, n_phi, sin2_edges, phi_cs)
        h[k] += 1


@jit(inline="always")
def flush_block_hist(h, hist, n_bins):
    """Add a chunk's private counts ``h`` (bins, then 8 absorbed, 8 missed, 8 dump) to ``hist``
    (bins, absorbed, missed)."""
    for k in range(n_bins):
        hist[k] += h[k]
    for k in range(8):
        hist[n_bins] += h[n_bins + k]
        hist[n_bins + 1] += h[n_bins + 8 + k]


@jit(nogil=True, error_model="numpy", family="block64")
def gonio_block_chunk(model, p, beam_kind, b, cargs, ring_margin, sector_margin, n_bins, n_rays, lane, s, hist):
    """One chunk of the block kernel: ``n_rays`` rays from the xoshiro lanes ``lane`` (advanced in
    place) added to ``hist``; ``s`` is a scalar xoshiro stream for the rare rays a fixed-count
    form leaves to a rejection loop (the plastic's diffuse lobe).

    Compiled on its own, without the GIL: :mod:`virtual.chunked` runs the chunks on threads
    (numba's parfor would cost every kernel a slow compile of its parallel loop, and inlined into
    a parfor body the block buffers would be hoisted and the loops no longer vectorize).
    ``error_model="numpy"``: a float division must not test its divisor and
    raise (a branch per division also stops vectorization); the formulas guard their divisors.
    ``p`` and ``b`` are tuples: loads from an array that the loop might write (for all LLVM
    knows) would be repeated every iteration.
    """
    nb = BLOCK_RAYS
    n_beam = BEAM_UNIFORMS if beam_kind == BEAM_CONICAL else 0
    n_scat = law_uniforms(model)  # 0 unless a law of virtual.kernels.laws
    if n_scat == 0:
        n_scat = GIVEN4_UNIFORMS if model == MODEL_DIELECTRIC \
            else (PLASTIC_UNIFORMS if model == MODEL_PLASTIC else GIVEN_UNIFORMS)
    ublock = np.empty(((n_beam + n_scat) * nb // LANES, LANES))
    u = ublock.reshape(ublock.size)
    s0 = n_beam * nb  # the scatterer's uniforms follow the beam's
    bo = nb if n_beam > 0 else 0  # a collimated beam reads none: any valid index will do
    code, vx, vy, vz, cx, cy, cz, h = block_buffers(nb, n_bins)
    absorbed = n_bins
    missed = n_bins + 8
    dump = n_bins + 16  # survivors' placeholder counts during compaction (discarded)
    left = n_rays
    while left > 0:
        m = min(left, nb)
        fill_uniforms(lane, ublock)
        # Each loop below is branch-free, so LLVM vectorizes it: a loop-invariant choice (the
        # model, the scheme) picks one copy of a loop, never a branch inside one.
        if law_uniforms(model) > 0:  # a law of virtual.kernels.laws: its generated loops
            law_block64(model, p, beam_kind, b, u, s0, nb, bo, vx, vy, vz, code, absorbed, missed)
        elif model == MODEL_PLASTIC:
            for i in range(nb):
                wx, wy, wz, hit = emit_given(beam_kind, b, u[i], u[bo + i], u[2 * bo + i], u[3 * bo + i])
                vx[i], vy[i], vz[i], alive, redo = plastic_given(
                    p, wx, wy, wz, u[s0 + i], u[s0 + nb + i], u[s0 + 2 * nb + i], u[s0 + 3 * nb + i],
                    u[s0 + 4 * nb + i], u[s0 + 5 * nb + i], u[s0 + 6 * nb + i])
                code[i] = -2 if (alive & hit) else (-3 if (redo & hit) else ((absorbed if hit else missed) + (i & 7)))
            for i in range(m):  # the diffuse rays whose one attempt was rejected: the loop continues
                if code[i] == -3:
                    ox, oy, oz = plastic_diffuse_redo(p[1], s)
                    vx[i] = ox
                    vy[i] = oy
                    vz[i] = oz if vz[i] > 0.0 else -oz
                    code[i] = -2
        elif model == MODEL_DIELECTRIC:
            for i in range(nb):
                wx, wy, wz, hit = emit_given(beam_kind, b, u[i], u[bo + i], u[2 * bo + i], u[3 * bo + i])
                vx[i], vy[i], vz[i], alive = scatter_given4(MODEL_DIELECTRIC, p, wx, wy, wz, u[s0 + i],
                                                            u[s0 + nb + i], u[s0 + 2 * nb + i], u[s0 + 3 * nb + i])
                code[i] = -2 if (alive & hit) else ((absorbed if hit else missed) + (i & 7))
        else:
            for i in range(nb):
                wx, wy, wz, hit = emit_given(beam_kind, b, u[i], u[bo + i], u[2 * bo + i], u[3 * bo + i])
                vx[i], vy[i], vz[i], alive = scatter_given(MODEL_GGX, p, wx, wy, wz, u[s0 + i],
                                                           u[s0 + nb + i], u[s0 + 2 * nb + i])
                code[i] = -2 if (alive & hit) else ((absorbed if hit else missed) + (i & 7))
        bin_block(code, vx, vy, vz, cx, cy, cz, m, h, dump, cargs, ring_margin, sector_margin)
        left -= m
    flush_block_hist(h, hist, n_bins)



@jit(nogil=True, error_model="numpy", family="block64")
def lambert_spectral_chunk(thr, beam_kind, b, cargs, ring_margin, sector_margin, n_rays, lane, cells, missed):
    """One chunk of the spectral Lambertian block kernel (:func:`virtual.chunked.lambert_spectral_kernel` runs it):
    every hit ray's upper-hemisphere patch counted in ``cells[cell of u0, patch]``, missed rays in
    ``missed[0]``. ``thr`` are the sorted survival thresholds of all wavelengths."""
    nb = BLOCK_RAYS
    n_beam = BEAM_UNIFORMS if beam_kind == BEAM_CONICAL else 0
    ublock = np.empty(((n_beam + GIVEN_UNIFORMS) * nb // LANES, LANES))
    u = ublock.reshape(ublock.size)
    s0 = n_beam * nb
    bo = nb if n_beam > 0 else 0
    scheme, n_theta, n_phi, sin2_edges, phi_cs = cargs
    n_thr = thr.shape[0]
    code = np.empty(nb, dtype=np.int64)
    cell = np.empty(nb, dtype=np.int64)
    vx = np.empty(nb)
    vy = np.empty(nb)
    vz = np.empty(nb)
    m_count = np.int64(0)
    left = n_rays
    while left > 0:
        m = min(left, nb)
        fill_uniforms(lane, ublock)
        for i in range(nb):
            wx, wy, wz, hit = emit_given(beam_kind, b, u[i], u[bo + i], u[2 * bo + i], u[3 * bo + i])
            x, y, z = warp_cosine_hemisphere(u[s0 + 2 * nb + i], u[s0 + nb + i])
            vx[i] = x
            vy[i] = y
            vz[i] = z
            cell[i] = 0 if hit else -(n_thr + 1)  # a missed ray's cell stays < 0
        for t in range(n_thr):  # the cell of u0: how many thresholds lie at or below it
            th = thr[t]
            for i in range(nb):
                cell[i] += u[s0 + i] >= th
        guess_bins(code, vx, vy, vz, nb, scheme, n_theta, n_phi, ring_margin, sector_margin)
        for i in range(m):
            c = cell[i]
            if c < 0:
                m_count += 1
                continue
            k = code[i]
            if k < 0:
                k = patch_of(vx[i], vy[i], vz[i], scheme, n_theta, n_phi, sin2_edges, phi_cs)
            cells[c, k] += 1
        left -= m
    missed[0] += m_count


@jit(nogil=True, error_model="numpy", family="block64")
def ggx_spectral_chunk(ax, ay, separable, etas, ks, beam_kind, b, cargs, ring_margin, sector_margin, n_rays, lane, hist, tally):
    """One chunk of the spectral GGX block kernel (:func:`virtual.chunked.ggx_spectral_kernel` runs it): surviving
    rays added to ``hist[patch, w]`` per wavelength w; ``tally`` = (hits, missed)."""
    nb = BLOCK_RAYS
    n_beam = BEAM_UNIFORMS if beam_kind == BEAM_CONICAL else 0
    ublock = np.empty(((n_beam + GIVEN_UNIFORMS) * nb // LANES, LANES))
    u = ublock.reshape(ublock.size)
    s0 = n_beam * nb
    bo = nb if n_beam > 0 else 0
    scheme, n_theta, n_phi, sin2_edges, phi_cs = cargs
    n_w = etas.shape[0]
    code = np.empty(nb, dtype=np.int64)
    vx = np.empty(nb)
    vy = np.empty(nb)
    vz = np.empty(nb)
    cc = np.empty(nb)
    lhs = np.empty(nb)  # u g_den
    rhs = np.empty(nb)  # g_num, 0 for an invalid or missed ray
    alive = np.empty((n_w, nb), dtype=np.bool_)
    hits = np.int64(0)
    left = n_rays
    while left > 0:
        m = min(left, nb)
        fill_uniforms(lane, ublock)
        for i in range(nb):
            wx, wy, wz, hit = emit_given(beam_kind, b, u[i], u[bo + i], u[2 * bo + i], u[3 * bo + i])
            ca, sa = sincos_2pi(u[s0 + 2 * nb + i])
            ox, oy, oz, c, g_num, g_den, valid = ggx_given_parts(ax, ay, separable, wx, wy, wz, ca, sa, u[s0 + nb + i])
            vx[i] = ox
            vy[i] = oy
            vz[i] = oz
            cc[i] = c
            lhs[i] = u[s0 + i] * g_den
            rhs[i] = g_num if (valid & hit) else -1.0
            code[i] = 1 if hit else 0
        for w in range(n_w):  # each wavelength's survival: the same u, its own Fresnel factor
            eta = etas[w]
            k = ks[w]
            for i in range(nb):
                f_num, f_den = fresnel_conductor_ratio(cc[i], eta, k, False)
                alive[w, i] = lhs[i] * f_den < f_num * rhs[i]
        for i in range(m):
            hits += code[i]
        guess_bins(code, vx, vy, vz, nb, scheme, n_theta, n_phi, ring_margin, sector_margin)
        for i in range(m):
            if rhs[i] < 0.0:
                continue  # missed, or absorbed at every wavelength (a cosine <= 0)
            kb = code[i]
            if kb < 0:
                kb = patch_of(vx[i], vy[i], vz[i], scheme, n_theta, n_phi, sin2_edges, phi_cs)
            row = hist[kb]  # (W,) contiguous: a ray's W counts share a few cache lines
            for w in range(n_w):
                row[w] += alive[w, i]
        left -= m
    tally[0] += hits
    tally[1] += n_rays - hits

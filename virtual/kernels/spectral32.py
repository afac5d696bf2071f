"""Float32 spectral batches: the Lambertian and one-roughness GGX at many wavelengths
at once on float32 vectors (as many lanes as the machine's hold), like :mod:`virtual.kernels.block32`.

* Lambertian (:func:`lambert_spectral32_chunk`): each hit ray's cosine-distributed direction
  is drawn and binned once; its survival uniform u0 is located among the sorted float64
  thresholds (every wavelength's R and R + T) -- counts by (cell of u0, patch). The grid
  uniform u0 is compared with each threshold's grid floor; only a u0 equal to one (the grid cell
  holding a threshold, one ray in 2^24 per threshold) is refined to 53 bits
  (:func:`~virtual.kernels.refine.refined_by`) and located among the float64 thresholds, so
  each cell has its exact probability.
* GGX (:func:`ggx_spectral32_chunk`): the direction, the microfacet cosine c and the masking
  ratio g_num / g_den are drawn once; wavelength w survives when u g_den < F_w(c) g_num. F_w is
  bracketed by a table of rigorous bounds over cells of c (:func:`fresnel_bounds`), laid out
  [cell, wavelength]: survive below the lower bound, die above the upper one, and only in
  between (a few % of the rays) compute F exactly (:func:`~virtual.kernels.ggx.fresnel_conductor_ratio` in float32),
  the bounds tested with u moved by :data:`~virtual.kernels.f32.DOUBT` either way; where the
  decision is in doubt for the grid uniform u (:func:`~virtual.kernels.f32.in_doubt32`), u is
  refined to 53 bits and F computed in float64.
  The decision is therefore the exact-Fresnel decision, with u's probability to 2^-53; the wavelength loop is contiguous in
  the table and in the histogram [patch, wavelength] (int32), so it vectorizes.
"""

from __future__ import annotations

import numpy as np
from numba import int32

from virtual.kernels import jit
from virtual.kernels.block32 import BLOCK32_RAYS, guess_bins32, normals_block32
from virtual.kernels.patch_lookup import patch_of
from virtual.kernels.f32 import DOUBT, ONE, emit_block32, in_doubt32, emit_side32, warp_cosine_hemisphere32
from virtual.kernels.ggx import fresnel_conductor_ratio
from virtual.kernels.ggx32 import fresnel_conductor_ratio as fresnel_conductor_ratio32, ggx_reflect as ggx_reflect32
from virtual.kernels.refine import ray_bits, refined_by
from virtual.kernels.xoshiro import LANES, fill_uniforms32

__all__ = ["FRESNEL_CELLS", "fresnel_bounds", "lambert_spectral32_chunk", "ggx_spectral32_chunk"]

from virtual.kernel_codes import FRESNEL_CELLS
#: Absolute padding of the bounds: covers the float32 evaluation of F (a few 1e-7) and of the
#: products u g_den, F g_num (a few ulp), with a wide margin.
FRESNEL_PAD = 1e-5
_BEAM_UNIFORMS = 4
_MISSED = int32(-(1 << 30))
_YES = int32(1)
_NO = int32(0)


@jit
def fresnel_bounds(etas, ks, n_cells, n_samples, wp):
    """float32 ``(lo, hi)``, each ``(n_cells, wp)``: for c in cell ``j`` (c n_cells in [j, j+1),
    the last cell also holding c >= 1), lo[j, w] <= F(c; etas[w], ks[w]) <= hi[j, w]. Each cell
    is sampled densely (slightly beyond its ends, for float32 rounding of c n_cells); the
    bounds widen the sampled range by the largest first and second differences of the samples
    (F's variation between samples: monotone stretches and smooth extrema) and
    :data:`FRESNEL_PAD`, then round outwards to float32. Columns w >= len(etas): lo = hi = 0
    (never survives, never uncertain)."""
    lo = np.zeros((n_cells, wp), dtype=np.float32)
    hi = np.zeros((n_cells, wp), dtype=np.float32)
    f = np.empty(n_samples + 1)
    for w in range(etas.shape[0]):
        for j in range(n_cells):
            a = max((j - 0.01) / n_cells, 0.0)
            b = (j + 1.01) / n_cells if j < n_cells - 1 else 1.001
            for s in range(n_samples + 1):
                num, den = fresnel_conductor_ratio(a + (b - a) * s / n_samples, etas[w], ks[w], False)
                f[s] = num / den if den > 0.0 else 1.0
            d1 = 0.0
            d2 = 0.0
            for s in range(n_samples):
                d1 = max(d1, abs(f[s + 1] - f[s]))
                if s > 0:
                    d2 = max(d2, abs(f[s + 1] - 2.0 * f[s] + f[s - 1]))
            pad = d1 + d2 + FRESNEL_PAD
            lo_v = np.float32(f.min() - pad)
            hi_v = np.float32(f.max() + pad)
            lo[j, w] = np.nextafter(lo_v, np.float32(-np.inf))
            hi[j, w] = np.nextafter(hi_v, np.float32(np.inf))
    return lo, hi


@jit(nogil=True, error_model="numpy", family="spectral32")
def lambert_spectral32_chunk(thr, floors, conical, b, cargs, ring_margin, sector_margin, n_patches, n_rays, lane, key,
                             cells, tally):
    """One chunk: hit rays counted in ``cells[cell of u0 * n_patches + patch]``, missed ones in
    ``tally[0]``; ``thr`` the sorted float64 thresholds, ``floors`` their float32 grid floors
    (floor(thr 2^24) 2^-24); ``key`` the chunk's key for :func:`~virtual.kernels.refine.ray_bits`."""
    nb = BLOCK32_RAYS
    n_beam = _BEAM_UNIFORMS if conical else 0
    ublock = np.empty(((n_beam + 3) * nb // LANES, LANES), dtype=np.float32)
    u = ublock.reshape(ublock.size)
    s0 = n_beam * nb
    bo = nb if conical else 0
    scheme, n_theta, n_phi, sin2_edges, phi_cs = cargs
    n_thr = thr.shape[0]
    code = np.empty(nb, dtype=np.int32)
    cell = np.empty(nb, dtype=np.int32)
    vx = np.empty(nb, dtype=np.float32)
    vy = np.empty(nb, dtype=np.float32)
    vz = np.empty(nb, dtype=np.float32)
    npat = int32(n_patches)
    missed = 0
    left = n_rays
    while left > 0:
        m = min(left, nb)
        fill_uniforms32(lane, ublock)
        for i in range(nb):
            _, hit = emit_side32(conical, b, u[i], u[bo + i])
            x, y, z = warp_cosine_hemisphere32(u[s0 + 2 * nb + i], u[s0 + nb + i])  # the Lambertian law's draw (virtual.kernels.laws.lambert)
            vx[i] = x
            vy[i] = y
            vz[i] = z
            cell[i] = int32(0) if hit else _MISSED
        for t in range(n_thr):  # the cell of u0: how many thresholds' grid floors lie at or below it
            th = floors[t]
            for i in range(nb):
                cell[i] += int32(u[s0 + i] >= th)
        done = n_rays - left
        for i in range(m):  # u0 in the grid cell of a threshold (u0 its floor): refined, located in float64
            c = cell[i]
            if c > 0 and u[s0 + i] == floors[c - 1]:
                uf = refined_by(u[s0 + i], ray_bits(key, done + i))
                c = 0
                while c < n_thr and thr[c] <= uf:
                    c += 1
                cell[i] = c
        guess_bins32(code, vx, vy, vz, nb, scheme, n_theta, n_phi, ring_margin, sector_margin)
        for i in range(m):
            c = cell[i]
            if c < 0:
                missed += 1
                continue
            k = code[i]
            if k < 0:
                k = patch_of(np.float64(vx[i]), np.float64(vy[i]), np.float64(vz[i]), scheme, n_theta, n_phi,
                             sin2_edges, phi_cs)
            cells[c * npat + k] += 1
        left -= m
    tally[0] += missed


@jit(inline="llvm")
def _survivor_rows(hist, wp, lo, hi, code, src, cell, ts, tl, i):
    """Compacted survivor ``i``'s histogram row (its bin ``code[i]``), its Fresnel cell's bound
    rows and its thresholds: ``(row, lrow, hrow, t, t_lo, r)``, ``r`` its ray in the block. Slices,
    so that LLVM vectorizes the loops over them (indexing the whole arrays, it does not)."""
    h0 = code[i] * wp
    r = src[i]
    ci = cell[r]
    return hist[h0:h0 + wp], lo[ci], hi[ci], ts[r], tl[r], r


@jit(nogil=True, error_model="numpy", family="spectral32")
def ggx_spectral32_chunk(p, etas, ks, lo, hi, conical, b, cargs, ring_margin, sector_margin, n_rays, lane, key, hist,
                         tally):
    """One chunk: survivors added to ``hist[patch * wp + w]`` (int32, wp = lo.shape[1]);
    ``tally`` = (hits, missed). ``p`` = (alpha_x, alpha_y, separable) as float32; ``key`` the
    chunk's key for :func:`~virtual.kernels.refine.ray_bits`."""
    nb = BLOCK32_RAYS
    n_beam = _BEAM_UNIFORMS if conical else 0
    ublock = np.empty(((n_beam + 3) * nb // LANES, LANES), dtype=np.float32)
    u = ublock.reshape(ublock.size)
    s0 = n_beam * nb
    bo = nb if conical else 0
    scheme, n_theta, n_phi, sin2_edges, phi_cs = cargs
    n_w = etas.shape[0]
    n_cells = lo.shape[0]
    wp = lo.shape[1]
    fc = np.float32(n_cells)
    top = np.empty(n_cells, dtype=np.float32)  # each cell's largest upper bound
    for j in range(n_cells):
        top[j] = hi[j].max()
    last = int32(n_cells - 1)
    code = np.empty(nb, dtype=np.int32)
    cell = np.empty(nb, dtype=np.int32)
    vx = np.empty(nb, dtype=np.float32)
    vy = np.empty(nb, dtype=np.float32)
    vz = np.empty(nb, dtype=np.float32)
    cc = np.empty(nb, dtype=np.float32)
    us = np.empty(nb, dtype=np.float32)  # u
    gs = np.empty(nb, dtype=np.float32)  # g_den
    ys = np.empty(nb, dtype=np.float32)  # g_num
    ts = np.empty(nb, dtype=np.float32)  # (u + DOUBT) g_den / g_num: survives at w when below lo_w
    tl = np.empty(nb, dtype=np.float32)  # (u - DOUBT) g_den / g_num: dies at w when at or above hi_w
    src = np.empty(nb, dtype=np.int32)  # a survivor's ray in the block
    unsure_rays = np.empty(nb, dtype=np.int32)  # rays whose decision at some wavelength needs the exact F
    hits = 0
    left = n_rays
    while left > 0:
        m = min(left, nb)
        fill_uniforms32(lane, ublock)
        emit_block32(conical, b, u, bo, nb, vx, vy, vz, code)  # the beam, then the normals, in loops of their own
        normals_block32(p[0], p[1], u[s0 + 2 * nb:s0 + 3 * nb], u[s0 + nb:s0 + 2 * nb], nb, vx, vy, vz, cc, gs, ys, ts,
                        False)  # the visible normals and ni into cc, gs, ys, ts until the loop below overwrites them
        for i in range(nb):
            hit = code[i] == 1
            ox, oy, oz, c, g_num, g_den, valid = ggx_reflect32(p[0], p[1], p[2], vx[i], vy[i], vz[i], cc[i], gs[i],
                                                               ys[i], ts[i], False)
            vx[i] = ox
            vy[i] = oy
            vz[i] = oz
            cc[i] = c
            us[i] = u[s0 + i]
            gs[i] = g_den
            ys[i] = g_num
            scale = g_den / (g_num if valid else ONE)  # the bounds' padding covers these roundings
            ts[i] = (u[s0 + i] + DOUBT) * scale
            tl[i] = (u[s0 + i] - DOUBT) * scale
            cell[i] = min(int32(c * fc), last)
            code[i] = int32(1) if (valid & hit) else (int32(0) if hit else int32(2))
        j = 0
        n_hit = 0
        done = n_rays - left
        for i in range(m):  # compaction of the directions and ray numbers of the valid rays below some
            # wavelength's upper bound (the others die at all); the rest is read through src
            k = code[i]
            vx[j] = vx[i]
            vy[j] = vy[i]
            vz[j] = vz[i]
            src[j] = i
            j += (k == 1) & (tl[i] < top[cell[i]])
            n_hit += k != 2
        hits += n_hit
        guess_bins32(code, vx, vy, vz, j, scheme, n_theta, n_phi, ring_margin, sector_margin)
        for i in range(j):  # the rare exact lookups in a loop of their own: no call in the hot loop below
            if code[i] < 0:
                code[i] = patch_of(np.float64(vx[i]), np.float64(vy[i]), np.float64(vz[i]), scheme, n_theta, n_phi,
                                   sin2_edges, phi_cs)
        n_unsure = 0
        for i in range(j):
            row, lrow, hrow, t, t_lo, r = _survivor_rows(hist, wp, lo, hi, code, src, cell, ts, tl, i)
            unsure = False  # a bool: an int32 would be widened to int64 by numba, half the lanes
            for w in range(wp):  # contiguous in the table and the histogram: whole vectors per ray
                sure = t < lrow[w]
                row[w] += _YES if sure else _NO
                unsure |= (t_lo < hrow[w]) != sure
            unsure_rays[n_unsure] = i  # kept when unsure: the exact decisions wait for the loop below
            n_unsure += unsure
        for q in range(n_unsure):  # between the bounds for some wavelength (about 1 ray in 10^3): exact Fresnel
            i = unsure_rays[q]
            row, lrow, hrow, t, t_lo, r = _survivor_rows(hist, wp, lo, hi, code, src, cell, ts, tl, i)
            y = ys[r]
            c = cc[r]
            uu = us[r]
            g_den = gs[r]
            for w in range(n_w):
                if (t >= lrow[w]) & (t_lo < hrow[w]):
                    f_num, f_den = fresnel_conductor_ratio32(c, etas[w], ks[w], False)
                    if in_doubt32(uu, f_num * y, f_den * g_den):  # u refined, F in float64
                        fn, fd = fresnel_conductor_ratio(np.float64(c), np.float64(etas[w]), np.float64(ks[w]), False)
                        uf = refined_by(uu, ray_bits(key, done + r))
                        row[w] += _YES if uf * fd * np.float64(g_den) < fn * np.float64(y) else _NO
                    else:
                        row[w] += _YES if uu * g_den * f_den < f_num * y else _NO
        left -= m
    tally[0] += hits
    tally[1] += n_rays - hits

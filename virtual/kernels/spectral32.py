"""Float32 spectral batches: the Lambertian and one-roughness GGX at many wavelengths
at once on float32 vectors (as many lanes as the machine's hold), like :mod:`virtual.kernels.block32`.

* Lambertian (:func:`lambert_spectral32_chunk`): each hit ray's cosine-distributed direction
  is drawn and binned once; its survival uniform u0 is located among the sorted float32
  thresholds (every wavelength's R and R + T, rounded as the single-wavelength
  :func:`~virtual.kernels.branchfree32.lambert_given32` rounds them) -- counts by (cell of u0, patch).
* GGX (:func:`ggx_spectral32_chunk`): the direction, the microfacet cosine c and the masking
  ratio g_num / g_den are drawn once; wavelength w survives when u g_den < F_w(c) g_num. F_w is
  bracketed by a table of rigorous bounds over cells of c (:func:`fresnel_bounds`), laid out
  [cell, wavelength]: survive below the lower bound, die above the upper one, and only in
  between (a few % of the rays) compute F exactly (:func:`~virtual.kernels.f32.fresnel_conductor_ratio32`).
  The decision is therefore the exact-Fresnel decision; the wavelength loop is contiguous in
  the table and in the histogram [patch, wavelength] (int32), so it vectorizes.
"""

from __future__ import annotations

import numpy as np
from numba import int32

from virtual.kernels import jit
from virtual.kernels.block32 import BLOCK32_RAYS, guess_bins32
from virtual.kernels.patch_lookup import patch_of
from virtual.kernels.f32 import (ONE, emit_given32, emit_side32, fresnel_conductor_ratio32, sincos_2pi32,
                                 warp_cosine_hemisphere32)
from virtual.kernels.branchfree32 import ggx_given_parts32
from virtual.kernels.microfacet import fresnel_conductor_ratio
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
                num, den = fresnel_conductor_ratio(a + (b - a) * s / n_samples, etas[w], ks[w])
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


@jit(nogil=True, error_model="numpy")
def lambert_spectral32_chunk(thr, conical, b, cargs, ring_margin, sector_margin, n_patches, n_rays, lane, cells, tally):
    """One chunk: hit rays counted in ``cells[cell of u0 * n_patches + patch]``, missed ones in
    ``tally[0]``; ``thr`` the sorted float32 thresholds."""
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
            x, y, z = warp_cosine_hemisphere32(u[s0 + 2 * nb + i], u[s0 + nb + i])  # lambert_given32's draw
            vx[i] = x
            vy[i] = y
            vz[i] = z
            cell[i] = int32(0) if hit else _MISSED
        for t in range(n_thr):  # the cell of u0: how many thresholds lie at or below it
            th = thr[t]
            for i in range(nb):
                cell[i] += int32(u[s0 + i] >= th)
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


@jit(nogil=True, error_model="numpy")
def ggx_spectral32_chunk(p, etas, ks, lo, hi, conical, b, cargs, ring_margin, sector_margin, n_rays, lane, hist,
                         tally):
    """One chunk: survivors added to ``hist[patch * wp + w]`` (int32, wp = lo.shape[1]);
    ``tally`` = (hits, missed). ``p`` = (alpha_x, alpha_y, separable) as float32."""
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
    xs = np.empty(nb, dtype=np.float32)  # u g_den
    ys = np.empty(nb, dtype=np.float32)  # g_num
    ts = np.empty(nb, dtype=np.float32)  # u g_den / g_num: survives at w when t < F_w(c)
    hits = 0
    left = n_rays
    while left > 0:
        m = min(left, nb)
        fill_uniforms32(lane, ublock)
        for i in range(nb):
            wx, wy, wz, hit = emit_given32(conical, b, u[i], u[bo + i], u[2 * bo + i], u[3 * bo + i])
            ca, sa = sincos_2pi32(u[s0 + 2 * nb + i])
            ox, oy, oz, c, g_num, g_den, valid = ggx_given_parts32(p[0], p[1], p[2], wx, wy, wz, ca, sa,
                                                                   u[s0 + nb + i], False)
            vx[i] = ox
            vy[i] = oy
            vz[i] = oz
            cc[i] = c
            xs[i] = u[s0 + i] * g_den
            ys[i] = g_num
            ts[i] = xs[i] / (g_num if valid else ONE)  # the bounds' padding covers this division's rounding
            cell[i] = min(int32(c * fc), last)
            code[i] = int32(1) if (valid & hit) else (int32(0) if hit else int32(2))
        j = 0
        n_hit = 0
        for i in range(m):  # compaction: the valid rays below some wavelength's upper bound (the others die at all)
            k = code[i]
            ci = cell[i]
            vx[j] = vx[i]
            vy[j] = vy[i]
            vz[j] = vz[i]
            cc[j] = cc[i]
            xs[j] = xs[i]
            ys[j] = ys[i]
            ts[j] = ts[i]
            cell[j] = ci
            j += (k == 1) & (ts[i] < top[ci])
            n_hit += k != 2
        hits += n_hit
        guess_bins32(code, vx, vy, vz, j, scheme, n_theta, n_phi, ring_margin, sector_margin)
        for i in range(j):
            kb = code[i]
            if kb < 0:
                kb = patch_of(np.float64(vx[i]), np.float64(vy[i]), np.float64(vz[i]), scheme, n_theta, n_phi,
                              sin2_edges, phi_cs)
            x = xs[i]
            y = ys[i]
            t = ts[i]
            ci = cell[i]
            h0 = kb * wp
            row = hist[h0:h0 + wp]  # slices: LLVM then vectorizes the loop (indexing the whole arrays, it does not)
            lrow = lo[ci]
            hrow = hi[ci]
            unsure = _NO
            for w in range(wp):  # contiguous in the table and the histogram: whole vectors per ray
                sure = t < lrow[w]
                row[w] += _YES if sure else _NO
                unsure |= _YES if (t < hrow[w]) != sure else _NO
            if unsure != _NO:  # between the bounds for some wavelength: the exact Fresnel factor decides
                c = cc[i]
                for w in range(n_w):
                    if (t >= lrow[w]) & (t < hrow[w]):
                        f_num, f_den = fresnel_conductor_ratio32(c, etas[w], ks[w], False)
                        row[w] += _YES if x * f_den < f_num * y else _NO
        left -= m
    tally[0] += hits
    tally[1] += n_rays - hits

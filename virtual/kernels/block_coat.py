"""The block kernel of the coated families: Mitsuba's roughplastic and the leaf (the
:data:`~virtual.kernel_codes.COAT_MODELS`), float64.

The same shape as :func:`virtual.kernels.block64.gonio_block_chunk` (a block's uniforms drawn
first on 64 lanes, one branch-free loop that emits, scatters and guesses bins, compaction, the
exact lookup for the rare uncertain bin), in a chunk of its own: the roughplastic reads its
tables from the parameter array (``tab``, :mod:`virtual.kernels.coat`), which the other models'
tuple of six parameters cannot carry, and compiling these two branches into the float64 block
kernel would lengthen its compile for every model.

Each family's rejection loop (the roughplastic's base direction thinned by t(cos_o); the leaf
body's cosine direction thinned by 1 - ks E_s(wo), each test a visible-normal sample) gets one
attempt in the branch-free loop; a ray whose attempt was rejected is marked and finished on the
chunk's scalar xoshiro stream ``s`` by the loop itself (:func:`~virtual.kernels.coat.roughplastic_base_redo`,
:func:`~virtual.kernels.scatter.leaf_body_redo`): attempts being independent, that is exactly the loop's law -- as the
rough plastic's ``plastic_diffuse_redo`` does. Tested against the ray-by-ray branches by
two-sample chi-square (tests/test_block_coat.py).
"""

from __future__ import annotations

import math

import numpy as np

from virtual.kernels import jit
from virtual.kernels.coat import roughplastic_base_redo, rp_e, rp_t
from virtual.kernels.emit import BEAM_CONICAL, emit_given
from virtual.kernels.ggx import fresnel_dielectric, ggx_normal, roughplastic_about
from virtual.kernels.scatter import ggx_given_parts, leaf_body_redo
from virtual.kernels.warps import sincos_2pi, warp_cosine_hemisphere
from virtual.kernels.xoshiro import LANES, fill_uniforms
from virtual.kernels.block64 import bin_block, block_buffers, flush_block_hist
from virtual.kernel_codes import BEAM_UNIFORMS, BLOCK_RAYS
from virtual.model_ids import MODEL_ROUGHPLASTIC

__all__ = ["RP_UNIFORMS", "LEAF_UNIFORMS", "roughplastic_given", "rp_lookups", "leaf_given", "gonio_coat_chunk"]

#: Uniforms :func:`roughplastic_given` consumes per ray.
RP_UNIFORMS = 7
#: Uniforms :func:`leaf_given` consumes per ray.
LEAF_UNIFORMS = 9


@jit(inline="llvm")
def _specular_given(a, wx, wy, wz, u1, u2, separable):
    """The mirror direction about the visible normal of w (wz > 0) drawn from (u1, u2):
    ``(sx, sy, sz, F-cosine c, G2/G1 numerator, denominator)`` under the masking ``separable``."""
    ca, sa = sincos_2pi(u1)
    sx, sy, sz, c, g_num, g_den, _ = ggx_given_parts(a, a, separable, wx, wy, wz, ca, sa, u2)
    return sx, sy, sz, c, g_num, g_den


@jit(inline="llvm")
def roughplastic_given(p, wx, wy, wz, u0, u1, u2, u3, u4, u5, u6, base_num, base_den, t_o):
    """:func:`~virtual.kernels.coat.roughplastic` with its uniforms given and one attempt of the
    base's rejection loop: ``(ox, oy, oz, alive, redo)``: the visible normal of |w| from (u1, u2)
    (:func:`~virtual.kernels.ggx.ggx_normal`), then :func:`~virtual.kernels.ggx.roughplastic_about`
    (the uniforms' roles there), the table values looked up by :func:`rp_lookups`."""
    a = p[0]
    ca, sa = sincos_2pi(u1)
    mx, my, mz, _ = ggx_normal(a, a, wx, wy, wz, ca, sa, u2, False)
    ox, oy, oz, alive, redo, _ = roughplastic_about(p, wx, wy, wz, mx, my, mz, u0, u3, u4, u5, u6, base_num,
                                                    base_den, t_o, False)
    return ox, oy, oz, alive, redo


@jit(inline="always")
def rp_lookups(p, tab, mu, dz, base_num, base_den, t_o, n):
    """The table reads of :func:`roughplastic_given` for rays i < n, in a loop of their own (an
    indexed read of ``tab`` among the stores would keep LLVM from vectorizing the main loop):
    from the cosines of incidence ``mu`` and of the attempts ``dz``."""
    for i in range(n):
        m = mu[i]
        base_num[i] = p[3] * rp_t(tab, m)
        base_den[i] = 1.0 - rp_e(tab, m)
        t_o[i] = rp_t(tab, dz[i])


@jit(inline="llvm")
def leaf_given(p, wx, wy, wz, u0, u1, u2, u3, u4, u5, u6, u7, u8):
    """:func:`~virtual.kernels.scatter._leaf` with its uniforms given and one attempt of the
    body's rejection loop: ``(ox, oy, oz, alive, redo)`` as :func:`roughplastic_given`.

    The cuticle keeps the ray when u0 < ks F G2/G1 (visible normal from (u1, u2)); else the body
    reflects (u3 < r_b) or transmits (u3 < r_b + t_b); its attempt is Malley's direction d from
    (u4, u5), rejected when light from d would have been kept by the cuticle (visible normal of
    d from (u6, u7), u8 < ks F G2/G1).
    """
    flip = wz < 0.0
    wz = abs(wz)
    a = p[0]
    eta = p[1]
    ks = p[2]
    sx, sy, sz, c, g_num, g_den = _specular_given(a, wx, wy, wz, u1, u2, 0.0)
    f, _ = fresnel_dielectric(c, eta)
    kept = (sz > 0.0) & (u0 * g_den < ks * f * g_num)
    body = (~kept) & (u3 < p[3] + p[4])
    up = u3 < p[3]
    dx, dy, dz = warp_cosine_hemisphere(u5, u4)
    bx, by, bz, bc, b_num, b_den = _specular_given(a, dx, dy, dz, u6, u7, 0.0)
    fb, _ = fresnel_dielectric(bc, eta)
    back = (dz > 0.0) & (bz > 0.0) & (u8 * b_den < ks * fb * b_num)
    ox = sx if kept else dx
    oy = sy if kept else dy
    oz = sz if kept else (dz if not back else 1.0)
    below = flip if kept else (up == flip)
    ok = wz > 0.0
    return ox, oy, (-oz if below else oz), ok & (kept | (body & (~back))), ok & body & back


@jit(nogil=True, error_model="numpy", family="block64")
def gonio_coat_chunk(model, p, tab, beam_kind, b, cargs, ring_margin, sector_margin, n_bins, n_rays, lane, s, hist):
    """One chunk of the coated families' block kernel: the arguments of
    :func:`~virtual.kernels.block64.gonio_block_chunk` plus ``tab``, the whole parameter vector
    (float64 array; ``p`` is its first six values as a tuple)."""
    nb = BLOCK_RAYS
    n_beam = BEAM_UNIFORMS if beam_kind == BEAM_CONICAL else 0
    n_scat = RP_UNIFORMS if model == MODEL_ROUGHPLASTIC else LEAF_UNIFORMS
    ublock = np.empty(((n_beam + n_scat) * nb // LANES, LANES))
    u = ublock.reshape(ublock.size)
    s0 = n_beam * nb
    bo = nb if n_beam > 0 else 0
    code, vx, vy, vz, cx, cy, cz, h = block_buffers(nb, n_bins)
    absorbed = n_bins
    missed = n_bins + 8
    dump = n_bins + 16
    left = n_rays
    while left > 0:
        m = min(left, nb)
        fill_uniforms(lane, ublock)
        if model == MODEL_ROUGHPLASTIC:
            for i in range(nb):  # the cosines the tables are read at (recomputed the same way below)
                _, _, wz, _ = emit_given(beam_kind, b, u[i], u[bo + i], u[2 * bo + i], u[3 * bo + i])
                vx[i] = abs(wz)
                vy[i] = math.sqrt(1.0 - u[s0 + 4 * nb + i])  # warp_cosine_hemisphere's z
            rp_lookups(p, tab, vx, vy, cx, cy, cz, nb)
            for i in range(nb):
                wx, wy, wz, hit = emit_given(beam_kind, b, u[i], u[bo + i], u[2 * bo + i], u[3 * bo + i])
                vx[i], vy[i], vz[i], alive, redo = roughplastic_given(
                    p, wx, wy, wz, u[s0 + i], u[s0 + nb + i], u[s0 + 2 * nb + i], u[s0 + 3 * nb + i],
                    u[s0 + 4 * nb + i], u[s0 + 5 * nb + i], u[s0 + 6 * nb + i], cx[i], cy[i], cz[i])
                code[i] = -2 if (alive & hit) else (-3 if (redo & hit) else ((absorbed if hit else missed) + (i & 7)))
            for i in range(m):  # the base rays whose one attempt was rejected: the loop continues
                if code[i] == -3:
                    ox, oy, oz = roughplastic_base_redo(tab, s)
                    vx[i] = ox
                    vy[i] = oy
                    vz[i] = oz if vz[i] > 0.0 else -oz
                    code[i] = -2
        else:
            for i in range(nb):
                wx, wy, wz, hit = emit_given(beam_kind, b, u[i], u[bo + i], u[2 * bo + i], u[3 * bo + i])
                vx[i], vy[i], vz[i], alive, redo = leaf_given(
                    p, wx, wy, wz, u[s0 + i], u[s0 + nb + i], u[s0 + 2 * nb + i], u[s0 + 3 * nb + i],
                    u[s0 + 4 * nb + i], u[s0 + 5 * nb + i], u[s0 + 6 * nb + i], u[s0 + 7 * nb + i],
                    u[s0 + 8 * nb + i])
                code[i] = -2 if (alive & hit) else (-3 if (redo & hit) else ((absorbed if hit else missed) + (i & 7)))
            for i in range(m):  # the body rays whose one attempt was rejected
                if code[i] == -3:
                    ox, oy, oz = leaf_body_redo(p[0], p[1], p[2], s)
                    vx[i] = ox
                    vy[i] = oy
                    vz[i] = oz if vz[i] > 0.0 else -oz
                    code[i] = -2
        bin_block(code, vx, vy, vz, cx, cy, cz, m, h, dump, cargs, ring_margin, sector_margin)  # as gonio_block_chunk
        left -= m
    flush_block_hist(h, hist, n_bins)

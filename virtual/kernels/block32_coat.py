"""The float32 block kernel of the coated families (Mitsuba's roughplastic and the leaf, the
:data:`~virtual.kernel_codes.COAT_MODELS`): :func:`~virtual.kernels.block_coat.gonio_coat_chunk` on
float32 vectors, in the shape of :func:`~virtual.kernels.block32.gonio_block32_chunk`.

A file of its own: the float32 block kernel's compile is paid by every model, this one's only by
the two coated ones. Each family's given form does one attempt of its rejection loop (as the
float64 :mod:`~virtual.kernels.block_coat` forms, the same uniforms in the same roles); a
rejected attempt is finished in float64 on the chunk's stream ``s``
(:func:`~virtual.kernels.coat.roughplastic_base_redo`, :func:`~virtual.kernels.scatter.leaf_body_redo`).
Every decision carries a ``doubt`` flag (:func:`~virtual.kernels.f32.in_doubt32`); a doubted
ray is decided again in float64 by :func:`redo_coat_ray64`. The roughplastic's attempt from its
visible normal on is one text for both precisions (:func:`~virtual.kernels.ggx.roughplastic_about`,
its generated float32 twin here with the isotropic short forms); the leaf's stays written here:
its cuticle takes F as the conductor ratio at k = 0 (no division) and the isotropic masking
terms, where the float64 leaf divides (``fresnel_dielectric``) and takes the general terms -- the
same law, rounded differently, and each precision's counts are pinned.

The roughplastic's table reads. Its decisions ``u3 (1 - E(mu)) < c t(mu)`` and ``u6 < t(mo)``
read the coat transmittance t and the specular albedo E at the incidence's cosine mu and the
attempt's cosine mo = sqrt(1 - u4), in float32 like every other float32 decision. The base test
is mostly decided by bounds on c t / (1 - E) over the beam's cosines (:func:`_rp_bounds`, in the
vectorized loop); only the rays whose u3 falls between them (about 2 % at 30 degrees, conical)
read the tables at their incidence (:func:`_rp_cells32`, E read in s = sqrt(1 - mu) computed from
the direction's transverse part, well conditioned at any incidence). t(mo) is read for every ray,
in a scalar loop of its own (:func:`_rp_read_block32`: indexed loads, which LLVM does not
vectorize next to stores it cannot prove apart). Each value is within a few float32 roundings of
the float64 :func:`~virtual.kernels.coat.rp_t` and :func:`~virtual.kernels.coat.rp_e`, and the
bounds hold those values with a margin (both tested, tests/test_block32_coat_tables.py); the
doubted rays are decided again on the float64 tables.

Where the time goes (one thread, a Zen 5, AVX-512 code, scratch timings, ns a ray): the
roughplastic ~8.4-8.8; the leaf ~8.0, of which the uniforms ~1.7 (13 a ray against GGX's 7), its
body rays' attempts with their gather and write-back ~2 (a quarter of the rays at 550 nm,
:func:`_leaf_bodies`) and the float64 finishing of their rejected attempts ~1 (~2 when every block
was scanned for them). The beam, the coat's visible normals and the rest of each attempt run as
separate loops (:func:`~virtual.kernels.f32.emit_block32`): in one loop per ray the chain of square
roots and divisions ran at its latency (leaf 10.3 ns a ray).
The scalar code (table reads, finishing of rejected and doubted rays) is
called, not inlined: inlined, it slowed the vectorized loops around it (leaf 1.35x, in A/B runs).
"""

from __future__ import annotations

import math

import numpy as np

from virtual.kernels import jit
from virtual.kernels.block32 import bin_block32, normals_block32
from virtual.kernels.block_coat import leaf_given, roughplastic_given
from virtual.kernels.coat import roughplastic_base_redo, rp_e, rp_t
from virtual.kernels.emit import BEAM_COLLIMATED, BEAM_CONICAL, emit_given
from virtual.kernels.ggx32 import (fresnel_conductor_ratio as fresnel_conductor_ratio32, ggx_mirror as ggx_mirror32,
                                   ggx_normal as ggx_normal32, roughplastic_about as roughplastic_about32)
from virtual.kernels.f32 import (ONE, TWO, ZERO, emit_block32, in_doubt32,
                                 sincos_2pi32, warp_cosine_hemisphere32)
from virtual.kernels.refine import refined
from virtual.kernels.scatter import leaf_body_redo
from virtual.kernels.xoshiro import LANES, fill_uniforms32
from virtual.kernel_codes import BLOCK32_RAYS, RP_E, RP_N_E, RP_S_HI, RP_S_LO, RP_TABLE, RP_TABLE_RES
from virtual.model_ids import MODEL_ROUGHPLASTIC

__all__ = ["RP32_UNIFORMS", "LEAF32_UNIFORMS", "leaf_cuticle_about32", "leaf_body_normal32",
           "leaf_body_about32", "redo_coat_ray64", "rp_tables32", "gonio_coat32_chunk"]

#: Uniforms the roughplastic's float32 attempt consumes per ray (u0-u6,
#: :func:`~virtual.kernels.ggx.roughplastic_about`'s float32 twin).
RP32_UNIFORMS = 7
#: Uniforms the leaf's float32 attempt consumes per ray (u0-u3 the cuticle's, u4-u8 the body's).
LEAF32_UNIFORMS = 9
_BEAM_UNIFORMS = 4


@jit(inline="llvm")
def _mirror_about32(a, wx, wy, wz, mx, my, mz, ni):
    """The mirror direction of w (wz > 0) about its isotropic GGX visible normal m
    (:func:`~virtual.kernels.ggx.ggx_normal`'s float32 twin): ``(sx, sy, sz, c, ni, no)``, c = w.m, ni
    and no the |(a x, a y, z)| of w and of the mirror direction (the masking terms)."""
    _, _, c, sx, sy, sz = ggx_mirror32(wx, wy, wz, mx, my, mz)
    return sx, sy, sz, c, ni, math.sqrt(a * a * (sx * sx + sy * sy) + sz * sz)


@jit(inline="llvm")
def leaf_cuticle_about32(p, wx, wy, wz, mx, my, mz, ni, u0, u3):
    """The cuticle's part of :func:`~virtual.kernels.block_coat.leaf_given` in float32
    from the visible normal m of |w| (:func:`~virtual.kernels.ggx.ggx_normal`'s float32 twin from (u1,
    u2)) on (height-correlated masking, isotropic: G2/G1 = (wz + ni) oz / (ni oz + no wz)): ``(ox, oy,
    oz, kept, body, doubt)``, the mirror direction when kept, else (0, 0, +-1) with the sign of
    the body's side. F is :func:`~virtual.kernels.ggx.fresnel_conductor_ratio` (float32) at k = 0 -- the
    dielectric's F as a ratio (no division; 3 % faster than ``fresnel_dielectric32`` here),
    tested against it by the law (tests/test_block32_coat.py). A body ray's attempt is
    :func:`leaf_body_normal32` and :func:`leaf_body_about32`, run only for the body rays (about a
    quarter of a green leaf's at 550 nm)."""
    flip = wz < ZERO
    wz = abs(wz)
    sx, sy, sz, c, ni, no = _mirror_about32(p[0], wx, wy, wz, mx, my, mz, ni)
    f_num, f_den = fresnel_conductor_ratio32(c, p[1], ZERO, True)  # k = 0: the dielectric's F, no division
    k_num = p[2] * f_num * ((wz + ni) * sz)
    k_den = f_den * (ni * sz + no * wz)
    kept = (sz > ZERO) & (u0 * k_den < k_num)
    rt = p[3] + p[4]
    below = flip if kept else ((u3 < p[3]) == flip)
    ok = wz > ZERO
    doubt = in_doubt32(u0, k_num, k_den) | in_doubt32(u3, rt, ONE) | in_doubt32(u3, p[3], ONE)
    oz = sz if kept else ONE
    return (sx if kept else ZERO), (sy if kept else ZERO), (-oz if below else oz), ok & kept, ok & (~kept) & (u3 < rt), doubt


@jit(inline="llvm")
def leaf_body_normal32(p, u4, u5, u6, u7):
    """The first half of a body ray's attempt (:func:`~virtual.kernels.block_coat.leaf_given`'s, in
    float32): Malley's direction d from (u4, u5) and its visible normal from (u6, u7), ``(dx, dy,
    dz, mx, my, mz, ni)``."""
    a = p[0]
    dx, dy, dz = warp_cosine_hemisphere32(u5, u4)
    ca, sa = sincos_2pi32(u6)
    mx, my, mz, ni = ggx_normal32(a, a, dx, dy, dz, ca, sa, u7, True)
    return dx, dy, dz, mx, my, mz, ni


@jit(inline="llvm")
def leaf_body_about32(p, side, dx, dy, dz, mx, my, mz, ni, u8):
    """The rest of a body ray's attempt, from :func:`leaf_body_normal32`: d on the side ``side``
    (+-1) of :func:`leaf_cuticle_about32`, rejected when the cuticle would have kept light from d
    (u8): ``(ox, oy, oz, back, doubt)``, oz = +-1 when rejected (the attempt is finished in float64)."""
    bx, by, bz, bc, bi, bo = _mirror_about32(p[0], dx, dy, dz, mx, my, mz, ni)
    fb_num, fb_den = fresnel_conductor_ratio32(bc, p[1], ZERO, True)
    b_num = p[2] * fb_num * ((dz + bi) * bz)
    b_den = fb_den * (bi * bz + bo * dz)
    back = (dz > ZERO) & (bz > ZERO) & (u8 * b_den < b_num)
    return dx, dy, side * (ONE if back else dz), back, in_doubt32(u8, b_num, b_den)


@jit
def redo_coat_ray64(model, p, kind, b, u, i, nb, bo, s0, s):
    """:func:`~virtual.kernels.refine.redo_ray64` for the coated families (here, not in
    :mod:`~virtual.kernels.refine`, whose importers' caches would then depend on these forms): ``p`` is
    the whole float64 parameter vector (an array: the roughplastic's tables, read at the float64
    cosines of the refined uniforms), the given forms those of :mod:`virtual.kernels.block_coat`;
    a rejected attempt continues on ``s`` as in the float64 block kernel."""
    wx, wy, wz, hit = emit_given(kind, b, refined(u[i], s), refined(u[bo + i], s), refined(u[2 * bo + i], s),
                                 refined(u[3 * bo + i], s))
    v0 = refined(u[s0 + i], s)
    v1 = refined(u[s0 + nb + i], s)
    v2 = refined(u[s0 + 2 * nb + i], s)
    v3 = refined(u[s0 + 3 * nb + i], s)
    v4 = refined(u[s0 + 4 * nb + i], s)
    v5 = refined(u[s0 + 5 * nb + i], s)
    v6 = refined(u[s0 + 6 * nb + i], s)
    if model == MODEL_ROUGHPLASTIC:
        mu = abs(wz)
        ox, oy, oz, alive, redo = roughplastic_given(p, wx, wy, wz, v0, v1, v2, v3, v4, v5, v6, p[3] * rp_t(p, mu),
                                                     1.0 - rp_e(p, mu), rp_t(p, math.sqrt(1.0 - v4)))
        if redo:
            dx, dy, dz = roughplastic_base_redo(p, s)
            return dx, dy, (dz if oz > 0.0 else -dz), True, hit
        return ox, oy, oz, alive, hit
    ox, oy, oz, alive, redo = leaf_given(p, wx, wy, wz, v0, v1, v2, v3, v4, v5, v6, refined(u[s0 + 7 * nb + i], s),
                                         refined(u[s0 + 8 * nb + i], s))
    if redo:
        dx, dy, dz = leaf_body_redo(p[0], p[1], p[2], s)
        return dx, dy, (dz if oz > 0.0 else -dz), True, hit
    return ox, oy, oz, alive, hit


_THREE = np.float32(3.0)
_SIXTH = np.float32(1.0 / 6.0)
_LAST_CELL = np.int32(RP_TABLE_RES - 2)
_MU_SCALE = np.float32(RP_TABLE_RES - 1)


@jit(inline="llvm")
def _t_cell32(cos):
    """Where :func:`~virtual.kernels.coat.rp_t` reads t at the cosine ``cos`` in [0, 1], in
    float32: ``(k, w)``, t = (1 - w) t_k + w t_(k+1)."""
    x = cos * _MU_SCALE
    k = min(np.int32(x), _LAST_CELL)
    return k, x - np.float32(k)


@jit(inline="llvm")
def _rp_cells32(wx, wy, wz, e_lo, e_hi, e_scale, n_e):
    """Where :func:`~virtual.kernels.coat.rp_t` reads t at the incidence ``mu = |wz|`` and
    :func:`~virtual.kernels.coat.rp_e` reads E at ``s = sqrt(1 - mu)``, with the weights of the
    nodes read: ``(k, w, j, l0, l1, l2, l3)``, in float32. s is computed as
    ``sqrt((wx^2 + wy^2) / (1 + mu))`` (the same value for a unit w): a few float32 roundings of
    s at any incidence (``sqrt(1 - mu)`` would turn mu's rounding into an error of s up to 2^-12
    near normal incidence)."""
    mu = abs(wz)
    k, w = _t_cell32(mu)
    s = math.sqrt((wx * wx + wy * wy) / (ONE + mu))
    xe = (min(max(s, e_lo), e_hi) - e_lo) * e_scale
    j = min(max(np.int32(xe) - np.int32(1), np.int32(0)), np.int32(n_e - 4))
    t = xe - np.float32(j)
    t1 = t - ONE
    t2 = t - TWO
    t3 = t - _THREE
    return (k, w, j, -t1 * t2 * t3 * _SIXTH, _THREE * t * t2 * t3 * _SIXTH, -_THREE * t * t1 * t3 * _SIXTH,
            t * t1 * t2 * _SIXTH)


@jit
def rp_tables32(p64, n_e, rp):
    """The roughplastic's tables in float32: ``(t, 1 - E, s_lo, s_hi, scale)`` -- t and 1 - E at
    their nodes, each rounded once from float64, and E's nodes' range in s with its nodes per unit
    of s (zeros and a unit range when ``rp`` is false: the leaf's chunk)."""
    t32 = np.zeros(RP_TABLE_RES, dtype=np.float32)
    e32 = np.zeros(n_e, dtype=np.float32)
    if not rp:
        return t32, e32, ZERO, ONE, np.float32(n_e - 1)
    for k in range(RP_TABLE_RES):
        t32[k] = p64[RP_TABLE + k]
    for k in range(n_e):
        e32[k] = 1.0 - p64[RP_E + k]
    return (t32, e32, np.float32(p64[RP_S_LO]), np.float32(p64[RP_S_HI]),
            np.float32((n_e - 1) / (p64[RP_S_HI] - p64[RP_S_LO])))


@jit
def _rp_bounds(p64, n_e, margin):
    """``(q_lo, q_hi, mu_lo, mu_hi)``: bounds on the base's probability ``c t(mu) / (1 - E(mu))``,
    as float32 computes it, for the cosines mu in [mu_lo, mu_hi] (the E table's range of
    s = sqrt(1 - mu) and a table cell more), widened by ``margin`` (far above float32
    rounding). t is a lerp: within its nodes over the cells those cosines touch; E a four-point
    Lagrange form: within its nodes' range widened twice over (the Lebesgue constant of four
    equispaced nodes is below 1.7). A ray whose u3 lies outside [q_lo, q_hi], and whose cosine
    inside [mu_lo, mu_hi], is decided without reading the tables at its incidence."""
    e_min = p64[RP_E]
    e_max = p64[RP_E]
    for k in range(n_e):
        e_min = min(e_min, p64[RP_E + k])
        e_max = max(e_max, p64[RP_E + k])
    spread = e_max - e_min
    s_lo = p64[RP_S_LO]
    s_hi = s_lo if n_e == 4 else p64[RP_S_HI]  # four nodes: one cosine's E, over [s, s + 1]
    k_lo = max(min(int((1.0 - s_hi * s_hi) * (RP_TABLE_RES - 1)) - 1, RP_TABLE_RES - 2), 0)
    k_hi = max(min(int((1.0 - s_lo * s_lo) * (RP_TABLE_RES - 1)) + 1, RP_TABLE_RES - 2), 0)
    t_min = p64[RP_TABLE + k_lo]
    t_max = t_min
    for k in range(k_lo, min(k_hi + 3, RP_TABLE_RES)):
        t_min = min(t_min, p64[RP_TABLE + k])
        t_max = max(t_max, p64[RP_TABLE + k])
    c = p64[3]
    q_lo = c * t_min / max(1.0 - (e_min - 2.0 * spread), 1e-30)
    q_hi = c * t_max / max(1.0 - min(e_max + 2.0 * spread, 1.0), 1e-30)
    return (np.float32(q_lo - margin), np.float32(min(q_hi + margin, 2.0)),
            np.float32((k_lo + 0.5) / (RP_TABLE_RES - 1)), np.float32((k_hi + 1.5) / (RP_TABLE_RES - 1)))


@jit
def _rp_read_block32(t32, e32, c, e_lo, e_hi, e_scale, n_e, nb, cell_i, cell_f, aux):
    """The table reads of a block, scalar (indexed loads): every ray's ``t(mo)`` into row 5 of
    ``aux``, and for the rays whose base test the bounds leave unsure (``cell_i[0]``, rare) the
    values ``c t(mu), 1 - E(mu)`` into rows 3-4 -- the expressions of
    :func:`~virtual.kernels.coat.rp_t` and :func:`~virtual.kernels.coat.rp_e` on the float32
    tables of :func:`rp_tables32` (1 - E interpolated itself: the same value, as the weights sum
    to 1, without the cancellation of 1 - E where E is near 1). Called, not inlined, like
    :func:`_finish_block`."""
    for i in range(nb):
        ko = cell_i[2, i]
        wo = cell_f[5, i]
        aux[5, i] = (ONE - wo) * t32[ko] + wo * t32[ko + 1]
        if cell_i[0, i] != 0:
            k, w, j, l0, l1, l2, l3 = _rp_cells32(aux[0, i], aux[1, i], aux[2, i], e_lo, e_hi, e_scale, n_e)
            aux[3, i] = c * ((ONE - w) * t32[k] + w * t32[k + 1])
            aux[4, i] = l0 * e32[j] + l1 * e32[j + 1] + l2 * e32[j + 2] + l3 * e32[j + 3]


@jit
def _finish_block(model, p64, kind, b64, u, nb, bo, s0, m, v, code, s):
    """The block's rays with code 3 (a rejected attempt: the loop continues in float64 on
    ``s``) and 4 (in doubt: decided again by :func:`redo_coat_ray64`), in that order. Called, not
    inlined: the scalar code kept out of the chunk's vectorized loops."""
    rp = model == MODEL_ROUGHPLASTIC
    for i in range(m):
        if code[i] == 3:
            if rp:
                ox, oy, oz = roughplastic_base_redo(p64, s)
            else:
                ox, oy, oz = leaf_body_redo(p64[0], p64[1], p64[2], s)
            v[0, i] = ox
            v[1, i] = oy
            v[2, i] = oz if v[2, i] > ZERO else -oz
            code[i] = 1
    for i in range(m):
        if code[i] == 4:
            ox, oy, oz, alive, hit = redo_coat_ray64(model, p64, kind, b64, u, i, nb, bo, s0, s)
            v[0, i] = ox
            v[1, i] = oy
            v[2, i] = oz
            code[i] = 1 if (alive & hit) else (0 if hit else 2)


@jit
def _finish_leaf_bodies(p64, s, n, idx, v, code):
    """The rejected attempts (``idx[1]`` 3) among a block's ``n`` body rays (``idx[0]``, ascending):
    the leaf body's loop continues in float64 on ``s``, as :func:`_finish_block` would continue it
    (the same rays in the same order, so the same numbers), from a list of a quarter of the block
    rather than two scans of all of it. Called, not inlined, like :func:`_finish_block`."""
    for k in range(n):
        if idx[1, k] == 3:
            i = idx[0, k]
            ox, oy, oz = leaf_body_redo(p64[0], p64[1], p64[2], s)
            v[0, i] = ox
            v[1, i] = oy
            v[2, i] = oz if v[2, i] > ZERO else -oz
            code[i] = 1


@jit(inline="always")
def _leaf_bodies(p, p64, s, u, s0, nb, m, v, code, aux, idx, t, ox, oy, oz):
    """The attempts of a block's body rays (code 5) of the ``m`` emitted: their uniforms and side
    gathered into the rows of ``aux`` (their ray numbers into ``idx[0]`` by a branch-free loop over
    the block, one store a ray), the attempt on the gathered rows (two vectorized loops:
    d and its visible normal into the rows of ``t``, then the rest) into ``ox, oy, oz``, the
    results written back -- code 1 accepted, 4 in doubt; a rejected attempt is finished in
    float64 on ``s`` here (:func:`_finish_leaf_bodies`), not by a scan of the whole block."""
    n = 0
    for i in range(m):
        idx[0, n] = i
        n += code[i] == 5
    for k in range(n):
        i = idx[0, k]
        aux[0, k] = u[s0 + 4 * nb + i]
        aux[1, k] = u[s0 + 5 * nb + i]
        aux[2, k] = u[s0 + 6 * nb + i]
        aux[3, k] = u[s0 + 7 * nb + i]
        aux[4, k] = u[s0 + 8 * nb + i]
        aux[5, k] = v[2, i]
    for k in range(n):  # d and its normal (into other arrays than the uniforms': LLVM vectorizes it)
        t[0, k], t[1, k], t[2, k], t[3, k], t[4, k], t[5, k], t[6, k] = leaf_body_normal32(p, aux[0, k], aux[1, k],
                                                                                           aux[2, k], aux[3, k])
    for k in range(n):  # the rest of the attempt, in a loop of its own (as emit_block32)
        ox[k], oy[k], oz[k], back, doubt = leaf_body_about32(p, aux[5, k], t[0, k], t[1, k], t[2, k], t[3, k], t[4, k],
                                                             t[5, k], t[6, k], aux[4, k])
        idx[1, k] = 4 if doubt else (3 if back else 1)
    n_back = 0
    for k in range(n):
        i = idx[0, k]
        v[0, i] = ox[k]
        v[1, i] = oy[k]
        v[2, i] = oz[k]
        code[i] = idx[1, k]
        n_back += idx[1, k] == 3
    if n_back > 0:
        _finish_leaf_bodies(p64, s, n, idx, v, code)


@jit(nogil=True, error_model="numpy", family="coat32")
def gonio_coat32_chunk(model, p, p64, conical, b, b64, cargs, ring_margin, sector_margin, n_bins, n_rays, lane, s,
                       hist):
    """One chunk: the arguments of :func:`~virtual.kernels.block32.gonio_block32_chunk`, except
    that ``p64`` is the whole float64 parameter vector (an array: the roughplastic's tables;
    ``p`` its first six values as a float32 tuple). Codes: 1 survivor, 0 absorbed, 2 missed,
    3 a rejected attempt (finished on ``s``), 4 in doubt (decided again in float64); 5, within
    a block only, a leaf's body ray whose attempt is still to run (:func:`_leaf_bodies`).

    A loop reads few arrays: LLVM vectorizes a loop only when it can check at run time that its
    stores overlap none of its loads, and it gives up beyond a handful of arrays. So the
    per-ray values live in rows of few 2-D arrays (``aux``: the roughplastic's incidence, table
    values; ``v``: the directions). The beam runs in a loop of its own first
    (:func:`~virtual.kernels.f32.emit_block32`), its hits in ``code`` until the rays are marked."""
    nb = BLOCK32_RAYS
    rp = model == MODEL_ROUGHPLASTIC
    n_beam = _BEAM_UNIFORMS if conical else 0
    n_scat = RP32_UNIFORMS if rp else LEAF32_UNIFORMS
    ublock = np.empty(((n_beam + n_scat) * nb // LANES, LANES), dtype=np.float32)
    u = ublock.reshape(ublock.size)
    s0 = n_beam * nb
    bo = nb if conical else 0
    kind = BEAM_CONICAL if conical else BEAM_COLLIMATED
    code = np.empty(nb, dtype=np.int32)
    v = np.empty((3, nb), dtype=np.float32)
    cx = np.empty(nb, dtype=np.float32)
    cy = np.empty(nb, dtype=np.float32)
    cz = np.empty(nb, dtype=np.float32)
    aux = np.empty((6, nb), dtype=np.float32)
    cell_i = np.empty((3, nb), dtype=np.int32)
    cell_f = np.empty((7, nb), dtype=np.float32)  # the roughplastic's table cells; the leaf's body normals
    n_e = int(p64[RP_N_E]) if rp else 4
    t32, e32, e_lo, e_hi, e_scale = rp_tables32(p64, n_e, rp)
    c_base = np.float32(p64[3])
    q_lo, q_hi, mu_lo, mu_hi = _rp_bounds(p64, n_e, 1e-5) if rp else (ZERO, ZERO, ZERO, ZERO)
    h = np.zeros(n_bins, dtype=np.int64)
    n_dead = np.zeros(2, dtype=np.int64)
    left = n_rays
    while left > 0:
        m = min(left, nb)
        fill_uniforms32(lane, ublock)
        if rp:
            emit_block32(conical, b, u, bo, nb, aux[0], aux[1], aux[2], code)  # code: the hits until marked
            for i in range(nb):  # the attempt's table cell, the base test by bounds (vectorized)
                wz = aux[2, i]
                cell_i[2, i], cell_f[5, i] = _t_cell32(math.sqrt(ONE - u[s0 + 4 * nb + i]))  # Malley's z; 1 - u4 exact
                u3 = u[s0 + 3 * nb + i]
                mu = abs(wz)
                cell_i[0, i] = ((u3 >= q_lo) & (u3 <= q_hi)) | (mu < mu_lo) | (mu > mu_hi)
                aux[3, i] = TWO if u3 < q_lo else -ONE  # num, den deciding u3 den < num as the bounds do,
                aux[4, i] = ONE  # never in doubt (the unsure rays' values are read below)
            _rp_read_block32(t32, e32, c_base, e_lo, e_hi, e_scale, n_e, nb, cell_i, cell_f, aux)
            normals_block32(p[0], p[0], u[s0 + nb:s0 + 2 * nb], u[s0 + 2 * nb:s0 + 3 * nb], nb, aux[0], aux[1], aux[2],
                            v[0], v[1], v[2], cell_f[6], True)  # the coat's normals into v; ni (unused) into cell_f[6]
            for i in range(nb):
                v[0, i], v[1, i], v[2, i], alive, redo, doubt = roughplastic_about32(
                    p, aux[0, i], aux[1, i], aux[2, i], v[0, i], v[1, i], v[2, i], u[s0 + i], u[s0 + 3 * nb + i],
                    u[s0 + 4 * nb + i], u[s0 + 5 * nb + i], u[s0 + 6 * nb + i], aux[3, i], aux[4, i], aux[5, i], True)
                hit = code[i] == 1
                code[i] = 4 if (doubt & hit) else (1 if (alive & hit) else (3 if (redo & hit) else (0 if hit else 2)))
        else:
            emit_block32(conical, b, u, bo, nb, v[0], v[1], v[2], code)  # code: the hits until marked
            normals_block32(p[0], p[0], u[s0 + nb:s0 + 2 * nb], u[s0 + 2 * nb:s0 + 3 * nb], nb, v[0], v[1], v[2],
                            aux[0], aux[1], aux[2], aux[3], True)  # the cuticle's visible normals
            for i in range(nb):  # the cuticle for every ray; code 5: a body ray, its attempt below
                hit = code[i] == 1
                v[0, i], v[1, i], v[2, i], kept, body, doubt = leaf_cuticle_about32(
                    p, v[0, i], v[1, i], v[2, i], aux[0, i], aux[1, i], aux[2, i], aux[3, i], u[s0 + i], u[s0 + 3 * nb + i])
                code[i] = 4 if (doubt & hit) else (1 if (kept & hit) else (5 if (body & hit) else (0 if hit else 2)))
            _leaf_bodies(p, p64, s, u, s0, nb, m, v, code, aux, cell_i, cell_f, cx, cy, cz)  # cx, cy, cz: scratch until binned
        n_redo = 0
        for i in range(m):  # a vectorized count of the rays to finish or decide again
            n_redo += code[i] >= 3
        if n_redo > 0:
            _finish_block(model, p64, kind, b64, u, nb, bo, s0, m, v, code, s)
        bin_block32(code, v[0], v[1], v[2], m, cx, cy, cz, cargs, ring_margin, sector_margin, h, n_dead)
        left -= m
    for k in range(n_bins):
        hist[k] += h[k]
    hist[n_bins] += n_dead[0]
    hist[n_bins + 1] += n_dead[1]

"""The float32 block kernel: :func:`~virtual.kernels.block64.gonio_block_chunk` on float32
vectors (as many lanes as the machine's hold: twice the float64 kernel's).

Same shape as the float64 block kernel -- a block's uniforms first (64 xoshiro128+ lanes,
:func:`~virtual.kernels.xoshiro.fill_uniforms32`), branch-free loops that emit, scatter and
mark every ray, compaction of the survivors, a vectorized guess of their bins
(:func:`~virtual.kernels.f32.guess_bin32`) and the exact float64
:func:`~virtual.kernels.patch_lookup.patch_of` for the few near an edge -- with twice the lanes
per instruction and half the generator's work per uniform. The beam, the microfacet normals and
the rest of each specimen run as separate loops over the block (:func:`~virtual.kernels.f32.emit_block32`,
:func:`normals_block32`): in one loop per ray the chain of square roots and divisions was longer
than the core could overlap across iterations, and GGX ran 1.5x slower. :func:`virtual.engine.gonio_kernel_for`
sends a specimen here only when float32 suffices for it (:mod:`virtual.kernels.f32`).
"""

from __future__ import annotations

import numpy as np
from numba import uint32
from numba.cpython.unsafe.numbers import trailing_zeros

from virtual.kernels import jit
from virtual.kernels.emit import BEAM_COLLIMATED, BEAM_CONICAL
from virtual.kernels.patch_lookup import SCHEME_EQUAL_ANGLE, SCHEME_EQUAL_PSA, SCHEME_EQUAL_SOLID_ANGLE, patch_of
from virtual.kernels.f32 import ONE, ZERO, emit_block32, guess_bin32, sincos_2pi32
from virtual.kernels.branchfree import PLASTIC_UNIFORMS, plastic_diffuse_redo
from virtual.kernels.refine import redo_ray64
from virtual.kernels.branchfree32 import ggx_finish32
from virtual.kernels.ggx32 import (dielectric_about as dielectric_about32, ggx_normal as ggx_normal32,
                                   plastic_about as plastic_about32, plastic_diffuse as plastic_diffuse32)
from virtual.kernels.law_dispatch import law32, law_block32, law_uniforms
from virtual.kernels.xoshiro import LANES, fill_uniforms32
from virtual.kernels.scatter import MODEL_DIELECTRIC, MODEL_PLASTIC

__all__ = ["BLOCK32_MODELS", "BLOCK32_RAYS", "guess_bins32", "normals_block32", "ggx_block32", "bin_block32", "gonio_block32_chunk"]

from virtual.kernel_codes import BLOCK32_MODELS, BLOCK32_RAYS, GIVEN4_UNIFORMS
_BEAM_UNIFORMS = 4


@jit(error_model="numpy", family="block32")
def guess_bins32(code, x, y, z, n, scheme, n_theta, n_phi, ring_margin, sector_margin):
    """``code[i] = guess_bin32(...)`` for i < n, one loop per scheme (the scheme a constant in
    each, so each vectorizes). Called, not inlined: inlined into a chunk kernel its loops ran
    slower (GGX on Zen 5, 0.2-0.4 ns a ray of the chunk's 5)."""
    if scheme == SCHEME_EQUAL_PSA:
        for i in range(n):
            code[i] = guess_bin32(x[i], y[i], z[i], SCHEME_EQUAL_PSA, n_theta, n_phi, ring_margin, sector_margin)
    elif scheme == SCHEME_EQUAL_SOLID_ANGLE:
        for i in range(n):
            code[i] = guess_bin32(x[i], y[i], z[i], SCHEME_EQUAL_SOLID_ANGLE, n_theta, n_phi, ring_margin,
                                  sector_margin)
    else:
        for i in range(n):
            code[i] = guess_bin32(x[i], y[i], z[i], SCHEME_EQUAL_ANGLE, n_theta, n_phi, ring_margin, sector_margin)


@jit(inline="always")
def normals_block32(ax, ay, angle, radius, n, vx, vy, vz, mx, my, mz, ni, plain):
    """The GGX visible normals (:func:`~virtual.kernels.ggx.ggx_normal` in float32) of the block's
    first ``n`` incident directions ``vx, vy, vz`` (:func:`~virtual.kernels.f32.emit_block32`),
    from the rows of uniforms ``angle`` and ``radius``, into ``mx, my, mz, ni``: a loop of its own,
    so that each loop's chain is short enough for the core to overlap its iterations
    (:func:`~virtual.kernels.f32.emit_block32`)."""
    for i in range(n):
        ca, sa = sincos_2pi32(angle[i])
        mx[i], my[i], mz[i], ni[i] = ggx_normal32(ax, ay, vx[i], vy[i], vz[i], ca, sa, radius[i], plain)


@jit(inline="always")
def ggx_block32(p, u, s0, nb, vx, vy, vz, code, mx, my, mz, ni, plain):
    """GGX on a block whose incident directions are in ``vx, vy, vz`` and hits in ``code``: the
    visible normals (:func:`normals_block32`), then the reflections and their tests in a loop of
    their own. Leaves the reflected directions in ``vx, vy, vz`` and the codes (1 survivor, 0
    absorbed, 2 missed, 4 in doubt) in ``code``. ``plain`` as
    :func:`~virtual.kernels.branchfree32.ggx_finish32`."""
    normals_block32(p[0], p[1], u[s0 + 2 * nb:s0 + 3 * nb], u[s0 + nb:s0 + 2 * nb], nb, vx, vy, vz, mx, my, mz, ni, plain)
    for i in range(nb):
        hit = code[i] == 1
        vx[i], vy[i], vz[i], alive, doubt = ggx_finish32(p, vx[i], vy[i], vz[i], mx[i], my[i], mz[i], ni[i], u[s0 + i],
                                                         plain)
        code[i] = 4 if (doubt & hit) else (1 if (alive & hit) else (0 if hit else 2))


@jit(inline="always")
def bin_block32(code, vx, vy, vz, m, cx, cy, cz, cargs, ring_margin, sector_margin, h, n_dead):
    """A block's ``m`` rays into ``h``, by their codes (1 survivor, 0 absorbed, 2 missed): the
    absorbed and missed counted into ``n_dead`` (a vectorized tally, not binned), the survivors'
    directions compacted into ``cx, cy, cz``, their bins guessed (:func:`guess_bins32`, a
    vectorized loop) and the few near an edge looked up exactly in float64."""
    scheme, n_theta, n_phi, sin2_edges, phi_cs = cargs
    n_live = 0
    n_missed = 0
    for i in range(m):  # a vectorized tally first
        k = code[i]
        n_live += k == 1
        n_missed += k == 2
    n_dead[0] += m - n_live - n_missed
    n_dead[1] += n_missed
    j = 0
    if 4 * n_live < m:  # few survivors (a dark or a specular specimen): the set bits of 32-ray masks
        g = 0
        while g + 32 <= m:
            bits = uint32(0)
            for k in range(32):  # a vectorized mask
                bits |= uint32(code[g + k] == 1) << uint32(k)
            while bits != uint32(0):  # a branch per survivor, not per ray
                i = g + trailing_zeros(bits)
                cx[j] = vx[i]
                cy[j] = vy[i]
                cz[j] = vz[i]
                j += 1
                bits &= bits - uint32(1)
            g += 32
        for i in range(g, m):
            if code[i] == 1:
                cx[j] = vx[i]
                cy[j] = vy[i]
                cz[j] = vz[i]
                j += 1
    else:  # many: branch-free (every ray written, j advances for survivors)
        for i in range(m):
            cx[j] = vx[i]
            cy[j] = vy[i]
            cz[j] = vz[i]
            j += code[i] == 1
    guess_bins32(code, cx, cy, cz, j, scheme, n_theta, n_phi, ring_margin, sector_margin)
    for i in range(j):
        k = code[i]
        if k < 0:  # near an edge, the pole or the horizon: the exact float64 lookup
            k = patch_of(np.float64(cx[i]), np.float64(cy[i]), np.float64(cz[i]), scheme, n_theta, n_phi, sin2_edges,
                         phi_cs)
        h[k] += 1


@jit(nogil=True, error_model="numpy", family="block32")
def gonio_block32_chunk(model, p, p64, conical, b, b64, cargs, ring_margin, sector_margin, n_bins, n_rays, lane, s,
                        hist):
    """One chunk: ``n_rays`` rays from the xoshiro128+ lanes ``lane`` (advanced in place) added
    to ``hist``. ``p`` and ``b`` are the float32 parameters and beam, ``p64`` and ``b64`` the
    same in float64 for the rays in doubt (code 4: a decision within a few 2^-24 of its
    threshold), which :func:`~virtual.kernels.refine.redo_ray64` decides again; ``s`` is a
    scalar float64 xoshiro stream for those rays and the plastic's rare rejected diffuse rays.
    Compiled on its own for the reasons given on the float64
    :func:`~virtual.kernels.block64.gonio_block_chunk`."""
    nb = BLOCK32_RAYS
    n_beam = _BEAM_UNIFORMS if conical else 0
    n_scat = 3
    if law32(model):  # a law of virtual.kernels.laws
        n_scat = law_uniforms(model)
    elif model == MODEL_DIELECTRIC:
        n_scat = GIVEN4_UNIFORMS
    elif model == MODEL_PLASTIC:
        n_scat = PLASTIC_UNIFORMS
    ublock = np.empty(((n_beam + n_scat) * nb // LANES, LANES), dtype=np.float32)
    u = ublock.reshape(ublock.size)
    s0 = n_beam * nb
    bo = nb if conical else 0
    code = np.empty(nb, dtype=np.int32)  # int32: 16 lanes per vector, like the float32 values
    vx = np.empty(nb, dtype=np.float32)
    vy = np.empty(nb, dtype=np.float32)
    vz = np.empty(nb, dtype=np.float32)
    cx = np.empty(nb, dtype=np.float32)
    cy = np.empty(nb, dtype=np.float32)
    cz = np.empty(nb, dtype=np.float32)
    cw = np.empty(nb, dtype=np.float32)  # cx..cw: the GGX normals, Phong's lobe, then the survivors
    dd = np.empty((4, nb), dtype=np.float32)  # the plastic's diffuse attempts
    h = np.zeros(n_bins, dtype=np.int64)
    n_dead = np.zeros(2, dtype=np.int64)  # absorbed, missed: summed in the vectorized loops, not binned
    left = n_rays
    while left > 0:
        m = min(left, nb)
        fill_uniforms32(lane, ublock)
        # code: 1 survivor, 0 absorbed, 2 missed, 4 in doubt (3: the plastic's rejected diffuse attempt)
        if law32(model):  # a law of virtual.kernels.laws: its generated loops, the beam's included
            law_block32(model, p, conical, b, u, bo, s0, nb, vx, vy, vz, code, cx, cy)
        else:  # the beam first, in a loop of its own (emit_block32); code holds the hits until marked
            emit_block32(conical, b, u, bo, nb, vx, vy, vz, code)
            if model == MODEL_DIELECTRIC:
                normals_block32(p[0], p[0], u[s0 + nb:s0 + 2 * nb], u[s0 + 2 * nb:s0 + 3 * nb], nb, vx, vy, vz, cx, cy,
                                cz, cw, False)
                inv_eta = ONE / p[1]  # the relative index from below is 1/eta, its inverse eta itself
                for i in range(nb):
                    hit = code[i] == 1
                    below = vz[i] < ZERO
                    vx[i], vy[i], vz[i], alive, doubt = dielectric_about32(
                        p, vx[i], vy[i], vz[i], cx[i], cy[i], cz[i], cw[i], inv_eta if below else p[1],
                        p[1] if below else inv_eta, u[s0 + i], u[s0 + 3 * nb + i])
                    code[i] = 4 if (doubt & hit) else (1 if (alive & hit) else (0 if hit else 2))
            elif model == MODEL_PLASTIC:
                normals_block32(p[0], p[0], u[s0 + nb:s0 + 2 * nb], u[s0 + 2 * nb:s0 + 3 * nb], nb, vx, vy, vz, cx, cy,
                                cz, cw, False)
                for i in range(nb):  # the diffuse attempts (independent of the incidence) in a loop of their own
                    dd[0, i], dd[1, i], dd[2, i], dd[3, i] = plastic_diffuse32(p, u[s0 + 4 * nb + i], u[s0 + 5 * nb + i])
                for i in range(nb):
                    hit = code[i] == 1
                    vx[i], vy[i], vz[i], alive, redo, doubt = plastic_about32(
                        p, vx[i], vy[i], vz[i], cx[i], cy[i], cz[i], cw[i], dd[0, i], dd[1, i], dd[2, i], dd[3, i],
                        u[s0 + i], u[s0 + 3 * nb + i], u[s0 + 6 * nb + i])
                    code[i] = 4 if (doubt & hit) else (1 if (alive & hit) else (3 if (redo & hit) else (0 if hit else 2)))
                for i in range(m):  # the diffuse rays whose one attempt was rejected: the loop continues in float64
                    if code[i] == 3:
                        ox, oy, oz = plastic_diffuse_redo(p64[1], s)
                        vx[i] = ox
                        vy[i] = oy
                        vz[i] = oz if vz[i] > ZERO else -oz
                        code[i] = 1
            elif p[0] == p[1] and p[3] == ZERO and p[4] == ZERO:  # isotropic, height-correlated, k = 0
                ggx_block32(p, u, s0, nb, vx, vy, vz, code, cx, cy, cz, cw, True)
            else:  # GGX, anisotropic GGX
                ggx_block32(p, u, s0, nb, vx, vy, vz, code, cx, cy, cz, cw, False)
        n_doubt = 0
        for i in range(m):  # a vectorized count of the rays in doubt first (about one in 10^6)
            n_doubt += code[i] == 4
        if n_doubt > 0:  # decided again in float64
            kind = BEAM_CONICAL if conical else BEAM_COLLIMATED
            for i in range(m):
                if code[i] == 4:
                    ox, oy, oz, alive, hit = redo_ray64(model, p64, kind, b64, u, i, nb, bo, s0, s)
                    vx[i] = ox
                    vy[i] = oy
                    vz[i] = oz
                    code[i] = 1 if (alive & hit) else (0 if hit else 2)
        bin_block32(code, vx, vy, vz, m, cx, cy, cz, cargs, ring_margin, sector_margin, h, n_dead)
        left -= m
    for k in range(n_bins):
        hist[k] += h[k]
    hist[n_bins] += n_dead[0]
    hist[n_bins + 1] += n_dead[1]

"""The float32 kernels' rays in doubt, decided again in float64 with 53-bit uniforms.

A float32 uniform is a multiple of 2^-24 (:func:`~virtual.kernels.xoshiro.fill_uniforms32`), so the
decision ``u < p`` alone would happen with probability ceil(p 2^24) 2^-24: never below 6e-8,
and off by up to 6e-8 at any p -- which 10^9 rays detect at a reflectance of 10^-9 or a
near-index-matched interface. The float32 forms therefore flag a ray whose decision lies within
a few grid cells of its threshold (:func:`~virtual.kernels.f32.in_doubt32`), and the kernel
decides that ray again here: its uniforms refined to 53 bits (the grid value plus 29 random
bits below it: uniform over its grid cell, independent of which cell), then the float64 given
form of the same model with the same uniforms in the same roles
(:func:`~virtual.kernels.scatter.scatter_given`, :mod:`virtual.kernels.branchfree`). A ray not
flagged decides the same for any refinement of its uniforms; so every decision happens with its
probability to 2^-53, p = 0 and p = 1 exactly. About one ray in 10^6 (eight grid cells of
2^24 per decision) comes here: the cost is nil.
"""

from __future__ import annotations

import numpy as np
from numba import uint64

from virtual.kernels import jit
from virtual.kernels.emit import emit_given
from virtual.kernels.branchfree import plastic_diffuse_redo, plastic_given, scatter_given4
from virtual.kernels.xoshiro import next_uint64
from virtual.kernels.scatter import MODEL_DIELECTRIC, MODEL_PLASTIC, scatter_given
from virtual.kernels.law_dispatch import law_given64, law_uniforms

__all__ = ["refined_by", "refined", "ray_bits", "redo_ray64"]

_BELOW_GRID = 2.0 ** -53  # the weight of the 29 bits added below the 2^-24 grid


@jit(inline="llvm")
def refined_by(u, bits):
    """A grid uniform u (k 2^-24, k < 2^24) completed by the top 29 of 64 random ``bits``:
    uniform over [u, u + 2^-24) on the 2^-53 grid, exact in float64 and below 1."""
    return np.float64(u) + np.float64(bits >> uint64(35)) * _BELOW_GRID


@jit(inline="llvm")
def refined(u, s):
    """:func:`refined_by` with the bits drawn from the xoshiro stream ``s``."""
    return refined_by(u, next_uint64(s))


@jit(inline="llvm")
def ray_bits(key, index):
    """64 random bits of ray ``index`` under ``key`` (splitmix64's finalizer of key + index times
    the golden ratio): a spectral batch refines a ray's uniform with bits that depend on the ray
    alone, not on how many other rays were in doubt -- so a wavelength's counts stay the same
    whichever wavelengths share its batch."""
    z = uint64(key) + uint64(index) * uint64(0x9E3779B97F4A7C15)
    z = (z ^ (z >> uint64(30))) * uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> uint64(27))) * uint64(0x94D049BB133111EB)
    return z ^ (z >> uint64(31))


@jit
def redo_ray64(model, p, kind, b, u, i, nb, bo, s0, s):
    """Ray ``i`` of a float32 block again, in float64: ``(ox, oy, oz, alive, hit)``.

    ``u`` is the block's uniforms (float32, as the block kernel lays them out: the beam's four
    rows of ``nb`` at stride ``bo`` (0 for a collimated beam), the scatterer's from ``s0`` at
    stride ``nb``), each refined by :func:`refined`; ``p`` and ``b`` are the float64 parameters
    and beam (``kind`` its :mod:`~virtual.kernels.emit` code). A plastic's rejected diffuse
    attempt continues on ``s`` (:func:`~virtual.kernels.branchfree.plastic_diffuse_redo`)."""
    wx, wy, wz, hit = emit_given(kind, b, refined(u[i], s), refined(u[bo + i], s), refined(u[2 * bo + i], s),
                                 refined(u[3 * bo + i], s))
    v0 = refined(u[s0 + i], s)
    v1 = refined(u[s0 + nb + i], s)
    v2 = refined(u[s0 + 2 * nb + i], s)
    k = law_uniforms(model)
    if k > 0:  # a law of virtual.kernels.laws: its uniforms from the fourth on refined in order
        v = np.empty(max(k, 3))
        v[0] = v0
        v[1] = v1
        v[2] = v2
        for j in range(3, k):
            v[j] = refined(u[s0 + j * nb + i], s)
        ox, oy, oz, alive = law_given64(model, p, wx, wy, wz, v)
        return ox, oy, oz, alive, hit
    if model == MODEL_DIELECTRIC:
        v3 = refined(u[s0 + 3 * nb + i], s)
        ox, oy, oz, alive = scatter_given4(model, p, wx, wy, wz, v0, v1, v2, v3)
        return ox, oy, oz, alive, hit
    if model == MODEL_PLASTIC:
        ox, oy, oz, alive, redo = plastic_given(p, wx, wy, wz, v0, v1, v2, refined(u[s0 + 3 * nb + i], s),
                                                refined(u[s0 + 4 * nb + i], s), refined(u[s0 + 5 * nb + i], s),
                                                refined(u[s0 + 6 * nb + i], s))
        if redo:
            dx, dy, dz = plastic_diffuse_redo(p[1], s)
            return dx, dy, (dz if oz > 0.0 else -dz), True, hit
        return ox, oy, oz, alive, hit
    ox, oy, oz, alive = scatter_given(model, p, wx, wy, wz, v0, v1, v2)
    return ox, oy, oz, alive, hit

"""Microfacet building blocks of the specimen kernels (float64): unit-disk points, orthonormal
frames, and the start and the lobe direction of the laws' samplers. GGX's visible normals, masking
ratios and reflection and the Fresnel factors, written once for both precisions, are
:mod:`virtual.kernels.ggx`.
"""

from __future__ import annotations

import math

from virtual.kernels import jit
from virtual.kernels.xoshiro import next_double

__all__ = ["two_sided_draw", "unit_disk", "disk_direction", "frame",
           "about_mirror"]


@jit(inline="llvm")
def two_sided_draw(wz, s):
    """The start of a two-sided law's ray-by-ray sampler: ``(flip, |wz|, alive, u)``, whether w
    comes from below, its cosine on the upper side, whether the ray lives (|wz| > 0: a grazing or
    NaN ray is dead) and, for a live ray only, the first draw of ``s`` (a dead one draws nothing)."""
    flip = wz < 0.0
    wz = abs(wz)
    if not (wz > 0.0):
        return flip, wz, False, 0.0
    return flip, wz, True, next_double(s)


@jit(inline="llvm")
def unit_disk(s):
    """A uniform point (a, b) of the open unit disk minus its centre, and r2 = a^2 + b^2.

    r2 is uniform in (0, 1) and independent of the direction (a, b) / sqrt(r2)."""
    while True:
        a = 2.0 * next_double(s) - 1.0
        b = 2.0 * next_double(s) - 1.0
        r2 = a * a + b * b
        if r2 < 1.0 and r2 > 0.0:
            return a, b, r2



@jit(inline="llvm")
def disk_direction(s):
    """A uniform point of the unit disk drawn by rejection from ``s``: its direction (unit) and
    its squared radius, uniform in (0, 1)."""
    a, b, r2 = unit_disk(s)
    inv = 1.0 / math.sqrt(r2)
    return a * inv, b * inv, r2



@jit(inline="llvm")
def frame(nx, ny, nz):
    """An orthonormal basis (t, b) around the unit vector n (Duff et al. 2017, branchless)."""
    sign = math.copysign(1.0, nz)
    a = -1.0 / (sign + nz)
    b = nx * ny * a
    return (1.0 + sign * nx * nx * a, sign * b, -sign * nx,
            b, sign + ny * ny * a, -ny)


@jit(inline="llvm")
def about_mirror(t, ta, tb, ca, wx, wy, wz):
    """The direction ``ta t1 + tb t2 + ca r`` about r = (-wx, -wy, wz), the mirror direction of w,
    ``t`` = (t1, t2) the frame of r (:func:`frame`, or its float32 twin): a lobe's direction from
    its cosine ``ca`` and its components ``ta``, ``tb`` across. No constant: it computes in its
    arguments' precision (the float64 and float32 laws call it alike)."""
    t1x, t1y, t1z, t2x, t2y, t2z = t
    return ta * t1x + tb * t2x - ca * wx, ta * t1y + tb * t2y - ca * wy, ta * t1z + tb * t2z + ca * wz

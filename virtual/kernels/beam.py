"""Emitting one incident ray: the unit vector toward its source and whether it hits the front.

``b`` is :meth:`virtual.beam.Beam.kernel_args`: the rotation to the incidence (b[0:9]), the
emitter and specimen disk radii (b[9], b[10]), the distance D (b[11]) and the axis (b[12:15]).
:func:`toward_source` is the one formula of a conical ray's direction.
"""

from __future__ import annotations

import math

from virtual.kernels import jit
from virtual.kernels.rng import next_double
from virtual.kernels.sampling import warp_polar, warp_square

__all__ = ["beam_tuple", "BEAM_COLLIMATED", "BEAM_CONICAL", "DISK_POLAR", "DISK_REJECTION", "DISK_AUTO", "emit",
           "emit_given", "toward_source"]

from virtual.kernel_codes import BEAM_COLLIMATED, BEAM_CONICAL, DISK_AUTO, DISK_POLAR, DISK_REJECTION  # noqa: E402


@jit(inline="always")
def _disk(u1, u2, r, code, s):
    if code != DISK_POLAR:  # rejection, also for "auto" in this ray-by-ray form
        while True:  # eq. 3.3 with rejection; acceptance pi/4, so the loop ends fast
            x, y = warp_square(u1, u2, r)
            if x * x + y * y < r * r:
                return x, y
            u1 = next_double(s)
            u2 = next_double(s)
    return warp_polar(u1, u2, r)



@jit(inline="always")
def emit(kind, disk, b, s):
    """One incident ray: the unit vector toward its source, and whether it hits the front face.

    ``b`` is :meth:`Beam.kernel_args`. Returns ``(wx, wy, wz, hit)``.
    """
    if kind == BEAM_COLLIMATED:
        return b[12], b[13], b[14], True
    x1, y1 = _disk(next_double(s), next_double(s), b[9], disk, s)
    x2, y2 = _disk(next_double(s), next_double(s), b[10], disk, s)
    return toward_source(b, x1, y1, x2, y2)



@jit(inline="always")
def toward_source(b, x1, y1, x2, y2):
    """Unit vector from the target (x2, y2, 0) to the emitter point R (x1, y1, D), and whether
    it arrives on the front face (the side the beam axis comes from)."""
    d = b[11]
    ox = b[0] * x1 + b[1] * y1 + b[2] * d - x2
    oy = b[3] * x1 + b[4] * y1 + b[5] * d - y2
    oz = b[6] * x1 + b[7] * y1 + b[8] * d
    inv = 1.0 / math.sqrt(ox * ox + oy * oy + oz * oz)
    wx, wy, wz = ox * inv, oy * inv, oz * inv
    return wx, wy, wz, wz * b[14] > 0.0



@jit(inline="always")
def emit_given(kind, b, u1, u2, u3, u4):
    """:func:`emit` with both disks drawn by the polar warp from the given uniforms (none are
    read for a collimated beam): branch-free, for the vectorized block kernel."""
    x1, y1 = warp_polar(u1, u2, b[9])
    x2, y2 = warp_polar(u3, u4, b[10])
    wx, wy, wz, hit = toward_source(b, x1, y1, x2, y2)
    col = kind == BEAM_COLLIMATED
    return (b[12] if col else wx), (b[13] if col else wy), (b[14] if col else wz), (True if col else hit)


@jit(inline="always")
def beam_tuple(beam_args):
    """The 15 values of :meth:`virtual.beam.Beam.kernel_args` as a tuple (of the array's float
    type): the block kernels pass it to their chunks, because LLVM must reload an array element
    every iteration of a loop that might write the array, and a tuple it keeps in registers."""
    return (beam_args[0], beam_args[1], beam_args[2], beam_args[3], beam_args[4], beam_args[5], beam_args[6],
            beam_args[7], beam_args[8], beam_args[9], beam_args[10], beam_args[11], beam_args[12], beam_args[13],
            beam_args[14])

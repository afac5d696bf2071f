"""Emitting one incident ray: the unit vector toward its source and whether it hits the front.

``b`` is :meth:`virtual.beam.Beam.kernel_args`, read through the ``B_*`` indices: the rotation to
the incidence (row-major, ``b[0:9]``), the emitter and specimen disk radii, the distance D and the
axis (the rotation's third column).
:func:`toward_source` is the one formula of a conical ray's direction.
"""

from __future__ import annotations

import math

from virtual.kernels import jit
from virtual.kernels.xoshiro import next_double
from virtual.kernels.warps import warp_polar, warp_square

__all__ = ["beam_tuple", "BEAM_COLLIMATED", "BEAM_CONICAL", "DISK_POLAR", "DISK_REJECTION", "DISK_AUTO", "emit",
           "emit_given", "toward_source", "B_EMITTER_RADIUS", "B_SPECIMEN_RADIUS",
           "B_DISTANCE", "B_AXIS_X", "B_AXIS_Y", "B_AXIS_Z", "N_BEAM_ARGS"]

from virtual.kernel_codes import (B_AXIS_X, B_AXIS_Y, B_AXIS_Z, B_DISTANCE, B_EMITTER_RADIUS,
                                  B_SPECIMEN_RADIUS, BEAM_COLLIMATED, BEAM_CONICAL, DISK_AUTO, DISK_POLAR,
                                  DISK_REJECTION, N_BEAM_ARGS)


@jit(inline="llvm")
def _disk(u1, u2, r, code, s):
    if code != DISK_POLAR:  # rejection, also for "auto" in this ray-by-ray form
        while True:  # eq. 3.3 with rejection; acceptance pi/4, so the loop ends fast
            x, y = warp_square(u1, u2, r)
            if x * x + y * y < r * r:
                return x, y
            u1 = next_double(s)
            u2 = next_double(s)
    return warp_polar(u1, u2, r)



@jit(inline="llvm")
def emit(kind, disk, b, s):
    """One incident ray: the unit vector toward its source, and whether it hits the front face.

    ``b`` is :meth:`Beam.kernel_args`. Returns ``(wx, wy, wz, hit)``.
    """
    if kind == BEAM_COLLIMATED:
        return b[B_AXIS_X], b[B_AXIS_Y], b[B_AXIS_Z], True
    x1, y1 = _disk(next_double(s), next_double(s), b[B_EMITTER_RADIUS], disk, s)
    x2, y2 = _disk(next_double(s), next_double(s), b[B_SPECIMEN_RADIUS], disk, s)
    return toward_source(b, x1, y1, x2, y2)



@jit(inline="llvm")
def toward_source(b, x1, y1, x2, y2):
    """Unit vector from the target (x2, y2, 0) to the emitter point R (x1, y1, D), and whether
    it arrives on the front face (the side the beam axis comes from)."""
    d = b[B_DISTANCE]
    ox = b[0] * x1 + b[1] * y1 + b[2] * d - x2
    oy = b[3] * x1 + b[4] * y1 + b[5] * d - y2
    oz = b[6] * x1 + b[7] * y1 + b[8] * d
    inv = 1.0 / math.sqrt(ox * ox + oy * oy + oz * oz)
    wx, wy, wz = ox * inv, oy * inv, oz * inv
    return wx, wy, wz, wz * b[B_AXIS_Z] > 0.0



@jit(inline="llvm")
def emit_given(kind, b, u1, u2, u3, u4):
    """:func:`emit` with both disks drawn by the polar warp from the given uniforms (none are
    read for a collimated beam): branch-free, for the vectorized block kernel."""
    x1, y1 = warp_polar(u1, u2, b[B_EMITTER_RADIUS])
    x2, y2 = warp_polar(u3, u4, b[B_SPECIMEN_RADIUS])
    wx, wy, wz, hit = toward_source(b, x1, y1, x2, y2)
    col = kind == BEAM_COLLIMATED
    return (b[B_AXIS_X] if col else wx), (b[B_AXIS_Y] if col else wy), (b[B_AXIS_Z] if col else wz), (True if col else hit)


@jit(inline="llvm")
def beam_tuple(beam_args):
    """The 15 values of :meth:`virtual.beam.Beam.kernel_args` as a tuple (of the array's float
    type): the block kernels pass it to their chunks, because LLVM must reload an array element
    every iteration of a loop that might write the array, and a tuple it keeps in registers."""
    return (beam_args[0], beam_args[1], beam_args[2], beam_args[3], beam_args[4], beam_args[5], beam_args[6],
            beam_args[7], beam_args[8], beam_args[9], beam_args[10], beam_args[11], beam_args[12], beam_args[13],
            beam_args[14])

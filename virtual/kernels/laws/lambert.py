"""Lambertian (:class:`virtual.specimens.diffuse.Lambertian`), params ``[R, T]``: absorbed with
probability 1 - R - T, else a cosine-distributed direction, on the source's side (reflected, u0
< R) or the other (transmitted).

Its direction does not depend on w, only its side does: the float32 block kernel emits only the
beam's side for it (``SIDE_ONLY``), and the ray-by-ray kernel inlines its ``ray`` (the commonest
and cheapest specimen; :func:`virtual.kernels.scatter.scatter`).
"""

from __future__ import annotations

from virtual.kernels import jit
from virtual.kernels.warps import sample_cosine_hemisphere
from virtual.kernels.xoshiro import next_double
from virtual.kernels.precision64 import ONE, ZERO, in_doubt, warp_cosine_hemisphere  # precision

MODEL = 0
TITLE = "Lambertian"
SPECIMEN = "virtual.specimens.diffuse"
UNIFORMS = 3
FLOAT32_LIMITS = ()
#: ``given`` reads only the sign of wz
SIDE_ONLY = True


@jit(inline="llvm")
def given(p, wx, wy, wz, u0, u1, u2):
    """Alive when u0 < R + T, reflected (the source's side) when u0 < R, the direction Malley's
    from (u1, u2)."""
    x, y, z = warp_cosine_hemisphere(u2, u1)
    up = (wz >= ZERO) != (u0 >= p[0])
    rt = p[0] + p[1]
    return x, y, (z if up else -z), u0 < rt, in_doubt(u0, p[0], ONE) | in_doubt(u0, rt, ONE)


@jit(inline="llvm")
def ray(p, wx, wy, wz, s):
    """The ray-by-ray sampler: survival first (an absorbed ray draws no direction), then Malley's
    direction on a rejection-sampled disk (float64 only)."""
    u = next_double(s)
    if u >= p[0] + p[1]:  # absorbed: no direction drawn
        return 0.0, 0.0, 0.0, False
    x, y, z = sample_cosine_hemisphere(s)
    up = (wz >= 0.0) != (u >= p[0])
    return x, y, (z if up else -z), u < p[0] + p[1]

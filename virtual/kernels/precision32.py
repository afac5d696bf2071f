"""The names a scattering law (:mod:`virtual.kernels.laws`) computes with, in float32: the
same names as :mod:`virtual.kernels.precision64`, bound to the float32 helpers of
:mod:`virtual.kernels.f32` (the twins in :mod:`virtual.kernels.laws32` import them).
"""

from __future__ import annotations

import math

from virtual.kernels import jit
from virtual.kernels.f32 import FOUR, HALF, ONE, TINY, TWO, ZERO, frame32, in_doubt32, sincos_2pi32, warp_cosine_hemisphere32

__all__ = ["ZERO", "ONE", "TWO", "FOUR", "HALF", "TINY", "sincos_2pi", "warp_cosine_hemisphere", "frame", "in_doubt", "lobe_cos_sin"]

sincos_2pi = sincos_2pi32
warp_cosine_hemisphere = warp_cosine_hemisphere32
frame = frame32
in_doubt = in_doubt32


@jit(inline="llvm")
def lobe_cos_sin(omc):
    """``(cos, sin)`` of an angle from its 1 - cos ``omc``: sin = sqrt(omc (2 - omc)), not
    sqrt((1 - cos)(1 + cos)), the cosine rounding to 1 in a narrow lobe."""
    return ONE - omc, math.sqrt(omc * (TWO - omc))

"""The names a scattering law (:mod:`virtual.kernels.laws`) computes with, in float64.

A law module imports its constants and helpers from here in one line; ``python -m
virtual.kernels.generate`` writes its float32 twin by importing the same names from
:mod:`virtual.kernels.precision32` instead. Both modules export the same names:

``ZERO, ONE, TWO, FOUR, HALF``  the constants (a float literal would turn a float32 loop into float64)
``TINY``  a positive floor for a denominator that may be 0 (1e-300 here, 1e-30 in float32)
``sincos_2pi``, ``warp_cosine_hemisphere``, ``frame``  the warps and the orthonormal frame
``lobe_cos_sin(x)``  the cosine and sine of a lobe's angle from a prepass's value ``x`` of its
                    cosine: the cosine itself here, 1 - cos in float32 (where a narrow lobe's
                    cosine rounds to 1)
``in_doubt(u, num, den)``  whether the decision ``u den < num`` lies within the float32 grid's
                          reach of its threshold (:func:`~virtual.kernels.f32.in_doubt32`);
                          float64 uniforms have no such grid: always False here, so the
                          float64 kernels' code for it folds away.
"""

from __future__ import annotations

import math

from virtual.kernels import jit
from virtual.kernels.microfacet import frame
from virtual.kernels.warps import sincos_2pi, warp_cosine_hemisphere

__all__ = ["ZERO", "ONE", "TWO", "FOUR", "HALF", "TINY", "sincos_2pi", "warp_cosine_hemisphere", "frame", "in_doubt", "lobe_cos_sin"]

ZERO = 0.0
ONE = 1.0
TWO = 2.0
FOUR = 4.0
HALF = 0.5
TINY = 1e-300


@jit(inline="llvm")
def in_doubt(u, num, den):
    """False: a float64 decision needs no second look (see the module docstring)."""
    return False


@jit(inline="llvm")
def lobe_cos_sin(x):
    """``(cos, sin)`` of an angle from its cosine ``x``."""
    return x, math.sqrt(max((1.0 - x) * (1.0 + x), 0.0))

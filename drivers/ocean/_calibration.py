"""Calibration maths of the Ocean driver (pure): the wavelength polynomial from the ``?x1..?x4``
coefficients and the non-linearity correction polynomial, with its plausibility check.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from bench.core.errors import CalibrationError

FULL_SCALE = 65535


def wavelength_polynomial(coeffs: Sequence[float], pixels: int) -> np.ndarray:
    """lambda(p) = c0 + c1 p + c2 p^2 + c3 p^3 for p = 0..pixels-1."""
    c = list(coeffs) + [0.0] * (4 - len(coeffs))
    p = np.arange(pixels, dtype=float)
    return c[0] + c[1] * p + c[2] * p**2 + c[3] * p**3


def nonlinearity_factor(coeffs: Sequence[float] | np.ndarray, counts: np.ndarray) -> np.ndarray:
    """sum_i k_i counts^i (Horner)."""
    x = np.asarray(counts, dtype=float)
    acc = np.zeros_like(x)
    for k in reversed(list(coeffs)):
        acc = acc * x + k
    return acc


def validate_nonlinearity(coeffs: Sequence[float],
                          bounds: tuple[float, float] = (0.5, 2.0)) -> np.ndarray:
    """Return the coefficients as an array, or raise :class:`CalibrationError`.

    Refused: no coefficients, a non-finite one, k0 == 0 (the stored "empty EEPROM" case that
    makes the correction infinite), or a polynomial that is <= 0 or leaves ``bounds`` anywhere
    on 0..65535 counts.
    """
    k = np.asarray(list(coeffs), dtype=float)
    if k.size == 0:
        raise CalibrationError("non-linearity correction: no coefficients stored")
    if not np.all(np.isfinite(k)):
        raise CalibrationError(f"non-linearity correction: non-finite coefficient(s) {k.tolist()}")
    if k[0] == 0.0:
        raise CalibrationError("non-linearity correction: k0 = 0 (empty or erased calibration); "
                               "the correction would divide by ~0")
    grid = np.linspace(0.0, FULL_SCALE, 4097)
    f = nonlinearity_factor(k, grid)
    if not np.all(np.isfinite(f)) or np.any(f <= 0):
        bad = grid[np.argmax(~np.isfinite(f) | (f <= 0))]
        raise CalibrationError(f"non-linearity correction: polynomial {k.tolist()} is <= 0 or "
                               f"not finite at {bad:.0f} counts")
    lo, hi = float(f.min()), float(f.max())
    if lo < bounds[0] or hi > bounds[1]:
        raise CalibrationError(f"non-linearity correction: polynomial {k.tolist()} ranges "
                               f"{lo:.4g}..{hi:.4g} over 0..65535 counts, outside the plausible "
                               f"{bounds[0]}..{bounds[1]}; refusing to apply it")
    return k

"""Pure codecs of the Ocean driver (no I/O): wavelength and non-linearity polynomials,
compressed pixel data, S-frame decoding, the version word and the frame checksums.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from bench.core.errors import CalibrationError, ChecksumError

ACK, NAK, STX, ETX, CR, LF = 0x06, 0x15, 0x02, 0x03, 0x0D, 0x0A
FULL_SCALE = 65535

def wavelength_polynomial(coeffs: Sequence[float], pixels: int) -> np.ndarray:
    """lambda(p) = c0 + c1 p + c2 p^2 + c3 p^3 for p = 0..pixels-1."""
    c = list(coeffs) + [0.0] * (4 - len(coeffs))
    p = np.arange(pixels, dtype=float)
    return c[0] + c[1] * p + c[2] * p**2 + c[3] * p**3


def nonlinearity_factor(coeffs: Sequence[float], counts: np.ndarray) -> np.ndarray:
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


def decode_compressed(data: bytes | bytearray, n: int, start: int = 0) -> tuple[np.ndarray, int]:
    """Decode ``n`` compressed pixel values from ``data[start:]``; return (values, end index).

    Raises
    ------
    ChecksumError
        If the data end before ``n`` values or a value leaves 0..65535.
    """
    out = np.empty(n, dtype=np.int64)
    i, prev = start, 0
    L = len(data)
    for j in range(n):
        if i >= L:
            raise ChecksumError(f"compressed pixel data ended after {j} of {n} pixels")
        b = data[i]
        if b == 0x80:
            if i + 2 >= L:
                raise ChecksumError(f"compressed pixel data ended inside the escape of pixel {j}")
            prev = data[i + 1] << 8 | data[i + 2]
            i += 3
        else:
            prev += b - 256 if b > 127 else b
            i += 1
            if not 0 <= prev <= FULL_SCALE:
                raise ChecksumError(f"compressed pixel data out of range at pixel {j}: {prev}")
        out[j] = prev
    return out, i


@dataclass
class _Frame:
    dwords: bool
    scans: int
    integration_ms: int
    baseline: int
    pixel_mode: int
    values: np.ndarray
    raw: bytes = field(repr=False, default=b"")

"""Positioning sensitivities of a calibrated reading from the bench description's specimen model.

An angle error ``d`` on an axis moves the detector (or source) while the record keeps the
read-back angle; the reading then changes by the model's slope along that axis. With the signal
``S ~ f(theta) cos(theta_r)`` and the calibration dividing by ``cos`` of the read-back
``theta_r``, the sensitivity (value per degree) is ``d/dtheta [f cos(theta_r)] / cos(theta_r)``,
a central difference of the specimen's BSDF (:meth:`virtual.specimens.Specimen.bsdf`). A
specimen without a density, or none declared, falls back on
:func:`bench.core.budget.cosine_slopes` (a Lambertian's slope).
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any, Mapping

import numpy as np

from bench.core.budget import AXES, cosine_slopes
from bench.core.errors import BenchError
from bench.core.geometry import Geometry

__all__ = ["model_slopes", "STEP_DEG"]

#: the central difference's half step (deg): small against any lobe a goniometer resolves
STEP_DEG = 0.05


def _specimen(description: Mapping[str, Any]) -> Any:
    spec = (description.get("specimen") or {}).get("spec")
    if not spec:
        return None
    from virtual.specimens import parse_specimen

    try:
        s = parse_specimen(spec)
    except BenchError:
        return None
    return s if s.has_density else None


def model_slopes(description: Mapping[str, Any], geometry: Geometry, wavelengths: np.ndarray,
                 values: np.ndarray) -> list[dict[str, float]]:
    """Per wavelength, the sensitivity of the calibrated value to each axis (value per degree);
    ``values`` (the calibrated readings) serve the fallback."""
    spec = _specimen(description)
    wl = np.asarray(wavelengths, dtype=float)
    if spec is None:
        return [cosine_slopes(float(v) if np.isfinite(v) else 0.0, geometry.theta_r) for v in values]
    cos_rep = abs(math.cos(math.radians(geometry.theta_r)))

    def signal(g: Geometry, w: float) -> float:
        f = float(np.asarray(spec.bsdf(g.incident, g.view[None, :], w), dtype=float).ravel()[0])
        return f * abs(math.cos(math.radians(g.theta_r)))

    out = []
    for w in wl:
        s: dict[str, float] = {}
        for axis in AXES:
            x = getattr(geometry, axis)
            x_lo = max(x - STEP_DEG, 0.0) if axis.startswith("theta") else x - STEP_DEG  # a zenith stays >= 0
            hi, lo = replace(geometry, **{axis: x + STEP_DEG}), replace(geometry, **{axis: x_lo})
            step = x + STEP_DEG - x_lo
            s[axis] = (signal(hi, float(w)) - signal(lo, float(w))) / step / cos_rep
        out.append(s)
    return out

"""Records: the tidy data every device, store, export and comparison shares.

:class:`Reading` is one detector acquisition, :class:`Spectrum` a spectrophotometric result,
:class:`BSDFRecord` a goniophotometric table; :func:`json_default` is the one JSON fallback for
their metadata.

A :class:`BSDFRecord` is a ``pandas.DataFrame`` with one row per (wavelength, incidence,
viewing patch or direction) and a metadata dict. Columns (angles in degrees):

=================  ============================================================================
wavelength_nm      wavelength
theta_i, phi_i     incidence (toward the source)
theta_r, phi_r     viewing direction (patch centre for a virtual collector)
hemisphere         ``"R"`` (reflection side) or ``"T"`` (transmission side)
value              BRDF or BTDF (1/sr)
std                standard uncertainty of ``value`` (1/sr)
ci_lo, ci_hi       interval at confidence ``1 - meta["delta"]`` (1/sr)
theta_min ...      patch bounds ``theta_min, theta_max, phi_min, phi_max`` (virtual collectors;
                   a physical detector gives its aperture instead)
psa                projected solid angle of the patch or aperture (sr)
count, N           rays in the patch and rays that reached the specimen (virtual)
=================  ============================================================================
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

__all__ = ["Reading", "Spectrum", "BSDFRecord", "BSDF_COLUMNS", "json_default"]

BSDF_COLUMNS = ["wavelength_nm", "theta_i", "phi_i", "theta_r", "phi_r", "hemisphere", "value", "std",
                "ci_lo", "ci_hi", "theta_min", "theta_max", "phi_min", "phi_max", "psa", "count", "N"]


def json_default(o: Any) -> Any:
    """``json.dumps`` fallback for record metadata: numpy scalars and arrays, sets and tuples,
    objects with ``as_dict``; anything else as its string."""
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (set, frozenset, tuple)):
        return list(o)
    if hasattr(o, "as_dict"):
        return o.as_dict()
    return str(o)


@dataclass(frozen=True)
class Reading:
    """One detector acquisition: signal per wavelength (counts, averaged over ``averages``).

    ``saturated`` flags pixels that hit full scale in any averaged scan (never calibrate them);
    ``dark`` says whether the light was off (a dark reading). ``std`` is the standard deviation
    of the mean per pixel when the device knows it.
    """

    wavelengths: np.ndarray
    signal: np.ndarray
    saturated: np.ndarray
    integration_s: float
    averages: int
    timestamp: float = field(default_factory=time.time)
    dark: bool = False
    std: np.ndarray | None = None


@dataclass(frozen=True)
class Spectrum:
    """Reflectance and/or transmittance per wavelength with two-sided confidence intervals.

    ``*_ci`` arrays have shape (n, 2) (lo, hi) at confidence ``1 - delta``; ``N`` is the number
    of rays per wavelength (virtual) or 0 for a physical measurement; ``seed`` the root seed.
    """

    geometry: str
    wavelengths: np.ndarray
    reflectance: np.ndarray
    transmittance: np.ndarray
    reflectance_ci: np.ndarray
    transmittance_ci: np.ndarray
    N: np.ndarray
    seed: int | None
    delta: float
    meta: Mapping[str, Any] = field(default_factory=dict)

    @property
    def absorptance(self) -> np.ndarray:
        return 1.0 - self.reflectance - self.transmittance


@dataclass
class BSDFRecord:
    """A goniophotometric record: ``table`` (pandas DataFrame, :data:`BSDF_COLUMNS`) and ``meta``."""

    table: Any
    meta: dict[str, Any] = field(default_factory=dict)

    def reflection(self) -> "BSDFRecord":
        return BSDFRecord(self.table[self.table.hemisphere == "R"].reset_index(drop=True), dict(self.meta))

    def transmission(self) -> "BSDFRecord":
        return BSDFRecord(self.table[self.table.hemisphere == "T"].reset_index(drop=True), dict(self.meta))

    def __len__(self) -> int:
        return len(self.table)

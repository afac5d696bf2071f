"""The detector a bench description declares (``[detector]``), for the emulated and virtual bodies alike.

One table says what the spectrometer's data sheet and calibration say; the emulated body starts
its spectrometer emulator with it (the real driver then reads the wavelength polynomial over the
wire, as from a real unit), and the virtual body reads through the same detector::

    [detector]
    pixels = 2048
    wavelength_coeffs = [339.0, 0.38, -1.5e-5, -1.0e-9]  # nm = c0 + c1 p + c2 p^2 + c3 p^3
    dark_counts = 1000.0          # dark level of one scan (counts)
    read_noise = 6.0              # read-out noise of one scan (counts, standard deviation)
    saturation_counts = 65535     # a scan at or above this reads full scale, flagged saturated
    integration_s = [0.001, 65.0] # shortest and longest integration the unit takes
    counts_per_ms = 1500.0        # counts per ms of a scan at reflected fraction 1 (lamp peak)

Without ``[detector]`` each body keeps its own detector (the emulator's defaults; the bare
virtual instrument, bit for bit). The band centres a description reports (``[bands]`` or
``[emulated] bands``) must lie on the detector; a plan's integration time within its limits
(:func:`check_integration`, refused before motion on every body).
"""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from bench.core.errors import ConfigError, PlanError
from bench.core.parsing import parse_wavelengths
from bench.core.schemas import Finite, Whole, validate_document

__all__ = ["DetectorTable", "detector_settings", "described_bands", "emulator_settings", "virtual_gain",
           "check_integration", "RESPONSE_GAIN", "FULL_SCALE"]

#: detector counts per unit of (BSDF x cos theta_r) per count of ``counts_per_ms``: the
#: emulated bench's optics (a 0.99 white at 45 deg gives ~45 % of full scale)
RESPONSE_GAIN = 2.0
#: what a 16-bit read-out reports at most (a saturated pixel reads this)
FULL_SCALE = 65535


class DetectorTable(BaseModel):
    """``[detector]``: the spectrometer's detector (defaults: the emulated unit's)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    pixels: Whole = Field(2048, ge=16, le=65536)
    wavelength_coeffs: list[Finite] = Field([339.0, 0.38, -1.5e-5, -1.0e-9], min_length=2, max_length=4)
    dark_counts: Finite = Field(1000.0, ge=0, le=FULL_SCALE)
    read_noise: Finite = Field(6.0, ge=0, le=FULL_SCALE)
    saturation_counts: Whole = Field(FULL_SCALE, ge=1, le=FULL_SCALE)
    integration_s: tuple[Finite, Finite] = (0.001, 65.0)
    counts_per_ms: Finite = Field(1500.0, gt=0, le=1e6)

    @model_validator(mode="after")
    def _ordered(self) -> "DetectorTable":
        lo, hi = self.integration_s
        if not 0 < lo <= hi <= 65.0:
            raise ValueError(f"integration_s = [{lo:g}, {hi:g}]: expected 0 < shortest <= longest <= 65 s")
        wl = self.wavelengths()
        if not np.all(np.diff(wl) > 0):
            raise ValueError(f"wavelength_coeffs {self.wavelength_coeffs}: wavelengths must rise with the pixel")
        return self

    def wavelengths(self) -> np.ndarray:
        """The pixels' wavelengths (nm) from the polynomial."""
        p = np.arange(self.pixels, dtype=float)
        return sum((c * p**k for k, c in enumerate(self.wavelength_coeffs)), np.zeros_like(p))


def detector_settings(d: Mapping[str, Any], source: str = "bench config") -> DetectorTable | None:
    """The validated ``[detector]`` of description ``d`` (one line naming the key), or None."""
    table = d.get("detector")
    return None if table is None else validate_document(DetectorTable, table, f"{source} [detector]")


def described_bands(d: Mapping[str, Any]) -> tuple[Any, float] | None:
    """The band centres and bandwidth (nm) description ``d`` reports: ``[bands]``, else
    ``[emulated] bands``, else None (the body's own). Checked against ``[detector]``."""
    bands, emulated = d.get("bands") or {}, d.get("emulated") or {}
    if "centres" in bands:
        found = (bands["centres"], float(bands.get("bandwidth_nm", 10.0)))
    elif "bands" in emulated:
        found = (emulated["bands"], float(emulated.get("bandwidth_nm", 10.0)))
    else:
        return None
    det = detector_settings(d)
    if det is not None:
        wl = det.wavelengths()
        for c in parse_wavelengths(found[0]):
            if not wl[0] <= c <= wl[-1]:
                raise ConfigError(f"bench config: band {c:g} nm is off the [detector] "
                                  f"({wl[0]:.1f}..{wl[-1]:.1f} nm from wavelength_coeffs)")
    return found


def emulator_settings(det: DetectorTable | None) -> dict[str, Any]:
    """The spectrometer emulator's settings (:class:`virtual.wire.ocean_model.SpectrometerConfig`
    fields) for the declared detector ({} without one: the emulator's defaults)."""
    if det is None:
        return {}
    return {"pixels": det.pixels, "wavelength_coeffs": tuple(det.wavelength_coeffs), "dark_counts": det.dark_counts,
            "read_noise": det.read_noise, "saturation_counts": det.saturation_counts,
            "peak_counts_per_ms": det.counts_per_ms}


def virtual_gain(det: DetectorTable) -> float:
    """The virtual goniophotometer's gain (counts per 1/sr per s) of the declared detector: the
    emulated optics at the lamp's peak."""
    return RESPONSE_GAIN * det.counts_per_ms * 1000.0


def check_integration(d: Mapping[str, Any], integration_s: float, what: str) -> None:
    """Refuse an integration time outside the declared detector's limits (before any motion)."""
    det = detector_settings(d)
    if det is None:
        return
    lo, hi = det.integration_s
    if not lo <= integration_s <= hi:
        raise PlanError(f"{what} integrates {integration_s:g} s; bench {d.get('name', 'bench')!r} [detector] "
                        f"takes {lo:g}..{hi:g} s (integration_s)")

"""Configuration of the Ocean spectrometer driver: per-model defaults (:data:`MODELS`) and
:class:`OceanConfig` (the keys of a bench-config ``[spectrometer]`` table), validated.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, Mapping

from bench.core.errors import ConfigError
from drivers.settings import settings_from_mapping

#: Per-model defaults: pixel count and the half-open index range of optically masked pixels
#: (electrical dark). Values as python-seabreeze uses them; confirm against the unit in hand.
MODELS: dict[str, dict[str, Any]] = {
    "USB2000+": {"pixels": 2048, "dark_pixels": (6, 21)},
    "FLAME-S": {"pixels": 2048, "dark_pixels": (6, 21)},
    "USB4000": {"pixels": 3648, "dark_pixels": (5, 16)},
    "EMU2000+": {"pixels": 2048, "dark_pixels": (6, 21)},
}


@dataclass(frozen=True)
class OceanConfig:
    """Settings of one spectrometer (keys of a bench-config table; all optional).

    Attributes
    ----------
    model : str
        Key of :data:`MODELS` (sets ``pixels`` and ``dark_pixels`` unless given).
    pixels : int or None
        Number of detector pixels.
    dark_pixels : (int, int) or None
        Half-open index range of the optically masked pixels.
    mode : str
        ``"binary"`` (default) or ``"ascii"``.
    checksum : bool
        Turn checksum mode on (k1) and verify every frame.
    compression : bool
        Turn data compression on (G1).
    trigger_mode : int
        0 free running (default), 1 software, 2 external level, 3 external sync, 4 external edge.
    accumulate_on_device : bool
        Average by the device's scans-to-add (one frame of dwords, no ``std``) instead of
        ``averages`` separate frames.
    subtract_electrical_dark : bool
        Subtract the per-scan mean of the masked pixels.
    nonlinearity : bool
        Apply the non-linearity correction from the calibration slots (opt-in).
    nonlinearity_bounds : (float, float)
        Allowed range of the correction polynomial over 0..65535 counts.
    wavelength_limits_nm : (float, float)
        Plausible wavelength span; a calibration outside it is refused.
    timeout_s : float
        Reply deadline of a command (the acquisition time and the line time are added for S).
    retries : int
        Extra attempts after a timeout or a corrupt reply (NAK/ETX never retry).
    baudrate : int
        Line rate (used for the transfer-time part of deadlines; a pty ignores it).
    dword_checksum : str
        Checksum of frames of 32-bit pixel values (scans to add > 1), which the public manual
        leaves open: ``"pixels"`` (sum of pixel values mod 65536), ``"words"`` (sum of all
        16-bit data words) or ``"auto"`` (default: accept either, detect and remember it on the
        first frame where they differ; ``describe()`` reports it).
    """

    model: str = "USB2000+"
    pixels: int | None = None
    dark_pixels: tuple[int, int] | None = None
    mode: str = "binary"
    checksum: bool = True
    compression: bool = False
    trigger_mode: int = 0
    accumulate_on_device: bool = False
    subtract_electrical_dark: bool = False
    nonlinearity: bool = False
    nonlinearity_bounds: tuple[float, float] = (0.5, 2.0)
    wavelength_limits_nm: tuple[float, float] = (150.0, 1200.0)
    timeout_s: float = 1.0
    retries: int = 2
    baudrate: int = 115200
    dword_checksum: str = "auto"

    def resolved(self) -> "OceanConfig":
        spec = MODELS.get(self.model.upper(), {})
        pixels = self.pixels if self.pixels is not None else spec.get("pixels")
        dark = self.dark_pixels if self.dark_pixels is not None else spec.get("dark_pixels")
        if pixels is None:
            raise ConfigError(f"unknown spectrometer model {self.model!r} (known: "
                              f"{', '.join(MODELS)}); give pixels= and dark_pixels=")
        cfg = replace(self, pixels=int(pixels),
                      dark_pixels=tuple(dark) if dark is not None else (0, 0))
        cfg.validate()
        return cfg

    def validate(self) -> None:
        def bad(msg: str) -> None:
            raise ConfigError(f"spectrometer config: {msg}")

        if self.mode not in ("binary", "ascii"):
            bad(f"mode must be 'binary' or 'ascii', got {self.mode!r}")
        if not (isinstance(self.pixels, int) and self.pixels > 0):
            bad(f"pixels must be a positive integer, got {self.pixels!r}")
        lo, hi = self.dark_pixels or (0, 0)
        if not 0 <= lo <= hi <= (self.pixels or 0):
            bad(f"dark_pixels {self.dark_pixels} is not a range inside 0..{self.pixels}")
        if self.subtract_electrical_dark and hi <= lo:
            bad("subtract_electrical_dark needs a non-empty dark_pixels range")
        if self.trigger_mode not in (0, 1, 2, 3, 4):
            bad(f"trigger_mode must be 0..4, got {self.trigger_mode!r}")
        if not (self.timeout_s > 0 and math.isfinite(self.timeout_s)):
            bad("timeout_s must be > 0")
        if self.dword_checksum not in ("auto", "pixels", "words"):
            bad(f"dword_checksum must be 'auto', 'pixels' or 'words', got {self.dword_checksum!r}")
        if self.retries < 0:
            bad("retries must be >= 0")
        b0, b1 = self.nonlinearity_bounds
        if not 0 < b0 < 1 < b1:
            bad(f"nonlinearity_bounds must satisfy 0 < lo < 1 < hi, got {self.nonlinearity_bounds}")

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "OceanConfig":
        return settings_from_mapping(cls, d, "spectrometer config",
                                     tuples=dict.fromkeys(("dark_pixels", "nonlinearity_bounds", "wavelength_limits_nm")))

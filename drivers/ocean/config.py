"""Configuration of the Ocean spectrometer driver: per-model defaults (:data:`MODELS`) and
:class:`OceanConfig` (the keys of a bench-config ``[spectrometer]`` table), validated.
"""

from __future__ import annotations

from typing import Annotated, Any, ClassVar, Literal

from pydantic import Field, StrictInt, field_validator

from bench.core.errors import ConfigError
from bench.core.validation import Finite, Settings

#: Per-model defaults: pixel count and the half-open index range of optically masked pixels
#: (electrical dark). Values as python-seabreeze uses them; confirm against the unit in hand.
MODELS: dict[str, dict[str, Any]] = {
    "USB2000+": {"pixels": 2048, "dark_pixels": (6, 21)},
    "FLAME-S": {"pixels": 2048, "dark_pixels": (6, 21)},
    "USB4000": {"pixels": 3648, "dark_pixels": (5, 16)},
    "EMU2000+": {"pixels": 2048, "dark_pixels": (6, 21)},
}


class OceanConfig(Settings):
    """Settings of one spectrometer (keys of a bench-config table; all optional), each declared
    once with its range (validated by pydantic, :class:`bench.core.schemas.Settings`).

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

    settings_of: ClassVar[str] = "spectrometer config"

    model: str = "USB2000+"
    pixels: Annotated[StrictInt, Field(gt=0)] | None = None
    dark_pixels: tuple[int, int] | None = None
    mode: Literal["binary", "ascii"] = "binary"
    checksum: bool = True
    compression: bool = False
    trigger_mode: Literal[0, 1, 2, 3, 4] = 0
    accumulate_on_device: bool = False
    subtract_electrical_dark: bool = False
    nonlinearity: bool = False
    nonlinearity_bounds: tuple[Finite, Finite] = (0.5, 2.0)
    wavelength_limits_nm: tuple[float, float] = (150.0, 1200.0)
    timeout_s: Annotated[Finite, Field(gt=0)] = 1.0
    retries: Annotated[int, Field(ge=0)] = 4  # at ~1 % faults a frame fails ~2 % of attempts: 5 make it ~3e-9
    baudrate: int = 115200
    dword_checksum: Literal["auto", "pixels", "words"] = "auto"

    @field_validator("nonlinearity_bounds")
    @classmethod
    def _around_one(cls, v: tuple[float, float]) -> tuple[float, float]:
        if not 0 < v[0] < 1 < v[1]:
            raise ValueError(f"expected 0 < lo < 1 < hi, got {v!r}")
        return v

    def resolved(self) -> "OceanConfig":
        """These settings with the model's pixel count and masked pixels filled in, checked
        against each other (the checks that need the model's table)."""
        spec = MODELS.get(self.model.upper(), {})
        pixels = self.pixels if self.pixels is not None else spec.get("pixels")
        dark = self.dark_pixels if self.dark_pixels is not None else spec.get("dark_pixels")
        if pixels is None:
            raise ConfigError(f"unknown spectrometer model {self.model!r} (known: "
                              f"{', '.join(MODELS)}); give pixels= and dark_pixels=")
        lo, hi = dark or (0, 0)
        if not 0 <= lo <= hi <= pixels:
            raise ConfigError(f"{self.settings_of}: dark_pixels {dark} is not a range inside 0..{pixels}")
        if self.subtract_electrical_dark and hi <= lo:
            raise ConfigError(f"{self.settings_of}: subtract_electrical_dark needs a non-empty dark_pixels range")
        return self.model_copy(update={"pixels": int(pixels), "dark_pixels": (lo, hi)})

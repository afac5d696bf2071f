"""The physics and settings of the Ocean spectrometer emulator.

Owns the response helpers (:func:`constant_response`, :func:`cosine_response`,
:func:`file_geometry_source`), :class:`SpectrometerConfig` (pixels, calibration slots),
:class:`Settings` (the device's state: mode, integration, scans, pixel mode, checksum, ...)
and :class:`SpectrometerModel` (counts from lamp x response x integration, dark, noise,
non-linearity, saturation at ``saturation_counts``).
"""

from __future__ import annotations

import importlib
import json
from dataclasses import dataclass, field

from bench.core.errors import ConfigError
from bench.core.parsing import json_problem
from typing import Any, Callable

import numpy as np

def constant_response(geometry: Any, wavelengths_nm: np.ndarray, factor: float = 0.5) -> np.ndarray:
    """The default signal model: the same reflected fraction at every wavelength."""
    return np.full(np.shape(wavelengths_nm), float(factor))


def cosine_response(geometry: Any, wavelengths_nm: np.ndarray, factor: float = 0.5) -> np.ndarray:
    """A Lambertian specimen seen by a fixed detector: ``factor * cos(theta_i)``.

    ``geometry`` is a mapping or object with ``theta_i`` in degrees (``None``: normal incidence).
    """
    if geometry is None:
        theta = 0.0
    elif isinstance(geometry, dict):
        theta = float(geometry.get("theta_i", 0.0))
    else:
        theta = float(getattr(geometry, "theta_i", 0.0))
    return np.full(np.shape(wavelengths_nm), float(factor) * max(np.cos(np.radians(theta)), 0.0))


def file_geometry_source(path: str) -> Any:
    """Read the current geometry from a JSON file (``None`` when it does not exist yet).

    A stand-in for a goniometer emulator publishing its joint angles: bind the path with
    ``functools.partial(file_geometry_source, path)``. A file caught half-written (not JSON yet)
    reads as ``None`` too; JSON no writer can mean (an integer longer than ``int()`` takes) is a
    :class:`ConfigError` naming the file.
    """
    try:
        with open(path, encoding="utf-8") as fh:
            return json.load(fh)
    except (FileNotFoundError, json.JSONDecodeError):
        return None
    except ValueError as exc:
        raise ConfigError(f"geometry file {path}: not JSON ({json_problem(exc)})") from None


def _resolve(spec: Any) -> Any:
    if isinstance(spec, str):
        mod, _, attr = spec.partition(":")
        obj: Any = importlib.import_module(mod)
        for part in attr.split("."):
            obj = getattr(obj, part)
        return obj
    return spec


@dataclass
class SpectrometerConfig:
    """Settings of the emulated unit.

    ``wavelength_coeffs`` are served from ``?x1..?x4``; ``nonlinearity_coeffs`` (k0..k7) from
    ``?x6..?x13`` and applied to the counts (``counts / sum k_i counts^i`` undoes it);
    ``dark_pixels`` is the half-open index range of masked pixels; ``time_scale`` > 1 makes
    acquisitions faster than real time; ``memory_pixels`` limits pixels x scans to add
    (beyond it S answers ETX).
    """

    model: str = "EMU2000+"
    serial: str = "EMU00001"
    firmware: str = "3.00.1"
    pixels: int = 2048
    dark_pixels: tuple[int, int] = (6, 21)
    wavelength_coeffs: tuple[float, ...] = (339.0, 0.38, -1.5e-5, -1.0e-9)
    nonlinearity_coeffs: tuple[float, ...] = (1.0, -1.0e-6, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    nonlinearity_order: int = 1
    extra_slots: dict[int, str] = field(default_factory=dict)
    lamp_temperature_k: float = 2856.0
    peak_counts_per_ms: float = 1500.0
    reflectance: float = 0.5
    dark_counts: float = 1000.0
    dark_counts_per_s: float = 200.0
    read_noise: float = 6.0
    #: a pixel whose counts reach this in a scan reads full scale (65535): its well is full
    saturation_counts: int = 65535
    counts_per_electron: float = 0.1
    seed: int | None = 12345
    time_scale: float = 1.0
    memory_pixels: int = 2048 * 5000
    #: command letters this unit does not have (NAKed; their data bytes are then taken as
    #: commands, as a real unit would), e.g. "G"
    unsupported: str = ""
    #: the mode the unit is in when the emulator starts (a unit left in ASCII mode: "ascii")
    start_mode: str = "binary"
    #: how this unit sums a DWORD frame's checksum: "pixels" or "words" (16-bit halves)
    dword_checksum: str = "pixels"

    def slot(self, n: int) -> str | None:
        if n in self.extra_slots:
            return self.extra_slots[n]
        if n == 0:
            return self.serial
        if 1 <= n <= 4:
            c = list(self.wavelength_coeffs) + [0.0] * 4
            return f"{c[n - 1]:.9e}"
        if n == 5:
            return "0.0"
        if 6 <= n <= 13:
            k = list(self.nonlinearity_coeffs) + [0.0] * 8
            return f"{k[n - 6]:.9e}"
        if n == 14:
            return str(self.nonlinearity_order)
        return None


@dataclass
class Settings:
    mode: str = "binary"
    integration_ms: int = 100
    scans: int = 1
    boxcar: int = 0
    compression: bool = False
    checksum: bool = False
    trigger: int = 0
    lamp: bool = True  # the lamp-enable line (J): on at power-up here, so a plain acquisition sees light
    baud_code: int = 6
    storage: int = 0
    pixel_mode: int = 0
    pixel_params: list[int] = field(default_factory=list)


class SpectrometerModel:
    """The physics and the frame builder (no I/O)."""

    def __init__(self, cfg: SpectrometerConfig, geometry_source: Any = None,
                 response: Any = None) -> None:
        self.cfg = cfg
        self.geometry_source: Callable[[], Any] | None = _resolve(geometry_source)
        self.response: Callable[[Any, np.ndarray], np.ndarray] | None = _resolve(response)
        p = np.arange(cfg.pixels, dtype=float)
        c = list(cfg.wavelength_coeffs) + [0.0] * 4
        self.wavelengths = c[0] + c[1] * p + c[2] * p**2 + c[3] * p**3
        self.rng = np.random.default_rng(cfg.seed)
        # lamp (Planck at lamp_temperature_k) x a detector responsivity bump, peak 1
        wl_m = np.clip(self.wavelengths, 100.0, None) * 1e-9
        planck = 1.0 / (wl_m**5 * (np.exp(1.4388e-2 / (wl_m * cfg.lamp_temperature_k)) - 1.0))
        qe = np.exp(-0.5 * ((self.wavelengths - 600.0) / 220.0) ** 2)
        lamp = planck * qe
        self.lamp = lamp / lamp.max()
        self.settings = Settings(mode=cfg.start_mode)
        self.last_geometry: Any = None
        k = np.asarray(cfg.nonlinearity_coeffs[: cfg.nonlinearity_order + 1], dtype=float)
        grid = np.linspace(0.0, 65535.0, 257)
        sane = k.size > 0 and np.all(np.isfinite(k)) and k[0] > 0
        if sane:
            f = _poly(k, grid)
            sane = bool(np.all(np.isfinite(f)) and f.min() > 0.5 and f.max() < 2.0)
        self._nl = k if sane else None

    def prepare(self) -> None:
        """Ask the response once without a geometry, before the first acquisition: a response that
        builds tables on first use (a specimen's) builds them now, not within a command's deadline."""
        if self.response is not None:
            self.response(None, self.wavelengths)

    def reset(self) -> None:
        mode = self.settings.mode
        self.settings = Settings(mode=mode)

    def fraction(self) -> np.ndarray:
        geom = self.geometry_source() if self.geometry_source is not None else None
        self.last_geometry = geom
        if self.response is not None:
            r = np.asarray(self.response(geom, self.wavelengths), dtype=float)
        else:
            r = constant_response(geom, self.wavelengths, self.cfg.reflectance)
        return np.broadcast_to(r, self.wavelengths.shape)

    def scan(self, fraction: np.ndarray) -> np.ndarray:
        """One scan of counts (int64, saturated at 65535)."""
        cfg, s = self.cfg, self.settings
        t_ms = s.integration_ms
        # J0 switches the lamp-enable line off: the detector then sees only its dark signal
        signal = self.lamp * fraction * cfg.peak_counts_per_ms * t_ms * float(s.lamp)
        lo, hi = cfg.dark_pixels
        signal = signal.copy()
        signal[lo:hi] = 0.0
        dark = cfg.dark_counts + cfg.dark_counts_per_s * t_ms / 1000.0
        shot = np.sqrt(np.maximum(signal, 0.0) * cfg.counts_per_electron)
        noise = self.rng.normal(0.0, 1.0, signal.shape) * np.sqrt(shot**2 + cfg.read_noise**2)
        true = np.maximum(signal + dark + noise, 0.0)
        # detector non-linearity: measured m with m / p(m) = true (p from the calibration
        # slots), solved by fixed-point iteration; nonsense coefficients (what a driver must
        # refuse) leave the emulated detector linear
        measured = true
        if self._nl is not None:
            for _ in range(8):
                measured = true * _poly(self._nl, measured)
        counts = np.clip(np.rint(measured), 0, 65535)
        return np.where(counts >= cfg.saturation_counts, 65535, counts).astype(np.int64)

    def selected_pixels(self) -> np.ndarray:
        s, n = self.settings, self.cfg.pixels
        m, prm = s.pixel_mode, s.pixel_params
        if m == 0:
            return np.arange(n)
        if m == 1:
            return np.arange(0, n, prm[0])
        if m == 3:
            return np.arange(prm[0], prm[1] + 1, prm[2])
        if m == 4:
            return np.asarray(prm[1:], dtype=int)
        if m == 5:
            idx = [np.arange(a, b + 1) for a, b in zip(prm[1::2], prm[2::2])]
            return np.concatenate(idx)
        raise ConfigError(f"pixel mode {m!r}: expected 0, 1, 3, 4 or 5")

    def acquire(self) -> np.ndarray:
        """Sum of ``scans`` scans over the selected pixels."""
        frac = self.fraction()
        total = np.zeros(self.cfg.pixels, dtype=np.int64)
        for _ in range(self.settings.scans):
            total += self.scan(frac)
        return total[self.selected_pixels()]


def _poly(k: np.ndarray, x: np.ndarray) -> np.ndarray:
    acc = np.zeros_like(np.asarray(x, dtype=float))
    for c in k[::-1]:
        acc = acc * x + c
    return acc

"""Spectral bands: a Spectrometer seen through a set of band centres and a bandwidth.

A 2048-pixel spectrometer is more than most scans need; a lab reports values in bands (e.g.
10 nm wide at 450, 550, 650 nm). :class:`SpectralBands` wraps any Spectrometer, averages the
pixels of each band (a rectangular bandpass), and reports the standard error of that mean.
Saturation of any pixel of a band flags the band. It fills the Spectrometer role itself.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from bench.core.errors import ConfigError
from bench.core.roles import InstrumentBase, InstrumentInfo, Reading, Spectrometer

__all__ = ["SpectralBands", "band_pixel_indices"]


def band_pixel_indices(pixel_nm: np.ndarray, centre_nm: float, bandwidth_nm: float) -> np.ndarray:
    """The indices of the pixels a band averages: those within ``centre +- bandwidth/2`` (nm).
    The one rule for reading a band and for predicting it (:mod:`bench.identify.prediction`)."""
    return np.flatnonzero(np.abs(np.asarray(pixel_nm, dtype=float) - centre_nm) <= bandwidth_nm / 2)


class SpectralBands(InstrumentBase):
    """Average a spectrometer's pixels over bands ``centre +- bandwidth/2`` (nm)."""

    def __init__(self, spectrometer: Spectrometer, centres_nm: Any, bandwidth_nm: float) -> None:
        self.inner = spectrometer
        self.centres = np.asarray(centres_nm, dtype=float)
        if not (math.isfinite(bandwidth_nm) and bandwidth_nm > 0):
            raise ConfigError(f"bandwidth_nm must be > 0, got {bandwidth_nm!r}")
        self.bandwidth = float(bandwidth_nm)
        wl = np.asarray(spectrometer.wavelengths, dtype=float)
        self._pixels = []
        for c in self.centres:
            idx = band_pixel_indices(wl, float(c), self.bandwidth)
            if idx.size == 0:
                raise ConfigError(f"band {c:g} +- {self.bandwidth / 2:g} nm holds no pixel of the "
                                  f"spectrometer ({wl[0]:.1f}..{wl[-1]:.1f} nm)")
            self._pixels.append(idx)

    @property
    def wavelengths(self) -> np.ndarray:
        return self.centres.copy()

    def describe(self) -> InstrumentInfo:
        inner = self.inner.describe()
        extra = dict(inner.extra)
        extra.update({"bands_nm": self.centres.tolist(), "bandwidth_nm": self.bandwidth,
                      "pixels_per_band": [int(p.size) for p in self._pixels]})
        return InstrumentInfo(kind=inner.kind, model=inner.model, serial=inner.serial, firmware=inner.firmware,
                              uncertainty=inner.uncertainty, ranges=dict(inner.ranges), extra=extra)

    def acquire(self, integration_s: float, averages: int = 1) -> Reading:
        r = self.inner.acquire(integration_s, averages)
        signal = np.array([r.signal[p].mean() for p in self._pixels])
        saturated = np.array([bool(r.saturated[p].any()) for p in self._pixels])
        if r.std is not None:
            std = np.array([math.sqrt(float(np.sum(np.asarray(r.std)[p] ** 2))) / p.size for p in self._pixels])
        else:  # shot-noise-like: counts/averages per pixel, averaged over the band
            std = np.array([math.sqrt(max(float(signal[i]), 1.0) / (max(r.averages, 1) * p.size))
                            for i, p in enumerate(self._pixels)])
        return Reading(wavelengths=self.centres.copy(), signal=signal, saturated=saturated,
                       integration_s=r.integration_s, averages=r.averages, timestamp=r.timestamp, dark=r.dark,
                       std=std)

    def close(self) -> None:
        self.inner.close()

"""What a bench body would read at a geometry, and how noisy, before anything is measured.

A design needs, for every candidate point, the calibrated BRDF a model predicts there and the
covariance of the reading the bench would give. The prediction is the specimen's density
(``Specimen.bsdf``, numpy, no kernel) averaged over the detector's aperture as the emulated
spectrometer and the virtual body read it (:func:`bench.identify.prediction.predicted_brdf`, the
fit's own prediction). The noise comes from the body's own declared noise model, pushed
through the calibration chain every run uses (:meth:`bench.core.calibration.Calibration.apply`)
on the expected readings:

* emulated body: the emulated spectrometer's detector (lamp spectrum, counts per ms, shot noise
  per electron, read noise, dark level: :class:`virtual.wire.ocean_model.SpectrometerConfig`)
  seen through the description's bands, with darks and the white as the plan takes them;
* virtual body: Monte Carlo counting (binomial in the collector patch of the viewing direction,
  ``rays`` per reading) plus the declared ``[instrument]`` read and shot noise;
* real body: the relative uncertainty per reading the plan estimator assumes
  (:func:`bench.plans.estimate`), for want of a declared detector.

Each reading's variance splits as the record's budgets split it (:meth:`ReadingModel.noise`): a part
of its own (signal), the dark's (one offset per dark and wavelength, shared by every reading that
dark corrects: with ``dark = "per-incidence"`` every reading of the incidence), and relative scales
shared by the record's readings (the white reading per wavelength, the white's certificate): the
design's Fisher information counts each shared part once, as the fit's covariance does.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, Mapping, Protocol, Sequence, cast

import numpy as np

from bench.config import Bench
from bench.core.calibration import Calibration, WhiteStandard
from bench.core.geometry import Geometry
from bench.core.parsing import parse_wavelengths
from bench.core.roles import Reading
from bench.identify.prediction import Band, band_pixels, predicted_brdf
from bench.identify.time_model import ReadingSettings

__all__ = ["ReadingModel", "NoiseParts", "bench_reading_model", "predicted_brdf", "SATURATION_MARGIN"]

#: a design avoids readings predicted above this fraction of the detector's full scale
SATURATION_MARGIN = 0.8


def _reading(signal: np.ndarray, std: np.ndarray, wavelengths: np.ndarray, settings: ReadingSettings,
             dark: bool = False) -> Reading:
    return Reading(wavelengths=wavelengths, signal=np.asarray(signal, dtype=float),
                   saturated=np.zeros(len(wavelengths), dtype=bool), integration_s=settings.integration_s,
                   averages=settings.averages, dark=dark, std=np.asarray(std, dtype=float))


@dataclass(frozen=True)
class ReadingModel:
    """Expected readings of one bench body: ``counts(f, cos_r)`` gives the expected signal and
    its standard deviation per wavelength for a BRDF ``f`` seen at ``cos(theta_r)``; darks read
    ``dark_level +- dark_std``; the white standard is read the same way."""

    body: str
    wavelengths: np.ndarray
    settings: ReadingSettings
    standard: WhiteStandard
    aperture_deg: float
    counts_per_brdf: np.ndarray  # expected net signal per unit of BRDF x cos(theta_r), per wavelength
    variance_per_count: np.ndarray  # signal variance per count of net signal (shot noise)
    variance_floor: np.ndarray  # signal variance of a reading with no light (read noise)
    dark_level: np.ndarray
    relative_floor: float = 0.0  # a relative uncertainty per reading (real body: the estimator's)
    #: a band saturates when its brightest pixel, dark included, would pass this many counts
    saturation: np.ndarray | None = None
    peak_ratio: np.ndarray | None = None  # brightest pixel / band mean, per band
    #: each band's averaged wavelengths and weights (:func:`bench.identify.prediction.band_pixels`;
    #: None: a reading at the wavelength itself)
    bands: tuple[Band, ...] | None = None

    def counts(self, brdf: np.ndarray, cos_r: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Expected signal, its standard deviation and whether it saturates, per wavelength."""
        net = self.counts_per_brdf * np.maximum(brdf, 0.0) * cos_r
        var = self.variance_per_count * net + self.variance_floor + (self.relative_floor * net) ** 2
        saturated = np.zeros(net.shape, dtype=bool)
        if self.saturation is not None and self.peak_ratio is not None:
            saturated = self.dark_level + net * self.peak_ratio >= self.saturation
        return self.dark_level + net, np.sqrt(var), saturated

    def _calibration(self, with_standard: bool, with_white_noise: bool) -> Calibration:
        rf = np.asarray(self.standard.rf(self.wavelengths), dtype=float)
        cos_w = abs(math.cos(math.radians(self.standard.geometry.theta_r)))
        signal, std, _ = self.counts(rf / math.pi, cos_w)
        if not with_white_noise:
            std = np.zeros_like(std)
        standard = self.standard if with_standard else replace(self.standard, uncertainty=0.0)
        dark = self._dark() if self.settings.dark != "none" else None
        if dark is not None and not with_white_noise:
            dark = replace(dark, std=np.zeros_like(dark.std))
        return Calibration(standard, _reading(signal, std, self.wavelengths, self.settings), dark)

    def _dark(self) -> Reading:
        return _reading(self.dark_level, np.sqrt(self.variance_floor), self.wavelengths, self.settings, dark=True)

    def noise(self, brdf: np.ndarray, geometries: Sequence[Geometry]) -> "NoiseParts":
        """Each reading's noise ``(points, wavelengths)`` split as the record's budgets split it
        (:mod:`bench.core.budget`): its own (signal), the dark's (an offset shared by every reading
        that dark corrects, per wavelength), and the relative scales shared by the record's readings
        (the white reading per wavelength, the white's certificate)."""
        alone = self._calibration(with_standard=False, with_white_noise=False)
        full = self._calibration(with_standard=True, with_white_noise=True)
        dark = self._dark() if self.settings.dark != "none" else None
        exact = replace(dark, std=np.zeros_like(dark.std)) if dark is not None else None
        own = np.empty(brdf.shape)
        with_dark = np.empty(brdf.shape)
        for k, g in enumerate(geometries):
            signal, std, saturated = self.counts(brdf[k], abs(math.cos(math.radians(g.theta_r))))
            r = replace(_reading(signal, std, self.wavelengths, self.settings), saturated=saturated)
            own[k] = alone.apply(r, g, exact).std
            with_dark[k] = alone.apply(r, g, dark).std
        ref, u_ref, _ = full.reference_rate()
        rf = np.asarray(self.standard.rf(self.wavelengths), dtype=float)
        with np.errstate(divide="ignore", invalid="ignore"):
            white = np.where(ref > 0, u_ref / ref, 0.0)
        return NoiseParts(own, np.sqrt(np.maximum(with_dark**2 - own**2, 0.0)), white, self.standard.uncertainty / rf)


@dataclass(frozen=True)
class NoiseParts:
    """The noise of calibrated readings ``(points, wavelengths)``, split by what shares it:
    ``own`` each reading's own standard deviation (NaN where the calibration masks it), ``dark``
    the BRDF a one-sigma error of the dark it was corrected with moves it by (shared by every
    reading of that dark and wavelength), ``white`` and ``certificate`` per wavelength the relative
    standard deviations of the white reading (shared by the record's readings of that wavelength)
    and of the white's certificate (shared by all)."""

    own: np.ndarray
    dark: np.ndarray
    white: np.ndarray
    certificate: np.ndarray


def _emulated_model(d: Mapping[str, Any], settings: ReadingSettings, standard: WhiteStandard) -> ReadingModel:
    from bench.builders.emulated import RESPONSE_GAIN
    from bench.builders.instrument import declared_aperture
    from drivers.ocean.codec import FULL_SCALE
    from virtual.wire.ocean_model import SpectrometerConfig, SpectrometerModel

    e = d.get("emulated") or {}
    cfg = SpectrometerConfig()  # the emulator's detector: the emulated builder configures no other
    detector = SpectrometerModel(cfg)
    centres = np.asarray(parse_wavelengths(e.get("bands", "450:650:100")), dtype=float)
    half = float(e.get("bandwidth_nm", 10.0)) / 2.0
    t_ms = round(settings.integration_s * 1000.0)
    per_count, per_var, floor, peak = [], [], [], []
    for c in centres:  # a band reads the mean of its pixels (bench.bands.SpectralBands)
        lamp = detector.lamp[np.abs(detector.wavelengths - c) <= half]
        n = lamp.size
        peak.append(float(lamp.max() / lamp.mean()))
        per_count.append(float(lamp.mean()) * cfg.peak_counts_per_ms * t_ms * RESPONSE_GAIN)
        # mean of n pixels x averages scans: shot (counts_per_electron x signal) and read noise
        per_var.append(cfg.counts_per_electron / (n * settings.averages))
        floor.append(cfg.read_noise**2 / (n * settings.averages))
    dark = cfg.dark_counts + cfg.dark_counts_per_s * t_ms / 1000.0
    # a band is flagged when any pixel of any scan reaches full scale: keep a margin for noise and
    # for a prior that is only a guess
    full = np.full(centres.size, SATURATION_MARGIN * FULL_SCALE)
    return ReadingModel("emulated", centres, settings, standard, declared_aperture(d),
                        np.array(per_count), np.array(per_var), np.array(floor), np.full(centres.size, dark),
                        saturation=full, peak_ratio=np.array(peak),
                        bands=band_pixels(centres, 2.0 * half, detector.wavelengths))


class _Patches(Protocol):
    psa: np.ndarray


class _MonteCarloDetector(Protocol):
    """What the reading model needs of a virtual bench's spectrometer: the virtual goniophotometer
    (:class:`virtual.goniophotometer.VirtualGoniophotometer`), seen through any declared effects'
    wrappers, which forward these attributes."""

    wavelengths: np.ndarray
    collector: _Patches
    gain: float
    rays: int


def _virtual_model(bench: Bench, settings: ReadingSettings, standard: WhiteStandard) -> ReadingModel:
    from bench.builders.instrument import declared_aperture, instrument_effects

    gonio = cast(_MonteCarloDetector, bench.spectrometer)  # the virtual goniophotometer (through any declared effects)
    wl = np.asarray(gonio.wavelengths, dtype=float)
    aperture = declared_aperture(bench.config)
    # binomial counting in a patch, or in the aperture's cone of solid angle 2 pi (1 - cos a):
    # var(f) ~ f / (rays psa) for f psa << 1
    psa = (2.0 * math.pi * (1.0 - math.cos(math.radians(aperture))) if aperture > 0
           else float(np.median(gonio.collector.psa)))
    scale = float(gonio.gain) * settings.integration_s  # signal per unit of BRDF x cos(theta_r)
    per_count = np.full(wl.size, scale / (float(gonio.rays) * psa))
    floor = np.zeros(wl.size)
    dark = np.zeros(wl.size)
    effects = instrument_effects(bench.config.get("instrument"))
    if effects is not None:
        per_count = per_count + (1.0 / settings.averages if effects.shot_noise else 0.0)
        floor = floor + effects.read_noise**2 / settings.averages
        dark = dark + effects.dark_counts
    return ReadingModel("virtual", wl, settings, standard, aperture, np.full(wl.size, scale), per_count, floor, dark)


def _real_model(bench: Bench, settings: ReadingSettings, standard: WhiteStandard) -> ReadingModel:
    from bench.builders.instrument import declared_aperture
    from bench.identify.time_model import plan_of_points
    from bench.plans import MotionProfile, estimate

    wl = np.asarray(bench.spectrometer.wavelengths, dtype=float)
    one_point = plan_of_points([Geometry(0.0, 0.0, 30.0, 180.0)], settings)
    rel = float(estimate(one_point, MotionProfile.instantaneous())["relative_uncertainty"])
    z = np.zeros(wl.size)
    return ReadingModel("real", wl, settings, standard, declared_aperture(bench.config), np.ones(wl.size), z, z, z,
                        relative_floor=rel)


def bench_reading_model(bench: Bench, settings: ReadingSettings) -> ReadingModel:
    """The reading model of an open bench, by the body that executes its description."""
    if bench.kind == "emulated":
        return _emulated_model(bench.config, settings, bench.white)
    if bench.kind == "virtual":
        return _virtual_model(bench, settings, bench.white)
    return _real_model(bench, settings, bench.white)

"""Instrument effects of the virtual body, each simulated only when the bench description declares
it (``[instrument]``; the mission: simulate only the effects a measurement calls for)::

    [instrument]
    dark_counts = 120.0          # detector offset added to every reading, lit or dark (counts)
    read_noise = 4.0             # read-out noise of one scan (counts, standard deviation)
    shot_noise = true            # Poisson statistics of the counts (averaged over the scans)
    lamp_drift = 0.001           # relative change of the lamp's output per lit reading
    positioning_error_deg = 0.05 # standard deviation of each angle the goniometer reaches
    aperture_deg = 2.0           # detector half-angle: the virtual detector counts the rays into this
                                 # cone (ApertureReading; declared_aperture says which table wins)
    seed = 11                    # the effects' random stream (default: 0)

A description without ``[instrument]`` (or with every effect at its default) gives the readings
of the bare virtual instrument, bit for bit. A declared ``[detector]``
(:mod:`bench.builders.detector`) is the detector of every body: its dark level and read noise
are then this table's ``dark_counts`` and ``read_noise`` (declare them in one of the two tables,
not both), and a scan at or above its ``saturation_counts`` reads full scale, flagged saturated.
The random stream is numpy's PCG64 from the seed, so results do not depend on the CPU. These
effects are the virtual body's; the emulators make their own noise (with ``[detector]``'s dark
level and read noise).
"""

from __future__ import annotations

import dataclasses
import logging
import math
from typing import Any, Mapping

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, StrictBool

from bench.builders.detector import FULL_SCALE, detector_settings
from bench.core.errors import ConfigError, InputError
from bench.core.geometry import Geometry, cone_cos_weights
from bench.core.roles import InstrumentInfo, Reading
from bench.core.schemas import EmulatedTable, Finite, Whole, validate_document

__all__ = ["InstrumentTable", "DetectorEffects", "EffectsSpectrometer", "PositioningError", "ApertureReading",
           "instrument_effects", "declared_effects", "declared_aperture"]

log = logging.getLogger(__name__)

#: the first spawn-key entry of the cone counts' streams (apart from the collector's simulations)
_CONE_STREAM = 0x636F6E65


class InstrumentTable(BaseModel):
    """``[instrument]``: the declared effects (all off by default)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    dark_counts: Finite = Field(0.0, ge=0, le=1e9)
    read_noise: Finite = Field(0.0, ge=0, le=1e9)
    shot_noise: StrictBool = False
    lamp_drift: Finite = Field(0.0, ge=-0.5, le=0.5)
    positioning_error_deg: Finite = Field(0.0, ge=0, le=10)
    #: half-angle (deg) of the detector's acceptance cone, solid angle 2 pi (1 - cos): the
    #: reading is the mean over the cone (by solid angle) of what a point detector would read
    aperture_deg: Finite = Field(0.0, ge=0, le=20)
    seed: Whole = Field(0, ge=0, lt=2**63)


def instrument_effects(table: Mapping[str, Any] | None, source: str = "bench config") -> InstrumentTable | None:
    """The validated ``[instrument]`` table, or None when it declares no effect."""
    if table is None:
        return None
    t = validate_document(InstrumentTable, table, f"{source} [instrument]")
    return t if _declares_any(t) else None


def _declares_any(t: InstrumentTable) -> bool:
    return any((t.dark_counts, t.read_noise, t.shot_noise, t.lamp_drift, t.positioning_error_deg, t.aperture_deg))


def declared_effects(d: Mapping[str, Any], source: str = "bench config") -> InstrumentTable | None:
    """The effects description ``d`` declares for the virtual body: ``[instrument]`` with the
    dark level and read noise of a declared ``[detector]``; None when it declares none."""
    det = detector_settings(d, source)
    table = dict(d.get("instrument") or {})
    if det is None:
        return instrument_effects(d.get("instrument"), source)
    for key in ("dark_counts", "read_noise"):
        if key in table:
            raise ConfigError(f"{source}: {key} is declared twice, in [instrument] and in [detector] "
                              f"(default {getattr(det, key):g}): keep the [detector] one")
        table[key] = getattr(det, key)
    t = validate_document(InstrumentTable, table, f"{source} [instrument]")
    return t if _declares_any(t) or det.saturation_counts < FULL_SCALE else None


def declared_aperture(d: Mapping[str, Any], source: str = "bench config") -> float:
    """The detector half-angle (deg) description ``d`` declares, for every body (0: none) -- the
    one answer the virtual body, the emulator, the fit and the design read:

    * ``[instrument] aperture_deg`` when declared (> 0): the lab's declaration of its detector,
      which wins over ``[emulated]``'s (the emulator then uses it too);
    * else ``[emulated] aperture_deg``, the aperture the emulator uses: when the table states it
      (as the emulated bench's twin, ``fixtures/benches/virtual.toml``, does), or by default
      (1 deg) for a description of a physical bench (``kind = "emulated"`` or ``"real"``);
    * else 0 (a virtual description: the detector is the collector patch of the viewing direction).
    """
    inst = validate_document(InstrumentTable, d.get("instrument") or {}, f"{source} [instrument]").aperture_deg
    emulated = d.get("emulated") or {}
    emu = validate_document(EmulatedTable, emulated, f"{source} [emulated]").aperture_deg
    if inst > 0:
        return float(inst)
    physical = str(d.get("kind", "virtual")) in ("emulated", "real")
    return float(emu) if physical or "aperture_deg" in emulated else 0.0


class DetectorEffects:
    """Turns a bare virtual reading into what the declared detector and lamp would give
    (``saturation``: a scan at or above it reads full scale, flagged; None: no limit)."""

    def __init__(self, effects: InstrumentTable, stream: int, saturation: float | None = None) -> None:
        self.effects = effects
        self.saturation = saturation
        self.rng = np.random.default_rng(np.random.SeedSequence(effects.seed, spawn_key=(stream,)))
        self.lit_readings = 0

    def apply(self, r: Reading) -> Reading:
        e = self.effects
        n = max(int(r.averages), 1)
        signal = np.asarray(r.signal, dtype=float).copy()
        var = np.zeros(signal.shape) if r.std is None else np.asarray(r.std, dtype=float) ** 2
        if not r.dark:
            if e.lamp_drift:
                signal *= 1.0 + e.lamp_drift * self.lit_readings
            self.lit_readings += 1
            if e.shot_noise:  # n scans of Poisson counts, averaged
                signal = self.rng.poisson(np.maximum(signal, 0.0) * n) / n
                var = var + np.maximum(signal, 0.0) / n
        if e.dark_counts:
            signal = signal + e.dark_counts
        if e.read_noise:
            signal = signal + self.rng.normal(0.0, e.read_noise / math.sqrt(n), signal.shape)
            var = var + e.read_noise**2 / n
        saturated = np.asarray(r.saturated, dtype=bool)
        if self.saturation is not None:
            full = signal >= self.saturation
            signal, saturated = np.where(full, float(FULL_SCALE), signal), saturated | full
        return dataclasses.replace(r, signal=signal, std=np.sqrt(var), saturated=saturated)


class EffectsSpectrometer:
    """The Spectrometer role of the virtual body with the declared detector effects."""

    def __init__(self, inner: Any, effects: DetectorEffects) -> None:
        self._inner = inner
        self.detector = effects

    def acquire(self, integration_s: float, averages: int = 1) -> Reading:
        return self.detector.apply(self._inner.acquire(integration_s, averages))

    def describe(self) -> InstrumentInfo:
        return self._inner.describe()

    def __getattr__(self, name: str) -> Any:  # wavelengths, close, seed, ... of the virtual instrument
        return getattr(self._inner, name)


class PositioningError:
    """The Goniometer role with a declared angular positioning error: each angle reached is the
    requested one plus a normal error (clamped to the hemispheres); the reading is taken there and
    ``move_to`` reports where it is, as a real arm's read-back does."""

    def __init__(self, inner: Any, effects: InstrumentTable) -> None:
        self._inner = inner
        self.sd = float(effects.positioning_error_deg)
        self.rng = np.random.default_rng(np.random.SeedSequence(effects.seed, spawn_key=(2,)))

    def check(self, geometry: Geometry) -> None:
        self._inner.check(geometry)

    def move_to(self, geometry: Geometry) -> Geometry:
        self.check(geometry)
        e = self.rng.normal(0.0, self.sd, 4)
        reached = Geometry(min(max(geometry.theta_i + e[0], 0.0), 89.999), geometry.phi_i + e[1],
                           min(max(geometry.theta_r + e[2], 0.0), 89.999), geometry.phi_r + e[3])
        return self._inner.move_to(reached)

    def describe(self) -> InstrumentInfo:
        return self._inner.describe()

    def __getattr__(self, name: str) -> Any:
        return getattr(self._inner, name)


class ApertureReading:
    """The Spectrometer role of a virtual goniophotometer ``inner`` whose detector is a cone of
    half-angle ``half_angle_deg`` around the viewing direction (the description's
    :func:`declared_aperture`), read as the emulated spectrometer reads it: per wavelength, the
    probability that a ray leaves into the cone is ``p = Omega mean_cone(f |cos theta|)``
    (``Omega = 2 pi (1 - cos a)``, the mean by :func:`~bench.core.geometry.cone_quadrature` of the
    specimen's density, directions on the far side of the specimen from the axis reading
    nothing), the count of ``N = inner.rays`` rays is ``Binomial(N, p)`` and the reading is
    ``gain t count / (N Omega)`` -- an unbiased estimate of ``gain t mean_cone(f cos)``, the
    emulator's ``RESPONSE_GAIN mean_cone(f cos)`` -- with the standard deviation
    ``gain t sqrt(p (1 - p) / N) / Omega`` at the observed ``p``, as the goniophotometer scales a
    patch count. Counts are drawn from numpy's PCG64 keyed by the instrument's seed, the
    geometry (millidegrees) and the wavelength (pm), so a repeated or resumed reading draws the
    same count on any CPU, as the collector's cached simulation does; a repeated trigger without
    a move in between (the k-th at the geometry, k > 0) adds k to the key, so repeated readings
    scatter as the reported standard deviation says, while a scan reading each point once draws
    what it always drew, whatever was read before. A specimen without a
    density (no ``has_density``) cannot be integrated over the cone: its reading stays the
    collector patch's, logged once and stated by :meth:`describe` (``detector_reads``)."""

    def __init__(self, inner: Any, half_angle_deg: float) -> None:
        self._inner = inner
        self.half_angle_deg = float(half_angle_deg)
        self.omega = 2.0 * math.pi * (1.0 - math.cos(math.radians(self.half_angle_deg)))
        #: (the goniometer's position since its last move, lit readings taken there): move_to sets a
        #: new position object, so a repeat is a trigger without a move in between
        self._repeat: tuple[Geometry, int] | None = None
        self.reads_cone = bool(getattr(inner.specimen, "has_density", False))
        if not self.reads_cone:
            log.info("detector aperture %g deg: specimen %s has no density, so the virtual detector reads the "
                     "collector patch of the viewing direction instead of the cone", self.half_angle_deg,
                     inner.specimen.label)

    def expected(self, geometry: Geometry, wavelengths: Any) -> np.ndarray:
        """``mean_cone(f |cos theta|)`` per wavelength: what a reading estimates, over ``gain t``."""
        dirs, w_cos = cone_cos_weights(geometry.view, self.half_angle_deg)
        wi = geometry.incident
        return np.array([float(w_cos @ np.asarray(self._inner.specimen.bsdf(wi, dirs, float(w)), dtype=float))
                         for w in np.asarray(wavelengths, dtype=float)])

    @staticmethod
    def _where(g: Geometry) -> tuple[int, ...]:
        return tuple(int(round((a % 360.0) * 1000)) for a in (g.theta_i, g.phi_i, g.theta_r, g.phi_r))

    def _stream(self, g: Geometry, wavelength_nm: float, repeat: int = 0) -> np.random.Generator:
        key = (_CONE_STREAM, *self._where(g), int(round(wavelength_nm * 1000)), *((repeat,) if repeat else ()))
        return np.random.default_rng(np.random.SeedSequence(int(self._inner.seed), spawn_key=key))

    def acquire(self, integration_s: float, averages: int = 1) -> Reading:
        if not self.reads_cone or not getattr(self._inner, "_light_on", True):
            return self._inner.acquire(integration_s, averages)  # the patch; or dark (zero)
        if not (isinstance(integration_s, (int, float)) and math.isfinite(integration_s) and integration_s > 0):
            raise InputError(f"integration_s must be finite and > 0, got {integration_s!r}")
        if not isinstance(averages, (int, np.integer)) or averages < 1:
            raise InputError(f"averages must be an integer >= 1, got {averages!r}")
        g = self._inner.position()
        wl = np.asarray(self._inner.wavelengths, dtype=float)
        p = np.clip(self.omega * self.expected(g, wl), 0.0, 1.0)
        n = int(self._inner.rays)
        repeat = self._repeat[1] if self._repeat is not None and self._repeat[0] is g else 0
        self._repeat = (g, repeat + 1)
        counts = np.array([self._stream(g, float(w), repeat).binomial(n, pk) for w, pk in zip(wl, p)], dtype=float)
        observed = counts / n
        scale = float(self._inner.gain) * float(integration_s) / self.omega
        return Reading(wavelengths=wl, signal=scale * observed, saturated=np.zeros(wl.size, dtype=bool),
                       integration_s=float(integration_s), averages=int(averages),
                       std=scale * np.sqrt(observed * (1.0 - observed) / n))

    def describe(self) -> InstrumentInfo:
        info = self._inner.describe()
        return dataclasses.replace(info, extra={**info.extra, "aperture_deg": self.half_angle_deg,
                                                "detector_reads": "cone" if self.reads_cone else "patch"})

    def __getattr__(self, name: str) -> Any:
        return getattr(self._inner, name)

"""Instrument effects of the virtual body, each simulated only when the bench description declares
it (``[instrument]``; the mission: simulate only the effects a measurement calls for)::

    [instrument]
    dark_counts = 120.0          # detector offset added to every reading, lit or dark (counts)
    read_noise = 4.0             # read-out noise of one scan (counts, standard deviation)
    shot_noise = true            # Poisson statistics of the counts (averaged over the scans)
    lamp_drift = 0.001           # relative change of the lamp's output per lit reading
    positioning_error_deg = 0.05 # standard deviation of each angle the goniometer reaches
    aperture_deg = 2.0           # detector half-angle: the reading averages the cone it sees
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
import math
from typing import Any, Mapping

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, StrictBool

from bench.builders.detector import FULL_SCALE, detector_settings
from bench.core.errors import ConfigError
from bench.core.geometry import Geometry, cone_quadrature, spherical
from bench.core.roles import InstrumentInfo, Reading
from bench.core.schemas import Finite, Whole, validate_document

__all__ = ["InstrumentTable", "DetectorEffects", "EffectsSpectrometer", "PositioningError", "ApertureReading",
           "instrument_effects", "declared_effects"]


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
    """The Spectrometer role of a virtual goniophotometer ``inner`` seen through a detector of
    finite aperture: the weighted mean of its readings at the directions of a
    :func:`~bench.core.geometry.cone_quadrature` around the current viewing direction (those
    below the horizon read nothing), each with its own ``cos theta_r``. The specimen is
    simulated once per incidence, so the directions cost no rays. Neighbouring directions may
    read one collector patch, so the standard deviations add linearly (an upper bound)."""

    def __init__(self, inner: Any, half_angle_deg: float) -> None:
        self._inner = inner
        self.half_angle_deg = float(half_angle_deg)

    def acquire(self, integration_s: float, averages: int = 1) -> Reading:
        g = self._inner.position()
        dirs, weights = cone_quadrature(g.view, self.half_angle_deg)
        signal, std, first = 0.0, 0.0, None
        try:
            for d, w in zip(dirs, weights):
                theta, phi = spherical(d)
                if theta >= 90.0:
                    continue
                self._inner.move_to(Geometry(g.theta_i, g.phi_i, theta, phi))
                r = self._inner.acquire(integration_s, averages)
                first = first or r
                signal = signal + w * np.asarray(r.signal, dtype=float)
                std = std + w * np.asarray(r.std if r.std is not None else 0.0, dtype=float)
        finally:
            self._inner.move_to(g)
        if first is None:  # the whole cone below the horizon
            return self._inner.acquire(integration_s, averages)
        return dataclasses.replace(first, signal=np.asarray(signal, dtype=float), std=np.asarray(std, dtype=float))

    def describe(self) -> InstrumentInfo:
        return self._inner.describe()

    def __getattr__(self, name: str) -> Any:
        return getattr(self._inner, name)

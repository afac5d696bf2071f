"""Instrument effects of the virtual body, each simulated only when the bench description declares
it (``[instrument]``; the mission: simulate only the effects a measurement calls for)::

    [instrument]
    dark_counts = 120.0          # detector offset added to every reading, lit or dark (counts)
    read_noise = 4.0             # read-out noise of one scan (counts, standard deviation)
    shot_noise = true            # Poisson statistics of the counts (averaged over the scans)
    lamp_drift = 0.001           # relative change of the lamp's output per lit reading
    positioning_error_deg = 0.05 # standard deviation of each angle the goniometer reaches
    seed = 11                    # the effects' random stream (default: 0)

A description without ``[instrument]`` (or with every effect at its default) gives the readings
of the bare virtual instrument, bit for bit. The random stream is numpy's PCG64 from the seed, so
results do not depend on the CPU. The emulated and real bodies have their own detector.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Mapping

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, StrictBool

from bench.core.geometry import Geometry
from bench.core.roles import InstrumentInfo, Reading
from bench.core.schemas import Finite, Whole, validate_document

__all__ = ["InstrumentTable", "DetectorEffects", "EffectsSpectrometer", "PositioningError", "instrument_effects"]


class InstrumentTable(BaseModel):
    """``[instrument]``: the declared effects (all off by default)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    dark_counts: Finite = Field(0.0, ge=0, le=1e9)
    read_noise: Finite = Field(0.0, ge=0, le=1e9)
    shot_noise: StrictBool = False
    lamp_drift: Finite = Field(0.0, ge=-0.5, le=0.5)
    positioning_error_deg: Finite = Field(0.0, ge=0, le=10)
    seed: Whole = Field(0, ge=0, lt=2**63)


def instrument_effects(table: Mapping[str, Any] | None, source: str = "bench config") -> InstrumentTable | None:
    """The validated ``[instrument]`` table, or None when it declares no effect."""
    if table is None:
        return None
    t = validate_document(InstrumentTable, table, f"{source} [instrument]")
    declared = (t.dark_counts, t.read_noise, t.shot_noise, t.lamp_drift, t.positioning_error_deg)
    return t if any(declared) else None


class DetectorEffects:
    """Turns a bare virtual reading into what the declared detector and lamp would give."""

    def __init__(self, effects: InstrumentTable, stream: int) -> None:
        self.effects = effects
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
        return dataclasses.replace(r, signal=signal, std=np.sqrt(var))


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

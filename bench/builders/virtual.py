"""The virtual bench (``kind = "virtual"``): a virtual goniophotometer in every role, and a virtual
white standard measured by a second one. Its detector reads the cone of the aperture the
description declares (:func:`bench.builders.instrument.declared_aperture`: rays counted into the
cone, as the emulated spectrometer averages it), else the collector patch of the viewing direction."""

from __future__ import annotations

import dataclasses
from typing import Any, Mapping

from bench.builders.detector import described_bands, detector_settings, virtual_gain
from bench.builders.drift import actual_white
from bench.builders.instrument import (ApertureReading, DetectorEffects, EffectsSpectrometer, PositioningError,
                                      declared_aperture, declared_effects)
from bench.builders.light import declares_light
from bench.config import Bench
from bench.core.calibration import WhiteStandard
from bench.core.errors import ConfigError
from bench.core.roles import Reading
from virtual.goniophotometer import VirtualGoniophotometer
from virtual.specimens import Lambertian

__all__ = ["build_virtual_bench"]

_VIRTUAL_KEYS = {"collector", "rays", "uncertainty", "delta", "beam", "wavelengths", "method", "gain"}


def build_virtual_bench(d: Mapping[str, Any], seed: int | None = None) -> Bench:
    """Build from a bench config dict (see :mod:`bench.config`). The white standard is measured
    by a second virtual goniophotometer holding a Lambertian of the standard's reflectance
    factor, with the same collector, rays and seed (its streams are keyed apart by specimen)."""
    spec = d.get("specimen", {}).get("spec")
    if not spec:
        raise ConfigError("virtual bench: [specimen] spec = \"...\" is required")
    v = dict(d.get("virtual", {}))
    unknown = set(v) - _VIRTUAL_KEYS
    if unknown:
        raise ConfigError(f"virtual bench: unknown [virtual] key(s) {sorted(unknown)}; known: {sorted(_VIRTUAL_KEYS)}")
    bands = described_bands(d)  # checked against a declared [detector]
    if "virtual" not in d and bands is not None:  # the virtual body of an emulated or real description
        v["wavelengths"] = bands[0]
    det = detector_settings(d)
    if det is not None and "gain" not in v:  # the declared detector's response
        v["gain"] = virtual_gain(det)
    if seed is not None:
        v["seed"] = seed
    elif "seed" in d:
        v["seed"] = int(d["seed"])
    gonio = VirtualGoniophotometer(spec, **v)
    white = WhiteStandard.from_dict(d.get("white", {}))
    v["seed"] = gonio.seed + 1  # the standard's rays are independent of the specimen's
    rf = actual_white(white.reflectance_factor, d)  # the certificate's, unless a declared [drift] soils it
    standard = VirtualGoniophotometer(Lambertian.from_keywords({"reflectance": rf}),  # a number or a spectrum
                                      **{**v, "method": v.get("method", "auto")})
    # A lab measures its standard with care: the reference is one reading every point divides
    # by, so its noise would be common to the whole record. With the exact fast path a
    # thousand times the rays cost nothing; counting rays, ten times.
    standard.rays = gonio.rays * (1000 if standard.uses_fast_path() else 10)

    effects = declared_effects(d)  # declared effects only; none: the bare instrument
    if effects is not None and seed is not None:  # the run's seed governs the detector's noise too
        effects = effects.model_copy(update={"seed": int(seed)})
    saturation = float(det.saturation_counts) if det is not None else None
    detector = DetectorEffects(effects, stream=1, saturation=saturation) if effects is not None else None
    aperture = declared_aperture(d)  # the detector's cone (0: the collector patch of the viewing direction)
    seen: Any = ApertureReading(gonio, aperture) if aperture > 0 else gonio
    white_seen: Any = ApertureReading(standard, aperture) if aperture > 0 else standard
    spectrometer: Any = EffectsSpectrometer(seen, detector) if detector is not None else seen

    def measure_whites(integration_s: float, averages: int, repeats: int) -> list[Reading]:
        # a new position each time the standard is mounted: its first reading is not a repeated
        # trigger of the last white's (bench.builders.instrument.ApertureReading), so a white reads
        # the same whichever whites came before it (a rerun of a failed step as if uninterrupted)
        standard.move_to(dataclasses.replace(white.geometry))
        out = []
        for _ in range(repeats):  # each a lit reading: the lamp drifts between them as between points
            reading = white_seen.acquire(integration_s, averages)
            out.append(detector.apply(reading) if detector is not None else reading)  # the same detector reads it
        return out

    def measure_white(integration_s: float, averages: int) -> Reading:
        return measure_whites(integration_s, averages, 1)[0]

    goniometer: Any = gonio
    motion = joints = None
    if str(d.get("kind", "virtual")) != "virtual" or "arm" in d or "emulated" in d:  # a physical bench's rules
        from bench.builders.twin import KinematicGoniometer, physical_rules

        rules = physical_rules(d)
        if rules is not None:
            goniometer, motion, joints = KinematicGoniometer(gonio, rules.kinematics), rules.motion, rules.joints
    if effects is not None and effects.positioning_error_deg > 0:
        goniometer = PositioningError(goniometer, effects)
    return Bench(name=str(d.get("name", "virtual")), kind="virtual", goniometer=goniometer, spectrometer=spectrometer,
                 light=gonio if declares_light(d) else None, white=white, measure_white=measure_white,
                 measure_whites=measure_whites, config=dict(d),
                 motion=motion, joints=joints, closers=[gonio.close, standard.close])


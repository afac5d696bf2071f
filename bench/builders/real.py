"""The real bench (``kind = "real"``): the drivers of :mod:`drivers` on the ports a config names.

Config::

    [arm]            # drivers.dynamixel ArmConfig keys, with port = "/dev/ttyUSB0"
    [turntable]      # optional: drivers.modbus AxisConfig keys, port = "/dev/ttyUSB1" or "tcp://host:port"
    [spectrometer]   # drivers.ocean OceanConfig keys, with port
    [bands]          # optional: centres = "450:650:100", bandwidth_nm = 10
    [light]          # optional: kind = "spectrometer-lamp" (bench.builders.light): darks need it
    [detector]       # optional: the unit's detector (bench.builders.detector): integration limits
    [white]          # the standard the operator mounts when a run asks for it, or
                     #   reference_file = "white-2026-11-30.csv" (bench white): no operator needed

``bench emulate`` prints such a config for a bench's emulators.
"""

from __future__ import annotations

import logging
import sys
from typing import Any, Mapping

from bench.bands import SpectralBands
from bench.builders.detector import described_bands
from bench.builders.light import build_light, light_settings
from bench.builders.motion import motion_profile
from bench.builders.ownership import lock_devices
from bench.config import Bench
from bench.core.calibration import WhiteStandard
from bench.core.errors import CalibrationRefused, ConfigError
from bench.core.parsing import parse_wavelengths
from bench.core.roles import Reading
from drivers.dynamixel import DynamixelArm
from drivers.kinematics import geometry_to_joints
from drivers.modbus import ModbusStageAxis
from drivers.ocean import OceanSpectrometer

log = logging.getLogger(__name__)

__all__ = ["build_real_bench"]


def build_real_bench(d: Mapping[str, Any], seed: int | None = None) -> Bench:
    """Real hardware: ``[arm]`` (with ``port``), optional ``[turntable]`` (``port`` or
    ``tcp://host:port``; the arm then lists ``external = ["turntable"]``), ``[spectrometer]``
    (``port``), ``[bands]`` (``centres``, ``bandwidth_nm``). The white standard is mounted by the
    operator when the run asks for it (interactive runs only)."""
    for table in ("arm", "spectrometer"):
        if "port" not in d.get(table, {}):
            raise ConfigError(f"real bench: [{table}] port = \"...\" is required")
    if seed is not None:  # nothing here draws noise: say so rather than record a seed that governs nothing
        log.warning("seed %d is recorded with the run; bench %r is hardware: its noise is its own", seed,
                    str(d.get("name", "real")))
    motion = motion_profile(d.get("arm"), d.get("turntable"))  # from the config, before any port opens
    described_bands(d)  # bands on the declared [detector], before any port opens
    lamp = light_settings(d.get("light"))
    # one owner per device: locked before any port opens (a second process is refused, exit 2)
    locks = lock_devices({"arm": d["arm"]["port"], "turntable": d.get("turntable", {}).get("port"),
                          "spectrometer": d["spectrometer"]["port"]})
    closers: list[Any] = [locks.release]
    try:
        external = {}
        if "turntable" in d:
            t = dict(d["turntable"])
            external["turntable"] = ModbusStageAxis(str(t.pop("port")), config=t, name="turntable")
            closers.append(external["turntable"].close)
            external["turntable"].establish()
        arm = DynamixelArm(dict(d["arm"]), external_axes=external)
        closers.append(arm.close)
        ocean = OceanSpectrometer.from_config(d["spectrometer"])
        closers.append(ocean.close)
        b = d.get("bands")
        spectrometer = SpectralBands(ocean, parse_wavelengths(b["centres"]), float(b.get("bandwidth_nm", 10))) \
            if b else ocean
        light = build_light(lamp, ocean)
    except BaseException:
        for c in reversed(closers):
            c()
        raise
    white = WhiteStandard.from_dict(d.get("white", {}))

    def measure_whites(integration_s: float, averages: int, repeats: int) -> list[Reading]:
        confirmed = bench.operator_confirmed
        if not confirmed and not sys.stdin.isatty():
            raise CalibrationRefused(
                f"white reference: bench {bench.name!r} needs the operator to mount the standard and no one "
                "can confirm it (no terminal): mount it and run `bench white --bench B --out FILE --yes`, then "
                "name FILE in [white] reference_file; or use white = \"none\" in the plan")
        arm.move_to(white.geometry)
        if confirmed:
            log.info("white standard %s: mounted, as the operator confirmed (--yes); %d reading(s)", white.name,
                     repeats)
            return [spectrometer.acquire(integration_s, averages) for _ in range(repeats)]
        input(f"Mount the white standard ({white.name}) and press Enter... ")  # once, for every repeat
        try:
            return [spectrometer.acquire(integration_s, averages) for _ in range(repeats)]
        finally:
            input("Mount the specimen again and press Enter... ")

    def measure_white(integration_s: float, averages: int) -> Reading:
        return measure_whites(integration_s, averages, 1)[0]

    kin = arm.config.kinematics
    bench = Bench(name=str(d.get("name", "real")), kind="real", goniometer=arm, spectrometer=spectrometer,
                  white=white, measure_white=measure_white, measure_whites=measure_whites, light=light,
                  motion=motion, white_needs_operator=True,
                  joints=lambda g: geometry_to_joints(g, kin).as_dict(), config=dict(d), closers=closers,
                  parts={"arm": arm, "spectrometer": ocean, **external})
    return bench


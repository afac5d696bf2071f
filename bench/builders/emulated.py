"""The emulated bench: the real drivers talking to wire-level emulators (``kind = "emulated"``).

``kind = "emulated"`` starts three emulator processes -- a Dynamixel bus on a pseudo-terminal
(source arm, detector azimuth, detector elevation), an AZ stage on Modbus TCP at 127.0.0.1 (the
specimen turntable) and an RS-232 spectrometer on a pseudo-terminal -- and connects the real
drivers (dynamixel-sdk, pymodbus, pyserial) to them. The spectrometer emulator's physics comes
from the virtual specimen: at each acquisition it asks the bus and the stage where the arms are
(over their wire protocols), and its counts follow the specimen's BSDF averaged over the
detector aperture, times ``cos(theta_r)``, times the lamp spectrum, plus dark and noise.

The white standard is "mounted" by writing a small mount file the emulator reads; a real bench
asks the operator instead (:mod:`bench.builders.real`). This module is application glue: it
imports both ``drivers`` and ``virtual``, which never import each other.

Config (beside ``[specimen]`` and ``[white]``, see :mod:`bench.config`)::

    [emulated]
    time_scale = 20          # emulated motion runs 20x faster than the real drives would
    bands = "450:650:100"    # band centres (nm) reported per point
    bandwidth_nm = 10
    aperture_deg = 1.0       # detector half-angle (an [instrument] aperture_deg is the same declaration:
                             # bench.builders.instrument.declared_aperture, read by every body)
    seed = 7                 # emulator noise (a run's --seed wins)
    [arm]                    # drivers.dynamixel ArmConfig keys (optional overrides)
    [turntable]              # drivers.modbus AxisConfig keys
    [spectrometer]           # drivers.ocean OceanConfig keys
"""

from __future__ import annotations

import functools
import json
import logging
import math
import os
import tempfile
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from pymodbus.client import ModbusTcpClient

from bench.bands import SpectralBands
from bench.config import Bench
from bench.core.calibration import WhiteStandard
from bench.core.errors import ConfigError
from bench.core.geometry import Geometry, cone_cos_weights
from bench.core.parsing import parse_wavelengths
from bench.core.schemas import EmulatedTable
from bench.core.roles import Reading
from bench.builders.detector import RESPONSE_GAIN, described_bands, detector_settings, emulator_settings
from bench.builders.drift import actual_white
from bench.builders.instrument import declared_aperture
from bench.builders.light import LAMP_LINE, LampLine, LightTable, build_light, declares_light, light_settings
from bench.builders.motion import motion_profile
from bench.builders.ownership import lock_devices
from drivers.dynamixel import ArmConfig, DynamixelArm
from drivers.kinematics import Joints, geometry_to_joints, joints_to_geometry
from drivers.modbus import ModbusStageAxis
from drivers.ocean import OceanSpectrometer
from drivers.registers import load_register_map
from virtual.specimens import Specimen, parse_specimen, weighted_spectrum
from virtual.wire.dynamixel_bus import BusControl, start_bus
from virtual.wire.modbus_stage import StageEmulator
from virtual.wire.ocean_spectrometer import SpectrometerEmulator

log = logging.getLogger(__name__)

__all__ = ["build_emulated_bench", "Emulators", "DEFAULT_EMULATED_CONFIG", "emulated_geometry",
           "emulated_response", "LampLine", "ARM_IDS", "emulated_arm_config", "emulated_turntable_config",
           "emulated_motion"]

#: servo ids of the arm joints on the emulated bus (the turntable is on the Modbus stage)
ARM_IDS = {"source": 1, "detector_azimuth": 2, "detector_elevation": 3}
STEPS_PER_REV = 1000
TURNTABLE_GEAR = 18.0


#: The embedded emulated bench (fixtures/benches/emulated.toml says the same; a test checks it).
DEFAULT_EMULATED_CONFIG: dict[str, Any] = {
    "name": "emulated", "kind": "emulated",
    "specimen": {"spec": "lambert:albedo=0.8"},
    "white": {"reflectance_factor": 0.99, "uncertainty": 0.005, "geometry": [0, 0, 45, 180]},
    "emulated": {"time_scale": 50, "bands": "450:650:100", "bandwidth_nm": 10, "aperture_deg": 1.0, "seed": 7},
    "spectrometer": {"nonlinearity": True},  # the emulated detector is non-linear; a lab corrects it
}


# --- physics inside the spectrometer emulator process ------------------------------------------------

_PROCESS_CACHE: dict[str, Any] = {}


def emulated_geometry(bus_control: str, stage_url: str, steps_per_deg: float,
                      register_map: str = "oriental_az") -> Any:
    """Where the emulated arms are, asked over the wire: joint angles from the bus emulator's
    control channel, the turntable from the stage's ``feedback_position`` register (Modbus TCP),
    whose address and word order come from the driver's register map ``register_map``
    (:mod:`drivers.registers`). Runs inside the spectrometer emulator process."""
    rmap = _PROCESS_CACHE.get(f"rmap:{register_map}")
    if rmap is None:
        rmap = _PROCESS_CACHE[f"rmap:{register_map}"] = load_register_map(register_map)
    bus = _PROCESS_CACHE.get("bus")
    if bus is None:
        bus = _PROCESS_CACHE["bus"] = BusControl(bus_control)
    client = _PROCESS_CACHE.get("stage")
    if client is None:
        host, port = stage_url.removeprefix("tcp://").rsplit(":", 1)
        client = _PROCESS_CACHE["stage"] = ModbusTcpClient(host, port=int(port), timeout=1.0)
        client.connect()
    j = bus.joints()
    rr = client.read_holding_registers(rmap.addr("feedback_position"), count=2, device_id=1)
    steps = rmap.from_words(list(rr.registers))
    turntable = steps / steps_per_deg
    clamp = lambda v: min(180.0, max(0.0, v))  # noqa: E731 - read-back noise at the poles
    return joints_to_geometry(Joints(turntable, clamp(j["source"]), j["detector_azimuth"],
                                     clamp(j["detector_elevation"])))


def _white_fraction(white_rf: Any, wl: np.ndarray) -> np.ndarray:
    """The white standard's BRDF (1/sr) per wavelength from its certificate: a number, or
    ``[[nm...], [factor...]]`` interpolated (held at the end values outside the certificate)."""
    if isinstance(white_rf, (int, float)):
        return np.full(wl.shape, float(white_rf) / math.pi)
    cert_wl, cert_rf = (np.asarray(a, dtype=float) for a in white_rf)
    return np.interp(wl, cert_wl, cert_rf) / math.pi


def emulated_response(geometry: Any, wavelengths_nm: np.ndarray, specimen: str, white_rf: Any,
                      mount_file: str, aperture_deg: float) -> np.ndarray:
    """Reflected fraction the emulated detector sees: ``GAIN * mean_aperture(f cos(theta_r))``
    for the mounted specimen (the virtual specimen, or a Lambertian white standard of the
    certificate's reflectance factor, ``white_rf``: a number or ``[[nm...], [factor...]]``).

    Asked without a geometry (the emulator does so once before it announces its port:
    :meth:`virtual.wire.ocean_model.SpectrometerModel.prepare`) it sees no light, but first makes
    the specimen ready: parsed and evaluated once, which builds the tables a spectral specimen
    computes on first use (a leaf's PROSPECT-D body and cuticle albedo: seconds on a loaded core).
    Built lazily inside the first acquisition instead, that time overran the driver's deadline
    for command 'S' on every retry, and the late frames then answered the next commands."""
    if geometry is None:
        if "specimen" not in _PROCESS_CACHE:
            _specimen_fraction(_mounted_specimen(specimen), _PREPARE_AT, np.asarray(wavelengths_nm, dtype=float),
                               aperture_deg)
        return np.zeros(np.shape(wavelengths_nm))
    try:
        mounted = json.loads(Path(mount_file).read_text()).get("mounted", "specimen")
    except (OSError, ValueError):
        mounted = "specimen"
    g = geometry
    wl = np.asarray(wavelengths_nm, dtype=float)
    dirs, w_cos = cone_cos_weights(g.view, aperture_deg)  # the detector's cone, as the virtual body's
    if mounted == "white":
        return RESPONSE_GAIN * _white_fraction(white_rf, wl) * float(w_cos.sum())
    return _specimen_fraction(_mounted_specimen(specimen), g, wl, aperture_deg)


#: how long the spectrometer emulator may take to announce its port (s): it prepares the specimen
#: first (:func:`emulated_response`), a leaf's tables taking ~10 s on a loaded core; a hang guard only
#: (an emulator that dies is seen at once)
SPECTROMETER_START_S = 120.0
#: where a prepared specimen is evaluated once (any lit geometry builds its tables)
_PREPARE_AT = Geometry(8.0, 0.0, 30.0, 180.0)


def _mounted_specimen(specimen: str) -> Specimen:
    """The specimen, parsed once per emulator process."""
    spec = _PROCESS_CACHE.get("specimen")
    if spec is None:
        spec = _PROCESS_CACHE["specimen"] = parse_specimen(specimen)
    return spec


def _specimen_fraction(spec: Specimen, g: Geometry, wl: np.ndarray, aperture_deg: float) -> np.ndarray:
    """``GAIN * mean_aperture(f cos(theta_r))`` of the specimen ``spec`` at geometry ``g``."""
    dirs, w_cos = cone_cos_weights(g.view, aperture_deg)
    wi = g.incident
    rng = spec.wavelength_range()
    if rng is None:  # not spectral: one evaluation serves every pixel
        return np.full(wl.shape, RESPONSE_GAIN * float(w_cos @ spec.bsdf(wi, dirs, float(wl[0]))))
    # each pixel sees the specimen at its own wavelength (held at the specimen's range ends beyond
    # it): all at once where the specimen can (a leaf: its cuticle's lobe once, its 1 nm body tables
    # interpolated per pixel), else on a 1 nm grid interpolated to the pixels (a coarse grid missed
    # a steep spectrum's band means by several per cent at diffuse geometries)
    return RESPONSE_GAIN * weighted_spectrum(spec, wi, dirs, w_cos, wl, grid_nm=1.0)


def _write_mount(path: Path, mounted: str) -> None:
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps({"mounted": mounted}))
    os.replace(tmp, path)


# --- builders ----------------------------------------------------------------------------------------


#: keys of a description's driver tables that name its own ports: the emulators have theirs
_PORT_KEYS = ("port", "name")


def _without_ports(table: Mapping[str, Any] | None) -> dict[str, Any]:
    return {k: v for k, v in (table or {}).items() if k not in _PORT_KEYS}


def emulated_arm_config(d: Mapping[str, Any], port: str) -> dict[str, Any]:
    """The emulated arm's driver settings: the description's ``[arm]`` (any body's: its port
    aside) over the emulated bench's defaults."""
    arm = {"port": port, "name": "emulated-arm", "external": ["turntable"], "tolerance_deg": 0.2,
           "settle_timeout_s": 10.0, "poll_interval_s": 0.002,
           "axes": {j: {"id": i, "operating_mode": 4, "profile_velocity": 60} for j, i in ARM_IDS.items()}}
    arm.update({k: v for k, v in d.get("arm", {}).items() if k != "port"})
    return arm


def _bus_axes(arm: Mapping[str, Any]) -> dict[str, dict[str, Any]]:
    """The servos the bus emulator plays: the arm's own ids, zero offsets, directions and gear
    ratios, so that the driver's joint angles and the emulator's agree."""
    return {j: {"id": a.id, "zero_offset": a.zero_offset, "direction": a.direction, "gear_ratio": a.gear_ratio}
            for j, a in ArmConfig.from_dict(arm).axes.items()}


def emulated_turntable_config(d: Mapping[str, Any]) -> dict[str, Any]:
    """The emulated turntable's driver settings: the description's ``[turntable]`` over defaults."""
    return {"gear_ratio": TURNTABLE_GEAR, "steps_per_rev": STEPS_PER_REV, "speed": 30.0, "tolerance": 0.05,
            "settle_s": 0.2, "poll_interval_s": 0.002, **_without_ports(d.get("turntable"))}


def emulated_motion(d: Mapping[str, Any]) -> Any:
    """The emulated bench's time model (constant-speed moves ``time_scale`` times faster than the
    configured drives): the emulated body's, and the virtual body's of the same description."""
    scale = float(d.get("emulated", {}).get("time_scale", 20.0))
    return motion_profile(emulated_arm_config(d, ""), emulated_turntable_config(d), scale, ramps=False, settle_s=0.01,
                          overhead_s=0.002)


class Emulators:
    """The three emulator processes of an emulated bench, and what the drivers need to reach them."""

    def __init__(self, d: Mapping[str, Any], seed: int | None = None) -> None:
        spec = d.get("specimen", {}).get("spec")
        if not spec:
            raise ConfigError("emulated bench: [specimen] spec = \"...\" is required")
        parse_specimen(spec)  # a bad specimen fails here, before any process starts
        self.specimen = str(spec)
        self.description = dict(d)
        e = dict(d.get("emulated", {}))
        self.time_scale = float(e.get("time_scale", 20.0))
        # the run's seed (``--seed``) governs the emulators' noise; else the description's, else 7
        described_seed = e.get("seed")
        emu_seed = int(seed) if seed is not None else (int(described_seed) if described_seed is not None else 7)
        self.seed = emu_seed
        self.white = WhiteStandard.from_dict(d.get("white", {}))
        bands = described_bands(d)  # [bands] or [emulated] bands, checked against a declared [detector]
        self.bands = bands if bands is not None else (EmulatedTable().bands, EmulatedTable().bandwidth_nm)
        self.detector = emulator_settings(detector_settings(d))
        self.arm_config = emulated_arm_config(d, "")
        self.workdir = Path(tempfile.mkdtemp(prefix="goniobench-emulated-"))
        self.mount = self.workdir / "mount.json"
        _write_mount(self.mount, "specimen")
        self._closers: list[Any] = []
        try:
            axes_map = _bus_axes(self.arm_config)
            self.bus = start_bus(ids=tuple(a["id"] for a in axes_map.values()), axes=axes_map,
                                 time_scale=self.time_scale, seed=emu_seed)
            self._closers.append(self.bus.close)
            self.stage = StageEmulator.start("tcp", time_scale=self.time_scale)
            self._closers.append(self.stage.stop)
            self.turntable_config = emulated_turntable_config(d)
            steps_per_deg = self.turntable_config["steps_per_rev"] * self.turntable_config["gear_ratio"] / 360.0
            self.spectrometer = SpectrometerEmulator.start(
                geometry_source=functools.partial(emulated_geometry, f"{self.bus.control[0]}:{self.bus.control[1]}",
                                                  self.stage.url, steps_per_deg,
                                                  str(self.turntable_config.get("register_map", "oriental_az"))),
                response=functools.partial(emulated_response, specimen=spec,
                                           white_rf=actual_white(self.white.as_dict()["reflectance_factor"], d),
                                           mount_file=str(self.mount), aperture_deg=declared_aperture(d)),
                seed=emu_seed, time_scale=max(1.0, self.time_scale), start_timeout=SPECTROMETER_START_S,
                **self.detector)
            self._closers.append(self.spectrometer.stop)
        except BaseException:
            self.close()
            raise
        self.arm_config = emulated_arm_config(d, self.bus.port)
        self.light = declares_light(d)

    def mount_white(self, white: bool) -> None:
        """Put the white standard (or the specimen) on the emulated turntable."""
        _write_mount(self.mount, "white" if white else "specimen")

    def ports(self) -> dict[str, Any]:
        return {"dynamixel_bus": self.bus.port, "dynamixel_control": f"{self.bus.control[0]}:{self.bus.control[1]}",
                "modbus_stage": self.stage.url, "spectrometer": self.spectrometer.port,
                "mount_file": str(self.mount)}

    def real_bench_config(self) -> dict[str, Any]:
        """A ``kind = "real"`` bench config whose ports are these emulators."""
        arm = {k: v for k, v in self.arm_config.items()}
        d = self.description
        # what the description declares about its detector, aperture and budget, so that the
        # printed description reads these emulators as the emulated bench reads them
        declared = {k: dict(d[k]) for k in ("uncertainty", "instrument") if d.get(k)}
        if not (d.get("instrument") or {}).get("aperture_deg"):
            declared["emulated"] = {"aperture_deg": declared_aperture(d)}
        return {"name": "emulators", "kind": "real", "arm": arm, **declared,
                "specimen": {"name": f"emulated {self.specimen}", "spec": self.specimen},
                **({"light": {"kind": LAMP_LINE}} if self.light else {}),  # the lamp-enable line: darks
                "turntable": {"port": self.stage.url, **self.turntable_config},
                "spectrometer": {"port": self.spectrometer.port, **_without_ports(d.get("spectrometer")),
                                 **self.spectrometer_settings()},
                "bands": {"centres": self.bands[0], "bandwidth_nm": self.bands[1]},
                "white": self.white.as_dict(),
                **({"detector": dict(self.description["detector"])} if "detector" in self.description else {})}

    def spectrometer_settings(self) -> dict[str, Any]:
        """The driver's pixel count when the declared detector is not the model's default."""
        return {"pixels": self.detector["pixels"]} if "pixels" in self.detector else {}

    def close(self) -> None:
        for c in reversed(self._closers):
            try:
                c()
            except Exception as exc:  # keep stopping the others
                log.warning("stopping an emulator: %s", exc)
        self._closers.clear()


def build_emulated_bench(d: Mapping[str, Any], seed: int | None = None) -> Bench:
    """Start the emulators and connect the real drivers to them (see the module docstring)."""
    emu = Emulators(d, seed)
    closers: list[Any] = [emu.close]
    try:
        # its own emulators, locked all the same: one owner per device, whatever the body
        locks = lock_devices({"arm": emu.bus.port, "turntable": emu.stage.url, "spectrometer": emu.spectrometer.port},
                             note_stale=False)
        closers.append(locks.release)
        turntable = ModbusStageAxis(emu.stage.url, config=emu.turntable_config, name="turntable")
        closers.append(turntable.close)
        turntable.establish()
        arm = DynamixelArm(emu.arm_config, external_axes={"turntable": turntable})
        closers.append(arm.close)
        ocean = OceanSpectrometer(emu.spectrometer.port, name="spectrometer",
                                  config={**_without_ports(d.get("spectrometer")), **emu.spectrometer_settings()})
        closers.append(ocean.close)
        lamp = build_light(light_settings(d.get("light")) or LightTable(settle_s=0.0), ocean)  # the emulator's lamp line, lit
        bands = SpectralBands(ocean, parse_wavelengths(emu.bands[0]), float(emu.bands[1]))
    except BaseException:
        for c in reversed(closers):
            c()
        raise
    white = emu.white

    def measure_whites(integration_s: float, averages: int, repeats: int) -> list[Reading]:
        emu.mount_white(True)  # mounted once, then read in sequence
        try:
            arm.move_to(white.geometry)
            return [bands.acquire(integration_s, averages) for _ in range(repeats)]
        finally:
            emu.mount_white(False)

    def measure_white(integration_s: float, averages: int) -> Reading:
        return measure_whites(integration_s, averages, 1)[0]

    kin = arm.config.kinematics
    return Bench(name=str(d.get("name", "emulated")), kind="emulated", goniometer=arm, spectrometer=bands,
                 white=white, measure_white=measure_white, measure_whites=measure_whites,
                 light=lamp if emu.light else None,
                 motion=emulated_motion(d),
                 joints=lambda g: geometry_to_joints(g, kin).as_dict(), config=dict(d), closers=closers,
                 parts={"emulators": emu, "arm": arm, "turntable": turntable, "spectrometer": ocean})

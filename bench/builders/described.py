"""A bench built from its description alone: what planning and the refusals before a run need,
with no port opened, no emulator started and no byte sent.

``bench plan`` checks, times and prices a plan on it, and ``bench scan`` / ``bench resume``
refuse a plan on it before they build the body that would run it: every rule they apply (the
kinematics' refusals, the calibration steps, the integration limits, the exposure) reads the
description, so a dead or stale port cannot make a plan fail, and a refused plan never opens
the hardware. The roles here check and describe; anything that would move or read raises.

The body is the one that would execute the description (``--body``, default its ``kind``):

* ``real``: the arm's kinematics and the drives' motion profiles of ``[arm]`` / ``[turntable]``
  (both ports named, as the real builder requires); a light when ``[light]`` declares one; the
  white standard mounted by an operator.
* ``emulated``: the emulated arm (the description's ``[arm]`` over the emulated defaults) and
  the emulators' time model; the emulators' lamp line.
* ``virtual``: the virtual bench itself (it opens nothing): :func:`planning_bench` builds it.

A port a run will open is also checked here (:func:`check_ports`): a device path that does not
exist, or a ``tcp://`` endpoint that refuses a connection, is one line naming the table and port.
"""

from __future__ import annotations

import os
import socket
from typing import Any, Mapping

from bench.builders.detector import described_bands
from bench.builders.emulated import emulated_arm_config, emulated_motion
from bench.builders.light import declares_light, light_settings
from bench.builders.motion import motion_profile
from bench.config import Bench, load_bench, load_description
from bench.core.calibration import WhiteStandard
from bench.core.errors import BenchError, ConfigError
from bench.core.geometry import Geometry
from bench.core.parsing import parse_wavelengths
from bench.core.roles import Closing, InstrumentInfo, Reading
from drivers.dynamixel import ArmConfig
from drivers.kinematics import KinematicsConfig, check, geometry_to_joints

__all__ = ["described_bench", "design_bench", "planning_bench", "check_ports", "DescribedGoniometer"]

#: driver tables whose ``port`` a real body opens
_PORT_TABLES = ("arm", "turntable", "spectrometer")


class _Described(Closing):
    """A role of a bench that exists only as its description: it can describe, not act (``with``
    and ``close()`` do nothing)."""

    what = "device"

    def __init__(self, bench_name: str) -> None:
        self.bench_name = bench_name

    def _refuse(self, action: str) -> BenchError:
        return BenchError(f"bench {self.bench_name!r} is a description here (planning): its {self.what} cannot "
                          f"{action}")

    def describe(self) -> InstrumentInfo:
        return InstrumentInfo(kind=self.what, model="described (not opened)")


class DescribedGoniometer(_Described):
    """The Goniometer role's ``check`` by the description's kinematics (the arm driver's rule)."""

    what = "goniometer"

    def __init__(self, bench_name: str, kinematics: KinematicsConfig) -> None:
        super().__init__(bench_name)
        self.kinematics = kinematics

    def check(self, geometry: Geometry) -> None:
        check(geometry, self.kinematics)

    def move_to(self, geometry: Geometry) -> Geometry:
        raise self._refuse(f"move to {geometry}")

    def position(self) -> Geometry:
        raise self._refuse("report a position")

    def stop(self) -> None:
        pass


class _DescribedSpectrometer(_Described):
    what = "spectrometer"

    def __init__(self, bench_name: str, wavelengths: Any = None) -> None:
        super().__init__(bench_name)
        self._wavelengths = wavelengths

    @property
    def wavelengths(self) -> Any:
        """The band centres the description declares (``[bands]``); refused where the body reports its own."""
        if self._wavelengths is None:
            raise self._refuse("report its wavelengths (declare [bands] to plan without opening it)")
        return self._wavelengths

    def acquire(self, integration_s: float, averages: int = 1) -> Reading:
        raise self._refuse("acquire")


class _DescribedLight(_Described):
    what = "light source"

    def on(self) -> None:
        raise self._refuse("switch on")

    def off(self) -> None:
        raise self._refuse("switch off")


def described_bench(d: Mapping[str, Any], body: str) -> Bench:
    """The bench description ``d`` (validated) as body ``body`` (``real`` or ``emulated``) would
    refuse and time a plan, with nothing opened (see the module docstring)."""
    name = str(d.get("name", body))
    if body == "real":
        for table in ("arm", "spectrometer"):
            if "port" not in (d.get(table) or {}):
                raise ConfigError(f"real bench: [{table}] port = \"...\" is required")
        arm = {k: v for k, v in dict(d["arm"]).items() if k != "port"}
        motion = motion_profile(d.get("arm"), d.get("turntable"))
        has_light = light_settings(d.get("light")) is not None
    elif body == "emulated":
        if not (d.get("specimen") or {}).get("spec"):
            raise ConfigError("emulated bench: [specimen] spec = \"...\" is required")
        arm = emulated_arm_config(d, "")
        motion = emulated_motion(d)
        has_light = declares_light(d)
    else:
        raise ConfigError(f"a described bench is the real or the emulated body, got {body!r}")
    bands = described_bands(d)  # bands on the declared [detector]
    kin = ArmConfig.from_dict(arm).kinematics
    return Bench(name=name, kind=body, goniometer=DescribedGoniometer(name, kin),
                 spectrometer=_DescribedSpectrometer(name, None if bands is None else parse_wavelengths(bands[0])), white=WhiteStandard.from_dict(d.get("white", {})),
                 measure_white=lambda t, n: _DescribedSpectrometer(name).acquire(t, n),
                 light=_DescribedLight(name) if has_light else None, motion=motion,
                 joints=lambda g: geometry_to_joints(g, kin).as_dict(), config=dict(d),
                 white_needs_operator=body == "real")


def design_bench(config: Any, body: str | None = None) -> Bench:
    """The bench a plan is designed on: the description alone where it says all a design reads
    (the emulated body; a real one that declares its bands), else the bench opened (the virtual
    body; a real one whose spectrometer reports its own wavelengths)."""
    d, kind = load_description(config, body)
    if kind == "emulated" or (kind == "real" and described_bands(d) is not None):
        return described_bench(d, kind)
    return load_bench(d, body=kind)


def planning_bench(config: Any, seed: int | None = None, body: str | None = None) -> Bench:
    """The bench a plan is checked and timed on: the description alone for a physical body
    (:func:`described_bench`), the virtual bench itself for the virtual body."""
    d, kind = load_description(config, body)
    if kind == "virtual":
        return load_bench(d, seed=seed, body=kind)
    return described_bench(d, kind)


def _tcp(port: str) -> tuple[str, int] | None:
    if not port.startswith(("tcp://", "socket://")):
        return None
    host, _, number = port.split("://", 1)[1].rpartition(":")
    return (host or "127.0.0.1", int(number)) if number.isdigit() else None


def check_ports(d: Mapping[str, Any], timeout_s: float = 1.0) -> None:
    """Refuse, in one line naming the table and the port, a port of description ``d`` that
    cannot be there: a device path that does not exist, or a ``tcp://`` / ``socket://``
    endpoint that refuses a connection within ``timeout_s`` (an emulator that has stopped).
    Other URLs (``loop://``, ``rfc2217://``) are left to the driver."""
    for table in _PORT_TABLES:
        port = (d.get(table) or {}).get("port")
        if not isinstance(port, str):
            continue
        where = f"bench {d.get('name', 'bench')!r} [{table}] port {port!r}"
        endpoint = _tcp(port)
        if endpoint is not None:
            try:
                socket.create_connection(endpoint, timeout=timeout_s).close()
            except OSError as exc:
                raise ConfigError(f"{where}: nothing answers there ({exc.strerror or exc}): is the device on, or "
                                  f"the emulator still running (`bench emulate` prints new ports each time)?") from None
        elif "://" not in port and not os.path.exists(port):
            raise ConfigError(f"{where}: no such device: is it plugged in, or is this a stale port from an "
                              f"earlier `bench emulate`?")

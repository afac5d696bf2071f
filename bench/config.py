"""Bench configs: one TOML file names the implementation filling each role.

Switching a scan script from virtual to emulated to real hardware is a config change only::

    name = "my-bench"
    kind = "virtual"            # "virtual", "emulated" or "real"

    [specimen]                  # virtual and emulated benches: what is mounted
    spec = "ggx:alpha=0.2,eta=1.5,k=0"

    [white]                     # the reflectance standard used for calibration
    reflectance_factor = 0.99
    uncertainty = 0.005
    geometry = [0, 0, 45, 180]  # theta_i, phi_i, theta_r, phi_r

    [virtual]                   # virtual goniophotometer (kind = "virtual")
    collector = "equal-psa:18x72"
    rays = 2000000
    beam = "collimated"
    wavelengths = "450:650:50"

Emulated and real benches add ``[arm]`` (drivers.dynamixel), ``[turntable]`` (drivers.modbus)
and ``[spectrometer]`` (drivers.ocean) tables; the emulated builder starts the wire emulators
itself and points the real drivers at them (see :mod:`bench.builders`). ``[detector]``
(:mod:`bench.builders.detector`) describes the detector for every body.

Builders are looked up by ``kind`` and imported lazily, so ``bench`` (the interface) does not
depend on ``virtual`` or ``drivers`` at import time.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping

from bench.core.calibration import WhiteStandard
from bench.core.errors import BenchError, ConfigError
from bench.core.parsing import read_toml
from bench.core.schemas import BENCH_KINDS, BenchFile, validate_document
from bench.core.roles import Closing, Goniometer, LightSource, Reading, Spectrometer
from bench.plans import MotionProfile

__all__ = ["Bench", "load_bench", "load_description", "BUILDERS"]

#: kind -> "module:function" building a Bench from (config dict, seed): one builder module per
#: kind the bench schema declares (bench.builders.KIND:build_KIND_bench)
BUILDERS: dict[str, str] = {kind: f"bench.builders.{kind}:build_{kind}_bench" for kind in BENCH_KINDS}


@dataclass
class Bench(Closing):
    """A named set of roles. Scan scripts only ever see this.

    ``measure_white(integration_s, averages)`` returns a reading of the white standard at its
    geometry (a virtual bench measures a virtual standard; an emulated one mounts it in the
    emulator; a real one asks the operator). ``joints`` maps a geometry to joint angles for
    time estimates, ``motion`` gives the axes' profiles.
    """

    name: str
    kind: str
    goniometer: Goniometer
    spectrometer: Spectrometer
    white: WhiteStandard
    measure_white: Callable[[float, int], Reading]
    light: LightSource | None = None
    motion: MotionProfile | None = None
    joints: Callable[[Any], Mapping[str, float]] | None = None
    config: dict[str, Any] = field(default_factory=dict)
    closers: list[Callable[[], None]] = field(default_factory=list)
    parts: dict[str, Any] = field(default_factory=dict)  # builder-specific handles (e.g. emulators)
    #: the white standard is mounted by a person (a real bench): unattended runs need a stored
    #: reading or ``operator_confirmed`` (``bench white --yes``: the operator says it is mounted)
    white_needs_operator: bool = False
    operator_confirmed: bool = False
    #: ``measure_whites(integration_s, averages, repeats)``: the standard mounted once, then read
    #: ``repeats`` times in sequence (None: ``measure_white`` called ``repeats`` times)
    measure_whites: Callable[[float, int, int], list[Reading]] | None = None

    def white_readings(self, integration_s: float, averages: int, repeats: int) -> list[Reading]:
        """``repeats`` readings of the white standard taken in sequence, mounted once."""
        if self.measure_whites is not None:
            return list(self.measure_whites(integration_s, averages, repeats))
        return [self.measure_white(integration_s, averages) for _ in range(repeats)]

    def describe(self) -> dict[str, Any]:
        out: dict[str, Any] = {"name": self.name, "kind": self.kind}
        for role in ("goniometer", "spectrometer", "light"):
            dev = getattr(self, role)
            if dev is not None:
                out[role] = dev.describe().as_dict()
        out["white"] = self.white.as_dict()
        return out

    def fault_counts(self) -> dict[str, int]:
        """The transaction faults and recoveries of the devices in :attr:`parts` that count them
        (the drivers' ``faults``), flat as ``PART.KEY`` (``arm.retries``, ``spectrometer.fault.nak``);
        empty for a bench without such devices (virtual)."""
        out: dict[str, int] = {}
        for name, part in sorted(self.parts.items()):
            snap = getattr(getattr(part, "faults", None), "snapshot", None)
            if callable(snap):
                out.update({f"{name}.{k}": int(v) for k, v in snap().items()})
        return out

    def close(self) -> None:
        """Close every device and stop what the builder started (emulators), last first."""
        errors = []
        for closer in reversed(self.closers):
            try:
                closer()
            except BenchError as exc:  # keep closing the rest
                errors.append(exc)
        self.closers.clear()
        if errors:
            raise errors[0]


def load_description(config: str | Path | Mapping[str, Any], body: str | None = None) -> tuple[dict[str, Any], str]:
    """A bench description (a TOML path or its dict) through the declared schema
    (:class:`bench.core.schemas.BenchFile`) and the drivers' tables, and the body that executes
    it (``body``, default its ``kind``): one :class:`ConfigError` naming the file and key, with
    nothing built or opened."""
    if isinstance(config, Mapping):
        d, source = dict(config), "bench config"
    else:
        d, source = read_toml(config, "bench config"), f"bench config {config}"
    described = validate_document(BenchFile, d, source).kind
    kind = str(body or described)  # the body executing the description (default: its kind)
    if kind not in BUILDERS:
        raise ConfigError(f"bench body must be one of {', '.join(BUILDERS)}, got {kind!r}")
    from bench.builders.tables import validate_driver_tables  # loads drivers only when a table needs them

    validate_driver_tables(d, source)
    if kind == "real" and d.get("drift") is not None:  # declared drift is the simulated bodies' (bench.builders.drift)
        raise ConfigError(f"{source} [drift] is simulated by the virtual and emulated bodies only; a real bench "
                          f"drifts by itself (remove [drift] or use --body virtual|emulated)")
    return d, kind


def load_bench(config: str | Path | Mapping[str, Any], seed: int | None = None, body: str | None = None) -> Bench:
    """Build the bench a config describes (a TOML path or its dict).

    The config goes through the declared schema (:class:`bench.core.schemas.BenchFile`) first,
    so a typo, a wrong type or an out-of-range value is one :class:`ConfigError` naming the file
    and key before any device is built or emulator started. ``body`` (``virtual``, ``emulated``
    or ``real``) picks what executes the description; default: its ``kind``.
    """
    d, kind = load_description(config, body)
    module, func = BUILDERS[kind].split(":")
    builder = getattr(importlib.import_module(module), func)
    return builder(d, seed)

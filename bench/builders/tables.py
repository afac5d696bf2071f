"""Driver tables validated before anything starts: ``[arm]``, ``[turntable]``, ``[spectrometer]``
and ``[light]`` of a bench file go through the drivers' declared settings (the same classes the
drivers build from them), so a wrong type or value is one :class:`ConfigError` line naming the
file, table, key and value, before an emulator starts or a port opens.

The tables are checked as the description's ``kind`` will use them: an emulated description's
tables over the emulated defaults (the emulators own the ports), a real one's with its ports.
"""

from __future__ import annotations

from typing import Any, Mapping

from bench.builders.light import light_settings
from bench.core.errors import ConfigError

__all__ = ["DRIVER_TABLES", "validate_driver_tables"]

#: the bench-file tables a driver (not the bench schema) declares the keys of
DRIVER_TABLES = ("arm", "turntable", "spectrometer", "light")
#: keys of a device table that are the builder's (where to reach it, what to call it)
_BUILDER_KEYS = ("port", "name")


def _device_keys(table: Mapping[str, Any]) -> dict[str, Any]:
    return {str(k): v for k, v in table.items() if k not in _BUILDER_KEYS}


def validate_driver_tables(d: Mapping[str, Any], source: str = "bench config") -> None:
    """Validate the driver tables of the bench description ``d`` (already through
    :class:`bench.core.schemas.BenchFile`); raises :class:`ConfigError` on the first problem.

    A virtual description without driver tables loads no driver module."""
    kind = str(d.get("kind", "virtual"))
    if kind == "virtual" and not any(t in d for t in DRIVER_TABLES):
        return
    from drivers.dynamixel.config import ArmConfig
    from drivers.modbus.config import AxisConfig as StageAxisConfig
    from drivers.ocean.config import OceanConfig

    light_settings(d.get("light"), source)
    if kind == "real":
        arm: Mapping[str, Any] | None = d.get("arm")
        turntable = _device_keys(d["turntable"]) if "turntable" in d else None
        spectrometer = _device_keys(d.get("spectrometer", {}))
    else:  # the emulated body's own defaults under the description's tables
        from bench.builders.emulated import emulated_arm_config, emulated_turntable_config

        arm = emulated_arm_config(d, "")
        turntable = emulated_turntable_config(d)
        spectrometer = dict(d.get("spectrometer", {}))
    checks = (("arm", ArmConfig.from_dict, arm), ("turntable", StageAxisConfig.from_dict, turntable),
              ("spectrometer", lambda t, where: OceanConfig.from_dict(t, where).resolved(), spectrometer))
    for name, check, table in checks:
        if table is None:
            continue
        where = f"{source} [{name}]"
        try:
            check(table, where)
        except ConfigError as exc:  # a nested table's or a cross-check's message names no file
            msg = str(exc)
            raise ConfigError(msg if msg.startswith(source) else f"{where}: {msg}") from None

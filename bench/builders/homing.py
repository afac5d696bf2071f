"""Return-to-home of a bench's axes, for ``bench home`` and for plans with ``home = true``.

Owns :func:`homeable_axes` and :func:`home_axis`. An axis can be homed when the bench's builder
exposes it in ``Bench.parts`` with a ``home(timeout_s=None) -> float`` method (the Modbus
turntable of emulated and real benches: ZHOME, then HOME-END, see
:mod:`drivers.modbus.homing`). A virtual bench has nothing to home.
"""

from __future__ import annotations

import logging
from typing import Any

from bench.config import Bench
from bench.core.errors import ConfigError

__all__ = ["homeable_axes", "home_axis", "HOME_AXIS"]

log = logging.getLogger(__name__)

#: the axis a plan's ``home = true`` and ``bench home`` home unless told otherwise
HOME_AXIS = "turntable"


def homeable_axes(bench: Bench) -> list[str]:
    """Names of the bench's axes that have a return-to-home (empty for a virtual bench)."""
    return sorted(name for name, part in bench.parts.items() if callable(getattr(part, "home", None)))


def home_axis(bench: Bench, axis: str = HOME_AXIS, timeout_s: float | None = None) -> float:
    """Home ``axis`` of ``bench``; return the position read back (degrees).

    Raises
    ------
    ConfigError
        The bench has no such axis with a return-to-home (a virtual bench has none).
    DeviceError
        From the driver: alarm (:class:`HardwareError`), no HOME-END in time
        (:class:`DeviceTimeoutError`), lost port, latched fault.
    """
    axes = homeable_axes(bench)
    if axis not in axes:
        have = f"it has {', '.join(axes)}" if axes else "it has no axis with a return-to-home"
        raise ConfigError(f"bench {bench.name!r} ({bench.kind}): nothing to home on axis {axis!r}; {have}")
    part: Any = bench.parts[axis]
    log.info("homing %s of bench %s", axis, bench.name)
    return float(part.home(timeout_s=timeout_s))

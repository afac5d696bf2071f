"""Configuration and vocabulary of the Modbus stage driver: the :class:`StageAxis` protocol,
Modbus exception names, and :class:`AxisConfig` (mechanics, motion, communication settings).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping, Protocol, runtime_checkable

from bench.core.errors import ConfigError
from bench.core.roles import InstrumentInfo
from drivers.settings import settings_from_mapping

MODBUS_EXCEPTIONS = {
    1: "ILLEGAL FUNCTION", 2: "ILLEGAL DATA ADDRESS", 3: "ILLEGAL DATA VALUE",
    4: "SLAVE DEVICE FAILURE", 5: "ACKNOWLEDGE", 6: "SLAVE DEVICE BUSY",
    8: "MEMORY PARITY ERROR", 10: "GATEWAY PATH UNAVAILABLE",
    11: "GATEWAY TARGET DEVICE FAILED TO RESPOND",
}
_FUNCTION_NAMES = {3: "read holding registers", 16: "write multiple registers"}


@runtime_checkable
class StageAxis(Protocol):
    """What a goniometer needs from one motorised axis (degrees for a rotary axis).

    ``move_to_deg`` blocks until in position and returns the position read back;
    ``check_deg`` raises :class:`GeometryError` for a target it would refuse, before any motion.
    (A candidate for ``bench.core.roles``; defined here until its owner adopts it.)
    """

    def check_deg(self, angle: float) -> None: ...

    def move_to_deg(self, angle: float) -> float: ...

    def position_deg(self) -> float: ...

    def stop(self) -> None: ...

    def reset_alarm(self) -> None: ...

    def describe(self) -> InstrumentInfo: ...

    def close(self) -> None: ...


@dataclass(frozen=True)
class AxisConfig:
    """Mechanics, motion and communication settings of one axis (all keys optional).

    Attributes
    ----------
    steps_per_rev : int
        Motor steps per motor revolution (AZ default 1000 = 0.36 deg/step).
    gear_ratio : float
        Motor revolutions per output revolution (e.g. 18 for an 18:1 rotary actuator).
    units_per_rev : float
        Output units per output revolution: 360 for a rotary axis in degrees, the screw lead
        in mm for a linear axis. The API says ``_deg``; for a linear axis read "unit".
    unit : str
        ``"deg"`` or ``"mm"`` (metadata only).
    zero_offset : float
        Output position (units) at step 0.
    limits : (float, float)
        Software travel limits in units; targets outside raise :class:`GeometryError`.
    speed : float
        Operating speed, units/s.
    accel, decel : int
        Raw acceleration/deceleration written to the drive (drive units, AZ: kHz/s).
    current : int
        Operating current in 0.1 % (1000 = 100 %).
    tolerance : float
        Largest |feedback - target| (units) accepted as "reached".
    move_timeout_s : float or None
        Time allowed for one move; None = travel time at ``speed`` x 1.5 + ``settle_s`` + 1 s.
    settle_s : float
        Extra time allowed after the travel time.
    home_timeout_s : float
        Time allowed for a return-to-home (ZHOME until HOME-END).
    poll_interval_s : float
        Status polling period while moving.
    timeout_s : float
        Reply timeout for one Modbus request.
    retries : int
        Extra attempts after a timeout / lost connection (exception responses never retry).
    retry_delay_s : float
        Pause between attempts.
    device_id : int
        Modbus unit id (1..247).
    baudrate, parity, stopbits, bytesize
        Serial settings (AZ default 115200 8E1; a pty needs parity "N").
    register_map : str
        Name in ``drivers/registers`` or a TOML path.
    """

    steps_per_rev: int = 1000
    gear_ratio: float = 1.0
    units_per_rev: float = 360.0
    unit: str = "deg"
    zero_offset: float = 0.0
    limits: tuple[float, float] = (-180.0, 180.0)
    speed: float = 30.0
    accel: int = 1000
    decel: int = 1000
    current: int = 1000
    tolerance: float = 0.05
    move_timeout_s: float | None = None
    settle_s: float = 0.5
    home_timeout_s: float = 60.0
    poll_interval_s: float = 0.01
    timeout_s: float = 0.5
    retries: int = 2
    retry_delay_s: float = 0.05
    device_id: int = 1
    baudrate: int = 115200
    parity: str = "E"
    stopbits: int = 1
    bytesize: int = 8
    register_map: str = "oriental_az"

    def __post_init__(self) -> None:
        def bad(msg: str) -> None:
            raise ConfigError(f"stage axis config: {msg}")

        if not (isinstance(self.steps_per_rev, int) and self.steps_per_rev > 0):
            bad(f"steps_per_rev must be a positive integer, got {self.steps_per_rev!r}")
        for name in ("gear_ratio", "units_per_rev", "speed", "tolerance", "timeout_s",
                     "poll_interval_s", "home_timeout_s"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                bad(f"{name} must be a finite number > 0, got {v!r}")
        lo, hi = self.limits
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            bad(f"limits must be finite (lo, hi) with lo < hi, got {self.limits!r}")
        if not 1 <= self.device_id <= 247:
            bad(f"device_id must be 1..247, got {self.device_id}")
        if self.retries < 0:
            bad("retries must be >= 0")
        if not 0 <= self.current <= 1000:
            bad(f"current must be 0..1000 (0.1 % units), got {self.current}")
        if self.parity not in ("N", "E", "O"):
            bad(f"parity must be N, E or O, got {self.parity!r}")

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "AxisConfig":
        return settings_from_mapping(cls, d, "stage axis config", tuples={"limits": float})

    @property
    def steps_per_unit(self) -> float:
        return self.steps_per_rev * self.gear_ratio / self.units_per_rev

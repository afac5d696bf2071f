"""Configuration and vocabulary of the Modbus stage driver: the :class:`StageAxis` protocol,
Modbus exception names, and :class:`AxisConfig` (mechanics, motion, communication settings).
"""

from __future__ import annotations

from typing import Annotated, ClassVar, Literal, Protocol, runtime_checkable

from pydantic import Field, StrictInt, field_validator

from bench.core.roles import InstrumentInfo
from bench.core.validation import Finite, Settings

_Positive = Annotated[Finite, Field(gt=0)]

MODBUS_EXCEPTIONS = {
    1: "ILLEGAL FUNCTION", 2: "ILLEGAL DATA ADDRESS", 3: "ILLEGAL DATA VALUE",
    4: "SLAVE DEVICE FAILURE", 5: "ACKNOWLEDGE", 6: "SLAVE DEVICE BUSY",
    8: "MEMORY PARITY ERROR", 10: "GATEWAY PATH UNAVAILABLE",
    11: "GATEWAY TARGET DEVICE FAILED TO RESPOND",
}
#: exception codes that say "not now" rather than "never": ACKNOWLEDGE (a long operation under way)
#: and SLAVE DEVICE BUSY; the request is retried (bounded) instead of refused
TRANSIENT_EXCEPTIONS = (5, 6)
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


class AxisConfig(Settings):
    """Mechanics, motion and communication settings of one axis (all keys optional), each
    declared once with its range (validated by pydantic, :class:`bench.core.schemas.Settings`).

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
        Extra attempts after a timeout, a garbled or foreign reply, a lost connection or a transient
        exception response (ACKNOWLEDGE, SLAVE DEVICE BUSY; other exception responses never retry).
    retry_delay_s : float
        Pause between attempts.
    device_id : int
        Modbus unit id (1..247).
    baudrate, parity, stopbits, bytesize
        Serial settings (AZ default 115200 8E1; a pty needs parity "N").
    register_map : str
        Name in ``drivers/registers`` or a TOML path.
    """

    settings_of: ClassVar[str] = "stage axis config"

    steps_per_rev: Annotated[StrictInt, Field(gt=0)] = 1000
    gear_ratio: _Positive = 1.0
    units_per_rev: _Positive = 360.0
    unit: str = "deg"
    zero_offset: Finite = 0.0
    limits: tuple[Finite, Finite] = (-180.0, 180.0)
    speed: _Positive = 30.0
    accel: Annotated[int, Field(ge=0)] = 1000
    decel: Annotated[int, Field(ge=0)] = 1000
    current: Annotated[int, Field(ge=0, le=1000)] = 1000
    tolerance: _Positive = 0.05
    move_timeout_s: Finite | None = None
    settle_s: Finite = 0.5
    home_timeout_s: _Positive = 60.0
    poll_interval_s: _Positive = 0.01
    timeout_s: _Positive = 0.5
    retries: Annotated[int, Field(ge=0)] = 3
    retry_delay_s: Finite = 0.05
    device_id: Annotated[int, Field(ge=1, le=247)] = 1
    baudrate: int = 115200
    parity: Literal["N", "E", "O"] = "E"
    stopbits: int = 1
    bytesize: int = 8
    register_map: str = "oriental_az"

    @field_validator("limits")
    @classmethod
    def _ordered(cls, v: tuple[float, float]) -> tuple[float, float]:
        if not v[0] < v[1]:
            raise ValueError(f"expected (lo, hi) with lo < hi, got {v!r}")
        return v

    @property
    def steps_per_unit(self) -> float:
        return self.steps_per_rev * self.gear_ratio / self.units_per_rev

"""Configuration of the Dynamixel arm: the driver's control-table addresses and error names
(from the X-series e-manual), :class:`AxisConfig` (one joint on one servo, degrees <-> ticks)
and :class:`ArmConfig` (four axes, port, kinematics, timing), validated from TOML dicts.
"""

from __future__ import annotations

from typing import Annotated, Any, ClassVar, Literal, Mapping

from pydantic import Field, StrictInt, field_validator, model_validator

from bench.core.errors import ConfigError
from bench.core.validation import Finite, Settings
from drivers.kinematics import JOINTS, Joint, KinematicsConfig

ADDR = {"model_number": 0, "return_delay": 9, "drive_mode": 10, "operating_mode": 11, "homing_offset": 20,
        "max_position": 48, "min_position": 52, "torque_enable": 64, "status_return_level": 68, "hardware_error": 70, "profile_acceleration": 108,
        "profile_velocity": 112, "goal_position": 116, "moving": 122, "moving_status": 123,
        "present_position": 132}
TICKS_PER_REV = 4096
ERRBIT_ALERT = 0x80
#: Drive Mode (10) bits the driver relies on being clear: 0 reverse direction (the config's
#: ``direction`` says it), 2 time-based profile (Profile Velocity/Acceleration read as velocities)
DRIVE_MODE_CLEAR = 0b101
#: Return Delay Time (9) unit, s; the register holds 0..254
RETURN_DELAY_UNIT_S = 2e-6
#: Status Return Level (68) the driver needs: a status for every instruction (0 ping only, 1 + reads)
STATUS_RETURN_ALL = 2
HW_ERROR_FLAGS = {0: "input_voltage", 1: "hall_sensor", 2: "overheating", 3: "motor_encoder",
                  4: "electrical_shock", 5: "overload"}
STATUS_ERRORS = {1: "result fail", 2: "instruction error", 3: "CRC error", 4: "data range error",
                 5: "data length error", 6: "data limit error", 7: "access error"}
# The poll block: Goal Position (116) .. Present Position (132..135) in one sync read, so that
# every poll also shows whether the broadcast goals landed. Offsets inside the block:
_BLOCK_ADDR = ADDR["goal_position"]
_BLOCK_LEN = ADDR["present_position"] + 4 - _BLOCK_ADDR
_OFF_GOAL = 0
_OFF_MOVING = ADDR["moving"] - _BLOCK_ADDR
_OFF_PRESENT = ADDR["present_position"] - _BLOCK_ADDR


def decode_hardware_error(code: int) -> list[str]:
    """Names of the set bits of Hardware Error Status (addr 70); unknown bits as ``bit<n>``."""
    return [HW_ERROR_FLAGS.get(b, f"bit{b}") for b in range(8) if code >> b & 1]


def _s32(v: int) -> int:
    v &= 0xFFFFFFFF
    return v - (1 << 32) if v & 0x80000000 else v


def _le(value: int, size: int) -> list[int]:
    return list((value & ((1 << (8 * size)) - 1)).to_bytes(size, "little"))


# --- configuration -------------------------------------------------------------------------

_NonNegative = Annotated[Finite, Field(ge=0)]


class AxisConfig(Settings):
    """One joint on one servo, each setting declared once with its range (validated by
    pydantic, :class:`bench.core.schemas.Settings`).

    ``ticks = zero_offset + direction * round(joint_deg * gear_ratio * 4096 / 360)``.
    """

    settings_of: ClassVar[str] = "axes"

    joint: Joint
    id: Annotated[StrictInt, Field(ge=0, le=252)]
    zero_offset: StrictInt = 2048
    direction: Literal[1, -1] = 1
    gear_ratio: Annotated[Finite, Field(gt=0)] = 1.0
    operating_mode: Literal[3, 4] = 3  # 3: position, 4: extended position
    limits: tuple[Finite, Finite] | None = None
    profile_velocity: Annotated[StrictInt, Field(ge=0)] = 0
    profile_acceleration: Annotated[StrictInt, Field(ge=0)] = 0

    @field_validator("limits")
    @classmethod
    def _ordered(cls, v: tuple[float, float] | None) -> tuple[float, float] | None:
        if v is not None and not v[0] <= v[1]:
            raise ValueError(f"expected [lo, hi] degrees with lo <= hi, got {list(v)!r}")
        return v

    @classmethod
    def from_dict(cls, joint: str, d: Mapping[str, Any]) -> "AxisConfig":  # type: ignore[override]
        """The axis of ``joint`` from its ``[axes.JOINT]`` table (errors name ``axes.JOINT``)."""
        if not isinstance(d, Mapping):
            raise ConfigError(f"axes.{joint}: expected a table of keys, got {type(d).__name__}")
        if "joint" in d:
            raise ConfigError(f"axes.{joint}: unknown key 'joint'")
        return super().from_dict({**d, "joint": joint}, f"axes.{joint}")

    @property
    def ticks_per_degree(self) -> float:
        return TICKS_PER_REV * self.gear_ratio / 360.0

    def to_ticks(self, degrees: float) -> int:
        return self.zero_offset + self.direction * int(round(degrees * self.ticks_per_degree))

    def to_degrees(self, ticks: int) -> float:
        return (ticks - self.zero_offset) * self.direction / self.ticks_per_degree


class ArmConfig(Settings):
    """The whole arm: four axes, port, kinematics and timing, each setting declared once with its
    range (validated by pydantic, :class:`bench.core.validation.Settings`), and the rules that
    join them (every joint on a servo or external, distinct servo ids, limits a position-mode
    servo can reach) in one model validator. See the module docstring."""

    settings_of: ClassVar[str] = "arm config"

    axes: dict[str, AxisConfig]
    port: str = ""
    baudrate: Annotated[StrictInt, Field(gt=0)] = 1_000_000
    kinematics: KinematicsConfig = Field(default_factory=KinematicsConfig)
    tolerance_deg: _NonNegative = 0.2
    settle_timeout_s: _NonNegative = 10.0
    poll_interval_s: _NonNegative = 0.01
    retries: Annotated[StrictInt, Field(ge=0)] = 5  # a 3-servo sync read fails ~2 % of attempts at ~1 % faults
    start_timeout_s: _NonNegative = 0.1
    return_delay_s: _NonNegative = 500e-6
    latency_s: _NonNegative = 0.016
    model_number: StrictInt | None = 1020
    torque_off_on_close: bool = False
    name: str = "dynamixel-arm"
    external: tuple[Joint, ...] = ()

    @model_validator(mode="after")
    def _joints_ids_and_reachable_limits(self) -> "ArmConfig":
        for j in self.external:
            if j in self.axes:
                raise ValueError(f"external joint {j!r} must not also be a servo axis")
        missing = [j for j in JOINTS if j not in self.axes and j not in self.external]
        if missing:
            raise ValueError(f"axes: missing joint(s) {missing}; need {list(JOINTS)} "
                             f"(or name them in external = [...] and drive them with another axis)")
        ids = [a.id for a in self.axes.values()]
        if len(set(ids)) != len(ids):
            raise ValueError(f"axes: servo ids must be distinct, got {ids}")
        # The joint limits actually used: the axis limits where given, else the kinematics
        # limits; in position mode 3 the latter are narrowed to what ticks 0..4095 reach.
        lim: dict[str, tuple[float, float]] = {}
        for a in self.axes.values():
            if a.limits is not None:
                lim[a.joint] = a.limits
                if a.operating_mode == 3:
                    for deg in a.limits:
                        t = a.to_ticks(deg)
                        if not 0 <= t <= TICKS_PER_REV - 1:
                            raise ValueError(
                                f"axes.{a.joint}: limit {deg:g} deg is tick {t}, outside 0..4095 of "
                                f"position mode 3 (use operating_mode = 4, or change zero_offset/limits)")
            elif a.operating_mode == 3:
                lo, hi = self.kinematics.limits[a.joint]
                r = sorted((a.to_degrees(0), a.to_degrees(TICKS_PER_REV - 1)))
                lo2, hi2 = max(lo, r[0]), min(hi, r[1])
                if lo2 > hi2:
                    raise ValueError(f"axes.{a.joint}: joint limits [{lo:g}, {hi:g}] deg and the "
                                     f"mode 3 tick range [{r[0]:g}, {r[1]:g}] deg do not overlap")
                lim[a.joint] = (lo2, hi2)
        object.__setattr__(self, "kinematics", self.kinematics.with_limits(**lim))
        return self

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], source: str | None = None) -> "ArmConfig":
        """Build from a dict (TOML table); unknown keys raise :class:`ConfigError`."""
        if not isinstance(d, Mapping):
            raise ConfigError(f"arm config: expected a table of keys, got {type(d).__name__}")
        d = dict(d)
        axes_d = d.pop("axes", None)
        if not isinstance(axes_d, Mapping):
            raise ConfigError("arm config needs an [axes] table with one table per joint")
        axes = {j: AxisConfig.from_dict(j, a) for j, a in axes_d.items()}
        kc = KinematicsConfig.from_dict(d.pop("kinematics", None))
        return super().from_dict({**d, "axes": axes, "kinematics": kc}, source)

    def axis_list(self) -> list[AxisConfig]:
        """Servo axes in :data:`drivers.kinematics.JOINTS` order (external joints left out)."""
        return [self.axes[j] for j in JOINTS if j in self.axes]

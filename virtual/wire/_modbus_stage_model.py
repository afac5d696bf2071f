"""The AZ stage emulator's register layout and motion model (its own reading of the AZ manual).

Owns :data:`AZ_LAYOUT` (the ONE register table of the stage emulator: addresses, input and
output bits, values, alarm codes), :class:`StageConfig`, the layout view :class:`_Layout`
(32-bit values as two registers) and :class:`StageModel` (time-driven motion, alarms, STOP,
ALM-RST, return-to-home on a ZHOME rising edge with HOME-END when done). Nothing here is
shared with ``drivers``: the two meet only on the wire.
"""

from __future__ import annotations

import logging
import time
import tomllib
from dataclasses import dataclass, field
from typing import Any, Callable

log = logging.getLogger(__name__)

@dataclass
class StageConfig:
    """Emulated drive settings (all in motor steps).

    ``register_map`` is ``"oriental_az"`` (the built-in layout) or the path of a TOML register
    map of the shape ``drivers/registers`` uses (read as data: the emulator imports nothing
    from ``drivers``, the two meet only on the wire); ``max_speed_hz``
    clips the commanded speed; ``travel_limits`` (lo, hi) in steps raises alarm 0x67
    (software overtravel) on a trigger beyond them; ``time_scale`` > 1 makes motion faster
    than real time (for tests); ``extra_device_ids`` adds more drives (same settings) on the
    same line, as on an RS-485 bus.
    """

    device_id: int = 1
    extra_device_ids: tuple[int, ...] = ()
    register_map: str = "oriental_az"
    initial_position: int = 0
    max_speed_hz: float = 4_000_000.0
    in_pos_tolerance: int = 1
    travel_limits: tuple[int, int] | None = None
    time_scale: float = 1.0
    baudrate: int = 115200
    parity: str = "N"  # Linux ptys refuse PARENB (tcsetattr EINVAL); real AZ drives default to "E"
    home_speed_hz: float = 2000.0
    homing: bool = True  # False: a drive whose return-to-home never finishes (no HOME-END)


AZ_LAYOUT: dict[str, Any] = {
    "registers": {"direct_data_no": 0x58, "direct_type": 0x5A, "direct_position": 0x5C,
                  "direct_speed": 0x5E, "direct_accel": 0x60, "direct_decel": 0x62,
                  "direct_current": 0x64, "direct_trigger": 0x66, "input_command": 0x7C,
                  "output_status": 0x7E, "present_alarm": 0x80, "feedback_position": 0x120,
                  "command_position": 0x122},
    "input_bits": {"START": 3, "ZHOME": 4, "STOP": 5, "FREE": 6, "ALM-RST": 7},
    "status_bits": {"HOME-END": 4, "READY": 5, "ALM": 7, "BUSY": 8, "MOVE": 13, "IN-POS": 14},
    "values": {"type_absolute": 1, "trigger_all": 1, "current_max": 1000, "home_position": 0},
    "alarms": {"overload": 0x30, "software_overtravel": 0x67},
    "word_order": "big",
}
_DIRECT = ("direct_data_no", "direct_type", "direct_position", "direct_speed", "direct_accel",
           "direct_decel", "direct_current", "direct_trigger")


class _Layout:
    """The emulator's own view of a register layout (32-bit values, two registers each)."""

    def __init__(self, d: dict[str, Any]) -> None:
        self.registers = {k: int(v) for k, v in d["registers"].items()}
        self.input_bits = {k: int(v) for k, v in d["input_bits"].items()}
        self.status_bits = {k: int(v) for k, v in d["status_bits"].items()}
        self.values = {k: int(v) for k, v in d.get("values", {}).items()}
        # name -> code; a TOML map may spell it code -> name ("0x30" = "overload")
        self.alarms = {(v if isinstance(v, str) else k).lower().replace(" ", "_"):
                       (int(k, 0) if isinstance(v, str) else int(v))
                       for k, v in d.get("alarms", {}).items()}
        self.big = d.get("word_order", "big") == "big"

    @classmethod
    def load(cls, spec: str) -> "_Layout":
        if spec in ("oriental_az", "oriental-az"):
            return cls(AZ_LAYOUT)
        with open(spec, "rb") as fh:
            return cls(tomllib.load(fh))

    def addr(self, key: str) -> int:
        return self.registers[key]

    def value(self, key: str, default: int) -> int:
        return self.values.get(key, default)

    @property
    def direct_block(self) -> tuple[int, int]:
        return self.registers["direct_data_no"], 2 * len(_DIRECT)

    def to_words(self, value: int) -> list[int]:
        v = int(value) & 0xFFFFFFFF
        w = [v >> 16, v & 0xFFFF]
        return w if self.big else w[::-1]

    def from_words(self, words: list[int]) -> int:
        hi, lo = (words[0], words[1]) if self.big else (words[1], words[0])
        v = (hi & 0xFFFF) << 16 | (lo & 0xFFFF)
        return v - (1 << 32) if v & 0x80000000 else v


@dataclass
class StageModel:
    """Time-driven state of one AZ axis; call :meth:`update` before reading anything."""

    rmap: Any
    cfg: StageConfig
    clock: Callable[[], float] = time.monotonic
    position: float = 0.0
    target: float = 0.0
    speed: float = 0.0
    moving: bool = False
    alarm: int = 0
    last_input: int = 0
    triggers: int = 0
    rejected_triggers: int = 0
    stops: int = 0
    alarm_resets: int = 0
    homing: bool = False
    home_end: bool = False
    homings: int = 0
    _t: float = field(default=0.0, repr=False)

    def __post_init__(self) -> None:
        self.position = self.target = float(self.cfg.initial_position)
        self._t = self.clock()

    def update(self) -> None:
        now = self.clock()
        dt = (now - self._t) * self.cfg.time_scale
        self._t = now
        if self.moving and not self.alarm and self.speed > 0:
            step = self.speed * dt
            remaining = self.target - self.position
            if abs(remaining) <= step:
                self.position = self.target
                self.moving = False
                if self.homing:
                    self.homing = False
                    self.home_end = True
            else:
                self.position += step if remaining > 0 else -step

    def status(self) -> int:
        b = self.rmap.status_bits
        s = 0
        if self.home_end:
            s |= 1 << b["HOME-END"]
        if self.alarm:
            s |= 1 << b["ALM"]
        else:
            if self.moving:
                s |= 1 << b["BUSY"] | 1 << b["MOVE"]
            else:
                s |= 1 << b["READY"]
                if abs(self.position - self.target) <= self.cfg.in_pos_tolerance:
                    s |= 1 << b["IN-POS"]
        return s

    def trigger(self, op_type: int, position: int, speed: int) -> None:
        self.update()
        if self.alarm:
            self.rejected_triggers += 1
            log.info("trigger ignored: alarm 0x%02X present", self.alarm)
            return
        self.triggers += 1
        if op_type != self.rmap.value("type_absolute", 1):
            self.rejected_triggers += 1
            log.info("trigger ignored: operation type %d not emulated", op_type)
            return
        lim = self.cfg.travel_limits
        if lim is not None and not lim[0] <= position <= lim[1]:
            self.raise_alarm(self.rmap.alarms["software_overtravel"])
            return
        self.target = float(position)
        self.speed = float(min(max(speed, 1), self.cfg.max_speed_hz))
        self.moving = self.position != self.target
        self.homing = self.home_end = False

    def input_command(self, value: int) -> None:
        self.update()
        bits = self.rmap.input_bits
        rising = value & ~self.last_input
        self.last_input = value
        if rising >> bits["STOP"] & 1:
            self.stops += 1
            self.moving = self.homing = False
            self.target = self.position
        if rising >> bits["ZHOME"] & 1 and not self.alarm:
            self.homings += 1
            self.home_end = False
            if self.cfg.homing:  # return to home at the homing speed; HOME-END when there
                self.homing = True
                self.target = float(self.rmap.value("home_position", 0))
                self.speed = float(self.cfg.home_speed_hz)
                self.moving = self.position != self.target
                if not self.moving:
                    self.homing, self.home_end = False, True
            else:               # a drive that starts homing and never finishes
                self.homing, self.moving, self.speed = True, True, 0.0
        if rising >> bits["ALM-RST"] & 1 and self.alarm:
            self.alarm_resets += 1
            self.alarm = 0
            self.moving = False
            self.target = round(self.position)
            self.position = self.target

    def raise_alarm(self, code: int) -> None:
        self.update()
        self.alarm = int(code)
        self.moving = False

    def snapshot(self) -> dict[str, Any]:
        self.update()
        return {"position": self.position, "target": self.target, "moving": self.moving,
                "alarm": self.alarm, "status": self.status(), "triggers": self.triggers,
                "rejected_triggers": self.rejected_triggers, "stops": self.stops,
                "alarm_resets": self.alarm_resets, "homings": self.homings,
                "home_end": self.home_end}


def read_feedback_steps(client: Any, device_id: int = 1, register_map: str = "oriental_az") -> int:
    """The feedback position (steps) of an emulated stage, read with a pymodbus ``client``.

    For code that watches the emulated stage from outside (e.g. the spectrometer emulator's
    geometry source) so that the address comes from this emulator's table, never a literal.
    """
    layout = _Layout.load(register_map)
    rr = client.read_holding_registers(layout.addr("feedback_position"), count=2, device_id=device_id)
    if rr.isError():
        raise ConnectionError(f"stage emulator: reading the feedback position failed: {rr}")
    return layout.from_words(list(rr.registers))

"""The servo model of the Dynamixel bus emulator: one XM430-W350-like control table.

Owns the emulator's control-table map (:data:`ADDR`, the ONE address table of the emulator),
the EEPROM/read-only areas and :class:`Servo` (finite-speed motion, EEPROM lock, hardware
errors, reboot).
"""

from __future__ import annotations

import math
import time
from typing import Callable

from virtual.wire._dxl_codec import ERR, ERRBIT_ALERT


# The ONE control table of the emulated servo (XM430-W350, from the e-manual):
# name -> (address, size, power-up value, access) with access "R" read-only, "RW" writable.
# Every other number in this module is a name looked up here.
CONTROL_TABLE: dict[str, tuple[int, int, int, str]] = {
    "model_number": (0, 2, 1020, "R"), "model_information": (2, 4, 0, "R"),
    "firmware_version": (6, 1, 52, "R"), "id": (7, 1, 1, "RW"), "baud_rate": (8, 1, 3, "RW"),
    "return_delay": (9, 1, 250, "RW"), "drive_mode": (10, 1, 0, "RW"),
    "operating_mode": (11, 1, 3, "RW"), "protocol_type": (13, 1, 2, "RW"),
    "homing_offset": (20, 4, 0, "RW"), "moving_threshold": (24, 4, 10, "RW"),
    "temperature_limit": (31, 1, 80, "RW"), "max_voltage": (32, 2, 160, "RW"),
    "min_voltage": (34, 2, 95, "RW"), "pwm_limit": (36, 2, 885, "RW"),
    "current_limit": (38, 2, 1193, "RW"), "velocity_limit": (44, 4, 265, "RW"),
    "max_position": (48, 4, 4095, "RW"), "min_position": (52, 4, 0, "RW"),
    "shutdown": (63, 1, 52, "RW"), "torque_enable": (64, 1, 0, "RW"), "led": (65, 1, 0, "RW"),
    "status_return_level": (68, 1, 2, "RW"), "registered": (69, 1, 0, "R"),
    "hardware_error": (70, 1, 0, "R"), "profile_acceleration": (108, 4, 0, "RW"),
    "profile_velocity": (112, 4, 0, "RW"), "goal_position": (116, 4, 0, "RW"),
    "realtime_tick": (120, 2, 0, "R"), "moving": (122, 1, 0, "R"), "moving_status": (123, 1, 0, "R"),
    "present_pwm": (124, 2, 0, "R"), "present_current": (126, 2, 0, "R"),
    "present_velocity": (128, 4, 0, "R"), "present_position": (132, 4, 0, "R"),
    "velocity_trajectory": (136, 4, 0, "R"), "position_trajectory": (140, 4, 0, "R"),
    "present_voltage": (144, 2, 120, "R"), "present_temperature": (146, 1, 35, "R"),
}
ADDR = {name: item[0] for name, item in CONTROL_TABLE.items()}
SIZE = {name: item[1] for name, item in CONTROL_TABLE.items()}
TABLE_SIZE = 228
EEPROM_END = ADDR["torque_enable"]  # addresses below are EEPROM (write-locked with torque on)
_READ_ONLY = {a for name, (addr, size, _, acc) in CONTROL_TABLE.items() if acc == "R"
              for a in range(addr, addr + size)}
_VALID_MODES = (0, 1, 3, 4, 5, 16)
TICKS_PER_REV = 4096
VELOCITY_UNIT_RPM = 0.229
_GOAL = "goal_position"


def _s32(v: int) -> int:
    v &= 0xFFFFFFFF
    return v - (1 << 32) if v & 0x80000000 else v


def _span(name: str) -> tuple[int, int]:
    return ADDR[name], ADDR[name] + SIZE[name]


class Servo:
    """One XM430-W350-like servo: a control table plus finite-speed position motion.

    Parameters
    ----------
    dev_id
        Bus ID (1..252).
    position
        Initial present position in ticks.
    clock
        Seconds clock (monotonic); motion is a function of it.
    time_scale
        Motion runs this many times faster than real time (CI knob; 1 = real).
    """

    def __init__(self, dev_id: int, position: int = 2048, model: int = 1020, firmware: int = 52,
                 clock: Callable[[], float] = time.monotonic, time_scale: float = 1.0) -> None:
        self.table = bytearray(TABLE_SIZE)
        self.clock = clock
        self.time_scale = time_scale
        for name, (_, _, value, _) in CONTROL_TABLE.items():
            self.put(name, value)
        self.put("model_number", model)
        self.put("firmware_version", firmware)
        self.put("id", dev_id)
        self.put("return_delay", 0)  # return delay is modelled by the transports, not here
        self.pos = float(position)
        self._last = clock()
        self.hw_error_on_goal = 0
        self._sync_present()

    # -- table access -----------------------------------------------------------------------
    @property
    def id(self) -> int:
        return self.value("id")

    def _set(self, addr: int, size: int, value: int) -> None:
        self.table[addr:addr + size] = (value & ((1 << (8 * size)) - 1)).to_bytes(size, "little")

    def get(self, addr: int, size: int, signed: bool = False) -> int:
        return int.from_bytes(self.table[addr:addr + size], "little", signed=signed)

    def put(self, name: str, value: int) -> None:
        """Set a control-table item by name."""
        self._set(ADDR[name], SIZE[name], value)

    def value(self, name: str, signed: bool = False) -> int:
        """A control-table item by name."""
        return self.get(ADDR[name], SIZE[name], signed)

    @property
    def torque(self) -> bool:
        return bool(self.value("torque_enable"))

    @property
    def hardware_error(self) -> int:
        return self.value("hardware_error")

    @property
    def mode(self) -> int:
        return self.value("operating_mode")

    def speed_ticks_per_s(self) -> float:
        pv = self.value("profile_velocity")
        lim = self.value("velocity_limit")
        v = min(pv, lim) if pv else lim
        return v * VELOCITY_UNIT_RPM / 60.0 * TICKS_PER_REV * self.time_scale

    # -- motion -----------------------------------------------------------------------------
    def update(self) -> None:
        """Advance the motion to now."""
        now = self.clock()
        dt = max(0.0, now - self._last)
        self._last = now
        goal = float(self.value(_GOAL, signed=True))
        if self.torque and not self.hardware_error and self.pos != goal:
            step = self.speed_ticks_per_s() * dt
            d = goal - self.pos
            self.pos = goal if abs(d) <= step else self.pos + math.copysign(step, d)
            self._vel = math.copysign(self.speed_ticks_per_s(), d) if self.pos != goal else 0.0
        else:
            self._vel = 0.0
        self._sync_present()

    def _sync_present(self) -> None:
        present = int(round(self.pos))
        self.put("present_position", present)
        goal = self.value(_GOAL, signed=True)
        moving = self.torque and not self.hardware_error and present != goal
        self.put("moving", 1 if moving else 0)
        self.put("moving_status", 0x02 if moving else (0x01 if self.torque else 0x00))
        vel = getattr(self, "_vel", 0.0)
        units = vel / self.time_scale / TICKS_PER_REV * 60.0 / VELOCITY_UNIT_RPM if vel else 0.0
        self.put("present_velocity", int(round(units)))
        self.put("realtime_tick", int(self.clock() * 1000) & 0x7FFF)

    def set_hardware_error(self, bits: int) -> None:
        """Latch Hardware Error Status bits: torque off, motion stops where it is."""
        self.update()
        self.put("hardware_error", self.hardware_error | bits & 0xFF)
        self.put("torque_enable", 0)
        self.put(_GOAL, int(round(self.pos)))
        self._sync_present()

    def reboot(self) -> None:
        self.update()
        self.put("hardware_error", 0)
        self.put("torque_enable", 0)
        if self.mode == 3:
            self.pos = float(int(round(self.pos)) % TICKS_PER_REV)
        self.put(_GOAL, int(round(self.pos)))
        self._sync_present()

    # -- instructions -----------------------------------------------------------------------
    def status_error(self, code: int = 0) -> int:
        return code | (ERRBIT_ALERT if self.hardware_error else 0)

    def read(self, addr: int, length: int) -> tuple[int, bytes]:
        self.update()
        if length == 0 or addr + length > TABLE_SIZE:
            return ERR["data_range"], b""
        return 0, bytes(self.table[addr:addr + length])

    def write(self, addr: int, data: bytes) -> int:
        """Apply a write; return a Protocol 2.0 error code (0 ok)."""
        self.update()
        end = addr + len(data)
        if not data or end > TABLE_SIZE:
            return ERR["data_range"]
        if any(a in _READ_ONLY for a in range(addr, end)):
            return ERR["access"]
        if addr < EEPROM_END and self.torque:
            return ERR["access"]
        new = bytearray(self.table)
        new[addr:end] = data

        def touches(name: str) -> bool:
            lo, hi = _span(name)
            return addr < hi and end > lo

        def new_value(name: str, signed: bool = False) -> int:
            lo, hi = _span(name)
            return int.from_bytes(new[lo:hi], "little", signed=signed)

        if touches(_GOAL):
            lo, hi = _span(_GOAL)
            if not (addr <= lo and end >= hi):
                return ERR["data_length"]  # Goal Position is written whole
            goal = new_value(_GOAL, signed=True)
            if self.mode == 3:
                if not new_value("min_position", True) <= goal <= new_value("max_position", True):
                    return ERR["data_limit"]
        if touches("operating_mode") and new_value("operating_mode") not in _VALID_MODES:
            return ERR["data_range"]
        if touches("torque_enable") and new_value("torque_enable") > 1:
            return ERR["data_range"]
        torque_on = touches("torque_enable") and new_value("torque_enable") == 1 and not self.torque
        mode_change = touches("operating_mode") and new_value("operating_mode") != self.mode
        self.table[addr:end] = new[addr:end]
        if self.hardware_error:
            self.put("torque_enable", 0)
        if mode_change and self.mode == 3:
            self.pos = float(int(round(self.pos)) % TICKS_PER_REV)
        if torque_on and self.torque:
            self.put(_GOAL, int(round(self.pos)))
        if touches(_GOAL) and self.hw_error_on_goal:
            bits, self.hw_error_on_goal = self.hw_error_on_goal, 0
            self.set_hardware_error(bits)
        self._sync_present()
        return 0

    def snapshot(self) -> dict[str, int]:
        self.update()
        return {"present_position": self.value("present_position", signed=True),
                "goal_position": self.value(_GOAL, signed=True),
                "moving": self.value("moving"), "torque": self.value("torque_enable"),
                "hardware_error": self.hardware_error, "operating_mode": self.mode}

"""A Dynamixel Protocol 2.0 bus emulator: several XM430-W350-like servos on one line.

Three layers, usable separately:

1. **Codec** (the one packet codec of the project, shared by this emulator and the tests; the
   driver itself uses dynamixel-sdk's own packets): :func:`crc16` (poly 0x8005, init 0, no
   reflection), :func:`stuff`/:func:`unstuff` (``FF FF FD`` -> ``FF FF FD FD``),
   :func:`encode_instruction`, :func:`encode_status`, :func:`decode_packet` and the streaming
   :class:`PacketParser`.
2. **Model**: :class:`Servo` (control table, finite-speed motion, EEPROM lock, hardware errors)
   and :class:`DynamixelBus` (routes instructions: ping, read, write, reboot, sync read, sync
   write, bulk read, bulk write; fault injection). In process, :class:`BusTransport` wraps a bus
   as a byte transport (``write``/``read``/``reset_input``/``close``) for fast tests, and
   :class:`PtyBusThread` serves it on a pty from a thread (thread mode).
3. **Process**: ``python -m virtual.wire.dynamixel_bus --ids 1,2,3,4`` owns a pseudo-terminal,
   prints one JSON line ``{"port": "/dev/pts/N", "control": "127.0.0.1:PORT", "pid": ...}`` and
   serves until killed. :func:`start_bus` does that from Python and returns an
   :class:`~virtual.wire.pty.EmulatorProcess`; :class:`BusControl` talks to its control channel.

Control channel (joint state for other emulators, fault injection)
------------------------------------------------------------------
A TCP socket on 127.0.0.1 speaking JSON lines: send one object per line, get one object back.

``{"cmd": "state"}``
    ``{"ok": true, "t": <monotonic s>, "servos": {"1": {"present_position": ticks,
    "goal_position": ticks, "moving": 0|1, "torque": 0|1, "hardware_error": bits,
    "operating_mode": 3|4}, ...}, "joints": {"<name>": degrees, ...}}``. ``joints`` is filled
    when the emulator was started with ``--axes`` (a JSON object ``{"name": {"id": 1,
    "zero_offset": 2048, "direction": 1, "gear_ratio": 1.0}}``, the same meaning as the
    driver's axis config): joint = (ticks - zero_offset) * direction * 360 / (4096 * gear_ratio).
    A spectrometer emulator polls this to know where the arms are.
``{"cmd": "faults", "drop_next": n, "corrupt_next": n, "drop_rate": p, "corrupt_rate": p,
"delay_s": s, "hang": bool}``
    Fault injection on status packets (only the keys given change).
``{"cmd": "hardware_error", "id": 1, "bits": 32, "on_goal": false}``
    Set Hardware Error Status bits (5 = overload -> 32): torque off, every later status packet
    of that servo carries the alert bit 0x80. With ``on_goal`` true it fires at the next Goal
    Position write instead (the servo faults as the move starts).
``{"cmd": "poke", "id": 1, "addr": 64, "size": 1, "value": 0}`` / ``{"cmd": "clear"}`` /
``{"cmd": "die"}`` (exit at once: the pty vanishes).

The process exits by itself when the process that started it dies (unless ``--no-orphan``).

Modelling simplifications: motion at constant profile velocity (Profile Acceleration is
stored, not simulated); Profile Velocity 0 means the Velocity Limit; no return delay; Status
Return Level is always 2; a Goal Position outside the position limits in mode 3 is refused
with error 6 (data limit) on a plain write and ignored in a sync/bulk write; Torque Enable = 1
sets Goal Position to Present Position (no jump).
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import random
import select
import signal
import socket
import sys
import time
from dataclasses import dataclass
from typing import Any, Callable, Iterable, Mapping, Sequence

__all__ = [
    "crc16", "stuff", "unstuff", "encode_instruction", "encode_status", "decode_packet",
    "Packet", "PacketParser", "PacketError",
    "Servo", "DynamixelBus", "BusTransport", "PtyBusThread", "BusControl", "start_bus", "serve",
    "main",
    "INST", "ERR", "ERRBIT_ALERT", "BROADCAST_ID", "HW_ERROR_BITS", "ADDR",
]

log = logging.getLogger(__name__)

# --- codec ---------------------------------------------------------------------------------

BROADCAST_ID = 0xFE
ERRBIT_ALERT = 0x80
HEADER = b"\xff\xff\xfd\x00"

INST = {"ping": 0x01, "read": 0x02, "write": 0x03, "reg_write": 0x04, "action": 0x05,
        "factory_reset": 0x06, "reboot": 0x08, "clear": 0x10, "status": 0x55,
        "sync_read": 0x82, "sync_write": 0x83, "fast_sync_read": 0x8A, "bulk_read": 0x92,
        "bulk_write": 0x93}
ERR = {"result_fail": 1, "instruction": 2, "crc": 3, "data_range": 4, "data_length": 5,
       "data_limit": 6, "access": 7}
HW_ERROR_BITS = {0: "input_voltage", 1: "hall_sensor", 2: "overheating", 3: "motor_encoder",
                 4: "electrical_shock", 5: "overload"}


def _make_table() -> list[int]:
    table = []
    for i in range(256):
        c = i << 8
        for _ in range(8):
            c = ((c << 1) ^ 0x8005) if c & 0x8000 else (c << 1)
        table.append(c & 0xFFFF)
    return table


_CRC_TABLE = _make_table()


def crc16(data: bytes | bytearray | Sequence[int], crc: int = 0) -> int:
    """CRC-16/BUYPASS as Dynamixel 2.0 uses it (``crc16(b"123456789") == 0xFEE8``)."""
    for b in data:
        crc = ((crc << 8) ^ _CRC_TABLE[((crc >> 8) ^ b) & 0xFF]) & 0xFFFF
    return crc


def stuff(payload: bytes) -> bytes:
    """Insert ``FD`` after every ``FF FF FD`` inside an instruction+parameter payload."""
    out = bytearray()
    for b in payload:
        out.append(b)
        if b == 0xFD and len(out) >= 3 and out[-3] == 0xFF and out[-2] == 0xFF:
            out.append(0xFD)
    return bytes(out)


def unstuff(payload: bytes) -> bytes:
    """Remove the ``FD`` that :func:`stuff` inserted (``FF FF FD FD`` -> ``FF FF FD``)."""
    out = bytearray()
    i = 0
    while i < len(payload):
        b = payload[i]
        out.append(b)
        if (b == 0xFD and len(out) >= 3 and out[-3] == 0xFF and out[-2] == 0xFF
                and i + 1 < len(payload) and payload[i + 1] == 0xFD):
            i += 1  # skip the stuffing byte
        i += 1
    return bytes(out)


def _encode(dev_id: int, payload: bytes) -> bytes:
    body = stuff(payload)
    n = len(body) + 2
    pkt = HEADER + bytes([dev_id & 0xFF, n & 0xFF, (n >> 8) & 0xFF]) + body
    c = crc16(pkt)
    return pkt + bytes([c & 0xFF, c >> 8])


def encode_instruction(dev_id: int, instruction: int, params: bytes = b"") -> bytes:
    """An instruction packet (header, stuffing, CRC), e.g. ``encode_instruction(1, 0x01)`` is ping."""
    return _encode(dev_id, bytes([instruction]) + bytes(params))


def encode_status(dev_id: int, error: int, params: bytes = b"") -> bytes:
    """A status packet (instruction 0x55, then the error byte, then ``params``)."""
    return _encode(dev_id, bytes([INST["status"], error & 0xFF]) + bytes(params))


class PacketError(ValueError):
    """A packet that does not decode (bad header, length or CRC)."""


@dataclass(frozen=True)
class Packet:
    """A decoded packet. For a status packet ``error`` is the error byte and ``params`` follow it."""

    id: int
    instruction: int
    params: bytes
    raw: bytes = b""

    @property
    def is_status(self) -> bool:
        return self.instruction == INST["status"]

    @property
    def error(self) -> int:
        return self.params[0] if self.is_status and self.params else 0

    @property
    def data(self) -> bytes:
        """Parameters after the error byte (status) or all parameters (instruction)."""
        return self.params[1:] if self.is_status else self.params


def decode_packet(raw: bytes) -> Packet:
    """Decode one complete packet (exactly its bytes); raise :class:`PacketError` if malformed."""
    raw = bytes(raw)
    if len(raw) < 10 or raw[:4] != HEADER:
        raise PacketError(f"not a Dynamixel 2.0 packet: {raw.hex(' ')}")
    n = raw[5] | (raw[6] << 8)
    if len(raw) != 7 + n:
        raise PacketError(f"length field says {7 + n} bytes, got {len(raw)}")
    crc = raw[-2] | (raw[-1] << 8)
    if crc16(raw[:-2]) != crc:
        raise PacketError(f"CRC mismatch: packet says 0x{crc:04X}, computed 0x{crc16(raw[:-2]):04X}")
    payload = unstuff(raw[7:-2])
    return Packet(raw[4], payload[0], payload[1:], raw)


class PacketParser:
    """Streaming parser: :meth:`feed` bytes, get complete valid packets back.

    Garbage before a header is skipped; a packet with a bad CRC is dropped (counted in
    :attr:`crc_errors`), as a servo ignores it.
    """

    def __init__(self) -> None:
        self.buf = bytearray()
        self.crc_errors = 0

    def feed(self, data: bytes) -> list[Packet]:
        self.buf += data
        out: list[Packet] = []
        while True:
            i = self.buf.find(HEADER)
            if i < 0:
                keep = 3 if len(self.buf) >= 3 else len(self.buf)
                del self.buf[:len(self.buf) - keep]
                return out
            if i:
                del self.buf[:i]
            if len(self.buf) < 7:
                return out
            n = self.buf[5] | (self.buf[6] << 8)
            if n < 3 or n > 1024:
                del self.buf[:1]
                continue
            if len(self.buf) < 7 + n:
                return out
            raw = bytes(self.buf[:7 + n])
            try:
                pkt = decode_packet(raw)
            except PacketError:
                self.crc_errors += 1
                del self.buf[:1]
                continue
            del self.buf[:7 + n]
            out.append(pkt)


# --- servo model ---------------------------------------------------------------------------

ADDR = {"model_number": 0, "firmware_version": 6, "id": 7, "baud_rate": 8, "return_delay": 9,
        "drive_mode": 10, "operating_mode": 11, "protocol_type": 13, "homing_offset": 20,
        "moving_threshold": 24, "temperature_limit": 31, "max_voltage": 32, "min_voltage": 34,
        "pwm_limit": 36, "current_limit": 38, "velocity_limit": 44, "max_position": 48,
        "min_position": 52, "shutdown": 63, "torque_enable": 64, "led": 65,
        "status_return_level": 68, "registered": 69, "hardware_error": 70,
        "profile_acceleration": 108, "profile_velocity": 112, "goal_position": 116,
        "realtime_tick": 120, "moving": 122, "moving_status": 123, "present_pwm": 124,
        "present_current": 126, "present_velocity": 128, "present_position": 132,
        "velocity_trajectory": 136, "position_trajectory": 140, "present_voltage": 144,
        "present_temperature": 146}
TABLE_SIZE = 228
EEPROM_END = 64
_READ_ONLY = set(range(0, 7)) | {69, 70} | set(range(120, 148))
TICKS_PER_REV = 4096
VELOCITY_UNIT_RPM = 0.229


def _s32(v: int) -> int:
    v &= 0xFFFFFFFF
    return v - (1 << 32) if v & 0x80000000 else v


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
        self._set(0, 2, model)
        self._set(6, 1, firmware)
        self._set(7, 1, dev_id)
        self._set(8, 1, 3)            # 1 Mbps
        self._set(9, 1, 0)            # return delay (modelled as none)
        self._set(11, 1, 3)           # position mode
        self._set(13, 1, 2)
        self._set(24, 4, 10)
        self._set(31, 1, 80)
        self._set(32, 2, 160)
        self._set(34, 2, 95)
        self._set(36, 2, 885)
        self._set(38, 2, 1193)
        self._set(44, 4, 265)
        self._set(48, 4, 4095)
        self._set(52, 4, 0)
        self._set(63, 1, 52)
        self._set(68, 1, 2)
        self._set(144, 2, 120)
        self._set(146, 1, 35)
        self.pos = float(position)
        self._last = clock()
        self.hw_error_on_goal = 0
        self._sync_present()

    # -- table access -----------------------------------------------------------------------
    @property
    def id(self) -> int:
        return self.table[7]

    def _set(self, addr: int, size: int, value: int) -> None:
        self.table[addr:addr + size] = (value & ((1 << (8 * size)) - 1)).to_bytes(size, "little")

    def get(self, addr: int, size: int, signed: bool = False) -> int:
        return int.from_bytes(self.table[addr:addr + size], "little", signed=signed)

    @property
    def torque(self) -> bool:
        return bool(self.table[64])

    @property
    def hardware_error(self) -> int:
        return self.table[70]

    @property
    def mode(self) -> int:
        return self.table[11]

    def speed_ticks_per_s(self) -> float:
        pv = self.get(112, 4)
        lim = self.get(44, 4)
        v = min(pv, lim) if pv else lim
        return v * VELOCITY_UNIT_RPM / 60.0 * TICKS_PER_REV * self.time_scale

    # -- motion -----------------------------------------------------------------------------
    def update(self) -> None:
        """Advance the motion to now."""
        now = self.clock()
        dt = max(0.0, now - self._last)
        self._last = now
        goal = float(self.get(116, 4, signed=True))
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
        self._set(132, 4, present)
        goal = self.get(116, 4, signed=True)
        moving = self.torque and not self.hardware_error and present != goal
        self._set(122, 1, 1 if moving else 0)
        self._set(123, 1, 0x02 if moving else (0x01 if self.torque else 0x00))
        vel = getattr(self, "_vel", 0.0)
        units = vel / self.time_scale / TICKS_PER_REV * 60.0 / VELOCITY_UNIT_RPM if vel else 0.0
        self._set(128, 4, int(round(units)))
        self._set(120, 2, int(self.clock() * 1000) & 0x7FFF)

    def set_hardware_error(self, bits: int) -> None:
        """Latch Hardware Error Status bits: torque off, motion stops where it is."""
        self.update()
        self.table[70] |= bits & 0xFF
        self.table[64] = 0
        self._set(116, 4, int(round(self.pos)))
        self._sync_present()

    def reboot(self) -> None:
        self.update()
        self.table[70] = 0
        self.table[64] = 0
        if self.mode == 3:
            self.pos = float(int(round(self.pos)) % TICKS_PER_REV)
        self._set(116, 4, int(round(self.pos)))
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
        if addr < 120 and end > 116:  # touches Goal Position
            if not (addr <= 116 and end >= 120):
                return ERR["data_length"]  # Goal Position is written whole
            goal = int.from_bytes(new[116:120], "little", signed=True)
            if self.mode == 3:
                lo = int.from_bytes(new[52:56], "little", signed=True)
                hi = int.from_bytes(new[48:52], "little", signed=True)
                if not lo <= goal <= hi:
                    return ERR["data_limit"]
        if addr <= 11 < end and new[11] not in (0, 1, 3, 4, 5, 16):
            return ERR["data_range"]
        if addr <= 64 < end and new[64] > 1:
            return ERR["data_range"]
        torque_on = addr <= 64 < end and new[64] == 1 and not self.torque
        mode_change = addr <= 11 < end and new[11] != self.mode
        self.table[addr:end] = new[addr:end]
        if self.hardware_error:
            self.table[64] = 0
        if mode_change and self.mode == 3:
            self.pos = float(int(round(self.pos)) % TICKS_PER_REV)
        if torque_on and self.torque:
            self._set(116, 4, int(round(self.pos)))
        if addr <= 116 < end and self.hw_error_on_goal:
            bits, self.hw_error_on_goal = self.hw_error_on_goal, 0
            self.set_hardware_error(bits)
        self._sync_present()
        return 0

    def snapshot(self) -> dict[str, int]:
        self.update()
        return {"present_position": self.get(132, 4, signed=True),
                "goal_position": self.get(116, 4, signed=True),
                "moving": self.table[122], "torque": self.table[64],
                "hardware_error": self.table[70], "operating_mode": self.table[11]}


# --- bus -----------------------------------------------------------------------------------


@dataclass
class Faults:
    """Fault injection on status packets (replies)."""

    drop_next: int = 0
    corrupt_next: int = 0
    drop_rate: float = 0.0
    corrupt_rate: float = 0.0
    delay_s: float = 0.0
    hang: bool = False
    dropped: int = 0
    corrupted: int = 0


@dataclass
class AxisMap:
    """Ticks -> joint degrees for the ``joints`` field of the state (same meaning as the driver)."""

    id: int
    zero_offset: int = 2048
    direction: int = 1
    gear_ratio: float = 1.0

    def degrees(self, ticks: int) -> float:
        return (ticks - self.zero_offset) * self.direction * 360.0 / (TICKS_PER_REV * self.gear_ratio)


class DynamixelBus:
    """Several servos on one Protocol 2.0 line: bytes in, reply bytes out.

    Parameters
    ----------
    ids
        Servo IDs on the bus.
    positions
        Initial present positions (ticks) per ID (default 2048).
    clock, time_scale
        Passed to every :class:`Servo`.
    seed
        Seed for the random fault rates.
    axes
        Optional ``{name: {"id", "zero_offset", "direction", "gear_ratio"}}`` for :meth:`state`.
    """

    def __init__(self, ids: Iterable[int] = (1, 2, 3, 4), positions: Mapping[int, int] | None = None,
                 clock: Callable[[], float] = time.monotonic, time_scale: float = 1.0,
                 seed: int | None = 0, axes: Mapping[str, Mapping[str, Any]] | None = None) -> None:
        positions = positions or {}
        self.clock = clock
        self.servos: dict[int, Servo] = {
            i: Servo(i, positions.get(i, 2048), clock=clock, time_scale=time_scale) for i in ids}
        self.parser = PacketParser()
        self.faults = Faults()
        self.rng = random.Random(seed)
        self.axes = {k: AxisMap(**dict(v)) for k, v in (axes or {}).items()}
        self.log: list[Packet] = []  # instructions received (bounded)

    # -- control ----------------------------------------------------------------------------
    def set_faults(self, **kw: Any) -> None:
        for k, v in kw.items():
            if not hasattr(self.faults, k) or k in ("dropped", "corrupted"):
                raise KeyError(f"unknown fault {k!r}")
            setattr(self.faults, k, type(getattr(self.faults, k))(v))

    def clear_faults(self) -> None:
        self.faults = Faults()

    def hardware_error(self, dev_id: int, bits: int, on_goal: bool = False) -> None:
        s = self.servos[dev_id]
        if on_goal:
            s.hw_error_on_goal |= bits
        else:
            s.set_hardware_error(bits)

    def state(self) -> dict[str, Any]:
        servos = {str(i): s.snapshot() for i, s in self.servos.items()}
        joints = {}
        for name, ax in self.axes.items():
            if ax.id in self.servos:
                joints[name] = ax.degrees(self.servos[ax.id].get(132, 4, signed=True))
        return {"t": self.clock(), "servos": servos, "joints": joints}

    # -- protocol ---------------------------------------------------------------------------
    def handle(self, data: bytes) -> bytes:
        """Feed received bytes; return the reply bytes (possibly several status packets)."""
        out = bytearray()
        for pkt in self.parser.feed(data):
            self.log.append(pkt)
            del self.log[:-1000]
            for reply in self.execute(pkt):
                out += self._inject(reply)
        return bytes(out)

    def _inject(self, reply: bytes) -> bytes:
        f = self.faults
        if f.hang:
            return b""
        if f.drop_next > 0 or (f.drop_rate and self.rng.random() < f.drop_rate):
            f.drop_next = max(0, f.drop_next - 1)
            f.dropped += 1
            return b""
        if f.corrupt_next > 0 or (f.corrupt_rate and self.rng.random() < f.corrupt_rate):
            f.corrupt_next = max(0, f.corrupt_next - 1)
            f.corrupted += 1
            b = bytearray(reply)
            b[-1] ^= 0x5A  # CRC high byte: framing intact, checksum wrong
            return bytes(b)
        return reply

    def execute(self, pkt: Packet) -> list[bytes]:
        """Status packets answering one instruction packet (in bus order)."""
        i, p = pkt.instruction, pkt.params
        targets = list(self.servos) if pkt.id == BROADCAST_ID else [pkt.id] if pkt.id in self.servos else []
        reply_ok = pkt.id != BROADCAST_ID
        if i == INST["ping"]:
            out = []
            for t in targets:
                s = self.servos[t]
                out.append(encode_status(t, s.status_error(), bytes(s.table[0:2]) + bytes([s.table[6]])))
            return out
        if i == INST["read"]:
            if not targets or not reply_ok:
                return []
            s = self.servos[pkt.id]
            if len(p) != 4:
                return [encode_status(pkt.id, s.status_error(ERR["data_length"]))]
            addr, n = p[0] | p[1] << 8, p[2] | p[3] << 8
            err, data = s.read(addr, n)
            return [encode_status(pkt.id, s.status_error(err), data)]
        if i == INST["write"]:
            out = []
            for t in targets:
                s = self.servos[t]
                err = s.write(p[0] | p[1] << 8, p[2:]) if len(p) > 2 else ERR["data_length"]
                if reply_ok:
                    out.append(encode_status(t, s.status_error(err)))
            return out
        if i == INST["reboot"]:
            out = []
            for t in targets:
                self.servos[t].reboot()
                if reply_ok:
                    out.append(encode_status(t, self.servos[t].status_error()))
            return out
        if i == INST["sync_read"] and pkt.id == BROADCAST_ID and len(p) >= 4:
            addr, n = p[0] | p[1] << 8, p[2] | p[3] << 8
            out = []
            for t in p[4:]:
                if t in self.servos:
                    s = self.servos[t]
                    err, data = s.read(addr, n)
                    out.append(encode_status(t, s.status_error(err), data))
            return out
        if i == INST["sync_write"] and pkt.id == BROADCAST_ID and len(p) >= 4:
            addr, n = p[0] | p[1] << 8, p[2] | p[3] << 8
            body = p[4:]
            for k in range(0, len(body) - n, n + 1):
                t = body[k]
                if t in self.servos:
                    self.servos[t].write(addr, body[k + 1:k + 1 + n])
            return []
        if i == INST["bulk_read"] and pkt.id == BROADCAST_ID:
            out = []
            for k in range(0, len(p) - 4, 5):
                t, addr, n = p[k], p[k + 1] | p[k + 2] << 8, p[k + 3] | p[k + 4] << 8
                if t in self.servos:
                    s = self.servos[t]
                    err, data = s.read(addr, n)
                    out.append(encode_status(t, s.status_error(err), data))
            return out
        if i == INST["bulk_write"] and pkt.id == BROADCAST_ID:
            k = 0
            while k + 5 <= len(p):
                t, addr, n = p[k], p[k + 1] | p[k + 2] << 8, p[k + 3] | p[k + 4] << 8
                if t in self.servos:
                    self.servos[t].write(addr, p[k + 5:k + 5 + n])
                k += 5 + n
            return []
        if reply_ok and targets:
            return [encode_status(pkt.id, self.servos[pkt.id].status_error(ERR["instruction"]))]
        return []


class BusTransport:
    """An in-process :class:`DynamixelBus` as a byte transport (``write``/``read``/...).

    Replies are available as soon as the instruction is written; ``read`` never waits, so a
    dropped reply is an instant timeout. For fast unit tests; timing-faithful tests use the
    process emulator on a pty.
    """

    def __init__(self, bus: DynamixelBus) -> None:
        self.bus = bus
        self._rx = bytearray()
        self.closed = False
        self.written: list[bytes] = []

    def write(self, data: bytes) -> None:
        if self.closed:
            raise OSError(5, "bus transport closed")
        self.written.append(bytes(data))
        self._rx += self.bus.handle(bytes(data))

    def read(self, n: int, timeout: float = 0.0) -> bytes:
        if self.closed:
            raise OSError(5, "bus transport closed")
        out = bytes(self._rx[:n])
        del self._rx[:n]
        return out

    @property
    def in_waiting(self) -> int:
        return len(self._rx)

    def reset_input(self) -> None:
        self._rx.clear()

    def close(self) -> None:
        self.closed = True


class PtyBusThread:
    """Thread mode: serve a :class:`DynamixelBus` on a fresh pty from a thread of this process.

    Convenient when a test wants the bus object itself at hand (``.bus``: faults, hardware
    errors, state). Timing is worse than the process mode (the SDK's busy-poll competes for
    the GIL), so prefer :func:`start_bus` for timing-sensitive work. :meth:`kill` closes the
    master side: the port vanishes as if the device were unplugged.
    """

    def __init__(self, bus: DynamixelBus) -> None:
        import threading

        from virtual.wire.pty import open_pty

        self.bus = bus
        self._master, self._slave, self.port = open_pty()
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._run, name=f"dxl-bus {self.port}", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                r, _, _ = select.select([self._master], [], [], 0.05)
                if not r:
                    continue
                data = os.read(self._master, 4096)
            except BlockingIOError:
                continue
            except (OSError, ValueError):
                return
            with self._lock:
                reply = self.bus.handle(data)
            if reply:
                if self.bus.faults.delay_s:
                    time.sleep(self.bus.faults.delay_s)
                try:
                    _write_all(self._master, reply)
                except OSError:
                    return

    def state(self) -> dict[str, Any]:
        with self._lock:
            return self.bus.state()

    def kill(self) -> None:
        """Close the pty (both sides held here): the client's port vanishes."""
        self._stop.set()
        self._thread.join(timeout=2)
        for fd in (self._master, self._slave):
            try:
                os.close(fd)
            except OSError:
                pass

    close = kill

    def __enter__(self) -> "PtyBusThread":
        return self

    def __exit__(self, *exc: object) -> None:
        self.kill()


# --- process -------------------------------------------------------------------------------


def _control(bus: DynamixelBus, req: Mapping[str, Any]) -> dict[str, Any]:
    cmd = req.get("cmd")
    if cmd == "state":
        return {"ok": True, **bus.state()}
    if cmd == "faults":
        bus.set_faults(**{k: v for k, v in req.items() if k != "cmd"})
        return {"ok": True, "faults": vars(bus.faults)}
    if cmd == "clear":
        bus.clear_faults()
        return {"ok": True}
    if cmd == "hardware_error":
        bus.hardware_error(int(req["id"]), int(req["bits"]), bool(req.get("on_goal", False)))
        return {"ok": True}
    if cmd == "poke":
        s = bus.servos[int(req["id"])]
        s.update()
        s._set(int(req["addr"]), int(req.get("size", 1)), int(req["value"]))
        return {"ok": True}
    if cmd == "ping":
        return {"ok": True}
    raise KeyError(f"unknown command {cmd!r}")


def serve(bus: DynamixelBus, master_fd: int, server: socket.socket,
          parent_pid: int | None = None) -> None:
    """Serve the pty master and the control socket until ``die`` (or a signal).

    With ``parent_pid`` the emulator exits within a second once that process is gone (it is
    re-parented), so a crashed test run leaves no emulator behind.
    """
    clients: dict[socket.socket, bytearray] = {}
    while True:
        if parent_pid is not None and os.getppid() != parent_pid:
            os._exit(0)
        rlist = [master_fd, server, *clients]
        r, _, _ = select.select(rlist, [], [], 0.5)
        for s in r:
            if s == master_fd:
                try:
                    data = os.read(master_fd, 4096)
                except BlockingIOError:
                    continue
                except OSError:
                    time.sleep(0.01)  # slave side not open (EIO): wait for a client
                    continue
                reply = bus.handle(data)
                if reply:
                    if bus.faults.delay_s:
                        time.sleep(bus.faults.delay_s)
                    _write_all(master_fd, reply)
            elif s is server:
                conn, _ = server.accept()
                clients[conn] = bytearray()
            else:
                try:
                    chunk = s.recv(65536)
                except OSError:
                    chunk = b""
                if not chunk:
                    clients.pop(s).clear()
                    s.close()
                    continue
                buf = clients[s]
                buf += chunk
                while b"\n" in buf:
                    line, _, rest = bytes(buf).partition(b"\n")
                    buf[:] = rest
                    try:
                        req = json.loads(line)
                        if req.get("cmd") == "die":
                            os._exit(3)  # the pty master closes with the process
                        resp = _control(bus, req)
                    except Exception as exc:  # report, keep serving
                        resp = {"ok": False, "error": f"{type(exc).__name__}: {exc}"}
                    s.sendall(json.dumps(resp).encode() + b"\n")


def _write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        try:
            n = os.write(fd, view)
            view = view[n:]
        except BlockingIOError:
            select.select([], [fd], [], 0.1)


class BusControl:
    """Client of an emulator's control channel (``host, port`` from the announcement)."""

    def __init__(self, address: tuple[str, int] | str, timeout: float = 3.0) -> None:
        if isinstance(address, str):
            host, port = address.rsplit(":", 1)
            address = (host, int(port))
        self.sock = socket.create_connection(address, timeout=timeout)
        self._buf = b""

    def request(self, cmd: str, **kw: Any) -> dict[str, Any]:
        self.sock.sendall(json.dumps({"cmd": cmd, **kw}).encode() + b"\n")
        while b"\n" not in self._buf:
            chunk = self.sock.recv(65536)
            if not chunk:
                raise ConnectionError("emulator control channel closed")
            self._buf += chunk
        line, _, self._buf = self._buf.partition(b"\n")
        resp = json.loads(line)
        if not resp.get("ok"):
            raise RuntimeError(f"emulator refused {cmd}: {resp.get('error')}")
        return resp

    def state(self) -> dict[str, Any]:
        return self.request("state")

    def joints(self) -> dict[str, float]:
        return dict(self.state()["joints"])

    def faults(self, **kw: Any) -> dict[str, Any]:
        return self.request("faults", **kw)

    def clear(self) -> None:
        self.request("clear")

    def hardware_error(self, dev_id: int, bits: int, on_goal: bool = False) -> None:
        self.request("hardware_error", id=dev_id, bits=bits, on_goal=on_goal)

    def poke(self, dev_id: int, addr: int, value: int, size: int = 1) -> None:
        self.request("poke", id=dev_id, addr=addr, value=value, size=size)

    def die(self) -> None:
        try:
            self.sock.sendall(b'{"cmd": "die"}\n')
        except OSError:
            pass

    def close(self) -> None:
        self.sock.close()

    def __enter__(self) -> "BusControl":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def start_bus(ids: Sequence[int] = (1, 2, 3, 4), *, positions: Mapping[int, int] | None = None,
              axes: Mapping[str, Mapping[str, Any]] | None = None, time_scale: float = 1.0,
              seed: int = 0, faults: Mapping[str, Any] | None = None,
              start_timeout: float = 10.0):
    """Start the emulator in its own process; return an ``EmulatorProcess`` (``.port``, ``.control``).

    Close it (or use it as a context manager) to stop the process.
    """
    from virtual.wire.pty import EmulatorProcess

    args = ["--ids", ",".join(str(i) for i in ids), "--seed", str(seed), "--time-scale", str(time_scale)]
    if positions:
        args += ["--positions", ",".join(f"{k}:{v}" for k, v in positions.items())]
    if axes:
        args += ["--axes", json.dumps(axes)]
    if faults:
        args += ["--faults", json.dumps(dict(faults))]
    return EmulatorProcess("virtual.wire.dynamixel_bus", args, start_timeout=start_timeout)


def main(argv: Sequence[str] | None = None) -> int:
    """Command line: start the bus on a fresh pty and print the announcement JSON line."""
    ap = argparse.ArgumentParser(prog="python -m virtual.wire.dynamixel_bus", description=__doc__.split("\n")[0])
    ap.add_argument("--ids", default="1,2,3,4", help="comma-separated servo IDs")
    ap.add_argument("--positions", default="", help="initial ticks, e.g. 1:2048,2:1024")
    ap.add_argument("--axes", default="", help="JSON {name: {id, zero_offset, direction, gear_ratio}}")
    ap.add_argument("--faults", default="", help='JSON, e.g. {"drop_rate": 0.1}')
    ap.add_argument("--time-scale", type=float, default=1.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--control-port", type=int, default=0)
    ap.add_argument("--no-orphan", action="store_true",
                    help="keep running when the starting process dies (default: exit)")
    a = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, stream=sys.stderr)
    from virtual.wire.pty import open_pty

    parent = None if a.no_orphan else os.getppid()
    ids = [int(x) for x in a.ids.split(",") if x.strip()]
    positions = {int(k): int(v) for k, v in (kv.split(":") for kv in a.positions.split(",") if kv)}
    bus = DynamixelBus(ids, positions, time_scale=a.time_scale, seed=a.seed,
                       axes=json.loads(a.axes) if a.axes else None)
    if a.faults:
        bus.set_faults(**json.loads(a.faults))
    master, slave, path = open_pty()
    server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    server.bind(("127.0.0.1", a.control_port))
    server.listen(8)
    signal.signal(signal.SIGTERM, lambda *_: os._exit(0))
    host, port = server.getsockname()
    sys.stdout.write(json.dumps({"port": path, "control": f"{host}:{port}", "pid": os.getpid(),
                                 "ids": ids}) + "\n")
    sys.stdout.flush()
    try:
        serve(bus, master, server, parent_pid=parent)
    finally:  # pragma: no cover - process exit
        os.close(slave)
    return 0


if __name__ == "__main__":
    sys.exit(main())

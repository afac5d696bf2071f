"""Dynamixel Protocol 2.0 packet codec of the bus emulator (its own reading of the manual).

Owns the instruction/error code tables, CRC-16 (poly 0x8005, init 0, no reflection), byte
stuffing (``FF FF FD`` -> ``FF FF FD FD``), :func:`encode_instruction`, :func:`encode_status`,
:func:`decode_packet` and the streaming :class:`PacketParser`. Shared by the emulator and the
tests, never by the drivers (they use dynamixel-sdk's packets).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence


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

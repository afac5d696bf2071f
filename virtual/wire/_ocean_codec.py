"""The Ocean emulator's frame encoders (its own reading of the manual, never the driver's).

Owns the byte codes (ACK, NAK, STX, ETX, CR), the binary S-frame layout (:func:`encode_frame`),
compression (:func:`compress`) and the ASCII S-frame (:func:`encode_frame_ascii`), including the
two readings of the DWORD-frame checksum (sum of pixel values, or of all 16-bit data words).
"""

from __future__ import annotations

import numpy as np

from virtual.wire.ocean_model import Settings

ACK, NAK, STX, ETX, CR, LF = 0x06, 0x15, 0x02, 0x03, 0x0D, 0x0A

def _words(values: list[int]) -> bytes:
    return b"".join(int(v & 0xFFFF).to_bytes(2, "big") for v in values)


def compress(values: np.ndarray) -> bytes:
    """Signed 8-bit deltas from the previous pixel (the first from 0); else 0x80 + 16-bit value."""
    out = bytearray()
    prev = 0
    for v in values.tolist():
        d = v - prev
        if -127 <= d <= 127:
            out.append(d & 0xFF)
        else:
            out.append(0x80)
            out += int(v).to_bytes(2, "big")
        prev = v
    return bytes(out)


def frame_checksum(values: np.ndarray, dwords: bool, convention: str = "pixels") -> int:
    """The frame checksum as this unit computes it: the sum of the pixel values mod 65536, or
    (``convention = "words"``, DWORD frames only) the sum of all 16-bit data words."""
    v = np.asarray(values, dtype=np.int64)
    if dwords and convention == "words":
        return int((v >> 16).sum() + (v & 0xFFFF).sum()) & 0xFFFF
    return int(v.sum()) & 0xFFFF


def encode_frame(values: np.ndarray, s: Settings, baseline: int = 0,
                 convention: str = "pixels") -> bytes:
    """The binary S reply after STX (header ... 0xFFFD [checksum])."""
    dwords = s.scans > 1
    head = [0xFFFF, 1 if dwords else 0, s.scans, s.integration_ms,
            (baseline >> 16) & 0xFFFF, baseline & 0xFFFF, s.pixel_mode] + list(s.pixel_params)
    out = bytearray(_words(head))
    if dwords:
        out += b"".join(int(v).to_bytes(4, "big") for v in values.tolist())
    elif s.compression:
        out += compress(values)
    else:
        out += _words(values.tolist())
    out += _words([0xFFFD])
    if s.checksum:
        out += _words([frame_checksum(values, dwords, convention)])
    return bytes(out)


def encode_frame_ascii(values: np.ndarray, s: Settings, baseline: int = 0,
                       convention: str = "pixels") -> bytes:
    """The ASCII-mode S reply after STX: every item in decimal ending CR LF."""
    dwords = s.scans > 1
    items = [0xFFFF, 1 if dwords else 0, s.scans, s.integration_ms,
             (baseline >> 16) & 0xFFFF, baseline & 0xFFFF, s.pixel_mode] + list(s.pixel_params)
    items += values.tolist() + [0xFFFD]
    if s.checksum:
        items.append(frame_checksum(values, dwords, convention))
    return b"".join(f"{int(v)}\r\n".encode() for v in items)

"""Wire codecs of the Ocean driver (pure, no I/O), from the Flame-S manual's "Firmware and
Advanced Communications" chapter:

- byte codes (ACK, NAK, STX, ETX, CR, LF) and command encoding in binary mode (letter + 16-bit
  words, MSB first) and ASCII mode (letter, then each data value in decimal ending with CR; a
  command without data is the letter alone);
- the ``v`` version word: its decimal digits are the version (1000 = "1.00.0");
- compressed pixel data (:func:`decode_compressed`);
- the binary S frame (:func:`parse_binary_frame`): header, pixel words / dwords / compressed
  bytes, trailer 0xFFFD, optional checksum. For DWORD frames the manual does not fix whether the
  checksum sums the pixel values or all 16-bit data words; :func:`dword_checksums` gives both and
  the parser accepts the configured one, or in ``"auto"`` either, reporting which one matched
  when the frame distinguishes them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from bench.core.errors import ChecksumError, ProtocolError

ACK, NAK, STX, ETX, CR, LF = 0x06, 0x15, 0x02, 0x03, 0x0D, 0x0A
FULL_SCALE = 65535
HEADER_WORDS = 7
TRAILER = 0xFFFD
DWORD_CONVENTIONS = ("pixels", "words")


def encode_binary(letter: str, args: Sequence[int]) -> bytes:
    """A binary-mode command: the letter(s), then each argument as a 16-bit word, MSB first."""
    return letter.encode("ascii") + b"".join(int(a & 0xFFFF).to_bytes(2, "big") for a in args)


def encode_ascii(letter: str, args: Sequence[int]) -> bytes:
    """An ASCII-mode command: the letter(s), then each data value in decimal ending with CR.
    A command without data is the letter alone (no CR)."""
    return letter.encode("ascii") + b"".join(f"{int(a)}".encode() + bytes([CR]) for a in args)


def decode_version(word: int) -> str:
    """The ``v`` reply word as a version: its decimal digits, e.g. 1000 -> ``"1.00.0"``."""
    if not 0 <= int(word) <= 0xFFFF:
        raise ProtocolError(f"version word {word!r} is not a 16-bit value")
    d = f"{int(word):04d}"
    return f"{int(d[:-3])}.{d[-3:-1]}.{d[-1]}"


def dword_checksums(values: np.ndarray) -> dict[str, int]:
    """The two readings of a DWORD frame's checksum: the sum of the pixel values, and the sum
    of all 16-bit data words (both halves of each DWORD), each modulo 65536."""
    v = np.asarray(values, dtype=np.int64)
    return {"pixels": int(v.sum()) & 0xFFFF,
            "words": int((v >> 16).sum() + (v & 0xFFFF).sum()) & 0xFFFF}


def check_checksum(got: int, values: np.ndarray, dwords: bool, convention: str) -> str | None:
    """Verify a frame checksum; return the DWORD convention this frame proved (or None).

    ``convention`` is ``"pixels"``, ``"words"`` or ``"auto"`` (either is accepted; when they
    differ, the one that matched is returned so the caller can remember it).

    Raises
    ------
    ChecksumError
        No accepted reading matches ``got``.
    """
    if not dwords:
        want = int(np.asarray(values, dtype=np.int64).sum()) & 0xFFFF
        if got != want:
            raise ChecksumError(f"frame checksum 0x{got:04X} != 0x{want:04X} computed over the "
                                f"pixel data")
        return None
    sums = dword_checksums(values)
    accepted = DWORD_CONVENTIONS if convention == "auto" else (convention,)
    matched = [c for c in accepted if sums[c] == got]
    if not matched:
        detail = ", ".join(f"{c} 0x{sums[c]:04X}" for c in accepted)
        raise ChecksumError(f"DWORD frame checksum 0x{got:04X} matches no accepted reading "
                            f"({detail})")
    if convention == "auto" and sums["pixels"] != sums["words"]:
        return matched[0]
    return None


def decode_compressed(data: bytes | bytearray, n: int, start: int = 0) -> tuple[np.ndarray, int]:
    """Decode ``n`` compressed pixel values from ``data[start:]``; return (values, end index).

    Raises
    ------
    ChecksumError
        If the data end before ``n`` values or a value leaves 0..65535.
    """
    out = np.empty(n, dtype=np.int64)
    i, prev = start, 0
    L = len(data)
    for j in range(n):
        if i >= L:
            raise ChecksumError(f"compressed pixel data ended after {j} of {n} pixels")
        b = data[i]
        if b == 0x80:
            if i + 2 >= L:
                raise ChecksumError(f"compressed pixel data ended inside the escape of pixel {j}")
            prev = data[i + 1] << 8 | data[i + 2]
            i += 3
        else:
            prev += b - 256 if b > 127 else b
            i += 1
            if not 0 <= prev <= FULL_SCALE:
                raise ChecksumError(f"compressed pixel data out of range at pixel {j}: {prev}")
        out[j] = prev
    return out, i


def compressed_missing(data: bytes | bytearray, npix: int, start: int = 0) -> int:
    """Lower bound of the bytes still missing for ``npix`` compressed values from ``start``."""
    i, j, n = start, 0, len(data)
    while j < npix and i < n:
        i += 3 if data[i] == 0x80 else 1
        j += 1
    return max(i - n, 0) + (npix - j)


class FrameLayoutError(ChecksumError):
    """The frame's bytes do not fit the expected layout (e.g. the trailer is not where an
    uncompressed frame puts it): a corrupted frame, or a unit sending another data format."""


class NeedMore(Exception):
    """Internal to the frame parser: ``n`` more bytes are needed (at least)."""

    def __init__(self, n: int) -> None:
        super().__init__(n)
        self.n = n


@dataclass
class Frame:
    """A decoded S frame."""

    dwords: bool
    scans: int
    integration_ms: int
    baseline: int
    pixel_mode: int
    values: np.ndarray
    checksum_convention: str | None = None  # DWORD convention this frame proved (auto mode)
    raw: bytes = field(repr=False, default=b"")


def parse_binary_frame(buf: bytes | bytearray, npix: int, *, compressed: bool, checksum: bool,
                       convention: str = "auto", expect_scans: int | None = None,
                       expect_integration_ms: int | None = None) -> tuple[Frame, int]:
    """Parse a binary S frame (the bytes after STX) from ``buf``; return (frame, bytes used).

    Raises
    ------
    NeedMore
        ``buf`` ends before the frame does (``.n``: at least that many more bytes).
    ChecksumError
        Malformed header or trailer, compressed data out of range, or a checksum mismatch.
    ProtocolError
        A well-formed frame that is not the answer to this request: other pixel mode, scans,
        integration time or data size than requested.
    """
    hb = 2 * HEADER_WORDS
    if len(buf) < hb:
        raise NeedMore(hb - len(buf))
    w = [int.from_bytes(buf[i:i + 2], "big") for i in range(0, hb, 2)]
    if w[0] != 0xFFFF or w[1] not in (0, 1):
        raise ChecksumError(f"frame header {bytes(buf[:hb]).hex(' ')} is not 0xFFFF + a "
                            f"data-size flag")
    dwords, scans, integ, baseline, pmode = bool(w[1]), w[2], w[3], w[4] << 16 | w[5], w[6]
    if pmode != 0:
        raise ProtocolError(f"frame pixel mode {pmode}, expected 0 (all pixels)")
    if expect_scans is not None and (scans != expect_scans or dwords != (expect_scans > 1)):
        raise ProtocolError(f"frame says {scans} scan(s) (dwords={dwords}), expected "
                            f"{expect_scans}")
    if expect_integration_ms is not None and integ != expect_integration_ms:
        raise ProtocolError(f"frame says {integ} ms, expected {expect_integration_ms} ms")
    pos = hb
    if dwords:
        end = pos + 4 * npix
        if len(buf) < end:
            raise NeedMore(end - len(buf))
        values = np.frombuffer(bytes(buf[pos:end]), dtype=">u4").astype(np.int64)
    elif compressed:
        missing = compressed_missing(buf, npix, pos)
        if missing:
            raise NeedMore(missing)
        values, end = decode_compressed(buf, npix, pos)
    else:
        end = pos + 2 * npix
        if len(buf) < end:
            raise NeedMore(end - len(buf))
        values = np.frombuffer(bytes(buf[pos:end]), dtype=">u2").astype(np.int64)
    tail = 2 + (2 if checksum else 0)
    if len(buf) < end + tail:
        raise NeedMore(end + tail - len(buf))
    if int.from_bytes(buf[end:end + 2], "big") != TRAILER:
        raise FrameLayoutError(f"frame trailer {bytes(buf[end:end + 2]).hex(' ')} is not FF FD "
                            f"(wrong pixel count, compression, or a corrupted frame)")
    proved = None
    if checksum:
        proved = check_checksum(int.from_bytes(buf[end + 2:end + 4], "big"), values, dwords,
                                convention)
    used = end + tail
    return Frame(dwords, scans, integ, baseline, pmode, values, proved, bytes(buf[:used])), used


def parse_ascii_frame(numbers: Sequence[int], npix: int, *, checksum: bool,
                      convention: str = "auto", expect_scans: int | None = None,
                      expect_integration_ms: int | None = None) -> Frame:
    """Check an ASCII-mode S frame given as its decimal values (header, pixels, trailer,
    [checksum]); same errors as :func:`parse_binary_frame`."""
    n = HEADER_WORDS + npix + 1 + (1 if checksum else 0)
    if len(numbers) != n:
        raise ChecksumError(f"ASCII frame has {len(numbers)} values, expected {n}")
    numbers = [int(x) for x in numbers]
    w = numbers[:HEADER_WORDS]
    if any(not 0 <= x <= 0xFFFF for x in w):
        raise ChecksumError(f"ASCII frame header {w} has a value outside 0..65535")
    if w[0] != 0xFFFF or w[1] not in (0, 1):
        raise ChecksumError(f"ASCII frame header {w} is malformed")
    if w[6] != 0:
        raise ProtocolError(f"frame pixel mode {w[6]}, expected 0 (all pixels)")
    dwords = bool(w[1])
    if expect_scans is not None and (w[2] != expect_scans or dwords != (expect_scans > 1)):
        raise ProtocolError(f"frame says {w[2]} scan(s), expected {expect_scans}")
    if expect_integration_ms is not None and w[3] != expect_integration_ms:
        raise ProtocolError(f"frame says {w[3]} ms, expected {expect_integration_ms} ms")
    values = np.asarray(numbers[HEADER_WORDS:HEADER_WORDS + npix], dtype=np.int64)
    limit = 0xFFFFFFFF if dwords else FULL_SCALE
    if values.size and (values.min() < 0 or values.max() > limit):
        raise ChecksumError("ASCII frame pixel value out of range")
    if numbers[HEADER_WORDS + npix] != TRAILER:
        raise ChecksumError("ASCII frame trailer is not 65533")
    proved = None
    if checksum:
        proved = check_checksum(int(numbers[-1]), values, dwords, convention)
    return Frame(dwords, w[2], w[3], w[4] << 16 | w[5], w[6], values, proved)

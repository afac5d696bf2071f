"""Reply-frame fuzz of the three driver codecs: random and mutated reply frames are
fed to the pure decode functions the drivers use. Whatever the bytes, only project errors
(:class:`bench.core.errors.BenchError` subclasses) come out (plus the Ocean parser's internal
"need more bytes" signal, which the live reader turns into a timeout), and a frame is never
accepted as the answer to a different request: every accepted frame is checked against an
independent oracle (our emulators' own codecs, or the request's own fields).

Each Hypothesis example drives a batch of frames; each test asserts how many frames it fed, so
the three together feed over 3e5 frames in bounded time (a few seconds here).
"""

from __future__ import annotations

import random
from typing import Callable

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bench.core.errors import BenchError
from drivers.dynamixel._link import Request, decode_status
from drivers.modbus._client import decode_rtu_reply
from drivers.ocean.codec import NeedMore, decode_version, parse_ascii_frame, parse_binary_frame
from virtual.wire._dxl_codec import decode_packet, encode_status
from virtual.wire._ocean_codec import compress

FUZZ = settings(max_examples=300, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
BATCH = 300


def mutate(rng: random.Random, frame: bytes) -> bytes:
    """One random mutation: flip, insert, delete, truncate, extend, splice, or a copy."""
    b = bytearray(frame)
    op = rng.randrange(8)
    if op == 0 and b:
        i = rng.randrange(len(b))
        b[i] ^= 1 << rng.randrange(8)
    elif op == 1:
        b.insert(rng.randrange(len(b) + 1), rng.randrange(256))
    elif op == 2 and b:
        del b[rng.randrange(len(b))]
    elif op == 3 and b:
        del b[rng.randrange(len(b)):]
    elif op == 4:
        b += bytes(rng.randrange(256) for _ in range(rng.randrange(1, 8)))
    elif op == 5 and b:
        i = rng.randrange(len(b))
        b[i] = rng.choice((0x00, 0xFF, 0xFD, 0x55, 0x80, 0x7F))
    elif op == 6 and len(b) > 2:
        i, j = sorted(rng.sample(range(len(b)), 2))
        b[i:j] = b[i:j][::-1]
    return bytes(b)


def run_batch(rng: random.Random, seeds: list[bytes], feed: Callable[[bytes], None]) -> int:
    n = 0
    for base in seeds:
        feed(base)
        n += 1
        frame = base
        for _ in range(BATCH // max(1, len(seeds))):
            frame = mutate(rng, frame if rng.random() < 0.7 else base)
            feed(frame)
            n += 1
    for _ in range(BATCH // 4):
        feed(bytes(rng.randrange(256) for _ in range(rng.randrange(0, 40))))
        n += 1
    return n


# --- Dynamixel ----------------------------------------------------------------------------------

DXL = {"frames": 0, "accepted": 0}


def dxl_feed(req: Request) -> Callable[[bytes], None]:
    def feed(frame: bytes) -> None:
        DXL["frames"] += 1
        try:
            params, err = decode_status(frame, req)
        except BenchError:
            return
        # accepted: an independent decoder must agree that this is req's answer
        pkt = decode_packet(frame)
        assert pkt.is_status and pkt.id == req.dxl_id
        assert params == pkt.data and len(params) == req.reply_len and err == pkt.error
        DXL["accepted"] += 1
    return feed


@FUZZ
@given(dev=st.integers(0, 252), want_len=st.sampled_from([0, 1, 2, 3, 4, 14, 20]),
       other_len=st.sampled_from([0, 1, 3, 4, 14, 20]), other_dev=st.integers(0, 252),
       err=st.integers(0, 255), seed=st.integers(0, 2**32 - 1), data=st.binary(max_size=24))
def fuzz_dynamixel_status_decoder(dev: int, want_len: int, other_len: int, other_dev: int,
                                       err: int, seed: int, data: bytes) -> None:
    rng = random.Random(seed)
    req = Request("fuzz", dev, want_len)
    right = encode_status(dev, err, (data + bytes(want_len))[:want_len])
    wrong = encode_status(other_dev, err, (data + bytes(other_len))[:other_len])
    run_batch(rng, [right, wrong, right + wrong], dxl_feed(req))


def test_fuzz_dynamixel_fed_enough_frames() -> None:
    fuzz_dynamixel_status_decoder()
    assert DXL["frames"] >= 100_000 and DXL["accepted"] > 0


# --- Ocean --------------------------------------------------------------------------------------

OCEAN = {"frames": 0, "accepted": 0}


def ocean_frame(values: list[int], scans: int, integ: int, compressed: bool, checksum: bool,
                convention: str, pmode: int = 0) -> bytes:
    dwords = scans > 1
    head = [0xFFFF, int(dwords), scans, integ, 0, 0, pmode]
    out = b"".join(int(v).to_bytes(2, "big") for v in head)
    v = np.asarray(values, dtype=np.int64)
    if dwords:
        out += b"".join(int(x).to_bytes(4, "big") for x in values)
    elif compressed:
        out += compress(v)
    else:
        out += b"".join(int(x).to_bytes(2, "big") for x in values)
    out += b"\xff\xfd"
    if checksum:
        s = int((v >> 16).sum() + (v & 0xFFFF).sum()) if dwords and convention == "words" \
            else int(v.sum())
        out += (s & 0xFFFF).to_bytes(2, "big")
    return out


@FUZZ
@given(npix=st.integers(1, 12), scans=st.sampled_from([1, 1, 2, 3]),
       integ=st.integers(1, 65000), other=st.integers(1, 65000),
       compressed=st.booleans(), checksum=st.booleans(),
       unit=st.sampled_from(["pixels", "words"]),
       driver=st.sampled_from(["auto", "pixels", "words"]), seed=st.integers(0, 2**32 - 1))
def fuzz_ocean_frame_decoder(npix: int, scans: int, integ: int, other: int,
                                  compressed: bool, checksum: bool, unit: str, driver: str,
                                  seed: int) -> None:
    rng = random.Random(seed)
    top = 65535 * scans
    vals = [rng.choice((0, 1, 127, 128, 65535, top, rng.randrange(top + 1))) for _ in range(npix)]
    right = ocean_frame(vals, scans, integ, compressed and scans == 1, checksum, unit)
    wrong = ocean_frame(vals, scans, other, compressed and scans == 1, checksum, unit)
    wrong_mode = ocean_frame(vals, scans, integ, False, checksum, unit, pmode=1)

    def feed(frame: bytes) -> None:
        OCEAN["frames"] += 1
        try:
            fr, used = parse_binary_frame(frame, npix, compressed=compressed, checksum=checksum,
                                          convention=driver, expect_scans=scans,
                                          expect_integration_ms=integ)
        except (BenchError, NeedMore):
            return
        assert fr.scans == scans and fr.integration_ms == integ and fr.pixel_mode == 0
        assert fr.dwords == (scans > 1) and fr.values.shape == (npix,)
        assert used <= len(frame) and int(fr.values.min()) >= 0
        OCEAN["accepted"] += 1

    run_batch(rng, [right, wrong, wrong_mode], feed)
    # the ASCII frame decoder gets the same values as numbers (and mutated lists)
    nums = list(np.frombuffer(right[:14], dtype=">u2")) + vals + [0xFFFD]
    if checksum:
        nums.append(int.from_bytes(right[-2:], "big"))
    for k in range(40):
        ns = list(nums)
        if k:
            i = rng.randrange(len(ns))
            ns[i] = rng.choice((0, -1, 65535, 65536, 2**32, rng.randrange(-5, 70000)))
        if k % 7 == 3:
            del ns[rng.randrange(len(ns))]
        OCEAN["frames"] += 1
        try:
            fr = parse_ascii_frame(ns, npix, checksum=checksum, convention=driver,
                                   expect_scans=scans, expect_integration_ms=integ)
        except BenchError:
            continue
        assert fr.scans == scans and fr.integration_ms == integ and fr.values.shape == (npix,)


def test_fuzz_ocean_fed_enough_frames() -> None:
    fuzz_ocean_frame_decoder()
    assert OCEAN["frames"] >= 100_000 and OCEAN["accepted"] > 0


@given(st.integers(-(2**20), 2**20))
@settings(max_examples=300, deadline=None, derandomize=True)
def test_fuzz_ocean_version_word(word: int) -> None:
    try:
        text = decode_version(word)
    except BenchError:
        assert not 0 <= word <= 0xFFFF
        return
    assert text.replace(".", "").lstrip("0") == str(word).lstrip("0")


# --- Modbus -------------------------------------------------------------------------------------

MODBUS = {"frames": 0, "accepted": 0}


def crc(body: bytes) -> bytes:
    from pymodbus.framer import FramerRTU
    return FramerRTU.compute_CRC(body).to_bytes(2, "big")


@FUZZ
@given(dev=st.integers(1, 247), other_dev=st.integers(1, 247), count=st.integers(1, 8),
       addr=st.integers(0, 0xFFFF), fc=st.sampled_from([3, 16]), exc=st.integers(1, 11),
       seed=st.integers(0, 2**32 - 1))
def fuzz_modbus_reply_decoder(dev: int, other_dev: int, count: int, addr: int, fc: int,
                                   exc: int, seed: int) -> None:
    rng = random.Random(seed)
    regs = b"".join(rng.randrange(65536).to_bytes(2, "big") for _ in range(count))
    read = bytes([dev, 3, 2 * count]) + regs
    write = bytes([dev, 16]) + addr.to_bytes(2, "big") + count.to_bytes(2, "big")
    excr = bytes([dev, fc | 0x80, exc])
    other = bytes([other_dev]) + (read if fc == 3 else write)[1:]
    short = bytes([dev, 3, 2 * (count - 1)]) + regs[2:]
    seeds = [b + crc(b) for b in (read, write, excr, other, short)]

    def feed(frame: bytes) -> None:
        MODBUS["frames"] += 1
        try:
            resp = decode_rtu_reply(frame, fc, dev, addr, count)
        except BenchError:
            return
        assert resp.dev_id == dev
        if resp.function_code == fc | 0x80:
            MODBUS["accepted"] += 1
            return
        assert resp.function_code == fc
        if fc == 3:
            assert len(resp.registers) == count
        else:
            assert (resp.address, resp.count) == (addr, count)
        MODBUS["accepted"] += 1

    run_batch(rng, seeds, feed)


def test_fuzz_modbus_fed_enough_frames() -> None:
    fuzz_modbus_reply_decoder()
    assert MODBUS["frames"] >= 100_000 and MODBUS["accepted"] > 0

"""The Ocean driver held to the manual (optional commands, ASCII framing, the version word,
calibration strings, checksums), against hand-made byte scripts and the in-process emulator
configured as the less-travelled real units behave (no ``G``; left in ASCII mode; the other DWORD
checksum reading). Facts: the Ocean Optics Flame-S manual, "Firmware and Advanced Communications".
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np
import pytest

from bench.core.errors import ChecksumError
from drivers.ocean import OceanSpectrometer, decode_version, dword_checksums
from drivers.transport import ScriptedTransport
from virtual.wire._ocean_device import DeviceTransport
from virtual.wire.ocean_model import SpectrometerConfig, SpectrometerModel

ACK, NAK, STX = b"\x06", b"\x15", b"\x02"
SMALL = dict(model="custom", pixels=8, dark_pixels=(0, 2), timeout_s=0.2, retries=1)


def w(*values: int) -> bytes:
    return b"".join(int(v & 0xFFFF).to_bytes(2, "big") for v in values)


class Tap(DeviceTransport):
    """The in-process emulated unit, remembering every byte it sent back."""

    def __init__(self, **cfg: Any) -> None:
        super().__init__(SpectrometerModel(SpectrometerConfig(pixels=64, dark_pixels=(0, 4),
                                                              seed=1, time_scale=50.0, **cfg)))
        self.replies = bytearray()

    def read(self, n: int, timeout: float = 0.0) -> bytes:
        out = super().read(n, timeout)
        self.replies += out
        return out

    def sent(self) -> bytes:
        return b"".join(self.written)


def spec_on(t: Tap, **kw: Any) -> OceanSpectrometer:
    return OceanSpectrometer(t, **{"model": "EMU", "pixels": 64, "dark_pixels": (0, 4),
                                   "timeout_s": 0.3, "retries": 1, **kw})


# --- a command the device does not need is never fatal ----------------------------------


#: what the driver sends after the calibration slots, whatever it assumes the unit holds (binary)
def settings(checksum: int = 1, g: list = None) -> list:
    pairs = [(b"k" + w(checksum), ACK)] + (g if g is not None else [(b"G" + w(0), ACK)])
    return pairs + [(b"T" + w(0), ACK), (b"?T", ACK + w(0)), (b"A" + w(1), ACK), (b"?A", ACK + w(1)),
                    (b"P" + w(0), ACK)]




def test_every_setting_is_sent_on_open_whatever_is_assumed() -> None:
    """A unit keeps its settings from an earlier program: G 0, k 0, T 0 are sent although they
    are the reset defaults, and ?T / ?A read back what was set."""
    t = Tap()
    s = spec_on(t, compression=False, checksum=False)
    s.acquire(0.01, 1)
    letters = [bytes(x[:2]) if x[:1] == b"?" else bytes(x[:1]) for x in t.written]
    assert [x for x in letters if x in (b"k", b"G", b"T", b"?T", b"A", b"?A", b"P")] == \
        [b"k", b"G", b"T", b"?T", b"A", b"?A", b"P"]
    assert not s.unsupported
    s.close()


def test_a_unit_left_in_checksum_mode_is_turned_out_of_it() -> None:
    """An earlier program left checksum mode on; checksum = false must send k 0, or
    the unit keeps appending checksums."""
    t = Tap()
    spec_on(t, checksum=True).close()
    t.closed = False
    assert t.device.s.checksum
    s = spec_on(t, checksum=False)
    assert not t.device.s.checksum and not s.checksum_on
    assert s.acquire(0.01, 1).signal.shape == (64,)
    s.close()


def test_unit_without_g_is_opened_and_the_nak_data_bytes_are_not_later_answers() -> None:
    """A unit that lacks G NAKs the letter and then takes the two data bytes for commands
    (two more NAKs): recorded as not supported, drained, and the session goes on."""
    t = Tap(unsupported="G")
    s = spec_on(t, compression=True)
    assert s.unsupported == {"G"} and s.describe().extra["unsupported"] == ["G"]
    assert s.describe().extra["compression"] is False
    assert t.replies.count(NAK) == 6  # the G, then its two data bytes, retried once: all drained at open
    r = s.acquire(0.01, 2)
    assert r.signal.shape == (64,) and np.all(r.signal > 0)
    s.close()


def test_scripted_nak_to_optional_g_is_recorded_byte_exactly() -> None:
    opening = [(b"bB", ACK), (b"v", ACK + w(1000))]
    opening += [(b"?x" + w(n), ACK + t + b"\r\n")
                for n, t in enumerate([b"SN1", b"400.0", b"10.0", b"0", b"0"])]
    pairs = opening + settings(g=[(b"G" + w(1), NAK + NAK + NAK)] * 2)  # a NAK is retried once
    pairs += [(b"I" + w(10), ACK), (b"?I", ACK + w(10))]
    vals = [100, 200, 300, 400, 500, 600, 700, 800]
    pairs += [(b"S", STX + w(0xFFFF, 0, 1, 10, 0, 0, 0, *vals, 0xFFFD, sum(vals)))]
    s = OceanSpectrometer(ScriptedTransport(pairs), **SMALL, compression=True)
    assert s.firmware == "1.00.0" and s.unsupported == {"G"}
    assert s.acquire(0.01, 1).signal.tolist() == vals
    s.close()


# --- ASCII framing per the manual; a unit left in ASCII mode -----------------------------


def test_ascii_commands_are_framed_per_manual_byte_by_byte() -> None:
    """Data values end with CR; commands without data are the letter alone; aA bare; every
    byte written alone and its echo read back before the next."""
    t = Tap()
    s = spec_on(t, mode="ascii", checksum=False)
    s.acquire(0.01, 1)
    sent = t.written
    assert b"aA" in sent and b"\r" not in sent[sent.index(b"aA") - 1:sent.index(b"aA") + 1]
    after = b"".join(sent[sent.index(b"aA") + 1:])
    assert after.startswith(b"v?x0\r?x1\r")          # v alone, then ?x + value + CR
    assert b"k0\rG0\rT0\r?TA1\r?AP0\rI10\r?IS" in after and after.endswith(b"S")
    assert all(len(x) == 1 for x in sent[sent.index(b"aA") + 1:])  # one byte per write
    s.command_mode("binary")
    assert sent[-2:] == [b"b", b"B"] and t.device.s.mode == "binary"
    s.close()


def test_unit_left_in_ascii_mode_is_recovered_without_a_stray_cr() -> None:
    t = Tap(start_mode="ascii")
    s = spec_on(t)
    assert s.found_mode == "ascii" and t.device.s.mode == "binary"
    assert NAK not in t.replies  # the old driver's CR after bB was NAKed by the binary unit
    assert b"\r" not in b"".join(t.written[:2])
    s.acquire(0.01, 1)
    s.close()


def test_next_open_after_an_ascii_session_succeeds() -> None:
    t = Tap()
    a = spec_on(t, mode="ascii")
    a.acquire(0.01, 1)
    a.close()
    t.closed = False
    b = spec_on(t)
    assert b.found_mode == "ascii"
    b.acquire(0.01, 1)
    b.close()


# --- the version word --------------------------------------------------------------------


@pytest.mark.parametrize("word,text", [(1000, "1.00.0"), (3001, "3.00.1"), (1210, "1.21.0"),
                                       (999, "0.99.9"), (12345, "12.34.5")])
def test_version_is_the_word_s_decimal_digits(word: int, text: str) -> None:
    assert decode_version(word) == text


def test_version_from_the_unit() -> None:
    t = Tap(firmware="1.00.0")
    s = spec_on(t)
    assert s.version_word == 1000 and s.firmware == "1.00.0" == s.describe().firmware
    s.close()


# --- calibration strings end CR LF: no stale-byte warnings ------------------------------------------


def test_calibration_strings_read_to_cr_lf_without_stale_warnings(caplog: Any) -> None:
    t = Tap()
    with caplog.at_level(logging.WARNING, logger="drivers.ocean"):
        s = spec_on(t)
        s.acquire(0.01, 1)
        s.close()
    assert not [r for r in caplog.records if "stale" in r.getMessage()]
    assert s.serial == "EMU00001"


def test_calibration_strings_ending_with_cr_alone_are_accepted() -> None:
    pairs = [(b"bB", ACK), (b"v", ACK + w(1000))]
    pairs += [(b"?x" + w(n), ACK + t + b"\r")
              for n, t in enumerate([b"SN1", b"400.0", b"10.0", b"0", b"0"])]
    pairs += settings()
    s = OceanSpectrometer(ScriptedTransport(pairs), **SMALL)
    assert s.wavelength_coeffs == [400.0, 10.0, 0.0, 0.0]
    s.close()


# --- the DWORD checksum convention ------------------------------------------------------------


def test_the_two_dword_readings_differ_only_above_16_bits() -> None:
    assert dword_checksums(np.array([1, 2, 65535])) == {"pixels": 2, "words": 2}
    assert dword_checksums(np.array([65536, 3])) == {"pixels": 3, "words": 4}


@pytest.mark.parametrize("unit", ["pixels", "words"])
def test_dword_checksum_convention_is_detected_and_remembered(unit: str) -> None:
    t = Tap(dword_checksum=unit)
    s = spec_on(t, accumulate_on_device=True)
    assert s.describe().extra["dword_checksum"] == "undetermined"
    r = s.acquire(0.05, 3)  # 3 x ~38000 counts: pixel values over 65535, the readings differ
    assert float(r.signal.max()) * 3 > 65535
    assert s.dword_checksum == unit and s.describe().extra["dword_checksum"] == unit
    s.acquire(0.05, 3)
    s.close()


def test_dword_checksum_convention_can_be_configured() -> None:
    t = Tap(dword_checksum="words")
    s = spec_on(t, accumulate_on_device=True, dword_checksum="words")
    s.acquire(0.05, 3)
    s.close()
    t.closed = False
    s = spec_on(t, accumulate_on_device=True, dword_checksum="pixels")
    with pytest.raises(ChecksumError, match="matches no accepted reading"):
        s.acquire(0.05, 3)
    s.close()


def test_unit_left_compressing_gets_g0_once() -> None:
    t = Tap()
    a = spec_on(t, compression=True)
    a.acquire(0.01, 1)
    a.close()
    t.closed = False
    n = len(t.written)
    b = spec_on(t)
    r = b.acquire(0.01, 1)
    assert r.signal.shape == (64,)
    later = t.written[n:]
    assert later.count(b"G" + w(0)) == 1 and not t.device.s.compression
    b.acquire(0.01, 1)
    assert t.written[n:].count(b"G" + w(0)) == 1
    b.close()

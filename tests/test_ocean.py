"""Ocean-style RS-232 spectrometer: hand-made byte vectors, recorded sessions, emulator end to end.

Fixtures in ``fixtures/ocean/`` were recorded from the emulator (512 pixels) with
``python tests/test_ocean.py --record``.
"""

from __future__ import annotations

import functools
import json
import math
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:  # for `python tests/test_ocean.py --record`
    sys.path.insert(0, str(ROOT))

from bench.core.errors import (CalibrationError, ChecksumError, ConfigError, DeviceTimeoutError, InputError,  # noqa: E402
                               PortGoneError, ProtocolError, TransportMismatchError)
from bench.core.records import Reading  # noqa: E402
from bench.core.roles import Spectrometer  # noqa: E402
from bench.core.conformance import check_conformance  # noqa: E402
from drivers.ocean import (  # noqa: E402
    OceanSpectrometer,
    decode_compressed,
    nonlinearity_factor,
    validate_nonlinearity,
    wavelength_polynomial,
)
from drivers.transport import (  # noqa: E402
    RecordingTransport,
    ScriptedTransport,
    SerialTransport,
    load_fixture,
)
from tests.helpers.clock import FakeClock, WaitingTransport  # noqa: E402
from virtual.wire._ocean_codec import compress  # noqa: E402
from virtual.wire.ocean_model import cosine_response, file_geometry_source  # noqa: E402
from virtual.wire.ocean_spectrometer import SpectrometerEmulator  # noqa: E402

FIX = ROOT / "fixtures" / "ocean"
ACK, NAK, STX, ETX = b"\x06", b"\x15", b"\x02", b"\x03"
SMALL = dict(model="custom", pixels=8, dark_pixels=(0, 2), timeout_s=0.2, retries=1)
FIXCFG = dict(model="EMU2000+", pixels=512, timeout_s=0.5, retries=1)


# --- hand-made byte vectors ------------------------------------------------------------------


def w(*values: int) -> bytes:
    return b"".join(int(v & 0xFFFF).to_bytes(2, "big") for v in values)


def open_pairs(slots: dict[int, str] | None = None, checksum: bool = True,
               compression: bool = False, trigger: int = 0) -> list[tuple[bytes, bytes]]:
    """The exact exchange of OceanSpectrometer's open in binary mode: every setting the driver
    relies on is sent whatever the unit was left with (checksum, compression, trigger, scans to
    add, pixel mode), and those the unit reports (?T, ?A) are read back."""
    s = {0: "SN0001", 1: "400.0", 2: "10.0", 3: "0", 4: "0"}
    s.update(slots or {})
    pairs = [(b"bB", ACK), (b"v", ACK + w(3001))]
    pairs += [(b"?x" + w(n), ACK + s[n].encode() + b"\r\n") for n in range(5)]
    pairs += [(b"k" + w(int(checksum)), ACK), (b"G" + w(int(compression)), ACK)]
    pairs += [(b"T" + w(trigger), ACK), (b"?T", ACK + w(trigger))]
    pairs += [(b"A" + w(1), ACK), (b"?A", ACK + w(1)), (b"P" + w(0), ACK)]
    return pairs


def frame(values: list[int], scans: int = 1, integ_ms: int = 10, checksum: bool = True,
          compressed: bool = False) -> bytes:
    dwords = scans > 1
    out = STX + w(0xFFFF, int(dwords), scans, integ_ms, 0, 0, 0)
    if dwords:
        out += b"".join(int(v).to_bytes(4, "big") for v in values)
    elif compressed:
        out += compress(np.asarray(values))
    else:
        out += w(*values)
    out += w(0xFFFD)
    if checksum:
        out += w(sum(values) & 0xFFFF)
    return out


def acquire_pairs(values_list: list[list[int]], integ_ms: int = 10, scans: int = 1,
                  **kw: bool) -> list[tuple[bytes, bytes]]:
    pairs = [(b"I" + w(integ_ms), ACK), (b"?I", ACK + w(integ_ms))]
    pairs += [(b"A" + w(scans), ACK), (b"?A", ACK + w(scans))] if scans != 1 else []
    pairs += [(b"S", frame(v, scans=scans, integ_ms=integ_ms, **kw)) for v in values_list]
    return pairs


VALS = [1000, 1002, 5000, 5100, 65535, 4000, 3999, 120]


def test_open_and_acquire_byte_exact() -> None:
    script = ScriptedTransport(open_pairs() + acquire_pairs([VALS, [v - 10 for v in VALS]]))
    spec = OceanSpectrometer(script, **SMALL)
    assert spec.serial == "SN0001" and spec.firmware == "3.00.1"
    np.testing.assert_allclose(spec.wavelengths, 400.0 + 10.0 * np.arange(8))
    r = spec.acquire(0.01, 2)
    assert isinstance(r, Reading) and r.averages == 2 and r.integration_s == pytest.approx(0.01)
    np.testing.assert_allclose(r.signal, np.array(VALS) - 5.0)
    assert r.saturated.tolist() == [v == 65535 for v in VALS]
    np.testing.assert_allclose(r.std, 5.0)  # std of the mean of (v, v - 10): 7.07 / sqrt(2)
    spec.close()  # the script has no leftovers


def test_settings_are_sent_once() -> None:
    pairs = open_pairs() + acquire_pairs([VALS]) + [(b"S", frame(VALS))]
    spec = OceanSpectrometer(ScriptedTransport(pairs), **SMALL)
    spec.acquire(0.01, 1)
    spec.acquire(0.01, 1)  # I, A, P unchanged: only S
    spec.close()


def test_compressed_frame_decodes() -> None:
    vals = [0, 127, 0, 300, 173, 173, 65535, 65407]   # -128 is not a delta: 0x80 escapes
    data = compress(np.asarray(vals))
    assert data == bytes([0, 127, 0x81, 0x80, 0x01, 0x2C, 0x81, 0x00, 0x80, 0xFF, 0xFF,
                          0x80, 0xFF, 0x7F])
    got, end = decode_compressed(data, 8)
    assert got.tolist() == vals and end == len(data)
    with pytest.raises(ChecksumError, match="ended"):
        decode_compressed(data[:-1], 8)
    script = ScriptedTransport(open_pairs(compression=True)
                               + acquire_pairs([vals], compressed=True))
    spec = OceanSpectrometer(script, **SMALL, compression=True)
    assert spec.acquire(0.01, 1).signal.tolist() == vals
    spec.close()


def test_accumulated_frame_is_dwords_and_flags_saturation_per_scan() -> None:
    vals = [2000, 2002, 131070, 131069, 100, 100, 100, 100]   # 2 scans accumulated
    script = ScriptedTransport(open_pairs() + acquire_pairs([vals], scans=2))
    spec = OceanSpectrometer(script, **SMALL, accumulate_on_device=True)
    r = spec.acquire(0.01, 2)
    assert r.saturated.tolist() == [False, False, True] + [False] * 5
    np.testing.assert_allclose(r.signal, np.array(vals) / 2)
    assert r.std is None
    spec.close()


def test_a_nak_is_retried_and_a_persistent_one_names_the_command() -> None:
    """A line glitch can turn a good command into an unknown one: one NAK is retried (counted
    as recovered); NAKs through every attempt are a typed error naming the command."""
    script = ScriptedTransport(open_pairs() + [(b"I" + w(10), NAK)] + acquire_pairs([VALS]))
    spec = OceanSpectrometer(script, **SMALL)
    spec.acquire(0.01, 1)
    assert spec.faults.snapshot() == {"retries": 1, "recovered": 1, "failed": 0, "discarded": 0, "fault.nak": 1}
    spec.close()
    script = ScriptedTransport(open_pairs() + [(b"I" + w(10), NAK)] * 2)  # retries=1: two attempts
    spec = OceanSpectrometer(script, **SMALL)
    with pytest.raises(ProtocolError, match=r"NAK to command 'I'.*after 2 attempt"):
        spec.acquire(0.01, 1)
    assert spec.faults.failed == 1
    spec.close()


def test_etx_is_insufficient_memory() -> None:
    script = ScriptedTransport(open_pairs() + acquire_pairs([])[:3] + [(b"S", ETX)])
    spec = OceanSpectrometer(script, **SMALL)
    with pytest.raises(ProtocolError, match="insufficient memory"):
        spec.acquire(0.01, 1)
    spec.close()


def test_bad_checksum_is_retried_then_refused() -> None:
    bad = bytearray(frame(VALS))
    bad[-1] ^= 0x01
    ok = open_pairs() + acquire_pairs([])[:3]
    spec = OceanSpectrometer(ScriptedTransport(ok + [(b"S", bytes(bad)), (b"S", frame(VALS))]),
                             **SMALL)
    assert spec.acquire(0.01, 1).signal.tolist() == VALS  # one retry
    spec.close()
    spec = OceanSpectrometer(ScriptedTransport(ok + [(b"S", bytes(bad))] * 2), **SMALL)
    with pytest.raises(ChecksumError, match="checksum"):
        spec.acquire(0.01, 1)
    spec.close()


def test_missing_reply_is_a_timeout_without_waiting() -> None:
    pairs = open_pairs() + acquire_pairs([])[:3] + [(b"S", b""), (b"S", b"")]
    clock = FakeClock()
    line = WaitingTransport(ScriptedTransport(pairs), clock)  # each short read waits out its timeout
    spec = OceanSpectrometer(line, clock=clock, **SMALL)
    start, opened = clock.now, len(line.waits)
    with pytest.raises(DeviceTimeoutError, match="2 attempt"):
        spec.acquire(0.01, 1)
    waits = line.waits[opened:]
    # two attempts (retries=1), each waiting once for the reply: the timeout plus the
    # acquisition's own time (integration and transfer, 27 ms here); the rest are short
    # quiet-line waits; all in all about half a second of the line's time, not a hang
    long = [w for w in waits if w > 0.1]
    assert len(long) == 2 and all(w <= SMALL["timeout_s"] + 0.03 for w in long)
    assert clock.now - start == pytest.approx(sum(waits)) and clock.now - start < 0.6
    spec.close()


def test_device_left_in_ascii_mode_is_brought_back() -> None:
    """Back to binary mode with a bare ``bB``; in ASCII mode each byte is echoed, then ACK (binary).
    No CR follows (a stray CR would be NAKed by the then binary device)."""
    pairs = [(b"b", b"b"), (b"B", b"B" + ACK)] + open_pairs()[1:]
    spec = OceanSpectrometer(ScriptedTransport(pairs), **SMALL)
    assert spec.found_mode == "ascii" and spec.describe().extra["found_in_mode"] == "ascii"
    spec.close()


def test_sent_bytes_differing_from_the_recording_fail() -> None:
    pairs = open_pairs() + [(b"I" + w(20), ACK)]
    spec = OceanSpectrometer(ScriptedTransport(pairs), **SMALL)
    with pytest.raises(TransportMismatchError, match="differs"):
        spec.acquire(0.01, 1)


def test_bad_inputs_are_input_errors() -> None:
    spec = OceanSpectrometer(ScriptedTransport(open_pairs()), **SMALL)
    for args in ((0.0, 1), (-1.0, 1), (math.nan, 1), (0.0004, 1), (66.0, 1), (0.01, 0),
                 (0.01, 1.5), (True, 1)):
        with pytest.raises(InputError):
            spec.acquire(*args)
    spec.close()
    with pytest.raises(ConfigError):
        OceanSpectrometer(ScriptedTransport([]), model="nonesuch")


def test_wavelength_calibration_is_checked() -> None:
    for slots in ({2: "-10.0"}, {1: "nan"}, {1: "40.0"}, {2: "abc"}):
        with pytest.raises(CalibrationError):
            OceanSpectrometer(ScriptedTransport(open_pairs(slots), strict_unread=False), **SMALL)
    np.testing.assert_allclose(wavelength_polynomial([1, 2, 3, 4], 3), [1, 10, 49])


# --- non-linearity -------------------------------------------------------------------------------


def test_nonlinearity_validation() -> None:
    good = [1.0, -1e-6, 0, 0, 0, 0, 0, 0]
    np.testing.assert_allclose(validate_nonlinearity(good), good)
    np.testing.assert_allclose(nonlinearity_factor([1.0, -1e-6], np.array([0.0, 1e5])), [1.0, 0.9])
    for bad, why in (([0.0] * 8, "k0 = 0"), ([], "no coefficients"), ([1.0, math.nan], "non-finite"),
                     ([1.0, -2e-5], "<= 0"), ([1.0, 1e-4], "plausible"), ([0.1], "plausible")):
        with pytest.raises(CalibrationError, match=why):
            validate_nonlinearity(bad)


def nl_pairs(ks: list[str], order: str) -> list[tuple[bytes, bytes]]:
    pairs = [(b"?x" + w(14), ACK + order.encode() + b"\r\n")]
    pairs += [(b"?x" + w(6 + i), ACK + k.encode() + b"\r\n") for i, k in enumerate(ks)]
    return pairs


def test_nonlinearity_is_opt_in_and_refuses_nonsense() -> None:
    o = open_pairs()
    zeros = o[:7] + nl_pairs(["0", "0"], "1")
    with pytest.raises(CalibrationError, match="k0 = 0"):
        OceanSpectrometer(ScriptedTransport(zeros), **SMALL, nonlinearity=True)
    good = o[:7] + nl_pairs(["1.0", "-1e-6"], "1") + o[7:] + acquire_pairs([VALS])
    spec = OceanSpectrometer(ScriptedTransport(good), **SMALL, nonlinearity=True)
    r = spec.acquire(0.01, 1)
    v = np.array(VALS, dtype=float)
    want = np.where(v >= 65535, v, v / (1.0 - 1e-6 * v))   # saturated pixels are never corrected
    np.testing.assert_allclose(r.signal, want)
    spec.close()


# --- recorded sessions replayed ----------------------------------------------------------------


def frames_in(pairs: list[tuple[bytes, bytes]], npix: int, compressed: bool = False) -> list[np.ndarray]:
    """Decode the recorded S replies independently of the driver."""
    out = []
    for sent, reply in pairs:
        if sent != b"S" or not reply.startswith(STX):
            continue
        head = np.frombuffer(reply[1:15], dtype=">u2")
        assert head[0] == 0xFFFF
        body = reply[15:]
        if head[1]:
            out.append(np.frombuffer(body[:4 * npix], dtype=">u4").astype(float))
        elif compressed:
            out.append(decode_compressed(body, npix)[0].astype(float))
        else:
            out.append(np.frombuffer(body[:2 * npix], dtype=">u2").astype(float))
    return out


@pytest.mark.parametrize("name,kw,averages", [
    ("binary_checksum", {}, 2),
    ("binary_compressed", {"compression": True, "checksum": False}, 1),
    ("binary_accumulate", {"accumulate_on_device": True}, 3),
])
def test_replay_recorded_binary_sessions(name: str, kw: dict, averages: int) -> None:
    pairs = load_fixture(FIX / f"{name}.jsonl")
    spec = OceanSpectrometer(ScriptedTransport(pairs), **FIXCFG, **kw)
    r = spec.acquire(0.01, averages)
    spec.close()
    frames = frames_in(pairs, 512, compressed=kw.get("compression", False))
    scans = averages if kw.get("accumulate_on_device") else 1
    np.testing.assert_allclose(r.signal, np.mean(frames, axis=0) / scans)
    assert r.wavelengths[0] == pytest.approx(339.0)


def test_replay_recorded_ascii_session() -> None:
    pairs = load_fixture(FIX / "ascii.jsonl")
    spec = OceanSpectrometer(ScriptedTransport(pairs), **FIXCFG, mode="ascii")
    r = spec.acquire(0.01, 1)
    spec.close()
    s_reply = [rep for sent, rep in pairs if sent == b"S"][0]
    assert s_reply.startswith(b"S" + STX)  # echo (no CR: S has no data), then decimal lines
    assert s_reply.endswith(b"\r\n")
    nums = [int(x) for x in s_reply[2:].split(b"\r\n") if x]
    assert nums[0] == 65535 and nums[7 + 512] == 65533
    np.testing.assert_allclose(r.signal, nums[7:7 + 512])


def test_replay_recorded_fault_session() -> None:
    spec = OceanSpectrometer(ScriptedTransport(load_fixture(FIX / "faults.jsonl")), **FIXCFG)
    spec.acquire(0.01, 1)          # a NAK to I, then a retry
    spec.acquire(0.01, 1)          # a dropped reply (to S), then a retry
    spec.acquire(0.01, 1)          # a corrupted frame (checksum), then a retry
    with pytest.raises(ProtocolError, match="insufficient memory"):
        spec.acquire(0.01, 1)
    spec.close()


# --- end to end against the emulator -------------------------------------------------------------


@pytest.fixture(scope="module")
def emu():
    with SpectrometerEmulator.start(seed=7) as e:
        yield e


@pytest.fixture()
def spec(emu: SpectrometerEmulator):
    emu.clear_faults()
    s = OceanSpectrometer(emu.port, model="EMU2000+", timeout_s=0.3, retries=1)
    yield s
    s.close()


@pytest.mark.parametrize("kw", [{}, {"mode": "ascii"}, {"compression": True},
                                {"accumulate_on_device": True}, {"checksum": False}])
def test_e2e_conformance(emu: SpectrometerEmulator, kw: dict) -> None:
    s = OceanSpectrometer(emu.port, model="EMU2000+", timeout_s=0.3, **kw)
    assert isinstance(s, Spectrometer)
    assert check_conformance(s, integration_s=0.01, averages=2) == ["Instrument", "Spectrometer"]
    s.close()


def test_e2e_from_config(emu: SpectrometerEmulator) -> None:
    with OceanSpectrometer.from_config({"port": emu.port, "name": "detector", "model": "EMU2000+",
                                        "mode": "binary", "checksum": True}) as s:
        assert s.describe().extra["name"] == "detector"
    with pytest.raises(ConfigError, match="unknown setting.*integraton"):
        OceanSpectrometer.from_config({"port": emu.port, "integraton": 3})


def test_e2e_reading_is_physical(spec: OceanSpectrometer) -> None:
    r = spec.acquire(0.01, 4)
    assert r.signal.shape == (2048,) and not r.saturated.any()
    lo, hi = spec.config.dark_pixels
    dark = r.signal[lo:hi].mean()
    assert 950 < dark < 1100                       # electrical dark only on the masked pixels
    assert r.signal[900:1100].mean() > dark + 3000   # lamp x 0.5 x 10 ms
    assert np.all(r.std > 0)
    info = spec.describe()
    assert info.ranges["wavelength_nm"][0] == pytest.approx(339.0)
    assert info.serial == "EMU00001"


def test_e2e_queries_and_settings(emu: SpectrometerEmulator) -> None:
    for mode in ("binary", "ascii"):
        with OceanSpectrometer(emu.port, model="EMU2000+", mode=mode) as s:
            s.acquire(0.025, 1)
            assert s.query("I") == 25 and s.query("A") == 1
            assert s.query("i") == 2500 and s.query("j") == 25000   # 10 us and 1 us units
            assert s.read_slot(1).startswith("3.39")
            s.set_trigger_mode(1)
            assert s.query("T") == 1 and s.trigger_mode == 1
            with pytest.raises(InputError):
                s.set_trigger_mode(7)
            s.reset_defaults()
            assert s.query("T") == 0 and s.query("I") == 100
            assert s.acquire(0.01, 1).integration_s == pytest.approx(0.01)
            with pytest.raises(ProtocolError, match="NAK"):
                s.query("Z")
    assert emu.state()["mode"] == "ascii"


def test_e2e_saturation(spec: OceanSpectrometer, emu: SpectrometerEmulator) -> None:
    r = spec.acquire(0.2, 1)
    assert r.saturated.any() and np.all(r.signal[r.saturated] == 65535)
    assert not r.saturated[:21].any()
    with OceanSpectrometer(emu.port, model="EMU2000+", accumulate_on_device=True) as acc:
        ra = acc.acquire(0.2, 2)
        assert ra.saturated.any() and np.all(ra.signal[ra.saturated] == 65535)


def test_e2e_electrical_dark_subtraction(emu: SpectrometerEmulator) -> None:
    with OceanSpectrometer(emu.port, model="EMU2000+", subtract_electrical_dark=True) as s:
        r = s.acquire(0.01, 2)
        assert abs(r.signal[6:21].mean()) < 1e-9
        assert abs(r.signal[:6].mean()) < 150   # unmasked, nearly no light at 339 nm


def test_e2e_nonlinearity_correction_restores_linearity(emu: SpectrometerEmulator) -> None:
    ratios = {}
    for on in (False, True):
        with OceanSpectrometer(emu.port, model="EMU2000+", nonlinearity=on,
                               subtract_electrical_dark=True) as s:
            a = s.acquire(0.01, 2).signal[800:1200].mean()
            b = s.acquire(0.04, 2).signal[800:1200].mean()
            ratios[on] = b / a
    assert ratios[True] == pytest.approx(4.0, abs=0.02)
    assert ratios[False] < 3.95   # the emulated detector droops by ~1e-6 per count


def test_e2e_nonsense_nonlinearity_refused_only_when_asked() -> None:
    with SpectrometerEmulator.start(nonlinearity_coeffs=(0.0,) * 8) as e:
        with pytest.raises(CalibrationError, match="k0 = 0"):
            OceanSpectrometer(e.port, model="EMU2000+", nonlinearity=True)
        with OceanSpectrometer(e.port, model="EMU2000+") as s:   # opt-in: off by default
            assert s.nonlinearity_coeffs is None
            assert np.all(np.isfinite(s.acquire(0.01, 1).signal))


def test_e2e_geometry_source_and_response_are_pluggable(tmp_path: Path) -> None:
    geo = tmp_path / "geometry.json"
    with SpectrometerEmulator.start(
            geometry_source=functools.partial(file_geometry_source, str(geo)),
            response=functools.partial(cosine_response, factor=0.8), read_noise=0.0) as e:
        with OceanSpectrometer(e.port, model="EMU2000+", subtract_electrical_dark=True) as s:
            sig = {}
            for theta in (0.0, 60.0):
                geo.write_text(json.dumps({"theta_i": theta}))
                sig[theta] = s.acquire(0.01, 2).signal[900:1100].mean()
            assert sig[60.0] / sig[0.0] == pytest.approx(0.5, abs=0.01)
            assert "60.0" in e.state()["last_geometry"]


def test_e2e_external_trigger(emu: SpectrometerEmulator) -> None:
    with OceanSpectrometer(emu.port, model="EMU2000+", trigger_mode=2, timeout_s=1.0) as s:
        t = threading.Timer(0.2, emu.trigger)
        t.start()
        r = s.acquire(0.01, 1)
        t.join()
        assert r.signal.shape == (2048,)
        s.command("T", 0)


@pytest.mark.timeout(60, func_only=True)  # a hang guard (pytest-timeout), not a speed assertion
def test_e2e_faults(spec: OceanSpectrometer, emu: SpectrometerEmulator) -> None:
    emu.nak("S")
    spec.acquire(0.01, 1)                      # a NAK is retried
    emu.nak("S", n=2)
    with pytest.raises(ProtocolError, match="NAK to command 'S'"):
        spec.acquire(0.01, 1)
    emu.drop_replies(1)
    spec.acquire(0.01, 1)                      # retried
    emu.corrupt_frames(1)
    spec.acquire(0.01, 1)                      # checksum caught, retried
    emu.corrupt_frames(2)
    with pytest.raises(ChecksumError):
        spec.acquire(0.01, 1)
    emu.no_memory(1)
    with pytest.raises(ProtocolError, match="insufficient memory"):
        spec.acquire(0.01, 1)
    emu.drop_replies(5)
    with pytest.raises(DeviceTimeoutError):
        spec.acquire(0.01, 1)
    emu.clear_faults()
    spec.acquire(0.01, 1)                      # healthy again


@pytest.mark.timeout(60, func_only=True)  # a hang guard (pytest-timeout), not a speed assertion
def test_e2e_killed_emulator_is_port_gone() -> None:
    with SpectrometerEmulator.start() as e:
        s = OceanSpectrometer(e.port, model="EMU2000+", timeout_s=0.3)
        s.acquire(0.01, 1)
        e.die()
        with pytest.raises(PortGoneError):
            s.acquire(0.01, 1)
        s.close()
    # (the dead emulator's pty path may already name another pty: open a path that never was)
    with pytest.raises(PortGoneError):
        OceanSpectrometer("/dev/pts/no-such-pty", model="EMU2000+")


# --- recording -----------------------------------------------------------------------------------


def record_fixtures() -> None:
    """Re-record ``fixtures/ocean/*.jsonl`` from the emulator (512 pixels)."""
    sessions = [
        ("binary_checksum", {}, 2, "binary mode, checksum on, 2 frames of 10 ms"),
        ("binary_compressed", {"compression": True, "checksum": False}, 1,
         "binary mode, compression on, checksum off, 1 frame"),
        ("binary_accumulate", {"accumulate_on_device": True}, 3,
         "binary mode, 3 scans accumulated on the device (dwords)"),
        ("ascii", {"mode": "ascii"}, 1, "ASCII mode, 1 frame"),
    ]
    with SpectrometerEmulator.start(pixels=512, seed=3) as e:
        for name, kw, averages, note in sessions:
            rec = RecordingTransport(SerialTransport(e.port), FIX / f"{name}.jsonl",
                                     note=f"ocean emulator, 512 px: {note} "
                                          f"(tests/test_ocean.py --record)")
            s = OceanSpectrometer(rec, **FIXCFG, **kw)
            s.acquire(0.01, averages)
            s.close()
        rec = RecordingTransport(SerialTransport(e.port), FIX / "faults.jsonl",
                                 note="ocean emulator, 512 px: NAK to I (retried), dropped S reply, "
                                      "corrupted frame, ETX (tests/test_ocean.py --record)")
        s = OceanSpectrometer(rec, **FIXCFG)
        e.nak("I")
        s.acquire(0.01, 1)
        e.drop_replies(1)
        s.acquire(0.01, 1)
        e.corrupt_frames(1)
        s.acquire(0.01, 1)
        e.no_memory(1)
        try:
            s.acquire(0.01, 1)
        except ProtocolError:
            pass
        s.close()


if __name__ == "__main__":
    if "--record" in sys.argv:
        record_fixtures()
        print("recorded", *sorted(p.name for p in FIX.glob("*.jsonl")))

"""Transports: scripted replay, recorder, fixture files, serial ports, and the SDK adapter."""

from __future__ import annotations

import os
import socket
import threading
import time
from pathlib import Path

import pytest
from dynamixel_sdk import COMM_RX_CORRUPT, COMM_RX_TIMEOUT, COMM_SUCCESS, PacketHandler

from bench.core.errors import ConfigError, PortGoneError, TransportMismatchError
from drivers.transport import (
    RecordingTransport,
    ScriptedTransport,
    SerialTransport,
    Transport,
    TransportPortHandler,
    load_fixture,
    save_fixture,
)
from tests.helpers.clock import FakeClock
from virtual.wire._dxl_codec import encode_status
from virtual.wire._pty import open_pty

FIXTURES = Path(__file__).resolve().parents[1] / "fixtures" / "dynamixel"

# The four packet examples of the ROBOTIS e-Manual, DYNAMIXEL Protocol 2.0 (ID 1), spelled as there.
PING = bytes.fromhex("FF FF FD 00 01 03 00 01 19 4E")
WRITE_GOAL_512 = bytes.fromhex("FF FF FD 00 01 09 00 03 74 00 00 02 00 00 CA 89")
READ_PRESENT = bytes.fromhex("FF FF FD 00 01 07 00 02 84 00 04 00 1D 15")
TORQUE_ON = bytes.fromhex("FF FF FD 00 01 06 00 03 40 00 01 DB 66")


# --- ScriptedTransport ---------------------------------------------------------------------


def test_scripted_replays_pairs_and_closes_clean() -> None:
    t = ScriptedTransport([(b"\x01\x02", b"\xaa\xbb\xcc"), (b"\x03", b"")])
    assert isinstance(t, Transport)
    t.write(b"\x01")  # a pair may arrive in pieces
    assert t.read(3, 1.0) == b""  # reply only after the whole 'sent'
    t.write(b"\x02")
    assert t.read(2, 1.0) == b"\xaa\xbb"
    assert t.read(5, 1.0) == b"\xcc"  # short read = instant timeout
    t.write(b"\x03")
    assert t.done
    t.close()


def test_scripted_mismatch_names_pair_byte_and_hex() -> None:
    t = ScriptedTransport([(b"\x01", b"\x02"), (b"\xff\xff\xfd\x00\x01", b"")])
    t.write(b"\x01")
    t.read(1, 0)
    with pytest.raises(TransportMismatchError) as ei:
        t.write(b"\xff\xff\xfd\x00\x02")
    msg = str(ei.value)
    assert "pair 1" in msg and "byte 4" in msg
    assert "expected FF FF FD 00 01" in msg and "got FF FF FD 00 02" in msg
    t.close()  # the first mismatch is not masked by a second complaint


def test_scripted_write_after_end_and_leftovers() -> None:
    t = ScriptedTransport([(b"\x01", b"")])
    t.write(b"\x01")
    with pytest.raises(TransportMismatchError, match="unexpected write after the last of 1"):
        t.write(b"\x09")

    t = ScriptedTransport([(b"\x01", b"\x05"), (b"\x02", b"")])
    t.write(b"\x01")
    with pytest.raises(TransportMismatchError) as ei:
        t.close()
    assert "never sent" in str(ei.value) and "pair 1: 02" in str(ei.value)
    assert "never read: 05" in str(ei.value)


def test_scripted_discarded_reply_is_a_leftover() -> None:
    t = ScriptedTransport([(b"\x01", b"\x05\x06")])
    t.write(b"\x01")
    t.reset_input()
    with pytest.raises(TransportMismatchError, match="discarded unread"):
        t.close()
    t = ScriptedTransport([(b"\x01", b"\x05\x06")], strict_unread=False)
    t.write(b"\x01")
    t.reset_input()
    t.close()


# --- fixture files and recording -----------------------------------------------------------


def test_fixture_round_trip_with_comments(tmp_path: Path) -> None:
    pairs = [(b"\x01\x02", b"\x03"), (b"\x04", b"")]
    p = tmp_path / "sub" / "x.jsonl"
    save_fixture(p, pairs, note="unit")
    text = p.read_text()
    assert '"format": "goniobench-transcript"' in text and '"sent": "01 02"' in text
    p.write_text("# a comment\n\n" + text)
    assert load_fixture(p) == pairs


def test_fixture_errors_name_the_line(tmp_path: Path) -> None:
    p = tmp_path / "bad.jsonl"
    p.write_text('{"sent": "01", "reply": ""}\n{"sent": "0G", "reply": ""}\n')
    with pytest.raises(ConfigError, match=r"bad.jsonl:2"):
        load_fixture(p)
    p.write_text('{"sent": "01"}\n')
    with pytest.raises(ConfigError, match="needs 'sent' and 'reply'"):
        load_fixture(p)


def test_recording_transport_captures_pairs(tmp_path: Path) -> None:
    inner = ScriptedTransport([(b"\x01", b"\x0a\x0b"), (b"\x02", b""), (b"\x03", b"\x0c")])
    path = tmp_path / "rec.jsonl"
    rec = RecordingTransport(inner, path, note="test")
    rec.write(b"\x01")
    assert rec.read(1, 0.1) + rec.read(1, 0.1) == b"\x0a\x0b"
    rec.write(b"\x02")
    rec.write(b"\x03")
    assert rec.read(4, 0.1) == b"\x0c"
    rec.close()
    assert load_fixture(path) == [(b"\x01", b"\x0a\x0b"), (b"\x02", b""), (b"\x03", b"\x0c")]


# --- SerialTransport -----------------------------------------------------------------------


def test_serial_loop_exact_reads_and_deadline() -> None:
    clock = FakeClock()
    t = SerialTransport("loop://", clock=clock, sleep=clock.sleep)
    t.write(b"abcdef")
    assert t.read(4, 1.0) == b"abcd"
    assert clock.elapsed == 0.0  # the bytes were there: no wait
    assert t.read(4, 0.05) == b"ef"  # short: the deadline passed, and no later than one poll after it
    assert 0.05 - 1e-9 <= clock.elapsed <= 0.05 + t.poll_s  # (1e-9: rounding of the summed polls)
    t.write(b"xyz")
    t.reset_input()
    assert t.read(1, 0.0) == b""
    t.close()
    t.close()


def test_serial_socket_url() -> None:
    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(1)
    port = srv.getsockname()[1]
    t = SerialTransport(f"socket://127.0.0.1:{port}")
    conn, _ = srv.accept()
    try:
        t.write(b"ping")
        assert conn.recv(4) == b"ping"
        def later() -> None:
            time.sleep(0.02)
            conn.sendall(b"po")
            time.sleep(0.02)
            conn.sendall(b"ng")
        th = threading.Thread(target=later)
        th.start()
        assert t.read(4, 2.0) == b"pong"  # assembled from two chunks, before the deadline
        th.join()
    finally:
        t.close()
        conn.close()
        srv.close()


@pytest.mark.timeout(60, func_only=True)  # a hang guard (pytest-timeout), not a speed assertion
def test_serial_pty_vanished_port_is_port_gone() -> None:
    master, slave, path = open_pty()
    t = SerialTransport(path)
    os.close(slave)
    try:
        os.write(master, b"hi")
        assert t.read(2, 1.0) == b"hi"
    finally:
        os.close(master)  # the "device" goes away
    with pytest.raises(PortGoneError, match="vanished"):
        t.read(1, 1.0)
    with pytest.raises(PortGoneError):
        t.write(b"x")
    t.close()


def test_serial_open_missing_port() -> None:
    with pytest.raises(PortGoneError, match="cannot open"):
        SerialTransport("/dev/does-not-exist-goniobench")


# --- the SDK through TransportPortHandler --------------------------------------------------


def _sdk(pairs):
    st = ScriptedTransport(pairs)
    return st, TransportPortHandler(st), PacketHandler(2.0)


def test_sdk_emits_the_reference_vectors_exactly() -> None:
    """dynamixel-sdk through TransportPortHandler sends exactly the reference bytes."""
    pairs = load_fixture(FIXTURES / "reference_vectors.jsonl")
    assert [s for s, _ in pairs] == [PING, WRITE_GOAL_512, READ_PRESENT, TORQUE_ON]
    st, port, pk = _sdk(pairs)
    assert pk.ping(port, 1) == (1020, COMM_SUCCESS, 0)
    assert pk.write4ByteTxRx(port, 1, 116, 512) == (COMM_SUCCESS, 0)
    assert pk.read4ByteTxRx(port, 1, 132) == (2048, COMM_SUCCESS, 0)
    assert pk.write1ByteTxRx(port, 1, 64, 1) == (COMM_SUCCESS, 0)
    st.close()


def test_reference_vector_replies_match_the_codec() -> None:
    pairs = load_fixture(FIXTURES / "reference_vectors.jsonl")
    assert pairs[0][1] == encode_status(1, 0, bytes([0xFC, 0x03, 0x2A]))
    assert pairs[2][1] == encode_status(1, 0, (2048).to_bytes(4, "little"))
    assert pairs[1][1] == pairs[3][1] == encode_status(1, 0)


def test_sdk_timeout_is_instant_and_deterministic_on_a_script() -> None:
    reads: list[int] = []  # a milliseconds clock that ticks 1 ms each time it is read
    st = ScriptedTransport([(PING, b"")] * 50)
    port, pk = TransportPortHandler(st, clock=lambda: float(reads.append(0) or len(reads))), \
        PacketHandler(2.0)
    for _ in range(50):
        assert pk.ping(port, 1) == (0, COMM_RX_TIMEOUT, 0)
    # a busy-wait for the SDK's 34 ms packet timeout would read this clock 34 times per ping (it reads it twice)
    assert len(reads) < 50 * 5
    st.close()


def test_sdk_corrupt_and_truncated_replies() -> None:
    good = encode_status(1, 0, bytes([0xFC, 0x03, 0x2A]))
    bad_crc = good[:-1] + bytes([good[-1] ^ 0xFF])
    st, port, pk = _sdk([(PING, bad_crc), (PING, good[:9]), (PING, b"\x00\x13" + good)])
    assert pk.ping(port, 1)[1] == COMM_RX_CORRUPT
    assert pk.ping(port, 1)[1] == COMM_RX_CORRUPT  # header arrived, the rest never did
    assert pk.ping(port, 1) == (1020, COMM_SUCCESS, 0)  # leading noise skipped
    st.close()


def test_port_handler_reads_through_a_real_deadline() -> None:
    """On a live transport a missing reply costs the SDK's own packet timeout, no more."""
    clock = FakeClock()  # the port's deadline and the SDK's packet timeout in one fake time
    t = SerialTransport("loop://", clock=clock, sleep=clock.sleep)
    port, pk = TransportPortHandler(t, clock=lambda: clock() * 1000.0), PacketHandler(2.0)
    # loop:// echoes the instruction; the SDK skips it (not a status packet) and times out
    _, comm, _ = pk.ping(port, 1)
    assert comm in (COMM_RX_TIMEOUT, COMM_RX_CORRUPT)
    # the SDK's packet timeout (34.11 ms for a ping status at 1 Mbaud) and at most one poll more
    assert 0.0341 <= clock.elapsed <= 0.03411 + t.poll_s
    port.closePort()

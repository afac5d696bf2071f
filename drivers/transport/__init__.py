"""Byte transports: a serial port, a scripted replay, a recorder, and an SDK adapter.

A :class:`Transport` moves bytes and nothing else; protocol code sits above it. Four pieces:

``SerialTransport``
    Any pyserial URL (``/dev/ttyUSB0``, a pty slave path, ``loop://``, ``socket://host:port``)
    with exact-length reads against a deadline. A vanished port (``OSError``, ``termios.error``,
    ``serial.SerialException``) becomes :class:`bench.core.errors.PortGoneError`.
``ScriptedTransport``
    Replays recorded ``(sent, reply)`` pairs (the PyMeasure ``expected_protocol`` idea): every
    written byte must equal the recording, else :class:`bench.core.errors.TransportMismatchError`
    names the pair, the first differing byte and both byte strings in hex; bytes left unsent or
    unread at :meth:`ScriptedTransport.close` are a mismatch too. It never waits: a reply shorter
    than asked for behaves as a timeout at once, so scripted tests are fast and deterministic.
``RecordingTransport``
    Wraps a live transport and writes the exchange as a fixture file (format below).
``TransportPortHandler``
    A ``dynamixel_sdk.PortHandler`` whose I/O goes through a Transport, so the SDK's exact bytes
    can be pinned by a ScriptedTransport and its busy-poll becomes a blocking read with a deadline.

Fixture format (JSON lines, ``*.jsonl``)
----------------------------------------
One JSON object per line; blank lines and lines starting with ``#`` are comments. An optional
first object ``{"format": "goniobench-transcript", "version": 1, ...}`` carries metadata (any
extra keys, e.g. ``"note"``). Every other line is one exchange::

    {"sent": "FF FF FD 00 01 03 00 01 19 4E", "reply": "FF FF FD 00 01 07 00 55 00 FC 03 2A 06 C3"}

``sent`` is what the host wrote, ``reply`` every byte the host read before its next write
(``""`` when nothing came back: a broadcast, or a dropped reply). Hex is case-insensitive and
may contain spaces.
"""

from __future__ import annotations

from drivers.transport.base import _GONE, Pair, Transport, hexbytes  # noqa: F401
from drivers.transport.replay import RecordingTransport, ScriptedTransport, load_fixture, save_fixture
from drivers.transport._sdk_port import TransportPortHandler
from drivers.transport.serial_port import SerialTransport


__all__ = [
    "Transport",
    "SerialTransport",
    "ScriptedTransport",
    "RecordingTransport",
    "TransportPortHandler",
    "load_fixture",
    "save_fixture",
    "hexbytes",
]

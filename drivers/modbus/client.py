"""A pymodbus RTU client whose bytes go through a :class:`drivers.transport.Transport`
(:class:`TransportModbusClient`): pymodbus frames, the transport only moves bytes.
"""

from __future__ import annotations

import time
from typing import Any, Callable

from pymodbus.client import ModbusSerialClient
from pymodbus.framer import FramerType

class TransportModbusClient(ModbusSerialClient):
    """A pymodbus RTU client whose bytes go through a :class:`drivers.transport.Transport`.

    pymodbus builds and parses the frames (CRC included); the transport only moves bytes, so
    a ``ScriptedTransport`` pins the exact bytes on the wire and a ``RecordingTransport``
    records them.
    """

    def __init__(self, transport: Any, *, timeout: float = 0.5, retries: int = 0,
                 trace_packet: Callable[[bool, bytes], bytes] | None = None) -> None:
        super().__init__("transport://", framer=FramerType.RTU, timeout=timeout,
                         retries=retries, trace_packet=trace_packet)
        self._transport = transport
        self.socket = None

    def connect(self) -> bool:
        self.socket = self._transport  # type: ignore[assignment]
        return True

    def close(self) -> None:
        # pymodbus calls this after errors; the transport stays open (its owner closes it)
        self.socket = None

    def is_socket_open(self) -> bool:
        return self.socket is not None

    def _in_waiting(self) -> int:
        return int(getattr(self._transport, "in_waiting", 0))

    def send(self, request: bytes, addr: tuple | None = None) -> int:
        if not request:
            return 0
        if self._in_waiting():
            self._transport.reset_input()
        self._transport.write(request)
        return len(request)

    def recv(self, size: int | None) -> bytes:
        timeout = self.comm_params.timeout_connect or 0.5
        if size is not None:
            return self._transport.read(size, timeout)
        first = self._transport.read(1, timeout)
        if not first:
            return b""
        # the rest of a frame follows within a few character times; take what is there
        rest = b""
        deadline = time.monotonic() + 0.02
        while True:
            n = self._in_waiting()
            if n:
                rest += self._transport.read(n, 0)
                deadline = time.monotonic() + 0.005
            elif time.monotonic() >= deadline:
                break
            else:
                time.sleep(0.0005)
        return first + rest

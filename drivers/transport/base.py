"""The byte-transport contract: :class:`Transport` (what protocol code needs from a pipe),
the fixture hex spelling :func:`hexbytes`, and the exceptions that mean "the port is gone".
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import serial

Pair = tuple[bytes, bytes]

try:
    from termios import error as _TermiosError
except ImportError:  # pragma: no cover - not POSIX
    _TermiosError = OSError  # type: ignore[misc,assignment]

_GONE = (OSError, _TermiosError, serial.SerialException)


def hexbytes(data: bytes) -> str:
    """``b"\\xff\\x01"`` -> ``"FF 01"`` (the fixture and error-message spelling)."""
    return data.hex(" ").upper()


@runtime_checkable
class Transport(Protocol):
    """What protocol code needs from a byte pipe.

    ``read(n, timeout)`` returns exactly ``n`` bytes, or fewer only when ``timeout`` seconds
    passed first (``timeout=0`` returns what is already there). It never returns more than
    ``n`` bytes and never blocks past the deadline.
    """

    def write(self, data: bytes) -> None: ...

    def read(self, n: int, timeout: float) -> bytes: ...

    def reset_input(self) -> None: ...

    def close(self) -> None: ...

"""Which physical device a port string names, so that two spellings of one device compare equal.

A bench locks each device it opens (:mod:`bench.builders.ownership`); the lock is keyed by the
device's identity, not by the string in a config: ``/dev/serial/by-id/usb-FTDI...`` and the
``/dev/ttyUSB0`` it links to are one adapter, ``tcp://localhost:502`` and ``tcp://127.0.0.1:502``
one Modbus endpoint. Ports that are no device (``loop://``) have no identity.
"""

from __future__ import annotations

import ipaddress
import os

__all__ = ["device_identity"]

#: pyserial URL schemes that reach a network endpoint ``host:port``
_NETWORK_SCHEMES = ("tcp", "socket", "rfc2217")
#: schemes whose target is no shared device
_PRIVATE_SCHEMES = ("loop",)


def _endpoint(hostport: str) -> str:
    """``host:port`` with the host spelled canonically (an IP literal normalised, ``localhost``
    as 127.0.0.1, a name lower-cased: no name lookup, which could hang on a dead resolver)."""
    hostport = hostport.split("/", 1)[0].split("?", 1)[0]
    host, _, port = hostport.rpartition(":")
    host = host.strip("[]").lower()
    if host in ("localhost", ""):
        host = "127.0.0.1"
    try:
        host = str(ipaddress.ip_address(host))
    except ValueError:
        pass
    return f"{host}:{port}"


def device_identity(port: str) -> str | None:
    """The identity of the device ``port`` names: ``tty:<resolved path>`` for a device path (a
    symlink resolved to its node), ``tcp:<host>:<port>`` for a network endpoint, None for a port
    that is no shared device (``loop://``)."""
    port = str(port).strip()
    if "://" in port:
        scheme, rest = port.split("://", 1)
        scheme = scheme.lower()
        if scheme in _NETWORK_SCHEMES:
            return f"tcp:{_endpoint(rest)}"
        if scheme in _PRIVATE_SCHEMES:
            return None
        if scheme in ("spy", "alt"):  # pyserial's wrappers around a device path
            return device_identity(rest.split("?", 1)[0])
        return f"{scheme}:{rest}"
    return f"tty:{os.path.realpath(port)}"

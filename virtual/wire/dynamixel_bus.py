"""A Dynamixel Protocol 2.0 bus emulator: several XM430-W350-like servos on one line.

Three layers, usable separately:

1. **Codec** (:mod:`virtual.wire._dxl_codec`; the one packet codec of the project, shared by this emulator and the tests; the
   driver itself uses dynamixel-sdk's own packets): :func:`crc16` (poly 0x8005, init 0, no
   reflection), :func:`stuff`/:func:`unstuff` (``FF FF FD`` -> ``FF FF FD FD``),
   :func:`encode_instruction`, :func:`encode_status`, :func:`decode_packet` and the streaming
   :class:`PacketParser`.
2. **Model** (:mod:`virtual.wire._dxl_servo`, :mod:`virtual.wire.dxl_bus`): :class:`Servo` (control table, finite-speed motion, EEPROM lock, hardware errors)
   and :class:`DynamixelBus` (routes instructions: ping, read, write, reboot, sync read, sync
   write, bulk read, bulk write; fault injection). In process, :class:`BusTransport` wraps a bus
   as a byte transport (``write``/``read``/``reset_input``/``close``) for fast tests, and
   :class:`PtyBusThread` serves it on a pty from a thread (thread mode).
3. **Process**: ``python -m virtual.wire.dynamixel_bus --ids 1,2,3,4`` owns a pseudo-terminal,
   prints one JSON line ``{"port": "/dev/pts/N", "control": "127.0.0.1:PORT", "pid": ...}`` and
   serves until killed. :func:`start_bus` does that from Python and returns an
   :class:`~virtual.wire._pty.EmulatorProcess`; :class:`BusControl` talks to its control channel.

Control channel (joint state for other emulators, fault injection)
------------------------------------------------------------------
A TCP socket on 127.0.0.1 speaking JSON lines: send one object per line, get one object back.

``{"cmd": "state"}``
    ``{"ok": true, "t": <monotonic s>, "servos": {"1": {"present_position": ticks,
    "goal_position": ticks, "moving": 0|1, "torque": 0|1, "hardware_error": bits,
    "operating_mode": 3|4}, ...}, "joints": {"<name>": degrees, ...}}``. ``joints`` is filled
    when the emulator was started with ``--axes`` (a JSON object ``{"name": {"id": 1,
    "zero_offset": 2048, "direction": 1, "gear_ratio": 1.0}}``, the same meaning as the
    driver's axis config): joint = (ticks - zero_offset) * direction * 360 / (4096 * gear_ratio).
    A spectrometer emulator polls this to know where the arms are.
``{"cmd": "faults", "drop_next": n, "corrupt_next": n, "drop_rate": p, "corrupt_rate": p,
"delay_s": s, "hang": bool, "late_s": s, "drop_broadcast_next": n}``
    Fault injection on status packets (only the keys given change). ``late_s``: after a
    corrupted status the rest of the same reply (e.g. of a SYNC_READ) arrives that much later;
    ``drop_broadcast_next``: the next n SYNC_WRITE/BULK_WRITE broadcasts are lost.
``{"cmd": "hardware_error", "id": 1, "bits": 32, "on_goal": false}``
    Set Hardware Error Status bits (5 = overload -> 32): torque off, every later status packet
    of that servo carries the alert bit 0x80. With ``on_goal`` true it fires at the next Goal
    Position write instead (the servo faults as the move starts).
``{"cmd": "poke", "id": 1, "addr": 64, "size": 1, "value": 0}`` / ``{"cmd": "clear"}`` /
``{"cmd": "die"}`` (exit at once: the pty vanishes).

The process exits by itself when the process that started it dies (unless ``--no-orphan``).

Modelling simplifications: motion at constant profile velocity (Profile Acceleration is
stored, not simulated); Profile Velocity 0 means the Velocity Limit; no return delay; Status
Return Level (68) as the manual says: 0 answers PING only, 1 PING and reads, 2 every instruction
(the level before a write decides whether it is answered); a Goal Position outside the position limits in mode 3 is refused
with error 6 (data limit) on a plain write and ignored in a sync/bulk write; Torque Enable = 1
sets Goal Position to Present Position (no jump).
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import select
import signal
import socket
import sys
import time
from typing import Any, Mapping, Sequence

from bench.core.errors import DeviceError
from bench.core.roles import Closing

from virtual.wire.dxl_bus import DynamixelBus
from virtual.wire._pty import EmulatorProcess, open_pty, starting_parent, write_all


__all__ = ["BusControl", "start_bus", "serve", "main"]

log = logging.getLogger(__name__)


# --- process -------------------------------------------------------------------------------


def _control(bus: DynamixelBus, req: Mapping[str, Any]) -> dict[str, Any]:
    cmd = req.get("cmd")
    if cmd == "state":
        return {"ok": True, **bus.state()}
    if cmd == "faults":
        bus.set_faults(**{k: v for k, v in req.items() if k != "cmd"})
        return {"ok": True, "faults": vars(bus.faults)}
    if cmd == "clear":
        bus.clear_faults()
        return {"ok": True}
    if cmd == "hardware_error":
        bus.hardware_error(int(req["id"]), int(req["bits"]), bool(req.get("on_goal", False)))
        return {"ok": True}
    if cmd == "poke":
        s = bus.servos[int(req["id"])]
        s.update()
        s._set(int(req["addr"]), int(req.get("size", 1)), int(req["value"]))
        return {"ok": True}
    if cmd == "ping":
        return {"ok": True}
    raise KeyError(f"unknown command {cmd!r}")


def serve(bus: DynamixelBus, master_fd: int, server: socket.socket,
          parent_pid: int | None = None) -> None:
    """Serve the pty master and the control socket until ``die`` (or a signal).

    With ``parent_pid`` the emulator exits within a second once that process is gone (it is
    re-parented), so a crashed test run leaves no emulator behind.
    """
    clients: dict[socket.socket, bytearray] = {}
    while True:
        if parent_pid is not None and os.getppid() != parent_pid:
            os._exit(0)
        rlist = [master_fd, server, *clients]
        due = bus.next_due()
        r, _, _ = select.select(rlist, [], [], 0.5 if due is None else
                                max(0.0, min(0.5, due - time.monotonic())))
        late = bus.take_due()
        if late:
            write_all(master_fd, late)
        for s in r:
            if s == master_fd:
                try:
                    data = os.read(master_fd, 4096)
                except BlockingIOError:
                    continue
                except OSError:
                    time.sleep(0.01)  # slave side not open (EIO): wait for a client
                    continue
                reply = bus.handle(data)
                if reply:
                    if bus.faults.delay_s:
                        time.sleep(bus.faults.delay_s)
                    write_all(master_fd, reply)
            elif s is server:
                conn, _ = server.accept()
                clients[conn] = bytearray()
            else:
                try:
                    chunk = s.recv(65536)
                except OSError:
                    chunk = b""
                if not chunk:
                    clients.pop(s).clear()
                    s.close()
                    continue
                buf = clients[s]
                buf += chunk
                while b"\n" in buf:
                    line, _, rest = bytes(buf).partition(b"\n")
                    buf[:] = rest
                    try:
                        req = json.loads(line)
                        if req.get("cmd") == "die":
                            os._exit(3)  # the pty master closes with the process
                        resp = _control(bus, req)
                    except Exception as exc:  # report, keep serving
                        resp = {"ok": False, "error": f"{type(exc).__name__}: {exc}"}
                    s.sendall(json.dumps(resp).encode() + b"\n")


class BusControl(Closing):
    """Client of an emulator's control channel (``host, port`` from the announcement)."""

    def __init__(self, address: tuple[str, int] | str, timeout: float = 3.0) -> None:
        if isinstance(address, str):
            host, port = address.rsplit(":", 1)
            address = (host, int(port))
        self.sock = socket.create_connection(address, timeout=timeout)
        self._buf = b""

    def request(self, cmd: str, **kw: Any) -> dict[str, Any]:
        self.sock.sendall(json.dumps({"cmd": cmd, **kw}).encode() + b"\n")
        while b"\n" not in self._buf:
            chunk = self.sock.recv(65536)
            if not chunk:
                raise ConnectionError("emulator control channel closed")
            self._buf += chunk
        line, _, self._buf = self._buf.partition(b"\n")
        resp = json.loads(line)
        if not resp.get("ok"):
            raise DeviceError(f"emulator refused {cmd}: {resp.get('error')}")
        return resp

    def state(self) -> dict[str, Any]:
        return self.request("state")

    def joints(self) -> dict[str, float]:
        return dict(self.state()["joints"])

    def faults(self, **kw: Any) -> dict[str, Any]:
        return self.request("faults", **kw)

    def clear(self) -> None:
        self.request("clear")

    def hardware_error(self, dev_id: int, bits: int, on_goal: bool = False) -> None:
        self.request("hardware_error", id=dev_id, bits=bits, on_goal=on_goal)

    def poke(self, dev_id: int, addr: int, value: int, size: int = 1) -> None:
        self.request("poke", id=dev_id, addr=addr, value=value, size=size)

    def die(self) -> None:
        try:
            self.sock.sendall(b'{"cmd": "die"}\n')
        except OSError:
            pass

    def close(self) -> None:
        self.sock.close()


def start_bus(ids: Sequence[int] = (1, 2, 3, 4), *, positions: Mapping[int, int] | None = None,
              axes: Mapping[str, Mapping[str, Any]] | None = None, time_scale: float = 1.0,
              seed: int = 0, faults: Mapping[str, Any] | None = None,
              start_timeout: float = 10.0):
    """Start the emulator in its own process; return an ``EmulatorProcess`` (``.port``, ``.control``).

    Close it (or use it as a context manager) to stop the process.
    """
    args = ["--ids", ",".join(str(i) for i in ids), "--seed", str(seed), "--time-scale", str(time_scale)]
    if positions:
        args += ["--positions", ",".join(f"{k}:{v}" for k, v in positions.items())]
    if axes:
        args += ["--axes", json.dumps(axes)]
    if faults:
        args += ["--faults", json.dumps(dict(faults))]
    return EmulatorProcess("virtual.wire.dynamixel_bus", args, start_timeout=start_timeout)


def main(argv: Sequence[str] | None = None) -> int:
    """Command line: start the bus on a fresh pty and print the announcement JSON line."""
    ap = argparse.ArgumentParser(prog="python -m virtual.wire.dynamixel_bus", description=__doc__.split("\n")[0])
    ap.add_argument("--ids", default="1,2,3,4", help="comma-separated servo IDs")
    ap.add_argument("--positions", default="", help="initial ticks, e.g. 1:2048,2:1024")
    ap.add_argument("--axes", default="", help="JSON {name: {id, zero_offset, direction, gear_ratio}}")
    ap.add_argument("--faults", default="", help='JSON, e.g. {"drop_rate": 0.1}')
    ap.add_argument("--time-scale", type=float, default=1.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--control-port", type=int, default=0)
    ap.add_argument("--no-orphan", action="store_true",
                    help="keep running when the starting process dies (default: exit)")
    a = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, stream=sys.stderr)
    parent = None if a.no_orphan else (starting_parent() or os.getppid())
    ids = [int(x) for x in a.ids.split(",") if x.strip()]
    positions = {int(k): int(v) for k, v in (kv.split(":") for kv in a.positions.split(",") if kv)}
    bus = DynamixelBus(ids, positions, time_scale=a.time_scale, seed=a.seed,
                       axes=json.loads(a.axes) if a.axes else None)
    if a.faults:
        bus.set_faults(**json.loads(a.faults))
    master, slave, path = open_pty()
    server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    server.bind(("127.0.0.1", a.control_port))
    server.listen(8)
    signal.signal(signal.SIGTERM, lambda *_: os._exit(0))
    host, port = server.getsockname()
    sys.stdout.write(json.dumps({"port": path, "control": f"{host}:{port}", "pid": os.getpid(),
                                 "ids": ids}) + "\n")
    sys.stdout.flush()
    try:
        serve(bus, master, server, parent_pid=parent)
    finally:  # pragma: no cover - process exit
        os.close(slave)
    return 0


if __name__ == "__main__":
    sys.exit(main())

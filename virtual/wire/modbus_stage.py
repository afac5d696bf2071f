"""An Oriental-Motor-AZ-style stage on Modbus, emulated in its own process.

The emulator is a pymodbus server (``pymodbus.simulator`` ``SimDevice`` with an action hook)
answering either Modbus RTU on a pseudo-terminal or Modbus TCP on 127.0.0.1. Its register
layout is its own copy of the AZ map (or any TOML of the shape ``drivers/registers`` uses, read
as data: ``virtual`` never imports ``drivers``): the direct-data block, the input command,
output status, present alarm and feedback/command position; every other address answers
exception 2 (illegal data address); status and positions are read-only (a write answers
exception 2 too); operation data out of range (current > 100 %, speed > ``max_speed_hz``)
answers exception 3 (illegal data value).

Physics (:class:`StageModel`, pure, time driven): a trigger of an absolute positioning starts
a move at the commanded speed (steps/s, constant-speed ramp; acceleration is accepted and
ignored); the feedback position ramps with time; BUSY/MOVE while moving, IN-POS and READY at
rest; an alarm (e.g. 0x30 overload) freezes the motion, raises ALM and keeps the code in the
present-alarm register until an ALM-RST rising edge; STOP halts at once; a trigger while an
alarm is present is ignored (counted in ``rejected_triggers``).

RTU on a pty: pymodbus's serial server opens the slave of one pty pair, the driver opens the
slave of a second pair, and a relay in the emulator's event loop joins the two masters (there
is no socat here). The path the driver opens is :attr:`StageEmulator.port`.

Start, inject faults, stop::

    from virtual.wire.modbus_stage import StageEmulator
    with StageEmulator.start("tcp") as emu:          # or "rtu"
        emu.url                   # "tcp://127.0.0.1:40123" or "/dev/pts/7": give it to the driver
        emu.alarm(0x30)           # overload alarm (motion freezes, ALM on)
        emu.drop_replies(2)       # the next 2 replies are not sent
        emu.corrupt_replies(1)    # the next reply has one byte flipped (CRC error on RTU)
        emu.fault_rate(0.01, 3)   # random dropped and corrupted replies from now on (soak)
        emu.state()               # dict: position, target, moving, alarm, triggers, ...
        emu.die()                 # the process exits at once (os._exit), like a pulled plug
    # leaving the block stops (or kills) the process

From a shell: ``python -m virtual.wire.modbus_stage --transport tcp`` prints one JSON line
with the address and serves until killed.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import logging
import os
import random
import sys
import threading
from typing import Any

from bench.core.errors import ConfigError

from virtual.wire._modbus_stage_model import (  # noqa: F401
    AZ_LAYOUT, StageConfig, StageModel, _Layout, read_feedback_steps,
)
from virtual.wire._pty import PipeEmulator, answer_control, close_quietly, open_raw_pty

log = logging.getLogger(__name__)

__all__ = ["StageConfig", "StageModel", "StageEmulator", "read_feedback_steps"]


# --------------------------------------------------------------------------------------------
# the server process
# --------------------------------------------------------------------------------------------


class _Faults:
    """Fault switches applied to outgoing packets (shared between control thread and loop)."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.drop = 0
        self.corrupt = 0
        self.drop_all = False
        #: random transient faults (soak): each reply dropped or corrupted with probability rate / 2
        self.rate = 0.0
        self.rng = random.Random(0)
        self.injected = {"drop": 0, "corrupt": 0}

    def outgoing(self, data: bytes) -> bytes:
        with self.lock:
            if self.drop_all:
                return b""
            if self.rate > 0 and data:
                u = self.rng.random()
                if u < self.rate / 2:
                    self.drop += 1
                    self.injected["drop"] += 1
                elif u < self.rate:
                    self.corrupt += 1
                    self.injected["corrupt"] += 1
            if self.drop > 0:
                self.drop -= 1
                log.info("fault: dropping reply %s", data.hex(" "))
                return b""
            if self.corrupt > 0 and data:
                self.corrupt -= 1
                i = len(data) // 2
                bad = data[:i] + bytes([data[i] ^ 0x5A]) + data[i + 1:]
                log.info("fault: corrupting reply %s -> %s", data.hex(" "), bad.hex(" "))
                return bad
        return data


def _build_device(model: StageModel, lock: threading.Lock, device_id: int) -> Any:
    from pymodbus.constants import ExcCodes
    from pymodbus.simulator import DataType, SimData, SimDevice

    r = model.rmap
    a0, n = r.direct_block
    rw = [SimData(a0, values=[0] * n, datatype=DataType.REGISTERS),
          SimData(r.addr("input_command"), values=[0, 0], datatype=DataType.REGISTERS)]
    ro = [SimData(r.addr(k), values=[0, 0], datatype=DataType.REGISTERS, readonly=True)
          for k in ("output_status", "present_alarm", "feedback_position", "command_position")]
    blocks = sorted(rw + ro, key=lambda s: s.address)
    start = blocks[0].address
    trig = r.addr("direct_trigger")

    def word(regs: list[int], addr: int) -> int:
        return r.from_words(regs[addr - start: addr - start + 2])

    async def action(fc: int, start_address: int, address: int, count: int,
                     registers: list[int], set_values: Any) -> Any:
        assert start_address == start
        with lock:
            if set_values:
                merged = list(registers)
                merged[address - start: address - start + count] = list(set_values)
                span = range(address, address + count)
                if r.addr("input_command") in span or r.addr("input_command") + 1 in span:
                    model.input_command(word(merged, r.addr("input_command")) & 0xFFFFFFFF)
                # out-of-range operation data is refused whole (exception 3), as a drive does
                cur, spd = r.addr("direct_current"), r.addr("direct_speed")
                if (cur in span or cur + 1 in span) and not 0 <= word(merged, cur) <= \
                        r.value("current_max", 1000):
                    return ExcCodes.ILLEGAL_VALUE
                if (spd in span or spd + 1 in span) and word(merged, spd) > model.cfg.max_speed_hz:
                    return ExcCodes.ILLEGAL_VALUE
                if trig + 1 in span or trig in span:
                    tv = word(merged, trig)
                    if tv == r.value("trigger_all", 1):
                        model.trigger(word(merged, r.addr("direct_type")),
                                      word(merged, r.addr("direct_position")),
                                      word(merged, r.addr("direct_speed")))
                    # the trigger register reads back 0 once the operation is taken
                    for k in (trig, trig + 1):
                        if address <= k < address + count:
                            set_values[k - address] = 0
            model.update()
            for key, val in (("output_status", model.status()), ("present_alarm", model.alarm),
                             ("feedback_position", round(model.position)),
                             ("command_position", round(model.target if model.moving
                                                        else model.position))):
                a = r.addr(key)
                registers[a - start: a - start + 2] = r.to_words(val)
        return None

    return SimDevice(id=device_id, simdata=blocks, action=action)


class _PtyRelay:
    """Copy bytes both ways between two pty masters inside the event loop."""

    def __init__(self, loop: asyncio.AbstractEventLoop, a: int, b: int) -> None:
        self.loop, self.a, self.b = loop, a, b
        os.set_blocking(a, False)
        os.set_blocking(b, False)
        loop.add_reader(a, self._pump, a, b)
        loop.add_reader(b, self._pump, b, a)

    @staticmethod
    def _pump(src: int, dst: int) -> None:
        try:
            data = os.read(src, 4096)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            return
        if data:
            try:
                os.write(dst, data)
            except OSError:
                pass


async def _serve(cfg: dict[str, Any], transport: str, conn: Any) -> None:
    from pymodbus.server import ModbusSerialServer, ModbusTcpServer

    scfg = StageConfig(**cfg)
    rmap = _Layout.load(scfg.register_map)
    lock = threading.Lock()
    ids = [scfg.device_id] + [i for i in scfg.extra_device_ids if i != scfg.device_id]
    models = {i: StageModel(rmap, scfg) for i in ids}
    faults = _Faults()
    device = [_build_device(models[i], lock, i) for i in ids]

    def trace(sending: bool, data: bytes) -> bytes:
        return faults.outgoing(data) if sending else data

    keep: list[int] = []
    if transport == "tcp":
        server = ModbusTcpServer(device, address=("127.0.0.1", 0), trace_packet=trace)
        await server.serve_forever(background=True)
        port = server.transport.sockets[0].getsockname()[1]
        address: dict[str, Any] = {"transport": "tcp", "host": "127.0.0.1", "port": port,
                                   "url": f"tcp://127.0.0.1:{port}"}
    elif transport == "rtu":
        m_srv, s_srv, p_srv = open_raw_pty()
        m_cli, s_cli, p_cli = open_raw_pty()
        keep += [m_srv, s_srv, m_cli, s_cli]   # hold the slaves open: no EIO when a side closes
        _PtyRelay(asyncio.get_running_loop(), m_srv, m_cli)
        server = ModbusSerialServer(device, port=p_srv, baudrate=scfg.baudrate,
                                    parity=scfg.parity, trace_packet=trace)
        await server.serve_forever(background=True)
        address = {"transport": "rtu", "port": p_cli, "url": p_cli,
                   "baudrate": scfg.baudrate, "parity": scfg.parity}
    else:
        raise ConfigError(f"transport must be 'tcp' or 'rtu', not {transport!r}")
    address["device_id"] = scfg.device_id
    address["device_ids"] = ids
    address["pid"] = os.getpid()

    loop = asyncio.get_running_loop()
    done = asyncio.Event()

    def handle(cmd: Any, msg: dict[str, Any], reply: dict[str, Any]) -> dict[str, Any]:
        unit = msg.get("unit", scfg.device_id)
        if unit not in models:
            return {"ok": False, "error": f"no unit {msg.get('unit')} (have {ids})"}
        if cmd == "alarm":
            models[unit].raise_alarm(int(msg["code"]))
        elif cmd == "state":
            reply["state"] = models[unit].snapshot()
        else:
            with faults.lock:
                if cmd == "drop":
                    faults.drop += int(msg.get("n", 1))
                elif cmd == "corrupt":
                    faults.corrupt += int(msg.get("n", 1))
                elif cmd == "silence":
                    faults.drop_all = bool(msg.get("on", True))
                elif cmd == "clear":
                    faults.drop = faults.corrupt = 0
                    faults.drop_all = False
                    faults.rate = 0.0
                elif cmd == "rates":
                    faults.rate = float(msg.get("rate", 0.0))
                    faults.rng.seed(int(msg.get("seed", 0)))
                elif cmd == "injected":
                    reply["injected"] = dict(faults.injected)
                else:
                    return {"ok": False, "error": f"unknown command {cmd!r}"}
        return reply

    def control() -> None:
        conn.send(address)
        while answer_control(conn, lock, handle):
            pass
        loop.call_soon_threadsafe(done.set)

    threading.Thread(target=control, daemon=True, name="stage-control").start()
    await done.wait()
    await server.shutdown()
    close_quietly(keep)


def _child_main(cfg: dict[str, Any], transport: str, conn: Any, log_level: int) -> None:
    logging.basicConfig(level=log_level, stream=sys.stderr,
                        format="modbus-stage %(levelname)s %(name)s: %(message)s")
    logging.getLogger("pymodbus").setLevel(logging.CRITICAL)
    try:
        asyncio.run(_serve(cfg, transport, conn))
    except Exception as exc:  # report start-up failures to the parent instead of hanging it
        try:
            conn.send({"error": f"{type(exc).__name__}: {exc}"})
        except Exception:
            pass
        raise


class StageEmulator(PipeEmulator):
    """Handle on a running stage emulator process (see the module docstring).

    Attributes
    ----------
    transport : str
        ``"tcp"`` or ``"rtu"``.
    url : str
        What the driver opens: ``"tcp://127.0.0.1:<port>"`` or the pty path.
    port : str | int
        TCP port number or pty path.
    device_id : int
        Modbus unit id.
    """

    label = "modbus stage emulator"

    def __init__(self, proc: Any, conn: Any, address: dict[str, Any]) -> None:
        super().__init__(proc, conn, address)
        self.address = address
        self.transport: str = address["transport"]
        self.url: str = address["url"]
        self.port = address["port"]
        self.device_id: int = address["device_id"]

    @classmethod
    def start(cls, transport: str = "tcp", *, start_timeout: float = 10.0,
              log_level: int = logging.WARNING, **config: Any) -> "StageEmulator":
        """Start an emulator process; keyword arguments are :class:`StageConfig` fields."""
        StageConfig(**config)  # validate names here, in the parent
        return cls(*cls._spawn(_child_main, (config, transport), (log_level,), f"modbus-stage-{transport}",
                               start_timeout))

    def state(self, unit: int | None = None) -> dict[str, Any]:
        """Position, target, moving, alarm, status word and command counters of one drive."""
        return self._call({"cmd": "state", "unit": unit or self.device_id})["state"]

    def alarm(self, code: int = 0x30, unit: int | None = None) -> None:
        """Raise alarm ``code`` now (0x30 overload by default) on one drive."""
        self._call({"cmd": "alarm", "code": code, "unit": unit or self.device_id})

    def drop_replies(self, n: int = 1) -> None:
        """Do not send the next ``n`` replies."""
        self._call({"cmd": "drop", "n": n})

    def corrupt_replies(self, n: int = 1) -> None:
        """Flip one byte in each of the next ``n`` replies."""
        self._call({"cmd": "corrupt", "n": n})

    def fault_rate(self, rate: float, seed: int = 0) -> None:
        """Random transient faults from now on (seeded): each reply dropped or corrupted with
        probability ``rate`` / 2."""
        self._call({"cmd": "rates", "rate": rate, "seed": seed})

    def injected(self) -> dict[str, int]:
        """Random faults injected so far, by kind."""
        return self._call({"cmd": "injected"})["injected"]

    def silence(self, on: bool = True) -> None:
        """Drop every reply until ``silence(False)``."""
        self._call({"cmd": "silence", "on": on})

    def __repr__(self) -> str:
        return f"StageEmulator({self.transport}, {self.url}, pid={self._proc.pid})"


def main(argv: list[str] | None = None) -> int:
    """Serve until killed; print the address as one JSON line."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--transport", choices=("tcp", "rtu"), default="tcp")
    p.add_argument("--config", default="{}", help="JSON object of StageConfig fields")
    a = p.parse_args(argv)
    emu = StageEmulator.start(a.transport, **json.loads(a.config))
    print(json.dumps(emu.address), flush=True)
    emu.serve_until_interrupted()
    return 0


if __name__ == "__main__":
    sys.exit(main())

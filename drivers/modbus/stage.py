"""The AZ stage driver: :class:`ModbusStageAxis` (connect, bounded retries, typed errors,
direct-data moves, in-position wait, homing, alarms and fault latching). Behaviour is described
in :mod:`drivers.modbus`.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping

from pymodbus.client import ModbusSerialClient, ModbusTcpClient
from pymodbus.exceptions import ConnectionException, ModbusException, ModbusIOException
from pymodbus.framer import FramerType

from bench.core.errors import (ChecksumError, ConfigError, DeviceError, DeviceTimeoutError, FaultLatchedError,
                               GeometryError, HardwareError, InputError, PortGoneError, ProtocolError)
from bench.core.roles import InstrumentBase, InstrumentInfo
from drivers._faultlog import FaultLog
from drivers._settings import port_and_name, settings_with_overrides
from drivers.registers import RegisterMap, load_register_map
from drivers.modbus._client import (
    TransportModbusClient, check_reply, port_open_hint, probe_serial_open,
)
from drivers.modbus.homing import HomingMixin
from drivers.modbus.config import _FUNCTION_NAMES, MODBUS_EXCEPTIONS, TRANSIENT_EXCEPTIONS, AxisConfig

log = logging.getLogger(__name__)


@dataclass
class _Fault:
    kind: str
    message: str
    code: int | None = None
    flags: list[str] = field(default_factory=list)


class ModbusStageAxis(HomingMixin, InstrumentBase):
    """A single stage axis (rotary or linear) on a Modbus drive in direct data operation.

    Deliberately *not* a ``Goniometer`` (no ``check``/``move_to``/``position`` taking a
    Geometry): a goniometer composes axes like this one and maps geometries to their angles.

    Parameters
    ----------
    port : str, optional
        Serial port / pty path / pyserial URL (RTU) or ``"tcp://host:port"`` (TCP).
    transport : Transport, optional
        A :class:`drivers.transport.Transport` to carry RTU frames instead of ``port``.
    client : pymodbus sync client, optional
        A connected ``ModbusSerialClient``/``ModbusTcpClient`` shared by several axes on one
        RS-485 line (different ``device_id``); the axis never closes it. With a shared client
        the serial settings and ``timeout_s`` of the client apply; ``retries`` of the axis still
        bound the attempts (create the client with ``retries=0``).
    config : AxisConfig or mapping, optional
        Settings; keyword arguments override single keys (see :class:`AxisConfig`), and the
        aliases ``limits_deg`` and ``speed_deg_s`` are accepted.
    name : str
        Name used in messages and ``describe()``.

    Raises
    ------
    ConfigError
        Bad configuration or register map.
    PortGoneError
        The port cannot be opened (first request after the bounded retries).
    """

    def __init__(self, port: str | None = None, *, transport: Any = None, client: Any = None,
                 config: AxisConfig | Mapping[str, Any] | None = None, name: str = "stage",
                 **overrides: Any) -> None:
        if sum(x is not None for x in (port, transport, client)) != 1:
            raise InputError("give exactly one of port=, transport= or client=")
        if "limits_deg" in overrides:
            overrides["limits"] = overrides.pop("limits_deg")
        if "speed_deg_s" in overrides:
            overrides["speed"] = overrides.pop("speed_deg_s")
        base = settings_with_overrides(AxisConfig, config, overrides, "stage axis")
        self.config: AxisConfig = base
        self.rmap: RegisterMap = load_register_map(base.register_map)
        self.name = name
        self.port = port if port is not None else repr(transport if client is None else client)
        self._fault: _Fault | None = None
        self._transport = transport
        self._owns_client = client is None
        self._rx_seen = False
        self._answered = False   # a reply ever came back on this link
        self.faults = FaultLog()
        self._gone: str | None = None
        self._closed = False
        cfg = base
        self._client: Any
        if client is not None:
            self._client = client
            self.link = "tcp" if isinstance(client, ModbusTcpClient) else "rtu"
        elif transport is not None:
            self._client = TransportModbusClient(transport, timeout=cfg.timeout_s,
                                                trace_packet=self._trace)
            self.link = "rtu"
        elif port is None:  # pragma: no cover - excluded by the one-of check above
            raise InputError("give exactly one of port=, transport= or client=")
        elif port.startswith("tcp://"):
            hostport = port[len("tcp://"):]
            host, _, p = hostport.rpartition(":")
            if not host or not p.isdigit():
                raise ConfigError(f"TCP address must look like tcp://host:port, got {port!r}")
            self._client = ModbusTcpClient(host, port=int(p), timeout=cfg.timeout_s, retries=0,
                                           reconnect_delay=0, trace_packet=self._trace)
            self.link = "tcp"
        else:
            self._client = ModbusSerialClient(port, framer=FramerType.RTU, baudrate=cfg.baudrate,
                                              parity=cfg.parity, stopbits=cfg.stopbits,
                                              bytesize=cfg.bytesize, timeout=cfg.timeout_s,
                                              retries=0, reconnect_delay=0,
                                              trace_packet=self._trace)
            self.link = "rtu"

    @classmethod
    def from_config(cls, cfg: Mapping[str, Any]) -> "ModbusStageAxis":
        """Build from a bench-config table: ``port`` (required), ``name`` and AxisConfig keys."""
        port, name, d = port_and_name(cfg, "stage axis config", "stage")
        return cls(port, name=name, **d)

    # --- unit conversion ----------------------------------------------------------------------
    def to_steps(self, value: float) -> int:
        """Output position (units) -> motor steps (rounded)."""
        return int(round((value - self.config.zero_offset) * self.config.steps_per_unit))

    def to_units(self, steps: int) -> float:
        """Motor steps -> output position (units)."""
        return steps / self.config.steps_per_unit + self.config.zero_offset

    # --- Modbus plumbing ----------------------------------------------------------------------
    def _trace(self, sending: bool, data: bytes) -> bytes:
        if not sending and data:
            self._rx_seen = True
        return data

    def _execute(self, fc: int, address: int, call: Callable[[], Any], count: int = 0) -> Any:
        """Run one request with bounded retries; map every failure to a bench error."""
        if self._closed:
            raise PortGoneError(f"{self.name}: the axis is closed")
        if self._gone is not None:
            raise PortGoneError(self._gone)
        cfg = self.config
        what = f"{_FUNCTION_NAMES.get(fc, f'function {fc}')} (0x{fc:02X}) at 0x{address:04X}"
        last: BaseException | None = None
        kind = "timeout"
        garbled = False
        for attempt in range(cfg.retries + 1):
            if attempt:
                time.sleep(cfg.retry_delay_s)
            self._rx_seen = False
            try:
                resp = call()
            except ConnectionException as exc:
                last, kind = exc, "gone"
                self.faults.attempt_failed("gone", attempt < cfg.retries)
                self._safe_close_client()
                if self.link == "rtu" and self._answered:
                    # A serial port that worked and then failed has vanished (adapter unplugged,
                    # emulator killed). Never reopen the path by itself: it may now name another
                    # device (ptys and USB adapters reuse names). Build a new axis instead.
                    self._gone = (f"{self.name}: {what}: port {self.port} vanished ({exc}); "
                                  f"not reopened automatically, create a new axis")
                    raise PortGoneError(self._gone) from None
                log.warning("%s: %s: connection failed (attempt %d): %s", self.name, what,
                            attempt + 1, exc)
                continue
            except ModbusIOException as exc:
                last, kind = exc, "timeout"
                garbled = garbled or self._rx_seen
                self.faults.attempt_failed("corrupt" if self._rx_seen else "timeout", attempt < cfg.retries)
                log.warning("%s: %s: no valid reply (attempt %d)", self.name, what, attempt + 1)
                continue
            except (PortGoneError, DeviceError):
                raise
            except ModbusException as exc:
                last, kind = exc, "timeout"
                self.faults.attempt_failed("timeout", attempt < cfg.retries)
                continue
            except OSError as exc:
                last, kind = exc, "gone"
                self.faults.attempt_failed("gone", attempt < cfg.retries)
                self._safe_close_client()
                continue
            try:
                check_reply(resp, fc, cfg.device_id, address, count)
            except ProtocolError as exc:  # a late answer to another request: never used
                last, kind, garbled = exc, "timeout", True
                self.faults.attempt_failed("foreign", attempt < cfg.retries)
                log.warning("%s: %s: reply does not match the request (attempt %d): %s",
                            self.name, what, attempt + 1, exc)
                self._flush_input()
                continue
            if resp.isError():
                code = getattr(resp, "exception_code", None)
                ename = MODBUS_EXCEPTIONS.get(code, "unknown") if code is not None else "?"
                if code in TRANSIENT_EXCEPTIONS and attempt < cfg.retries:  # busy now, not refused
                    last, kind = ProtocolError(f"Modbus exception code {code} ({ename})"), "timeout"
                    self.faults.attempt_failed("exception", True)
                    continue
                self.faults.finished(attempt + 1, False)
                raise ProtocolError(f"{self.name}: {what}: Modbus exception code {code} ({ename})"
                                    f" from device {cfg.device_id}")
            self._answered = True
            self.faults.finished(attempt, True)
            return resp
        tries = cfg.retries + 1
        self.faults.finished(tries, False)
        if kind == "gone":
            hint = ""
            if self.link == "rtu":
                cause = last
                if self._transport is None and self._owns_client and not self._answered:
                    # pymodbus only logs why the port would not open: ask the port ourselves
                    cause = probe_serial_open(self.port, cfg.baudrate, cfg.parity, cfg.bytesize,
                                              cfg.stopbits) or last
                hint = port_open_hint(self.port, cfg.parity, cause)
                if cause is not last:
                    hint = f" [{cause}]" + hint
            raise PortGoneError(f"{self.name}: {what}: cannot reach {self.port} after {tries} "
                                f"attempt(s): {last}{hint}")
        if garbled:
            raise ChecksumError(f"{self.name}: {what}: replies from device {cfg.device_id} "
                                f"failed the CRC/framing check or did not match the request "
                                f"{tries} time(s){f': {last}' if last else ''}")
        raise DeviceTimeoutError(f"{self.name}: {what}: no reply from device {cfg.device_id} "
                                 f"within {cfg.timeout_s} s after {tries} attempt(s)")

    def _flush_input(self) -> None:
        """Drop what has arrived (a late reply) before the next attempt."""
        if self._transport is not None:
            self._transport.reset_input()
            return
        sock: Any = getattr(self._client, "socket", None)
        try:
            if hasattr(sock, "reset_input_buffer"):
                sock.reset_input_buffer()
        except Exception:  # pragma: no cover - a dying port; the next attempt reports it
            pass

    def _safe_close_client(self) -> None:
        if not self._owns_client:
            return  # a shared bus: its owner closes it
        try:
            self._client.close()
        except Exception:  # pragma: no cover - closing a dead link
            pass

    def _read(self, address: int, count: int) -> list[int]:
        resp = self._execute(3, address, lambda: self._client.read_holding_registers(
            address, count=count, device_id=self.config.device_id), count)
        regs = list(resp.registers)
        if len(regs) != count:
            raise ProtocolError(f"{self.name}: read of {count} registers at 0x{address:04X} "
                                f"returned {len(regs)}")
        return regs

    def _write(self, address: int, values: list[int]) -> None:
        self._execute(16, address, lambda: self._client.write_registers(
            address, values, device_id=self.config.device_id), len(values))

    def read_int32(self, key: str) -> int:
        """Read the 32-bit register pair ``key`` of the register map (signed)."""
        return self.rmap.from_words(self._read(self.rmap.addr(key), 2))

    def write_int32(self, key: str, value: int) -> None:
        """Write the 32-bit register pair ``key`` (function 16)."""
        self._write(self.rmap.addr(key), self.rmap.to_words(value))

    # --- status and faults --------------------------------------------------------------------
    def status(self) -> dict[str, Any]:
        """Read the output status: ``{"word": int, "flags": [...], "alarm": code or 0}``."""
        word = self.read_int32("output_status") & 0xFFFFFFFF
        flags = self.rmap.status_flags(word)
        alarm = self.read_int32("present_alarm") if "ALM" in flags else 0
        return {"word": word, "flags": flags, "alarm": alarm}

    def _raise_alarm(self, st: dict[str, Any], during: str) -> None:
        code = int(st["alarm"])
        msg = (f"{self.name}: drive alarm 0x{code:02X} ({self.rmap.alarm_name(code)}) {during}; "
               f"status {'|'.join(st['flags'])}; call reset_alarm() after removing the cause")
        self._fault = _Fault("alarm", msg, code, list(st["flags"]))
        log.error(msg)
        raise HardwareError(msg, code=code, flags=st["flags"])

    def _set_fault(self, kind: str, message: str) -> None:
        self._fault = _Fault(kind, message)

    @property
    def fault(self) -> str | None:
        """The latched fault message, or None."""
        return self._fault.message if self._fault else None

    def _check_latch(self) -> None:
        if self._fault is not None:
            raise FaultLatchedError(f"{self.name}: no motion while a fault is latched "
                                    f"({self._fault.message}); call reset_alarm() first")

    def reset_alarm(self) -> None:
        """Pulse ALM-RST, then clear the latched fault if the drive reports no alarm.

        Raises
        ------
        HardwareError
            The alarm is still present after the reset (its cause persists).
        """
        bit = 1 << self.rmap.input_bits["ALM-RST"]
        self.write_int32("input_command", bit)
        self.write_int32("input_command", 0)
        st = self.status()
        if "ALM" in st["flags"]:
            self._raise_alarm(st, "persists after ALM-RST")
        if self._fault is not None:
            log.info("%s: fault cleared (%s)", self.name, self._fault.message)
        self._fault = None

    def establish(self) -> dict[str, Any]:
        """Set the registers the driver relies on, whatever an earlier program left, and read
        them back: the input command word all off (a START/ZHOME/ALM-RST bit left on would
        swallow the rising edge the driver pulses; FREE de-energizes the motor; STOP blocks
        motion). The direct-data block is written whole with every move. Returns the status
        (an alarm present is reported by the first move, which :meth:`reset_alarm` clears).

        Builders call it right after constructing the axis (the axis's "open")."""
        self.write_int32("input_command", 0)
        left = self.read_int32("input_command")
        if left != 0:
            raise ProtocolError(f"{self.name}: input command reads back 0x{left & 0xFFFFFFFF:08X} after "
                                f"writing 0 (register map {self.rmap.name})")
        return self.status()

    # --- motion ---------------------------------------------------------------------------------
    def check_deg(self, value: float) -> None:
        """Raise :class:`GeometryError` if ``value`` (units) is not a finite in-limits target."""
        lo, hi = self.config.limits
        if not isinstance(value, (int, float)) or not math.isfinite(value):
            raise GeometryError(f"{self.name}: target {value!r} is not a finite number", value)
        if not lo <= value <= hi:
            raise GeometryError(f"{self.name}: target {value} {self.config.unit} is outside the "
                                f"limits [{lo}, {hi}]", value)

    def move_to_deg(self, angle: float) -> float:
        """Move to ``angle`` (units), block until IN-POS, return the position read back.

        Raises
        ------
        GeometryError
            Outside the limits (nothing is sent).
        FaultLatchedError
            A fault is latched (nothing is sent).
        HardwareError
            The drive is in alarm before or during the move (fault latched).
        DeviceTimeoutError
            Not in position within the move timeout (a STOP is sent, fault latched).
        """
        self.check_deg(angle)
        self._check_latch()
        cfg = self.config
        target = self.to_steps(angle)
        try:
            st = self.status()
            if "ALM" in st["flags"]:
                self._raise_alarm(st, "before the move")
            start = self.read_int32("feedback_position")
            speed_hz = max(1, int(round(cfg.speed * cfg.steps_per_unit)))
            block = [0, self.rmap.value("type_absolute", 1), target, speed_hz, cfg.accel,
                     cfg.decel, cfg.current, self.rmap.value("trigger_all", 1)]
            words: list[int] = []
            for v in block:
                words += self.rmap.to_words(v)
            a0, n = self.rmap.direct_block
            assert len(words) == n
            log.debug("%s: move %s -> %s steps at %s Hz", self.name, start, target, speed_hz)
            self._write(a0, words)
            return self._wait_in_position(target, start, speed_hz)
        except HardwareError:
            raise
        except (DeviceTimeoutError, ChecksumError, PortGoneError, ProtocolError) as exc:
            if self._fault is None:
                self._fault = _Fault("communication", f"{type(exc).__name__} during a move: {exc}")
            raise

    def _wait_in_position(self, target: int, start: int, speed_hz: int) -> float:
        cfg = self.config
        travel = abs(target - start) / speed_hz
        limit = cfg.move_timeout_s if cfg.move_timeout_s is not None else \
            travel * 1.5 + cfg.settle_s + 1.0
        deadline = time.monotonic() + limit
        tol = max(1, int(math.ceil(cfg.tolerance * cfg.steps_per_unit)))
        busy = {"BUSY", "MOVE"}
        while True:
            st = self.status()
            if "ALM" in st["flags"]:
                self._raise_alarm(st, f"while moving to {self.to_units(target):.4g} {cfg.unit}")
            if "IN-POS" in st["flags"] and not busy & set(st["flags"]):
                fb = self.read_int32("feedback_position")
                if abs(fb - target) <= tol:
                    return self.to_units(fb)
            if time.monotonic() >= deadline:
                try:
                    fb = self.read_int32("feedback_position")
                    where = f"{self.to_units(fb):.4g} {cfg.unit}"
                except DeviceError:
                    where = "unknown"
                try:
                    self.stop()
                except DeviceError:
                    pass
                msg = (f"{self.name}: not in position at {self.to_units(target):.4g} {cfg.unit} "
                       f"within {limit:.3g} s (at {where}, status {'|'.join(st['flags'])})")
                self._fault = _Fault("timeout", msg)
                raise DeviceTimeoutError(msg)
            time.sleep(cfg.poll_interval_s)

    def position_deg(self) -> float:
        """Feedback position in units (degrees for a rotary axis)."""
        return self.to_units(self.read_int32("feedback_position"))

    def stop(self) -> None:
        """Pulse STOP (always allowed, also with a latched fault)."""
        bit = 1 << self.rmap.input_bits["STOP"]
        self.write_int32("input_command", bit)
        self.write_int32("input_command", 0)

    # --- Instrument ---------------------------------------------------------------------------
    def describe(self) -> InstrumentInfo:
        cfg = self.config
        step = 1.0 / cfg.steps_per_unit
        return InstrumentInfo(
            kind="stage-axis", model=f"modbus:{self.rmap.name}", serial="", firmware="",
            uncertainty=step / math.sqrt(12.0),
            ranges={f"position_{cfg.unit}": (float(cfg.limits[0]), float(cfg.limits[1])),
                    f"speed_{cfg.unit}_s": (0.0, float(cfg.speed))},
            extra={"name": self.name, "port": self.port, "link": self.link,
                   "device_id": cfg.device_id, "steps_per_unit": cfg.steps_per_unit,
                   "unit": cfg.unit, "register_map": self.rmap.name,
                   "fault": self.fault})

    def close(self) -> None:
        """Close the connection (and a transport given to the constructor)."""
        if not self._closed:
            self._closed = True
            self._safe_close_client()
            if self._transport is not None:
                self._transport.close()

    def __repr__(self) -> str:
        return f"ModbusStageAxis({self.name!r}, {self.port!r}, device {self.config.device_id})"

"""The Dynamixel arm driver: :class:`DynamixelArm`, the ``Goniometer`` role on four servos
(connect/reset, move_to with verified motion, position, stop, hardware-fault latching).
The module docstring of :mod:`drivers.dynamixel` describes the behaviour.
"""

from __future__ import annotations


import logging
import math
import time
from typing import Any, Callable, Mapping, Sequence

from dynamixel_sdk import (
    COMM_RX_CORRUPT,
    COMM_RX_TIMEOUT,
    COMM_SUCCESS,
    GroupSyncRead,
    GroupSyncWrite,
    PacketHandler,
)
from bench.core.errors import (
    BenchError,
    ChecksumError,
    CommunicationError,
    ConfigError,
    DeviceError,
    DeviceTimeoutError,
    FaultLatchedError,
    GeometryError,
    HardwareError,
    PortGoneError,
    ProtocolError,
)
from bench.core.geometry import Geometry
from bench.core.roles import InstrumentBase, InstrumentInfo
from drivers import kinematics as kin
from drivers.dynamixel.config import (
    ADDR, ERRBIT_ALERT, STATUS_ERRORS, TICKS_PER_REV, ArmConfig, _BLOCK_ADDR, _BLOCK_LEN, _le, _s32,
    decode_hardware_error,
)
from drivers.kinematics import Joints
from drivers.transport import SerialTransport, Transport, TransportPortHandler

log = logging.getLogger(__name__)



class DynamixelArm(InstrumentBase):
    """Goniometer on four Dynamixel servos (see the module docstring for the behaviour).

    Parameters
    ----------
    config
        An :class:`ArmConfig` or its dict form.
    transport
        Byte transport; default :class:`~drivers.transport.SerialTransport` on ``config.port``.
    connect
        Ping the servos, apply the settings and enable torque now (default). With ``False``
        call :meth:`connect` (or :meth:`reset`) yourself.
    sleep
        Sleep function used between settle polls (tests may pass a no-op).
    external_axes
        ``{joint: axis}`` for the joints of ``config.external`` driven by another drive (e.g. a
        turntable on a Modbus stage, :class:`drivers.modbus.ModbusStageAxis`): objects with
        ``move_to_deg(angle) -> reached``, ``position_deg()`` and ``stop()``. They move first
        and settle (blocking), then the servos move together.
    """

    def __init__(self, config: ArmConfig | Mapping[str, Any], transport: Transport | None = None,
                 *, connect: bool = True, sleep: Callable[[float], None] = time.sleep,
                 external_axes: Mapping[str, Any] | None = None) -> None:
        self.config = config if isinstance(config, ArmConfig) else ArmConfig.from_dict(config)
        self._external = dict(external_axes or {})
        self._external_deg: dict[str, float] = {}  # last read-back of each external axis
        if set(self._external) != set(self.config.external):
            raise ConfigError(f"external axes {sorted(self._external)} do not match the config's "
                              f"external joints {list(self.config.external)}")
        if transport is None:
            if not self.config.port:
                raise ConfigError("arm config needs a port (or pass a transport)")
            transport = SerialTransport(self.config.port, self.config.baudrate)
        self.transport = transport
        self._port = TransportPortHandler(transport, baudrate=self.config.baudrate
                                          if self.config.baudrate in _SDK_BAUDS else 1_000_000)
        self._ph = PacketHandler(2.0)
        self._sleep = sleep
        self._axes = self.config.axis_list()
        self._ids = [a.id for a in self._axes]
        self._fault: BaseException | None = None
        self._joints: Joints | None = None
        self._closed = False
        self._models: dict[int, int] = {}
        if connect:
            try:
                self.connect()
            except BaseException:
                try:
                    self._port.closePort()
                except BenchError:
                    pass
                self._closed = True
                raise

    # -- state ------------------------------------------------------------------------------
    @property
    def fault(self) -> BaseException | None:
        """The latched fault, or ``None``."""
        return self._fault

    def _latch(self, exc: BaseException) -> None:
        if self._fault is None:
            self._fault = exc
            log.warning("%s: fault latched: %s", self.config.name, exc)

    def _require_unlatched(self, what: str) -> None:
        if self._closed:
            raise PortGoneError(f"{self.config.name} is closed")
        if self._fault is not None:
            raise FaultLatchedError(
                f"{what} refused: a fault is latched ({type(self._fault).__name__}: {self._fault}); "
                f"call reset() first")

    # -- communication ----------------------------------------------------------------------
    def _call(self, what: str, fn: Callable[..., Any], *args: Any) -> tuple[Any, int]:
        """Run one SDK transaction with bounded retries; return ``(value, status_error)``."""
        comm = COMM_SUCCESS
        for attempt in range(self.config.retries + 1):
            try:
                res = fn(self._port, *args)
            finally:
                self._port.is_using = False  # an exception inside the SDK leaves it set
            if len(res) == 3:
                value, comm, err = res
            else:
                value, (comm, err) = None, res
            if comm == COMM_SUCCESS:
                return value, int(err)
            log.debug("%s: %s attempt %d: %s", self.config.name, what, attempt + 1,
                      self._ph.getTxRxResult(comm))
        raise self._comm_error(what, comm)

    def _comm_error(self, what: str, comm: int) -> CommunicationError:
        n = self.config.retries + 1
        if comm == COMM_RX_TIMEOUT:
            return DeviceTimeoutError(f"{self.config.name}: no reply to {what} after {n} attempt(s)")
        if comm == COMM_RX_CORRUPT:
            return ChecksumError(f"{self.config.name}: corrupt reply (CRC/framing) to {what} "
                                 f"after {n} attempt(s)")
        return CommunicationError(f"{self.config.name}: {what} failed after {n} attempt(s): "
                                  f"{self._ph.getTxRxResult(comm)} ({comm})")

    def _status(self, what: str, dxl_id: int, err: int) -> None:
        """Turn a status error byte into the right exception (hardware path on the alert bit)."""
        if err & ERRBIT_ALERT:
            self._hardware_fault([dxl_id], what)
        code = err & 0x7F
        if code:
            raise ProtocolError(f"{self.config.name}: servo {dxl_id} ({self._joint(dxl_id)}) "
                                f"refused {what}: {STATUS_ERRORS.get(code, 'unknown error')} ({code})")

    def _joint(self, dxl_id: int) -> str:
        return next((a.joint for a in self._axes if a.id == dxl_id), "?")

    def _read(self, dxl_id: int, addr: int, size: int, what: str) -> int:
        fn = {1: self._ph.read1ByteTxRx, 2: self._ph.read2ByteTxRx, 4: self._ph.read4ByteTxRx}[size]
        value, err = self._call(f"{what} (read {addr}) on servo {dxl_id}", fn, dxl_id, addr)
        self._status(what, dxl_id, err)
        return int(value)

    def _write(self, dxl_id: int, addr: int, size: int, value: int, what: str) -> None:
        fn = {1: self._ph.write1ByteTxRx, 2: self._ph.write2ByteTxRx, 4: self._ph.write4ByteTxRx}[size]
        _, err = self._call(f"{what} (write {addr}) on servo {dxl_id}", fn, dxl_id, addr,
                            value & ((1 << (8 * size)) - 1))
        self._status(what, dxl_id, err)

    def _sync_read_block(self) -> dict[int, bytes]:
        """One sync read of Moving..Present Position for every axis (bounded retries)."""
        what = f"sync read {_BLOCK_ADDR}+{_BLOCK_LEN}"
        comm = COMM_SUCCESS
        for attempt in range(self.config.retries + 1):
            group = GroupSyncRead(self._port, self._ph, _BLOCK_ADDR, _BLOCK_LEN)
            for i in self._ids:
                group.addParam(i)
            data: dict[int, bytes] = {}
            errors: dict[int, int] = {}
            try:
                comm = group.txPacket()
                if comm == COMM_SUCCESS:
                    for i in self._ids:  # own rx loop: GroupSyncRead drops the error byte
                        d, comm, err = self._ph.readRx(self._port, i, _BLOCK_LEN)
                        if comm != COMM_SUCCESS:
                            break
                        data[i], errors[i] = bytes(d), int(err)
            finally:
                self._port.is_using = False
            if comm == COMM_SUCCESS:
                alerts = [i for i, e in errors.items() if e & ERRBIT_ALERT]
                if alerts and not isinstance(self._fault, HardwareError):
                    self._hardware_fault(alerts, what)
                for i, e in errors.items():  # already latched: reading stays possible
                    self._status(what, i, e & 0x7F)
                return data
            log.debug("%s: %s attempt %d: %s", self.config.name, what, attempt + 1,
                      self._ph.getTxRxResult(comm))
        raise self._comm_error(what, comm)

    def _hardware_fault(self, ids: Sequence[int], what: str) -> None:
        """Read addr 70 of the alerting servos, torque off everywhere, latch, raise."""
        codes: dict[int, int | None] = {}
        for i in ids:
            try:
                v, _ = self._call(f"read Hardware Error Status of servo {i}",
                                  self._ph.read1ByteTxRx, i, ADDR["hardware_error"])
                codes[i] = int(v)
            except DeviceError:
                codes[i] = None
        self._torque_off_best_effort()
        parts, flags = [], []
        for i, c in codes.items():
            f = decode_hardware_error(c) if c is not None else ["unreadable"]
            flags += [x for x in f if x not in flags]
            parts.append(f"servo {i} ({self._joint(i)}): "
                         f"{', '.join(f) or 'alert without error bits'}"
                         + (f" (0x{c:02X})" if c is not None else ""))
        code = next((c for c in codes.values() if c is not None), None)
        exc = HardwareError(f"{self.config.name}: hardware error during {what}: "
                            f"{'; '.join(parts)}; torque switched off", code=code, flags=flags)
        self._latch(exc)
        raise exc

    def _torque_off_best_effort(self) -> None:
        for i in self._ids:
            try:
                self._call(f"torque off servo {i}", self._ph.write1ByteTxRx, i,
                           ADDR["torque_enable"], 0)
            except DeviceError as exc:
                log.warning("%s: torque off servo %d failed: %s", self.config.name, i, exc)
                if isinstance(exc, PortGoneError):
                    return

    def _guard(self, what: str, fn: Callable[[], Any]) -> Any:
        """Run ``fn``; latch any device fault it raises (geometry errors pass through)."""
        try:
            return fn()
        except GeometryError:
            raise
        except DeviceError as exc:
            self._latch(exc)
            raise

    # -- connection -------------------------------------------------------------------------
    def connect(self) -> None:
        """Ping, check hardware errors, apply EEPROM (torque off) and RAM settings, torque on."""
        self._guard("connect", self._setup)

    def _setup(self) -> None:
        for a in self._axes:
            model, err = self._call(f"ping servo {a.id}", self._ph.ping, a.id)
            self._status("ping", a.id, err)
            self._models[a.id] = int(model)
            if self.config.model_number is not None and model != self.config.model_number:
                raise ProtocolError(f"{self.config.name}: servo {a.id} ({a.joint}) is model "
                                    f"{model}, expected {self.config.model_number}")
            hw = self._read(a.id, ADDR["hardware_error"], 1, "read Hardware Error Status")
            if hw:
                self._torque_off_best_effort()
                exc = HardwareError(f"{self.config.name}: servo {a.id} ({a.joint}) reports "
                                    f"{', '.join(decode_hardware_error(hw))} (0x{hw:02X}); "
                                    f"call reset() to reboot it", code=hw, flags=decode_hardware_error(hw))
                self._latch(exc)
                raise exc
            mode = self._read(a.id, ADDR["operating_mode"], 1, "read Operating Mode")
            writes: list[tuple[int, int, int, str]] = []
            if mode != a.operating_mode:
                writes.append((ADDR["operating_mode"], 1, a.operating_mode, "Operating Mode"))
            if a.operating_mode == 3:
                lo, hi = self.config.kinematics.limits[a.joint]
                t = sorted((a.to_ticks(lo), a.to_ticks(hi)))
                cur_max = _s32(self._read(a.id, ADDR["max_position"], 4, "read Max Position Limit"))
                cur_min = _s32(self._read(a.id, ADDR["min_position"], 4, "read Min Position Limit"))
                if cur_max != t[1]:
                    writes.append((ADDR["max_position"], 4, t[1], "Max Position Limit"))
                if cur_min != t[0]:
                    writes.append((ADDR["min_position"], 4, t[0], "Min Position Limit"))
            if writes:  # EEPROM: only with torque off
                self._write(a.id, ADDR["torque_enable"], 1, 0, "torque off for EEPROM")
                for addr, size, value, name in writes:
                    self._write(a.id, addr, size, value, f"write {name}")
            self._write(a.id, ADDR["profile_acceleration"], 4, a.profile_acceleration,
                        "write Profile Acceleration")
            self._write(a.id, ADDR["profile_velocity"], 4, a.profile_velocity, "write Profile Velocity")
            self._write(a.id, ADDR["torque_enable"], 1, 1, "torque on")
        self._joints = self._joints_from(self._sync_read_block())

    def reset(self) -> None:
        """Clear a latched fault: reboot servos with hardware errors, re-apply settings, torque on.

        Raises the underlying error (and stays latched) if the bus still fails.
        """
        if self._closed:
            raise PortGoneError(f"{self.config.name} is closed")

        def run() -> None:
            for a in self._axes:
                hw = self._call(f"read Hardware Error Status of servo {a.id}",
                                self._ph.read1ByteTxRx, a.id, ADDR["hardware_error"])[0]
                if hw:
                    log.info("%s: rebooting servo %d (hardware error 0x%02X)", self.config.name, a.id, hw)
                    self._call(f"reboot servo {a.id}", self._ph.reboot, a.id)
                    self._wait_ping(a.id)
            self._setup()

        saved, self._fault = self._fault, None
        try:
            self._guard("reset", run)
        except BaseException:
            if self._fault is None:
                self._fault = saved
            raise

    def _wait_ping(self, dxl_id: int, timeout: float = 3.0) -> None:
        deadline = time.monotonic() + timeout
        while True:
            try:
                self._call(f"ping servo {dxl_id} after reboot", self._ph.ping, dxl_id)
                return
            except DeviceTimeoutError:
                if time.monotonic() > deadline:
                    raise
                self._sleep(0.05)

    # -- geometry <-> ticks -----------------------------------------------------------------
    def _joints_from(self, block: Mapping[int, bytes]) -> Joints:
        vals = {}
        for a in self._axes:
            ticks = _s32(int.from_bytes(block[a.id][_BLOCK_LEN - 4:], "little"))
            vals[a.joint] = a.to_degrees(ticks)
        for joint, axis in self._external.items():
            if joint not in self._external_deg:
                self._external_deg[joint] = float(axis.position_deg())
            vals[joint] = self._external_deg[joint]
        return Joints(**vals)

    @staticmethod
    def _geometry(j: Joints) -> Geometry:
        clamp = lambda v: min(180.0, max(0.0, v))  # noqa: E731 - read-back noise at the poles
        return kin.joints_to_geometry(j._replace(source=clamp(j.source),
                                                 detector_elevation=clamp(j.detector_elevation)))

    def _goal_ticks(self, j: Joints) -> dict[int, int]:
        return {a.id: a.to_ticks(getattr(j, a.joint)) for a in self._axes}

    # -- Goniometer role --------------------------------------------------------------------
    def describe(self) -> InstrumentInfo:
        lim = self.config.kinematics.limits
        res = max(360.0 / (TICKS_PER_REV * a.gear_ratio) for a in self._axes)
        return InstrumentInfo(
            kind="goniometer", model="Dynamixel 4-axis gonioreflectometer arm",
            serial=str(getattr(self.transport, "url", "")),
            uncertainty=res / math.sqrt(12.0),
            ranges={"theta_i": lim["source"], "theta_r": lim["detector_elevation"],
                    "phi_i": (0.0, 360.0), "phi_r": (0.0, 360.0)},
            extra={"uncertainty_unit": "deg (joint quantisation, 1 tick / sqrt(12))",
                   "ids": {a.joint: a.id for a in self._axes},
                   "models": dict(self._models), "resolution_deg": res,
                   "kinematics": self.config.kinematics.as_dict()})

    def check(self, geometry: Geometry) -> None:
        """Raise :class:`GeometryError` if ``geometry`` is unreachable, blocks the beam or
        collides. Pure: no byte is sent."""
        kin.check(geometry, self.config.kinematics)

    def move_to(self, geometry: Geometry) -> Geometry:
        """Check, sync-write all goals, wait until settled; return the geometry read back."""
        kin.check(geometry, self.config.kinematics)  # before any byte, latched or not
        self._require_unlatched(f"move_to({geometry})")
        joints = kin.geometry_to_joints(geometry, self.config.kinematics, near=self._joints)
        goals = self._goal_ticks(joints)

        def run() -> Geometry:
            for joint, axis in self._external.items():
                target = getattr(joints, joint)
                last = self._external_deg.get(joint)
                if last is None or abs(last - target) > self.config.tolerance_deg:
                    self._external_deg.pop(joint, None)
                    self._external_deg[joint] = float(axis.move_to_deg(target))  # blocks until in position
            return self._move(goals, f"move_to({geometry})")

        return self._guard("move_to", run)

    def _move(self, goals: Mapping[int, int], what: str) -> Geometry:
        group = GroupSyncWrite(self._port, self._ph, ADDR["goal_position"], 4)
        for i, t in goals.items():
            group.addParam(i, _le(t, 4))
        self._call(f"{what}: sync write Goal Position", lambda _port: (group.txPacket(), 0))
        tol = {a.id: max(1, int(math.ceil(self.config.tolerance_deg * a.ticks_per_degree)))
               for a in self._axes}
        deadline = time.monotonic() + self.config.settle_timeout_s
        while True:
            block = self._sync_read_block()
            settled = True
            for i, goal in goals.items():
                d = block[i]
                present = _s32(int.from_bytes(d[_BLOCK_LEN - 4:], "little"))
                if d[0] or abs(present - goal) > tol[i]:
                    settled = False
                    break
            if settled:
                self._joints = self._joints_from(block)
                return self._geometry(self._joints)
            if time.monotonic() > deadline:
                late = {self._joint(i): (goal, _s32(int.from_bytes(block[i][_BLOCK_LEN - 4:], "little")))
                        for i, goal in goals.items()}
                raise DeviceTimeoutError(f"{self.config.name}: {what} did not settle within "
                                         f"{self.config.settle_timeout_s:g} s; (goal, present) "
                                         f"ticks: {late}")
            self._sleep(self.config.poll_interval_s)

    def position(self) -> Geometry:
        """The geometry read back from Present Position (a read; allowed while latched)."""
        if self._closed:
            raise PortGoneError(f"{self.config.name} is closed")
        block = self._guard("position", self._sync_read_block)
        self._external_deg.clear()  # read the external axes again too
        self._joints = self._joints_from(block)
        return self._geometry(self._joints)

    def joints(self) -> Joints:
        """Joint angles (degrees) read back from the servos."""
        self.position()
        assert self._joints is not None
        return self._joints

    def stop(self) -> None:
        """Hold where the arm is: Goal Position = Present Position (torque stays on).

        A no-op while a fault is latched (torque is already off after a hardware error, and no
        motion bytes are sent after a fault).
        """
        if self._closed or self._fault is not None:
            return

        def run() -> None:
            for axis in self._external.values():
                axis.stop()
            block = self._sync_read_block()
            goals = {i: _s32(int.from_bytes(block[i][_BLOCK_LEN - 4:], "little")) for i in self._ids}
            group = GroupSyncWrite(self._port, self._ph, ADDR["goal_position"], 4)
            for i, t in goals.items():
                group.addParam(i, _le(t, 4))
            self._call("stop: sync write Goal Position", lambda _port: (group.txPacket(), 0))

        self._guard("stop", run)

    def close(self) -> None:
        """Optionally torque off (``torque_off_on_close``), then close the port. Idempotent."""
        if self._closed:
            return
        self._closed = True
        try:
            if self.config.torque_off_on_close and not isinstance(self._fault, PortGoneError):
                try:
                    self._torque_off_best_effort()
                except DeviceError:
                    pass
        finally:
            self._port.closePort()

    def __repr__(self) -> str:
        state = "closed" if self._closed else ("faulted" if self._fault else "ready")
        return f"DynamixelArm({self.config.name!r}, ids={self._ids}, {state})"


_SDK_BAUDS = {9600, 19200, 38400, 57600, 115200, 230400, 460800, 500000, 576000, 921600,
              1000000, 1152000, 2000000, 2500000, 3000000, 3500000, 4000000}

"""The Dynamixel arm driver: :class:`DynamixelArm`, the ``Goniometer`` role on four servos
(connect/reset, move_to with verified motion, position, stop, hardware-fault latching).
The module docstring of :mod:`drivers.dynamixel` describes the behaviour; the request/reply
discipline is :mod:`drivers.dynamixel._link`.
"""

from __future__ import annotations

import logging
import math
import time
from typing import Any, Callable, Mapping, Sequence

from bench.core.errors import (BenchError, CommunicationError, ConfigError, DeviceError, DeviceTimeoutError,
                               FaultLatchedError, GeometryError, HardwareError, PortGoneError, ProtocolError)
from bench.core.geometry import Geometry
from bench.core.roles import InstrumentBase, InstrumentInfo
from drivers import kinematics as kin
from drivers.dynamixel.config import (_BLOCK_ADDR, _BLOCK_LEN, _OFF_GOAL, _OFF_MOVING, _OFF_PRESENT, ADDR,
                                      DRIVE_MODE_CLEAR, ERRBIT_ALERT, RETURN_DELAY_UNIT_S, STATUS_ERRORS,
                                      STATUS_RETURN_ALL, TICKS_PER_REV, ArmConfig, _le, _s32, decode_hardware_error)
from drivers._faultlog import FaultLog
from drivers.dynamixel._link import DxlLink
from drivers.kinematics import Joints
from drivers.transport import SerialTransport, Transport, TransportPortHandler

log = logging.getLogger(__name__)


def _field(data: bytes, offset: int, size: int) -> int:
    return _s32(int.from_bytes(data[offset:offset + size], "little")) if size == 4 else \
        int.from_bytes(data[offset:offset + size], "little")


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
    sleep, clock
        Sleep between polls and the time source of the start and settle windows (default wall
        time; tests pass a fake clock whose sleep advances it).
    external_axes
        ``{joint: axis}`` for the joints of ``config.external`` driven by another drive (e.g. a
        turntable on a Modbus stage, :class:`drivers.modbus.ModbusStageAxis`): objects with
        ``move_to_deg(angle) -> reached``, ``position_deg()`` and ``stop()``. They move first
        and settle (blocking), then the servos move together.
    """

    def __init__(self, config: ArmConfig | Mapping[str, Any], transport: Transport | None = None,
                 *, connect: bool = True, sleep: Callable[[float], None] = time.sleep,
                 clock: Callable[[], float] = time.monotonic,
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
                                          if self.config.baudrate in _SDK_BAUDS else 1_000_000,
                                          clock=lambda: clock() * 1000.0)
        self._link = DxlLink(self._port, self.config.baudrate, self.config.retries,
                             self.config.return_delay_s, self.config.latency_s, self.config.name,
                             clock=clock, sleep=sleep)
        self._sleep, self._clock = sleep, clock
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

    # -- communication (every exchange goes through the link's request/reply discipline) ---
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
        data, err = self._link.read(dxl_id, addr, size, f"{what} (read {addr}) on servo {dxl_id}")
        self._status(what, dxl_id, err)
        return _field(data, 0, size)

    def _write(self, dxl_id: int, addr: int, size: int, value: int, what: str) -> None:
        err = self._link.write(dxl_id, addr, bytes(_le(value, size)),
                               f"{what} (write {addr}) on servo {dxl_id}")
        self._status(what, dxl_id, err)

    def _sync_read_block(self) -> dict[int, bytes]:
        """One sync read of Goal Position .. Present Position for every axis."""
        what = f"sync read {_BLOCK_ADDR}+{_BLOCK_LEN}"
        replies = self._link.sync_read(_BLOCK_ADDR, _BLOCK_LEN, self._ids, what)
        alerts = [i for i, (_, e) in replies.items() if e & ERRBIT_ALERT]
        if alerts and not isinstance(self._fault, HardwareError):
            self._hardware_fault(alerts, what)
        for i, (_, e) in replies.items():  # already latched: reading stays possible
            self._status(what, i, e & 0x7F)
        return {i: d for i, (d, _) in replies.items()}

    def _sync_write_goals(self, goals: Mapping[int, int], what: str) -> None:
        self._link.sync_write(ADDR["goal_position"], 4,
                              {i: bytes(_le(t, 4)) for i, t in goals.items()},
                              f"{what}: sync write Goal Position")

    def _hardware_error_confirmed(self, dxl_id: int) -> int | None:
        """Hardware Error Status (70) of a servo, only if two clean reads both say non-zero.

        Returns the code (non-zero) when confirmed, 0 when either read says 0, ``None`` when it
        cannot be read (the bus keeps failing)."""
        codes = []
        for k in (1, 2):
            try:
                data, _ = self._link.read(dxl_id, ADDR["hardware_error"], 1,
                                          f"read Hardware Error Status of servo {dxl_id} ({k}/2)")
            except CommunicationError:
                return None
            codes.append(data[0])
            if not data[0]:
                return 0
        return codes[-1]

    def _hardware_fault(self, ids: Sequence[int], what: str) -> None:
        """Confirm Hardware Error Status of the alerting servos by two clean reads; if any is
        confirmed: torque off everywhere, latch, raise :class:`HardwareError`."""
        codes = {i: self._hardware_error_confirmed(i) for i in ids}
        confirmed = {i: c for i, c in codes.items() if c}
        if not confirmed:
            if any(c is None for c in codes.values()):
                unreadable = [i for i, c in codes.items() if c is None]
                raise CommunicationError(f"{self.config.name}: alert bit during {what} but the "
                                         f"Hardware Error Status of servo(s) {unreadable} could "
                                         f"not be read")
            log.warning("%s: alert bit during %s not confirmed by Hardware Error Status of "
                        "servo(s) %s (both reads 0): ignored", self.config.name, what, list(ids))
            return
        self._torque_off_best_effort()
        parts, flags = [], []
        for i, c in confirmed.items():
            f = decode_hardware_error(c)
            flags += [x for x in f if x not in flags]
            parts.append(f"servo {i} ({self._joint(i)}): {', '.join(f)} (0x{c:02X})")
        exc = HardwareError(f"{self.config.name}: hardware error during {what}: "
                            f"{'; '.join(parts)}; torque switched off",
                            code=next(iter(confirmed.values())), flags=flags)
        self._latch(exc)
        raise exc

    def _torque_off_best_effort(self) -> None:
        for i in self._ids:
            try:
                self._link.write(i, ADDR["torque_enable"], b"\x00", f"torque off servo {i}")
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
            model, err = self._link.ping(a.id, f"ping servo {a.id}")
            self._models[a.id] = int(model)
            if err & 0x7F:
                self._status("ping", a.id, err & 0x7F)
            if self.config.model_number is not None and model != self.config.model_number:
                raise ProtocolError(f"{self.config.name}: servo {a.id} ({a.joint}) is model "
                                    f"{model}, expected {self.config.model_number}")
            hw = self._hardware_error_confirmed(a.id)  # two clean reads, whatever the alert bit
            if hw is None:
                raise CommunicationError(f"{self.config.name}: Hardware Error Status of servo "
                                         f"{a.id} ({a.joint}) could not be read")
            if hw:
                self._torque_off_best_effort()
                exc = HardwareError(f"{self.config.name}: servo {a.id} ({a.joint}) reports "
                                    f"{', '.join(decode_hardware_error(hw))} (0x{hw:02X}); "
                                    f"call reset() to reboot it", code=hw, flags=decode_hardware_error(hw))
                self._latch(exc)
                raise exc
            self._establish(a)
        self._joints = self._joints_from(self._sync_read_block())

    def _establish(self, a: Any) -> None:
        """Set every setting of servo ``a`` the driver relies on, whatever an earlier program left
        (a servo keeps its EEPROM and, until powered off, its RAM), and read back what it wrote:
        Status Return Level 2 (a status for every write), Operating Mode, Drive Mode (forward,
        velocity-based profile), Homing Offset 0, Return Delay Time, the position limits of mode 3,
        Profile Acceleration/Velocity; then torque on."""
        # a SYNC_WRITE is answered at no level, so it sets the level whatever the level is
        self._link.sync_write(ADDR["status_return_level"], 1, {a.id: bytes([STATUS_RETURN_ALL])},
                              f"set Status Return Level of servo {a.id}")
        wanted: list[tuple[int, int, int | None, str]] = [
            (ADDR["operating_mode"], 1, a.operating_mode, "Operating Mode"),
            (ADDR["drive_mode"], 1, None, "Drive Mode"),
            (ADDR["homing_offset"], 4, 0, "Homing Offset"),
            (ADDR["return_delay"], 1, min(254, round(self.config.return_delay_s / RETURN_DELAY_UNIT_S)),
             "Return Delay Time")]
        if a.operating_mode == 3:
            lo, hi = sorted((a.to_ticks(x) for x in self.config.kinematics.limits[a.joint]))
            wanted += [(ADDR["max_position"], 4, hi, "Max Position Limit"),
                       (ADDR["min_position"], 4, lo, "Min Position Limit")]
        writes: list[tuple[int, int, int, str]] = []
        for addr, size, value, name in wanted:
            now = self._read(a.id, addr, size, f"read {name}")
            now = _s32(now) if size == 4 else now
            if value is None:  # Drive Mode: clear the bits the driver relies on, keep the rest
                value = now & ~DRIVE_MODE_CLEAR
            if now != value:
                writes.append((addr, size, value, name))
        if writes:  # EEPROM: only with torque off
            self._write(a.id, ADDR["torque_enable"], 1, 0, "torque off for EEPROM")
            for addr, size, value, name in writes:
                self._write(a.id, addr, size, value, f"write {name}")
        self._write(a.id, ADDR["profile_acceleration"], 4, a.profile_acceleration, "write Profile Acceleration")
        self._write(a.id, ADDR["profile_velocity"], 4, a.profile_velocity, "write Profile Velocity")
        checks = [(ADDR["status_return_level"], 1, STATUS_RETURN_ALL, "Status Return Level"),
                  *[(addr, size, value, name) for addr, size, value, name in writes],
                  (ADDR["profile_acceleration"], 4, a.profile_acceleration, "Profile Acceleration"),
                  (ADDR["profile_velocity"], 4, a.profile_velocity, "Profile Velocity")]
        for addr, size, value, name in checks:
            for attempt in range(self.config.retries + 1):
                got = self._read(a.id, addr, size, f"read back {name}")
                got = _s32(got) if size == 4 else got
                if got == value:
                    break
                # a late status of an earlier read of the same length is indistinguishable from the
                # answer (Protocol 2.0 has no sequence number): read again before believing it
                self.faults.attempt_failed("foreign", attempt < self.config.retries)
            else:
                raise ProtocolError(f"{self.config.name}: servo {a.id} ({a.joint}) kept {name} = {got} "
                                    f"after the driver wrote {value} ({self.config.retries + 1} reads)")
        self._write(a.id, ADDR["torque_enable"], 1, 1, "torque on")

    def reset(self) -> None:
        """Clear a latched fault: reboot servos with hardware errors, re-apply settings, torque on.

        Raises the underlying error (and stays latched) if the bus still fails.
        """
        if self._closed:
            raise PortGoneError(f"{self.config.name} is closed")

        def run() -> None:
            for a in self._axes:
                hw = self._hardware_error_confirmed(a.id)  # REBOOT only on a confirmed error
                if hw is None:
                    raise CommunicationError(f"{self.config.name}: Hardware Error Status of "
                                             f"servo {a.id} could not be read; not rebooting")
                if hw:
                    log.info("%s: rebooting servo %d (hardware error 0x%02X, read twice)",
                             self.config.name, a.id, hw)
                    self._link.reboot(a.id, f"reboot servo {a.id}")
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
        deadline = self._clock() + timeout
        while True:
            try:
                self._link.ping(dxl_id, f"ping servo {dxl_id} after reboot")
                return
            except DeviceTimeoutError:
                if self._clock() > deadline:
                    raise
                self._sleep(0.05)

    # -- geometry <-> ticks -----------------------------------------------------------------
    def _joints_from(self, block: Mapping[int, bytes]) -> Joints:
        vals: dict[str, float] = {}  # joint name -> degrees
        for a in self._axes:
            ticks = _field(block[a.id], _OFF_PRESENT, 4)
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
    @property
    def faults(self) -> FaultLog:
        """The bus's transaction faults and recoveries (:class:`drivers._faultlog.FaultLog`)."""
        return self._link.faults

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
                   "bus_recoveries": self._link.recoveries,
                   "late_bytes_discarded": self._link.discarded,
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
        """Sync-write the goals, confirm they landed (re-send once), confirm every axis that
        has to move starts within ``start_timeout_s``, then wait until settled."""
        cfg = self.config
        tol = {a.id: max(1, int(math.ceil(cfg.tolerance_deg * a.ticks_per_degree)))
               for a in self._axes}
        self._sync_write_goals(goals, what)
        sent = 1
        t0 = self._clock()
        deadline = t0 + cfg.settle_timeout_s
        first: dict[int, int] | None = None   # present ticks at the first confirmed poll
        started: set[int] = set()
        while True:
            block = self._sync_read_block()
            lost = {i: _field(block[i], _OFF_GOAL, 4) for i, g in goals.items()
                    if _field(block[i], _OFF_GOAL, 4) != g}
            if lost:
                if sent >= 2:
                    raise CommunicationError(
                        f"{cfg.name}: {what}: the sync write of Goal Position did not land on "
                        f"servo(s) {sorted(lost)} after {sent} sends (read back {lost})")
                log.warning("%s: %s: Goal Position not taken by servo(s) %s (read back %s); "
                            "re-sending the sync write", cfg.name, what, sorted(lost), lost)
                self._sync_write_goals(goals, what)
                sent += 1
                t0 = self._clock()
                continue
            present = {i: _field(block[i], _OFF_PRESENT, 4) for i in goals}
            if first is None:
                first = present
            settled = True
            for i, goal in goals.items():
                moving = block[i][_OFF_MOVING]
                if moving or present[i] != first[i]:
                    started.add(i)
                if moving or abs(present[i] - goal) > tol[i]:
                    settled = False
            if settled:
                self._joints = self._joints_from(block)
                return self._geometry(self._joints)
            now = self._clock()
            idle = [i for i, goal in goals.items() if i not in started
                    and abs(first[i] - goal) > tol[i]]
            if idle and now - t0 > cfg.start_timeout_s:
                raise DeviceTimeoutError(
                    f"{cfg.name}: {what}: servo(s) {', '.join(f'{i} ({self._joint(i)})' for i in idle)} "
                    f"did not start moving within {cfg.start_timeout_s:g} s (goal taken, Moving "
                    f"never 1, position unchanged; torque off?)")
            if now > deadline:
                late = {self._joint(i): (goal, present[i]) for i, goal in goals.items()}
                raise DeviceTimeoutError(f"{cfg.name}: {what} did not settle within "
                                         f"{cfg.settle_timeout_s:g} s; (goal, present) "
                                         f"ticks: {late}")
            self._sleep(cfg.poll_interval_s)

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
            goals = {i: _field(block[i], _OFF_PRESENT, 4) for i in self._ids}
            for _ in range(2):  # a broadcast has no status: read back, re-send once
                self._sync_write_goals(goals, "stop")
                block = self._sync_read_block()
                if all(_field(block[i], _OFF_GOAL, 4) == g for i, g in goals.items()):
                    return
            raise CommunicationError(f"{self.config.name}: stop: Goal Position did not land "
                                     f"after 2 sync writes")

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

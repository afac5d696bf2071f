"""A four-axis goniometer on Dynamixel X-series servos (Protocol 2.0) through dynamixel-sdk.

:class:`DynamixelArm` fills the ``Goniometer`` role. Bytes go through dynamixel-sdk's
``PacketHandler(2.0)``, ``GroupSyncWrite`` (Goal Position of all axes in one packet) and
``GroupSyncRead`` (Moving .. Present Position of all axes in one transaction) on a
:class:`~drivers.transport.TransportPortHandler`, so the same driver runs on a real port, on an
emulator's pty, or against a :class:`~drivers.transport.ScriptedTransport` fixture.

Behaviour
---------
- ``check(g)`` runs the kinematics rules (:mod:`drivers.kinematics`) and the tick ranges; it is
  pure and sends nothing. ``move_to`` calls it before any byte is written.
- ``move_to`` writes all Goal Positions in one sync write, then polls one sync read of
  addresses 122..135 (Moving, Moving Status, ..., Present Position) every ``poll_interval_s``
  until every axis has Moving = 0 and Present Position within ``tolerance_deg`` of its goal, or
  ``settle_timeout_s`` passes (:class:`DeviceTimeoutError`). It returns the geometry computed
  from the Present Positions read back.
- Communication: each transaction is retried ``retries`` times on COMM_RX_TIMEOUT (-3001),
  COMM_RX_CORRUPT (-3002) and TX failures, then raises :class:`DeviceTimeoutError` /
  :class:`ChecksumError` / :class:`CommunicationError`. A vanished port is
  :class:`PortGoneError` (from the transport), never a hang: every read has a deadline.
- A status packet with the alert bit (0x80) makes the driver read Hardware Error Status
  (addr 70) of that servo, switch torque off on every axis, and raise :class:`HardwareError`
  whose ``flags`` name the bits (``overload`` ...) and ``code`` is the raw byte. A status
  error code 1..7 raises :class:`ProtocolError`.
- Any device fault latches: ``move_to`` and ``stop`` then raise :class:`FaultLatchedError`
  (``stop`` is a silent no-op) without writing a byte, until :meth:`DynamixelArm.reset`
  (reboots servos with hardware errors, re-applies the settings, torque on).
- ``stop()`` writes Goal Position = Present Position for every axis (torque stays on, the arm
  holds where it is). Torque is switched off only on hardware errors, or at ``close()`` when
  ``torque_off_on_close`` is set (arms may sag without torque, so the default keeps it on).
- At connect every axis is pinged (model number checked), its Hardware Error Status read,
  Operating Mode and (mode 3) position limits compared with the config and written only if
  different and only with torque off; then profile acceleration/velocity are written and
  torque enabled.

Config dict (TOML-friendly)
---------------------------
::

    port = "/dev/ttyUSB0"          # any pyserial URL
    baudrate = 1000000
    tolerance_deg = 0.2            # settle tolerance per joint
    settle_timeout_s = 10.0
    poll_interval_s = 0.01
    retries = 3
    model_number = 1020            # expected ping answer (omit/None to accept any)
    torque_off_on_close = false
    [kinematics]                   # see drivers.kinematics.KinematicsConfig
    min_retro_deg = 5.0
    arm_clearance_deg = 8.0
    [axes.turntable]               # one table per joint: turntable, source,
    id = 1                         #   detector_azimuth, detector_elevation
    zero_offset = 2048             # ticks at joint angle 0
    direction = 1                  # +1 or -1
    gear_ratio = 1.0               # servo revolutions per joint revolution
    operating_mode = 3             # 3 position, 4 extended position
    limits = [-170, 170]           # joint degrees (override the kinematics limits; without
                                   #   it, mode 3 narrows them to what ticks 0..4095 reach)
    profile_velocity = 0           # 0.229 rpm units (0 = the servo's velocity limit)
    profile_acceleration = 0
"""

from __future__ import annotations

from drivers.dynamixel.arm import DynamixelArm
from drivers.dynamixel.config import ADDR, ArmConfig, AxisConfig, decode_hardware_error

__all__ = ["AxisConfig", "ArmConfig", "DynamixelArm", "decode_hardware_error", "ADDR"]

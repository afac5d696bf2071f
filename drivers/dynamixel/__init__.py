"""A four-axis goniometer on Dynamixel X-series servos (Protocol 2.0) through dynamixel-sdk.

:class:`DynamixelArm` fills the ``Goniometer`` role. Packets are built, stuffed, checksummed and
framed by dynamixel-sdk's ``PacketHandler(2.0)`` (SYNC_WRITE of Goal Position of all axes in one
packet, SYNC_READ of Goal .. Present Position of all axes in one transaction) on a
:class:`~drivers.transport.TransportPortHandler`; :mod:`drivers.dynamixel._link` matches replies
to requests. So the same driver runs on a real port, on an
emulator's pty, or against a :class:`~drivers.transport.ScriptedTransport` fixture.

Behaviour
---------
- ``check(g)`` runs the kinematics rules (:mod:`drivers.kinematics`) and the tick ranges; it is
  pure and sends nothing. ``move_to`` calls it before any byte is written.
- ``move_to`` writes all Goal Positions in one sync write (a broadcast: no status), then polls
  one sync read of addresses 116..135 (Goal Position .. Present Position) every
  ``poll_interval_s``. Verified motion: a goal that did not land (read back differs) is re-sent
  once, a second loss is a :class:`CommunicationError`; an axis that has to move but shows
  neither Moving = 1 nor a position change within ``start_timeout_s`` (0.1 s) is a
  :class:`DeviceTimeoutError` at once; otherwise the poll ends when every axis has Moving = 0
  and Present Position within ``tolerance_deg`` of its goal, or ``settle_timeout_s`` passes
  (:class:`DeviceTimeoutError`). It returns the geometry computed from the Present Positions.
- Request/reply discipline (:mod:`drivers.dynamixel._link`): every status is checked against its
  request (id, instruction 0x55, parameter length, each id of a sync read once and in order);
  a mismatch is never data. After a timeout, a corrupt reply or a mismatch the driver waits
  until the bus is quiet (``return_delay_s`` + the outstanding statuses' transmit time at the
  baud rate + ``latency_s``) and flushes before retrying; ``retries`` bounds the attempts, then
  :class:`DeviceTimeoutError` / :class:`ChecksumError` / :class:`ProtocolError`. A vanished
  port is :class:`PortGoneError` (from the transport), never a hang.
- A status with the alert bit (0x80) makes the driver read Hardware Error Status (addr 70) of
  that servo twice; only when both clean reads are non-zero does it switch torque off on every
  axis and raise :class:`HardwareError` (``flags`` name the bits, ``code`` the raw byte). The
  same confirmation guards REBOOT in :meth:`DynamixelArm.reset`. A status error code 1..7
  raises :class:`ProtocolError`.
- Any device fault latches: ``move_to`` and ``stop`` then raise :class:`FaultLatchedError`
  (``stop`` is a silent no-op) without writing a byte, until :meth:`DynamixelArm.reset`
  (reboots servos with hardware errors, re-applies the settings, torque on).
- ``stop()`` writes Goal Position = Present Position for every axis (torque stays on, the arm
  holds where it is). Torque is switched off only on hardware errors, or at ``close()`` when
  ``torque_off_on_close`` is set (arms may sag without torque, so the default keeps it on).
- At connect every axis is pinged (model number checked), its Hardware Error Status read (twice),
  and every setting the driver relies on is established whatever an earlier program left:
  Status Return Level 2 (set by a SYNC_WRITE, which no level answers), Operating Mode, Drive
  Mode (forward, velocity-based profile), Homing Offset 0, Return Delay Time and (mode 3)
  position limits are compared with the config and written only if different, only with torque
  off; profile acceleration/velocity are written; each written value is read back (a read-back
  that disagrees is read again: a late status of the same length looks like an answer); then
  torque is enabled.
- A well-framed status answering another request is discarded while the awaited one is listened
  for, and bytes waiting before a transaction are dropped; failed attempts, recoveries and
  discards are counted in ``DynamixelArm.faults`` (a :class:`drivers._faultlog.FaultLog`).

Config dict (TOML-friendly)
---------------------------
::

    port = "/dev/ttyUSB0"          # any pyserial URL
    baudrate = 1000000
    tolerance_deg = 0.2            # settle tolerance per joint
    settle_timeout_s = 10.0
    poll_interval_s = 0.01
    retries = 5
    start_timeout_s = 0.1          # an axis that must move shows motion within this
    return_delay_s = 0.0005        # the servos' Return Delay Time (quiet-bus wait)
    latency_s = 0.016              # USB adapter latency timer (quiet-bus wait)
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

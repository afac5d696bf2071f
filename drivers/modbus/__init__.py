"""One stage axis on an Oriental-Motor-AZ-style drive, through pymodbus (RTU or TCP).

The drive is operated in "direct data operation": the whole block operation No./type/
position/speed/acceleration/deceleration/current/trigger is written with one function-16
request and the trigger starts the move; the driver then polls the output status (READY,
IN-POS, ALM, BUSY, MOVE) and the feedback position until the axis is in position. Every
address, bit and code comes from a :class:`drivers.registers.RegisterMap` (TOML data), so a
different drive is a different map.

Connection
----------
``port`` is either a serial port for Modbus RTU (a device path, a pty slave path or any
pyserial URL) or ``"tcp://host:port"`` for Modbus TCP. Alternatively pass ``transport=``, any
:class:`drivers.transport.Transport` (e.g. a ``ScriptedTransport`` replaying a recorded
session, or a ``RecordingTransport``): Modbus RTU frames are then built and parsed by
pymodbus's own framer and moved by that transport.

Homing
------
:meth:`ModbusStageAxis.home` sends a rising edge of ZHOME (bit 4 of the input command
0x007C/0x007D; written 0, ZHOME, 0) and polls the output status until HOME-END (output bit 4)
with neither BUSY nor MOVE, within ``home_timeout_s``; it returns the position read back. An
alarm is :class:`HardwareError`, no HOME-END in time a STOP and :class:`DeviceTimeoutError`
(both latch).

Faults
------
* A Modbus exception response -> :class:`ProtocolError` naming the function, address and
  exception code (no retry: the drive answered; ACKNOWLEDGE and SLAVE DEVICE BUSY are retried).
* No reply / a garbled reply -> retried ``retries`` times, then :class:`DeviceTimeoutError`
  (or :class:`ChecksumError` when bytes came back but never a valid frame). A valid reply that
  does not answer this request (another device, function code, register count or echoed
  address: pymodbus itself checks only the device id) is dropped with the input buffer and
  the request retried; it is never used as data (:func:`drivers.modbus._client.check_reply`).
* A serial port that will not open: the message names the cause (a pseudo-terminal refusing
  even parity with EINVAL, or the adapter refusing the settings, or a port held elsewhere).
* The connection cannot be made or is lost -> retried, then :class:`PortGoneError`.
* ALM on the drive -> :class:`HardwareError` with the alarm code (``err.code``).
* Any fault during a move (alarm, timeout, lost connection, not in position in time) latches:
  no motion command is sent until :meth:`ModbusStageAxis.reset_alarm` succeeds; meanwhile
  :meth:`ModbusStageAxis.move_to_deg` raises :class:`FaultLatchedError` without bus traffic.
  :meth:`ModbusStageAxis.stop` is always allowed.

Example
-------
>>> with ModbusStageAxis("tcp://127.0.0.1:5020", steps_per_rev=1000, gear_ratio=18,
...                      limits_deg=(-170, 170), speed_deg_s=20) as axis:   # doctest: +SKIP
...     reached = axis.move_to_deg(45.0)
"""
from __future__ import annotations

from drivers.modbus._client import TransportModbusClient
from drivers.modbus.config import MODBUS_EXCEPTIONS, AxisConfig, StageAxis
from drivers.modbus.stage import ModbusStageAxis

__all__ = ["StageAxis", "AxisConfig", "ModbusStageAxis", "TransportModbusClient",
           "MODBUS_EXCEPTIONS"]

"""Real hardware behind the instrument interface: transports, Dynamixel arms, Modbus stages,
serial spectrometers, goniometer kinematics and safety limits.

The names a user imports are exported here (``from drivers import OceanSpectrometer,
ScriptedTransport``), each loaded on first use (:mod:`bench.core.exports`): no vendor library
loads before a driver is asked for. Any module not exported here is an implementation detail.
"""

from bench.core.exports import lazy_exports

#: each public name and the module that defines it
_WHERE = {
    # transports: serial ports, recorded sessions replayed byte for byte, the recorder
    **dict.fromkeys(["Transport", "SerialTransport", "ScriptedTransport", "RecordingTransport", "load_fixture",
                     "save_fixture"], "drivers.transport"),
    # the devices
    **dict.fromkeys(["DynamixelArm", "ArmConfig"], "drivers.dynamixel"),
    **dict.fromkeys(["ModbusStageAxis", "StageAxis"], "drivers.modbus"),
    **dict.fromkeys(["OceanSpectrometer", "OceanConfig"], "drivers.ocean"),
    # kinematics and safety: geometry <-> joints, what a goniometer refuses before motion
    **dict.fromkeys(["KinematicsConfig", "Joints", "geometry_to_joints", "joints_to_geometry", "violations"],
                    "drivers.kinematics"),
}

__all__ = list(_WHERE)

__getattr__, __dir__ = lazy_exports(__name__, _WHERE)

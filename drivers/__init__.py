"""Real hardware behind the instrument interface: transports, Dynamixel arms, Modbus stages,
serial spectrometers, goniometer kinematics and safety limits.

The names a user imports are exported here (``from drivers import OceanSpectrometer,
ScriptedTransport``), each loaded on first use (:mod:`bench.core.exports`): no vendor library
loads before a driver is asked for. Any module not exported here is an implementation detail.
"""

from typing import TYPE_CHECKING

from bench.core.exports import lazy_exports, type_checking_imports

if TYPE_CHECKING:  # the public names; at run time each loads on first use (lazy_exports)
    from drivers.transport import (Transport as Transport, SerialTransport as SerialTransport,
                                   ScriptedTransport as ScriptedTransport, RecordingTransport as RecordingTransport,
                                   load_fixture as load_fixture, save_fixture as save_fixture)
    from drivers.dynamixel import (DynamixelArm as DynamixelArm, ArmConfig as ArmConfig)
    from drivers.modbus import (ModbusStageAxis as ModbusStageAxis, StageAxis as StageAxis)
    from drivers.ocean import (OceanSpectrometer as OceanSpectrometer, OceanConfig as OceanConfig)
    from drivers.kinematics import (KinematicsConfig as KinematicsConfig, Joints as Joints,
                                    geometry_to_joints as geometry_to_joints,
                                    joints_to_geometry as joints_to_geometry, violations as violations)

#: each public name and the module that defines it: the imports above, read from this file
_WHERE = type_checking_imports(__file__)

__all__ = list(_WHERE)

__getattr__, __dir__ = lazy_exports(__name__, _WHERE)

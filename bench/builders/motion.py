"""Motion profiles of emulated and real benches, from the axes' configured speeds and ramps.

Owns :func:`motion_profile`: the :class:`bench.plans.MotionProfile` (deg/s, deg/s^2 per joint)
that ``bench plan`` uses to estimate motion time, computed from a bench config's ``[arm]`` and
``[turntable]`` tables without opening any port. Units (vendor manuals):

* Dynamixel X-series (e-manual, control table): Profile Velocity (addr 112) in units of
  0.229 rev/min, Profile Acceleration (addr 108) in units of 214.577 rev/min^2, both of the
  servo; a joint turns ``1 / gear_ratio`` as fast. 0 means "no profile": acceleration 0 is a
  step (infinite acceleration); velocity 0 is the servo's Velocity Limit, which the config does
  not hold, so the estimate falls back to ``MotionProfile.default_velocity`` for that joint.
* Oriental AZ direct data operation: speed is given in the config in deg/s (``speed``) and the
  acceleration/deceleration as the drive's raw value (``accel``, ``decel``) in units of
  0.001 kHz/s = 1 step/s^2; the slower of the two ramps is used.

Emulated benches run ``time_scale`` times faster than the real drives, and their emulators move
at constant speed (ramps are stored, not simulated: see ``virtual/wire``), so their profile has
velocities scaled by ``time_scale`` and no ramps.
"""

from __future__ import annotations

import math
from typing import Any, Mapping

from bench.plans import MotionProfile
from drivers.dynamixel.config import AxisConfig as ServoAxisConfig
from drivers.modbus.config import AxisConfig as StageAxisConfig

__all__ = ["motion_profile", "PROFILE_VELOCITY_DEG_S", "PROFILE_ACCELERATION_DEG_S2", "AZ_ACCEL_STEPS_S2"]

#: one unit of Dynamixel Profile Velocity (0.229 rev/min) in deg/s of the servo
PROFILE_VELOCITY_DEG_S = 0.229 * 360.0 / 60.0
#: one unit of Dynamixel Profile Acceleration (214.577 rev/min^2) in deg/s^2 of the servo
PROFILE_ACCELERATION_DEG_S2 = 214.577 * 360.0 / 3600.0
#: one unit of the AZ drive's acceleration rate (0.001 kHz/s) in steps/s^2
AZ_ACCEL_STEPS_S2 = 1.0

#: keys of a ``[turntable]`` table that are the builder's, not the drive's settings
_STAGE_TABLE_KEYS = ("port", "name")


def motion_profile(arm: Mapping[str, Any] | None, turntable: Mapping[str, Any] | None = None,
                   time_scale: float = 1.0, ramps: bool = True, settle_s: float = 0.2,
                   overhead_s: float = 0.005) -> MotionProfile:
    """The motion profile of a bench's axes from its ``[arm]`` and ``[turntable]`` tables.

    Parameters
    ----------
    arm : mapping or None
        The ``[arm]`` table (its ``axes.<joint>`` tables give ``profile_velocity``,
        ``profile_acceleration`` and ``gear_ratio``).
    turntable : mapping or None
        The ``[turntable]`` table (``speed`` deg/s, ``accel``/``decel`` raw, ``steps_per_rev``,
        ``gear_ratio``, ``units_per_rev``), or None when the bench has no Modbus turntable.
    time_scale : float
        How many times faster than the configured drives the axes run (emulators).
    ramps : bool
        Use the configured accelerations (False: constant-speed moves, as the emulators make).
    settle_s, overhead_s : float
        Settle time after a move and per-reading overhead (s).

    Raises
    ------
    ConfigError
        A setting the drivers' declarations refuse (the same the drivers apply, with their
        defaults for keys the tables omit).
    """
    vel: dict[str, float] = {}
    acc: dict[str, float] = {}
    for joint, table in ((arm or {}).get("axes") or {}).items():
        a = ServoAxisConfig.from_dict(joint, table)
        gear, pv, pa = a.gear_ratio, a.profile_velocity, a.profile_acceleration
        if pv > 0:  # 0 = the servo's Velocity Limit, unknown here: the profile's default applies
            vel[joint] = pv * PROFILE_VELOCITY_DEG_S / gear * time_scale
        acc[joint] = pa * PROFILE_ACCELERATION_DEG_S2 / gear * time_scale**2 if (ramps and pa > 0) else math.inf
    if turntable is not None:
        t = StageAxisConfig.from_dict({k: v for k, v in turntable.items() if k not in _STAGE_TABLE_KEYS},
                                      "[turntable]")
        steps_per_deg = t.steps_per_unit
        vel["turntable"] = t.speed * time_scale
        ramp = min(t.accel, t.decel)
        acc["turntable"] = (ramp * AZ_ACCEL_STEPS_S2 / steps_per_deg * time_scale**2
                            if (ramps and ramp > 0 and steps_per_deg > 0) else math.inf)
    base = MotionProfile({}, {})  # its defaults stand for joints whose speed the config does not give
    return MotionProfile(vel, acc, settle_s=settle_s, overhead_s=overhead_s,
                         default_velocity=base.default_velocity * time_scale,
                         default_acceleration=base.default_acceleration * time_scale**2 if ramps else math.inf)

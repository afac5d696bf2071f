"""The virtual body of a physical bench description: the same refusals and the same time model.

A description of a physical bench (``kind = "emulated"`` or ``"real"``, or any file with an
``[arm]`` or ``[emulated]`` table) declares kinematics (joint limits, beam-block and arm-collision rules) and
motion profiles. Its virtual body checks every geometry with the same rules, by the same code
(:func:`drivers.kinematics.check` on the :class:`drivers.dynamixel.ArmConfig` the arm driver
builds), so a plan is refused with the same rule names on every body, and estimates motion
from the same profiles: the emulators' (``time_scale`` times faster drives, no ramps) for an
emulated description or a virtual one that declares ``[emulated]`` (the twin of the emulated
bench, as ``fixtures/benches/virtual.toml``), the drives' own for the others. A plain virtual
description (neither ``[arm]`` nor ``[emulated]``) keeps the ideal goniometer.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

from bench.builders.emulated import emulated_arm_config, emulated_motion
from bench.builders.motion import motion_profile
from bench.core.geometry import Geometry
from bench.core.roles import InstrumentInfo
from bench.plans import MotionProfile
from drivers.dynamixel import ArmConfig
from drivers.kinematics import KinematicsConfig, check, geometry_to_joints

__all__ = ["PhysicalRules", "physical_rules", "KinematicGoniometer"]


@dataclass(frozen=True)
class PhysicalRules:
    """What a physical bench description says about motion: kinematics and time model."""

    kinematics: KinematicsConfig
    motion: MotionProfile

    def joints(self, g: Geometry) -> Mapping[str, float]:
        return geometry_to_joints(g, self.kinematics).as_dict()


def physical_rules(d: Mapping[str, Any]) -> PhysicalRules | None:
    """The rules of description ``d`` as the hardware its ``kind`` names applies them, or None for
    a plain virtual description (``kind = "virtual"``, neither ``[arm]`` nor ``[emulated]``)."""
    kind = str(d.get("kind", "virtual"))
    if kind == "emulated" or (kind == "virtual" and "emulated" in d):  # the emulated bench or its twin
        arm = emulated_arm_config(d, "")
        return PhysicalRules(ArmConfig.from_dict(arm).kinematics, emulated_motion(d))
    if kind == "real" or "arm" in d:
        arm = {k: v for k, v in dict(d.get("arm") or {}).items()}
        return PhysicalRules(ArmConfig.from_dict(arm).kinematics, motion_profile(arm, d.get("turntable")))
    return None


class KinematicGoniometer:
    """A virtual goniometer that refuses what the physical arm refuses (the Goniometer role:
    ``check`` before ``move_to``); everything else is the virtual instrument's."""

    def __init__(self, inner: Any, kinematics: KinematicsConfig) -> None:
        self._inner = inner
        self.kinematics = kinematics

    def check(self, geometry: Geometry) -> None:
        check(geometry, self.kinematics)
        self._inner.check(geometry)

    def move_to(self, geometry: Geometry) -> Geometry:
        self.check(geometry)
        return self._inner.move_to(geometry)

    def describe(self) -> InstrumentInfo:
        return self._inner.describe()

    def __getattr__(self, name: str) -> Any:  # position, stop, close, seed, ... of the virtual goniometer
        return getattr(self._inner, name)

    def __enter__(self) -> "KinematicGoniometer":
        return self

    def __exit__(self, *exc: object) -> None:
        self._inner.close()


"""Kinematics and safety rules of a four-axis gonioreflectometer.

Layout (all joint angles in degrees)
------------------------------------
The lab frame has +z up (the specimen normal) and its x axis along the fixed plane in which
the source arm swings.

``turntable``
    Rotates the specimen about its normal. At turntable angle ``t`` a direction at lab azimuth
    ``a`` has specimen azimuth ``a + t`` (the specimen's X mark sits at lab azimuth ``-t``).
``source``
    Source arm elevation: the source looks at the specimen from zenith angle ``s`` at lab
    azimuth 0. So ``theta_i = s`` and ``phi_i = t``.
``detector_azimuth``
    Rotation ``d`` of the detector arm's plane about the vertical axis (lab azimuth of the
    detector plane, 0 = the source arm's plane on the source's side).
``detector_elevation``
    Detector zenith angle ``e`` in that plane: ``theta_r = e`` and ``phi_r = d + t``.

Hence ``Geometry -> joints``: ``t = phi_i``, ``s = theta_i``, ``d = phi_r - phi_i``,
``e = theta_r`` (each angle taken as the representative of its class mod 360 inside the joint
limits, nearest to a given current position if any), and back: ``theta_i = s``,
``phi_i = t mod 360``, ``theta_r = e``, ``phi_r = (t + d) mod 360`` (canonical at the poles).

Degenerate poles. At ``theta_i = 0`` the source is on the normal and the turntable is a free
degree of freedom; at ``theta_r = 0`` the detector azimuth is free. The canonical form of a
geometry (:func:`canonical`) therefore sets ``phi_i = 0`` when ``theta_i = 0`` and ``phi_r = 0``
when ``theta_r = 0`` (the convention of :func:`bench.core.geometry.spherical`), and
:func:`joints_to_geometry` returns canonical geometries; round trips compare canonical forms.
``geometry_to_joints`` resolves the free joints so: at ``theta_i = 0`` (and ``theta_r > 0``)
the turntable is set to ``phi_r - 180`` so that the detector sits opposite the source arm
(``detector_azimuth = 180``, the most clearance); at ``theta_r = 0`` the detector azimuth
stays where it is (``near``) or 0; with both at 0 the turntable stays too (or 0).

Safety rules (:func:`check`), each named in the :class:`GeometryError` message
-------------------------------------------------------------------------------
``joint_limit``
    A joint target outside its ``[lo, hi]`` limits (for every representative mod 360).
``source_hemisphere``
    ``theta_i >= 90``: the source arm cannot go to or below the specimen plane.
``beam_block``
    Angle between the incident and viewing directions below ``min_retro_deg`` (the detector
    head sits in the beam near retro-reflection).
``arm_collision``
    The arms are booms from the horizon ring up to their heads; the source arm at the larger
    radius, the detector arm inside it with a head that reaches out to the source arm's radius.
    The detector head collides with the source boom (the arc from the source head at zenith
    ``theta_i`` down to the horizon at lab azimuth 0) when its angular distance to that arc is
    below ``arm_clearance_deg`` (half the widths of head and boom, as angles at the source
    radius). So the detector can pass *between* the zenith and the source head on the source's
    side, but not below the source head on that side.

All functions are pure; :class:`KinematicsConfig` is a frozen dataclass built from a
TOML-friendly dict by :meth:`KinematicsConfig.from_dict`.
"""

from __future__ import annotations

import math
from typing import Annotated, Any, ClassVar, Literal, Mapping, NamedTuple, get_args

import numpy as np
from pydantic import Field, field_validator

from bench.core.errors import GeometryError
from bench.core.geometry import Geometry, direction
from bench.core.validation import Finite, Settings

__all__ = [
    "JOINTS",
    "Joint",
    "Joints",
    "KinematicsConfig",
    "geometry_to_joints",
    "joints_to_geometry",
    "canonical",
    "check",
    "violations",
    "wrap180",
]

#: a joint's name, as keys and tables name it
Joint = Literal["turntable", "source", "detector_azimuth", "detector_elevation"]
JOINTS: tuple[Joint, ...] = get_args(Joint)


class Joints(NamedTuple):
    """Joint targets in degrees (see the module docstring for their meaning)."""

    turntable: float
    source: float
    detector_azimuth: float
    detector_elevation: float

    def as_dict(self) -> dict[str, float]:
        return dict(self._asdict())


def _default_limits() -> dict[Joint, tuple[float, float]]:
    return {"turntable": (-180.0, 180.0), "source": (0.0, 85.0),
            "detector_azimuth": (-180.0, 180.0), "detector_elevation": (0.0, 85.0)}


class KinematicsConfig(Settings):
    """Joint limits and safety margins (degrees), each declared once with its range (validated by
    pydantic, :class:`bench.core.validation.Settings`).

    Dict form (TOML-friendly)::

        [kinematics]
        min_retro_deg = 5.0
        arm_clearance_deg = 8.0
        [kinematics.limits]
        turntable = [-180, 180]
        source = [0, 85]
        detector_azimuth = [-180, 180]
        detector_elevation = [0, 85]

    Every key is optional; limits not given keep their defaults.
    """

    settings_of: ClassVar[str] = "kinematics"

    limits: dict[Joint, tuple[Finite, Finite]] = Field(default_factory=_default_limits)
    min_retro_deg: Annotated[Finite, Field(ge=0)] = 5.0
    arm_clearance_deg: Annotated[Finite, Field(ge=0)] = 8.0

    @field_validator("limits")
    @classmethod
    def _ordered_and_complete(cls, v: dict[Joint, tuple[float, float]]) -> dict[Joint, tuple[float, float]]:
        for joint, (lo, hi) in v.items():
            if not lo <= hi:
                raise ValueError(f"{joint} = [{lo:g}, {hi:g}]: expected [lo, hi] degrees with lo <= hi")
        return {**_default_limits(), **v}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any] | None, source: str | None = None) -> "KinematicsConfig":
        """Build from a dict (e.g. a TOML table; None: the defaults); unknown keys raise :class:`ConfigError`."""
        return super().from_dict({} if d is None else d, source)

    def with_limits(self, **limits: tuple[float, float]) -> "KinematicsConfig":
        """A copy with some joint limits replaced (validated again; every other setting kept)."""
        merged = {str(j): lim for j, lim in self.limits.items()} | limits
        return type(self)(**{**self.model_dump(), "limits": merged})

    def as_dict(self) -> dict[str, Any]:
        return {"limits": {k: list(v) for k, v in self.limits.items()},
                "min_retro_deg": self.min_retro_deg, "arm_clearance_deg": self.arm_clearance_deg}


def wrap180(a: float) -> float:
    """Angle in (-180, 180]."""
    r = math.fmod(a, 360.0)
    if r > 180.0:
        r -= 360.0
    elif r <= -180.0:
        r += 360.0
    return r


def _representative(angle: float, lo: float, hi: float, near: float | None) -> float | None:
    """The value ``angle + 360 k`` inside ``[lo, hi]`` nearest ``near`` (or 0); None if none."""
    base = wrap180(angle)
    k_lo = math.ceil((lo - base) / 360.0 - 1e-12)
    k_hi = math.floor((hi - base) / 360.0 + 1e-12)
    cands = [base + 360.0 * k for k in range(k_lo, k_hi + 1)]
    cands = [min(max(c, lo), hi) for c in cands if lo - 1e-9 <= c <= hi + 1e-9]
    if not cands:
        return None
    ref = 0.0 if near is None else near
    return min(cands, key=lambda c: (abs(c - ref), -c))  # ties: the larger


def canonical(g: Geometry) -> Geometry:
    """The canonical form: ``phi_i = 0`` at ``theta_i = 0``, ``phi_r = 0`` at ``theta_r = 0``."""
    pi_ = 0.0 if g.theta_i == 0.0 else g.phi_i
    pr = 0.0 if g.theta_r == 0.0 else g.phi_r
    if pi_ == g.phi_i and pr == g.phi_r:
        return g
    return Geometry(g.theta_i, pi_, g.theta_r, pr)


def _targets(g: Geometry, near: Joints | None) -> tuple[float, float, float, float]:
    """Joint angles before limits (see "Degenerate poles" in the module docstring)."""
    if g.theta_i > 0.0:
        t = g.phi_i
    elif g.theta_r > 0.0:
        t = g.phi_r - 180.0  # source on the normal: put the detector opposite the source boom
    else:
        t = near.turntable if near is not None else 0.0
    if g.theta_r > 0.0:
        d = g.phi_r - t
    else:
        d = near.detector_azimuth if near is not None else 0.0
    return t, g.theta_i, d, g.theta_r


def geometry_to_joints(g: Geometry, config: KinematicsConfig | None = None,
                       near: Joints | None = None) -> Joints:
    """Joint targets for ``g`` (degrees); raise :class:`GeometryError` (``joint_limit``) if none.

    Parameters
    ----------
    g
        The requested geometry.
    config
        Joint limits (defaults: :class:`KinematicsConfig`).
    near
        Current joints: among equivalent targets (mod 360) the one nearest to them is chosen,
        and at ``theta_r = 0`` the detector azimuth stays where it is.

    Notes
    -----
    Only joint limits are applied here; :func:`check` applies every safety rule.
    """
    cfg = config or KinematicsConfig()
    t, s, d, e = _targets(g, near)
    lim = cfg.limits
    out: list[float] = []
    targets: tuple[tuple[Joint, float, bool], ...] = (("turntable", t, True), ("source", s, False),
                                                      ("detector_azimuth", d, True), ("detector_elevation", e, False))
    for name, val, periodic in targets:
        lo, hi = lim[name]
        ref = getattr(near, name) if near is not None else None
        if periodic:
            v = _representative(val, lo, hi, ref)
        else:
            v = val if lo <= val <= hi else None
        if v is None:
            mod = " (mod 360)" if periodic else ""
            raise GeometryError(f"joint_limit: {g} refused: needs {name} = {val:.6g} deg{mod}, "
                                f"outside its limits [{lo:g}, {hi:g}] deg", geometry=g)
        out.append(v)
    return Joints(*out)


def joints_to_geometry(j: Joints) -> Geometry:
    """The (canonical) geometry the joints realise."""
    t, s, d, e = (float(x) for x in j)
    if not (0.0 <= s <= 180.0 and 0.0 <= e <= 180.0):
        raise GeometryError(f"joint elevations out of [0, 180] deg: source={s}, detector={e}")
    return canonical(Geometry(s, t, e, t + d))


def _arc_distance_deg(v: np.ndarray, theta_head: float) -> float:
    """Angle from unit vector ``v`` to the arc at lab azimuth 0 from zenith ``theta_head`` to 90."""
    th = math.radians(theta_head)
    head = np.array([math.sin(th), 0.0, math.cos(th)])
    foot = np.array([1.0, 0.0, 0.0])

    def ang(a: np.ndarray, b: np.ndarray) -> float:
        return math.degrees(math.atan2(np.linalg.norm(np.cross(a, b)), float(np.dot(a, b))))

    best = min(ang(v, head), ang(v, foot))
    # closest point of the great circle (x-z plane) to v, if it lies on the arc
    px, pz = float(v[0]), float(v[2])
    if px > 0.0:
        tp = math.atan2(px, pz)  # zenith angle of the projection
        if th <= tp <= math.pi / 2:
            best = min(best, math.degrees(math.asin(min(1.0, abs(float(v[1]))))))
    return best


def violations(g: Geometry, config: KinematicsConfig | None = None) -> list[tuple[str, str]]:
    """Every broken rule as ``(rule, explanation)``; empty if ``g`` is safe and reachable."""
    cfg = config or KinematicsConfig()
    out: list[tuple[str, str]] = []
    if g.theta_i >= 90.0:
        out.append(("source_hemisphere",
                    f"theta_i = {g.theta_i:g} deg: the source arm cannot reach 90 deg or below"))
    try:
        geometry_to_joints(g, cfg)
    except GeometryError as exc:
        out.append(("joint_limit", str(exc).split(" refused: ", 1)[1]))
    sep = g.angle_between_source_and_detector()
    if sep < cfg.min_retro_deg:
        out.append(("beam_block", f"detector {sep:.3g} deg from the incident direction blocks the "
                                  f"beam (minimum {cfg.min_retro_deg:g} deg)"))
    # arm collision in the lab frame: the source arm is at lab azimuth 0
    _, _, d, e = _targets(g, None)  # the detector in the lab frame (source arm at azimuth 0)
    lab_view = direction(e, d) if e > 0.0 else np.array([0.0, 0.0, 1.0])
    dist = _arc_distance_deg(lab_view, g.theta_i)
    if dist < cfg.arm_clearance_deg:
        out.append(("arm_collision", f"detector head {dist:.3g} deg from the source arm "
                                     f"(minimum clearance {cfg.arm_clearance_deg:g} deg)"))
    return out


def check(g: Geometry, config: KinematicsConfig | None = None) -> Joints:
    """Raise :class:`GeometryError` naming the first broken rule; else return the joint targets.

    The error's ``geometry`` attribute is ``g``; the message starts with the rule name
    (``source_hemisphere``, ``joint_limit``, ``beam_block`` or ``arm_collision``) and names
    the geometry.
    """
    if not isinstance(g, Geometry):
        raise GeometryError(f"expected a Geometry, got {type(g).__name__}: {g!r}", geometry=g)
    problems = violations(g, config)
    if problems:
        rule, why = problems[0]
        more = f" (also: {', '.join(r for r, _ in problems[1:])})" if len(problems) > 1 else ""
        raise GeometryError(f"{rule}: {g} refused: {why}{more}", geometry=g)
    return geometry_to_joints(g, config)

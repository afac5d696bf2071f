"""Scan plans: which geometries to visit, how to read each, in what order, and at what cost.

A plan is a TOML file (or a dict, or built in Python) with a ``kind`` and its table:

``spectral``       CIE geometries (``45/0``, ``0/45``) measured on the goniometer: one point each.
``in-plane``       the abridged record: emitter ``theta_i`` over a range, detector ``theta_r`` over
                   a signed range (-90..90, > 0 on the specular side), in the plane ``phi_i``.
``hemispherical``  every ``theta_i`` x (``theta_r`` x ``phi_r``) grid over the viewing hemisphere.
``half-vector``    Rusinkiewicz half/difference angles (``theta_h``, ``theta_d``, ``phi_d``) at a
                   fixed ``phi_h``, converted to incident and viewing directions.
``list``           explicit ``points = [[theta_i, phi_i, theta_r, phi_r], ...]``.

Common keys: ``name``, ``integration_s``, ``averages``, ``dark`` (``"none"``, ``"once"``,
``"per-incidence"``, ``"per-point"``), ``white`` (``"none"``, ``"once"``, ``"repeated"``: the
operator mounts the standard once and ``white_repeats`` (>= 3, default 5) white readings are taken
in sequence, from which the lamp's drift is estimated, :mod:`bench.core.calibration`), ``order``
(``"travel"`` to cut motion time, or ``"as-given"``), ``home`` (``true``: return the turntable
to home after validation, before any other motion; a bench without one skips it). Ranges are lists or
``{start, stop, step}`` tables (stop included when on the grid).

:func:`validate` checks every point against the bench *before any motion* and refuses the plan
whole, naming each offending point. :func:`estimate` gives the duration from the axes' profile
velocity and acceleration, settle time, integration x averages and references.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from bench.core.errors import ConfigError, GeometryError, PlanError
from bench.core.geometry import Geometry, cie_geometry
from bench.core.parsing import parse_range, read_toml
from bench.core.schemas import DEFAULT_WHITE_REPEATS, MAX_PLAN_POINTS, PlanFile, validate_document

__all__ = [
    "Plan",
    "load_plan",
    "plan_from_dict",
    "validate",
    "refusals",
    "refusal_message",
    "Refusal",
    "order_for_travel",
    "MotionProfile",
    "estimate",
    "half_vector_to_geometry",
    "default_joints",
]

KINDS = ("spectral", "in-plane", "hemispherical", "half-vector", "list")
DARK_MODES = ("none", "once", "per-incidence", "per-point")
WHITE_MODES = ("none", "once", "repeated")


@dataclass(frozen=True)
class Plan:
    """A validated-shape plan: its points in the order given, and how to read them."""

    name: str
    kind: str
    points: tuple[Geometry, ...]
    integration_s: float = 0.1
    averages: int = 1
    dark: str = "once"
    white: str = "once"
    order: str = "travel"
    home: bool = False
    source: Mapping[str, Any] = field(default_factory=dict)
    unreachable: str = "refuse"  # "skip": measure the reachable points, record the others as skipped
    white_repeats: int = DEFAULT_WHITE_REPEATS  # white readings taken when white = "repeated"
    #: the plan says integration_s = "auto": the bench chooses it (:func:`bench.exposure.resolve_integration`)
    integration_auto: bool = False

    @property
    def n_whites(self) -> int:
        """How many white readings the plan takes (0, 1 or ``white_repeats``)."""
        return {"none": 0, "once": 1}.get(self.white, self.white_repeats)

    def __len__(self) -> int:
        return len(self.points)

    def as_dict(self) -> dict[str, Any]:
        """The plan as given (its source table), for run metadata."""
        return dict(self.source)


# --- building -----------------------------------------------------------------------------------


def _range(value: Any, where: str) -> list[float]:
    return parse_range(value, where, limit=MAX_PLAN_POINTS)


def _bounded(where: str, *axes: Sequence[float]) -> None:
    """Refuse a grid whose product of axes exceeds :data:`MAX_PLAN_POINTS` before building it."""
    n = math.prod(len(a) for a in axes)
    if n > MAX_PLAN_POINTS:
        raise ConfigError(f"{where}: {' x '.join(str(len(a)) for a in axes)} = {n:,} points, more than the "
                          f"limit of {MAX_PLAN_POINTS:,} (a step too small?)")


def half_vector_to_geometry(theta_h: float, phi_h: float, theta_d: float, phi_d: float) -> Geometry:
    """Rusinkiewicz (1998): rotate the difference vector (theta_d, phi_d) into the frame of the
    half vector (theta_h, phi_h); incident = h rotated by d, viewing = its mirror about h."""
    th, ph, td, pd = (math.radians(v) for v in (theta_h, phi_h, theta_d, phi_d))
    d = np.array([math.sin(td) * math.cos(pd), math.sin(td) * math.sin(pd), math.cos(td)])

    def rot_z(a: float) -> np.ndarray:
        return np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])

    def rot_y(a: float) -> np.ndarray:
        return np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])

    wi = rot_z(ph) @ rot_y(th) @ d
    h = np.array([math.sin(th) * math.cos(ph), math.sin(th) * math.sin(ph), math.cos(th)])
    wo = 2.0 * float(np.dot(wi, h)) * h - wi
    return Geometry.from_vectors(wi, wo)


def _points(kind: str, t: Mapping[str, Any]) -> list[Geometry]:
    where = f"plan [{kind}]"
    if kind == "spectral":
        out = []
        for name in t.get("geometries", []):
            g = cie_geometry(name)
            if g.illumination == "diffuse" or g.viewing == "diffuse":
                raise ConfigError(f"{where}: {g.name} needs an integrating sphere, not a goniometer "
                                  f"(use the spectrophotometer)")
            out.append(Geometry(g.theta_i, float(t.get("phi_i", 0.0)), g.theta_r, float(t.get("phi_i", 0.0)) + 180.0))
        if not out:
            raise ConfigError(f"{where}: list the CIE geometries, e.g. geometries = [\"45/0\", \"0/45\"]")
        return out
    if kind == "in-plane":
        phi_i = float(t.get("phi_i", 0.0))
        tis = _range(t.get("theta_i", [30.0]), f"{where} theta_i")
        trs = _range(t.get("theta_r", {"start": -80, "stop": 80, "step": 10}), f"{where} theta_r")
        _bounded(where, tis, trs)
        return [Geometry.in_plane(ti, tr, phi_i) for ti in tis for tr in trs]
    if kind == "hemispherical":
        phis = _range(t.get("phi_r", {"start": 0, "stop": 345, "step": 15}), f"{where} phi_r")
        tis = _range(t.get("theta_i", [30.0]), f"{where} theta_i")
        trs = _range(t.get("theta_r", {"start": 0, "stop": 80, "step": 10}), f"{where} theta_r")
        _bounded(where, tis, trs, phis)
        pts = []
        for ti in tis:
            for tr in trs:
                for pr in ([0.0] if tr == 0 else phis):
                    pts.append(Geometry(ti, float(t.get("phi_i", 0.0)), tr, pr))
        return pts
    if kind == "half-vector":
        phi_h = float(t.get("phi_h", 90.0))
        ths = _range(t.get("theta_h", [0.0, 10.0, 20.0]), f"{where} theta_h")
        tds = _range(t.get("theta_d", [10.0, 30.0]), f"{where} theta_d")
        pds = _range(t.get("phi_d", [90.0]), f"{where} phi_d")
        _bounded(where, ths, tds, pds)
        return [half_vector_to_geometry(th, phi_h, td, pd) for th in ths for td in tds for pd in pds]
    if kind == "list":
        rows = t.get("points")
        if not isinstance(rows, Sequence) or isinstance(rows, str) or not rows:
            raise ConfigError(f"{where}: points = [[theta_i, phi_i, theta_r, phi_r], ...] is required")
        if len(rows) > MAX_PLAN_POINTS:
            raise ConfigError(f"{where}: {len(rows):,} points, more than the limit of {MAX_PLAN_POINTS:,}")
        out = []
        for i, r in enumerate(rows):
            if not isinstance(r, Sequence) or isinstance(r, str) or len(r) != 4:
                raise ConfigError(f"{where}: point {i} must be [theta_i, phi_i, theta_r, phi_r], got {r!r}")
            try:
                out.append(Geometry(*(float(v) for v in r)))
            except (GeometryError, TypeError, ValueError, OverflowError) as exc:
                raise ConfigError(f"{where}: point {i} {r!r}: {exc}") from None
        return out
    raise ConfigError(f"unknown plan kind {kind!r}; known: {', '.join(KINDS)}")


def plan_from_dict(d: Mapping[str, Any], name: str = "plan", source: str | None = None) -> Plan:
    """Build a :class:`Plan` from its TOML table; errors name the key (and ``source``, the file).

    The table goes through the declared schema (:class:`bench.core.schemas.PlanFile`) first:
    unknown keys, wrong types, non-finite or out-of-range numbers and oversized ranges are one
    :class:`ConfigError` line before anything is built.
    """
    validate_document(PlanFile, d, source or f"plan {name!r}")
    d = dict(d)
    kind = str(d.get("kind", "")).strip().lower()
    if kind not in KINDS:
        raise ConfigError(f"plan kind must be one of {', '.join(KINDS)}, got {d.get('kind')!r}")
    table = d.get(kind.replace("-", "_"), d.get(kind, {}))
    if kind == "list" and "points" in d:
        table = {"points": d["points"]}
    if not isinstance(table, Mapping):
        raise ConfigError(f"plan [{kind}] must be a table")
    auto = d.get("integration_s") == "auto"  # chosen by the bench: bench.exposure.resolve_integration
    try:
        integration = 0.1 if auto else float(d.get("integration_s", 0.1))
        averages = int(d.get("averages", 1))
    except (TypeError, ValueError):
        raise ConfigError("plan integration_s must be a number and averages an integer") from None
    if not (math.isfinite(integration) and integration > 0):
        raise ConfigError(f"plan integration_s must be > 0, got {integration}")
    if averages < 1:
        raise ConfigError(f"plan averages must be >= 1, got {averages}")
    dark, white, order = str(d.get("dark", "once")), str(d.get("white", "once")), str(d.get("order", "travel"))
    if dark not in DARK_MODES:
        raise ConfigError(f"plan dark must be one of {', '.join(DARK_MODES)}, got {dark!r}")
    if white not in WHITE_MODES:
        raise ConfigError(f"plan white must be one of {', '.join(WHITE_MODES)}, got {white!r}")
    if "white_repeats" in d and white != "repeated":
        raise ConfigError(f"plan white_repeats: needs white = \"repeated\", the plan has white = {white!r}")
    repeats = int(d.get("white_repeats", DEFAULT_WHITE_REPEATS))
    if order not in ("travel", "as-given"):
        raise ConfigError(f"plan order must be 'travel' or 'as-given', got {order!r}")
    home = d.get("home", False)
    if not isinstance(home, bool):
        raise ConfigError(f"plan home must be true or false, got {home!r}")
    pts = _points(kind, table)
    return Plan(name=str(d.get("name", name)), kind=kind, points=tuple(pts), integration_s=integration,
                averages=averages, dark=dark, white=white, order=order, home=home, source=d,
                unreachable=str(d.get("unreachable", "refuse")), white_repeats=repeats, integration_auto=auto)


def load_plan(path: str | Path) -> Plan:
    """Read a plan TOML file."""
    p = Path(path)
    d = read_toml(p, "plan file")
    return plan_from_dict(d, name=p.stem, source=f"plan file {p}")


# --- validation ---------------------------------------------------------------------------------


#: refused points a refusal message shows (``bench plan --json`` lists them all)
SHOWN_REFUSALS = 3
_RULE = re.compile(r"^([a-z][a-z_]*): ")


@dataclass(frozen=True)
class Refusal:
    """A plan point the bench refuses: its index, geometry, the rule broken and the bench's words."""

    index: int
    geometry: Geometry
    rule: str
    message: str

    def as_dict(self) -> dict[str, Any]:
        return {"index": self.index, **self.geometry.as_dict(), "rule": self.rule, "message": self.message}


def refusals(plan: Plan, check: Callable[[Geometry], Any]) -> list[Refusal]:
    """Run ``check`` (the bench goniometer's) on every point; the points it refuses, with the rule
    each breaks (the message's leading ``rule:``, as :mod:`drivers.kinematics` and the virtual
    goniometer name them; ``unreachable`` when a check names none)."""
    out = []
    for i, g in enumerate(plan.points):
        try:
            check(g)
        except GeometryError as exc:
            m = _RULE.match(str(exc))
            out.append(Refusal(i, g, m.group(1) if m else "unreachable", str(exc)))
    return out


def refusal_message(plan: Plan, refused: Sequence[Refusal]) -> str:
    """One line: how many points are refused, the first few with their rule, and how many more."""
    shown = "; ".join(f"point {r.index} {r.geometry}: {r.rule}" for r in refused[:SHOWN_REFUSALS])
    more = (f"; and {len(refused) - SHOWN_REFUSALS} more (bench plan --json lists them all)"
            if len(refused) > SHOWN_REFUSALS else "")
    rules = ", ".join(sorted({r.rule for r in refused}))
    return (f"plan {plan.name!r} refused, {len(refused)} of {len(plan.points)} points cannot be measured "
            f"({rules}): {shown}{more}; or set unreachable = \"skip\" in the plan to measure the others")


def validate(plan: Plan, check: Callable[[Geometry], Any]) -> list[Refusal]:
    """Check every point before the first motion. A plan with refused points is refused whole
    (:class:`PlanError`, one line: :func:`refusal_message`) unless it says ``unreachable =
    "skip"``; then the refused points are returned (the run skips and records them)."""
    refused = refusals(plan, check)
    if refused and plan.unreachable != "skip":
        raise PlanError(refusal_message(plan, refused), [(r.index, r.geometry, r.message) for r in refused])
    return refused


# --- ordering and time ----------------------------------------------------------------------------


def order_for_travel(points: Sequence[Geometry]) -> list[int]:
    """Indices that visit ``points`` with little motion: grouped by incidence (the source arm and
    turntable are the slow, heavy axes), incidences in ascending order, and within a group the
    detector sweeps back and forth (boustrophedon over signed theta_r, then phi_r)."""
    groups: dict[tuple[float, float], list[int]] = {}
    for i, g in enumerate(points):
        groups.setdefault((g.theta_i, g.phi_i), []).append(i)
    order: list[int] = []
    forward = True
    for key in sorted(groups):
        idx = sorted(groups[key], key=lambda i: (points[i].theta_r_signed, points[i].phi_r))
        order += idx if forward else idx[::-1]
        forward = not forward
    return order


@dataclass(frozen=True)
class MotionProfile:
    """Per-axis trapezoidal motion: velocity (deg/s) and acceleration (deg/s^2), plus settle (s)."""

    velocity: Mapping[str, float]
    acceleration: Mapping[str, float]
    settle_s: float = 0.2
    overhead_s: float = 0.005
    default_velocity: float = 30.0
    default_acceleration: float = 60.0

    @classmethod
    def instantaneous(cls) -> "MotionProfile":
        """Axes that move in no time (a virtual bench)."""
        return cls({}, {}, 0.0, 0.0, math.inf, math.inf)

    def move_time(self, a: Mapping[str, float], b: Mapping[str, float]) -> float:
        """Time of a synchronised move (the slowest axis sets it), plus settle when anything moves."""
        longest = 0.0
        for joint, start in a.items():
            dist = abs(b[joint] - start)
            if dist == 0.0:
                continue
            v = self.velocity.get(joint, self.default_velocity)
            acc = self.acceleration.get(joint, self.default_acceleration)
            if math.isinf(v) and math.isinf(acc):
                continue
            d_ramp = v * v / acc  # distance to reach v and stop again
            t = 2.0 * math.sqrt(dist / acc) if dist < d_ramp else dist / v + v / acc
            longest = max(longest, t)
        return longest + (self.settle_s if longest > 0 else 0.0)


def default_joints(g: Geometry) -> dict[str, float]:
    """Joint angles of ``g`` for a time estimate on a bench that declares no joint map."""
    # the kinematic map of drivers/kinematics.py (turntable = phi_i, source = theta_i,
    # detector azimuth = phi_r - phi_i, detector elevation = theta_r), in the small form a
    # time estimate needs; the bench's own map is used when it has one
    return {"turntable": g.phi_i, "source": g.theta_i,
            "detector_azimuth": ((g.phi_r - g.phi_i + 180.0) % 360.0) - 180.0, "detector_elevation": g.theta_r}


def estimate(plan: Plan, profile: MotionProfile, order: Sequence[int] | None = None,
             joints: Callable[[Geometry], Mapping[str, float]] = default_joints,
             reading_overhead_s: float = 0.01, relative_noise_per_reading: float = 0.01) -> dict[str, Any]:
    """Duration and expected uncertainty of a plan on a physical bench.

    Returns seconds split into motion, acquisition and references, and the relative standard
    uncertainty per point from averaging (``relative_noise_per_reading / sqrt(averages)``).
    """
    order = list(range(len(plan.points))) if order is None else list(order)
    motion = 0.0
    prev = None
    n_incidences = 0
    last_inc = None
    for i in order:
        g = plan.points[i]
        j = joints(g)
        if prev is not None:
            motion += profile.move_time(prev, j)
        prev = j
        if (g.theta_i, g.phi_i) != last_inc:
            n_incidences += 1
            last_inc = (g.theta_i, g.phi_i)
    per_reading = plan.integration_s * plan.averages + reading_overhead_s + profile.overhead_s
    acquisition = len(order) * per_reading
    darks = {"none": 0, "once": 1, "per-incidence": n_incidences, "per-point": len(order)}[plan.dark]
    whites = plan.n_whites  # the standard is mounted once: one move there and back, then its readings
    references = (darks + whites) * per_reading + (2 * profile.settle_s if whites else 0.0)
    total = motion + acquisition + references
    return {"points": len(order), "incidences": n_incidences, "seconds": total, "motion_s": motion,
            "acquisition_s": acquisition, "references_s": references,
            "relative_uncertainty": relative_noise_per_reading / math.sqrt(plan.averages)}

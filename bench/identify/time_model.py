"""Where a bench can measure and what each point costs in bench time, for designed plans.

Candidates are the reachable points of a grid (in-plane by default): every point the bench's
goniometer refuses (the rules :func:`bench.plans.refusals` applies before any scan) is left out.
The time of a set of points is what ``bench plan`` reports for the plan that measures them
(:func:`bench.plans.estimate`, in travel order, with the plan's darks and white); a greedy design
needs the cost of one more point many times over, so :class:`TimeModel` also gives a cheap
marginal cost (one reading, the detector's move from the nearest chosen point of the same
incidence, and for a new incidence its dark and the source arm's move), and the design is then
checked and trimmed against the full estimate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from bench.config import Bench
from bench.core.errors import ConfigError
from bench.core.geometry import Geometry
from bench.exposure import unsaturated
from bench.plans import MotionProfile, Plan, default_joints, estimate, order_for_travel, plan_from_dict, refusals

__all__ = ["ReadingSettings", "TimeModel", "candidate_grid", "reachable", "plan_of_points", "bench_time_model",
           "DEFAULT_STEP_DEG", "DEFAULT_INTEGRATIONS"]

#: the in-plane candidate grid's default step (deg): the shipped in-plane plan's theta_r step
DEFAULT_STEP_DEG = 5.0
#: integration times a design chooses from by default (s): the shipped in-plane plan's 0.02 s and
#: shorter and longer ones (shorter buys more points, longer less noise per point)
DEFAULT_INTEGRATIONS = "0.005,0.01,0.02,0.05"


@dataclass(frozen=True)
class ReadingSettings:
    """How every point of a designed plan is read (the keys of a plan file it writes)."""

    integration_s: float = 0.02
    averages: int = 2
    dark: str = "per-incidence"
    white: str = "once"
    white_repeats: int | None = None  # white = "repeated": how many

    @classmethod
    def like(cls, plan: Plan) -> "ReadingSettings":
        """The reading settings of an existing plan (a design compared with it reads alike)."""
        return cls(plan.integration_s, plan.averages, plan.dark, plan.white,
                   plan.white_repeats if plan.white == "repeated" else None)

    def plan_table(self) -> dict[str, Any]:
        table = {"integration_s": self.integration_s, "averages": self.averages, "dark": self.dark,
                 "white": self.white}
        if self.white_repeats is not None:
            table["white_repeats"] = self.white_repeats
        return table


def candidate_grid(step_deg: float = DEFAULT_STEP_DEG, theta_i_max: float = 80.0, theta_r_max: float = 85.0,
                   phi_i: float = 0.0) -> list[Geometry]:
    """The in-plane grid: ``theta_i`` 0..theta_i_max and signed ``theta_r`` -theta_r_max..theta_r_max
    in steps of ``step_deg`` (the plane an isotropic model's parameters show in)."""
    if not (math.isfinite(step_deg) and 0.5 <= step_deg <= 45.0):
        raise ConfigError(f"design grid step must be 0.5..45 deg, got {step_deg!r}")
    tis = np.arange(0.0, theta_i_max + 1e-9, step_deg)
    trs = np.arange(-theta_r_max, theta_r_max + 1e-9, step_deg)
    return [Geometry.in_plane(float(ti), float(tr), phi_i) for ti in tis for tr in trs]


def plan_of_points(points: Sequence[Geometry], settings: ReadingSettings, name: str = "designed",
                   description: str = "") -> Plan:
    """An ordinary ``kind = "list"`` plan of ``points`` read with ``settings``."""
    table = {"name": name, "kind": "list", **settings.plan_table(), "order": "travel",
             "points": [[g.theta_i, g.phi_i, g.theta_r, g.phi_r] for g in points]}
    if description:
        table["description"] = description
    return plan_from_dict(table, name=name)


def reachable(points: Sequence[Geometry], check: Callable[[Geometry], Any], settings: ReadingSettings,
              description: Mapping[str, Any] | None = None, longest_s: float | None = None) -> list[Geometry]:
    """The points ``check`` (a bench goniometer's) accepts, by the plan validator's own rule; with
    the bench's ``description``, only those it does not saturate at ``longest_s`` (default: the
    settings' integration), as ``bench plan`` and ``bench scan`` refuse (:mod:`bench.exposure`)."""
    if not points:
        return []
    refused = {r.index for r in refusals(plan_of_points(points, settings), check)}
    kept = [g for i, g in enumerate(points) if i not in refused]
    if description is None:
        return kept
    return unsaturated(kept, description, settings.integration_s if longest_s is None else longest_s)


class TimeModel:
    """Bench seconds of a set of points, from the bench's motion profile and joint map."""

    def __init__(self, profile: MotionProfile, settings: ReadingSettings,
                 joints: Callable[[Geometry], Mapping[str, float]] | None = None) -> None:
        self.profile = profile
        self.settings = settings
        self._map = joints if joints is not None else default_joints
        self._joint_cache: dict[Geometry, Mapping[str, float]] = {}
        # one point's own cost, and a dark's: what estimate() charges per reading
        one = self.seconds([Geometry(0.0, 0.0, 30.0, 180.0)])
        self.per_reading = one["acquisition_s"]
        self.dark_s = self.per_reading if settings.dark == "per-incidence" else 0.0

    def seconds(self, points: Sequence[Geometry]) -> dict[str, Any]:
        """``bench plan``'s estimate of the plan measuring ``points`` in travel order."""
        if not points:
            return {"points": 0, "seconds": 0.0, "motion_s": 0.0, "acquisition_s": 0.0, "references_s": 0.0,
                    "incidences": 0}
        s = self.settings
        plan = Plan("designed", "list", tuple(points), s.integration_s, s.averages, s.dark, s.white)
        return estimate(plan, self.profile, order_for_travel(plan.points), joints=self._joints)

    def _joints(self, g: Geometry) -> Mapping[str, float]:
        """The bench's joint map, remembered per point (a design asks for the same points often)."""
        j = self._joint_cache.get(g)
        if j is None:
            j = self._joint_cache[g] = self._map(g)
        return j

    def marginal(self, candidates: Sequence[Geometry], chosen: Sequence[Geometry]) -> np.ndarray:
        """Approximate extra seconds of adding each candidate to ``chosen``: its reading, the
        detector's move to it from the nearest chosen point of its incidence, and, when its
        incidence is new, a dark (``per-incidence``) and a source move from the nearest chosen
        incidence."""
        by_inc: dict[tuple[float, float], list[Geometry]] = {}
        for g in chosen:
            by_inc.setdefault((g.theta_i, g.phi_i), []).append(g)
        out = np.empty(len(candidates))
        for k, g in enumerate(candidates):
            cost = self.per_reading
            j = self._joints(g)
            same = by_inc.get((g.theta_i, g.phi_i))
            if same:
                near = min(same, key=lambda h: abs(h.theta_r_signed - g.theta_r_signed) + abs(h.phi_r - g.phi_r))
                cost += self.profile.move_time(self._joints(near), j)
            elif by_inc:
                cost += self.dark_s
                near_inc = min(by_inc.values(), key=lambda gs: abs(gs[0].theta_i - g.theta_i))[0]
                cost += self.profile.move_time(self._joints(near_inc), j)
            else:
                cost += self.dark_s
            out[k] = cost
        return out


def bench_time_model(bench: Bench, settings: ReadingSettings) -> TimeModel:
    """The time model of an open bench (its profile and joint map; a virtual bench moves in no time)."""
    return TimeModel(bench.motion or MotionProfile.instantaneous(), settings, bench.joints)

"""Scan duration of a physical bench against angular step and averaging (``bench tradeoff`` on a
``physical`` scene): plans built with :mod:`bench.plans`, timed with its motion-profile estimate.

The virtual part of the accuracy-versus-time study (rays, strategies, collectors, budgets)
stays in :mod:`virtual.tradeoff`; this is the application's part, because it needs plans.
"""

from __future__ import annotations

from typing import Any, Sequence

from bench.core.outputs import save_figure
from bench.plans import MotionProfile, estimate, order_for_travel, plan_from_dict
from compare.figures import pyplot

__all__ = ["physical_sweep", "plot_physical"]


def physical_sweep(scene: Any) -> list[dict[str, Any]]:
    """Scan duration of an in-plane record against angular step and averaging (physical scene).

    ``[physical]`` keys: ``theta_i`` (list), ``theta_r = [start, stop]``, ``steps_deg``,
    ``averages``, ``integration_s``, ``velocity_deg_s``, ``acceleration_deg_s2``, ``settle_s``,
    ``relative_noise_per_reading``.
    """
    p = scene.physical
    th_i = p.get("theta_i", [30.0])
    th_i = [th_i] if isinstance(th_i, (int, float)) else list(th_i)
    lo, hi = (float(x) for x in p.get("theta_r", [-75.0, 75.0]))
    profile = MotionProfile({}, {}, float(p.get("settle_s", 0.2)), 0.005, float(p.get("velocity_deg_s", 30.0)),
                            float(p.get("acceleration_deg_s2", 60.0)))
    noise = float(p.get("relative_noise_per_reading", 0.01))
    rows = []
    for step in p.get("steps_deg", [1, 2, 5, 10]):
        for avg in p.get("averages", [1, 4, 16]):
            plan = plan_from_dict({"kind": "in-plane", "integration_s": float(p.get("integration_s", 0.05)),
                                   "averages": int(avg), "dark": "once", "white": "once",
                                   "in_plane": {"theta_i": th_i, "theta_r": {"start": lo, "stop": hi, "step": float(step)},
                                                "phi_i": 0}}, name=scene.name)
            est = estimate(plan, profile, order_for_travel(plan.points), relative_noise_per_reading=noise)
            rows.append({"step_deg": float(step), "averages": int(avg), "points": est["points"],
                         "seconds": est["seconds"], "motion_s": est["motion_s"],
                         "acquisition_s": est["acquisition_s"], "relative_uncertainty": est["relative_uncertainty"]})
    return rows


def plot_physical(rows: Sequence[dict[str, Any]], path: str, title: str = "") -> str:
    """Scan duration against angular step, one line per number of averages (log-log)."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7, 5))
    for avg in sorted({r["averages"] for r in rows}):
        rs = sorted((r for r in rows if r["averages"] == avg), key=lambda r: r["step_deg"])
        ax.loglog([r["step_deg"] for r in rs], [r["seconds"] for r in rs], marker="o",
                  label=f"{avg} averages (u = {rs[0]['relative_uncertainty']:.2%})")
    ax.set_xlabel("angular step (deg)")
    ax.set_ylabel("scan duration (s)")
    ax.set_title(title or "scan duration")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    save_figure(fig, path, dpi=120)
    plt.close(fig)
    return path

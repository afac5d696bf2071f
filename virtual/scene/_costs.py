"""What each declared effect costs: wall time of a scene with and without each effect."""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

from virtual.scene.declared import Effects
from virtual.scene.simulate import Scene

__all__ = ["effect_costs"]


def effect_costs(scene: Scene, rays: int | None = None, repeat: int = 3) -> list[dict[str, Any]]:
    """Wall time of the scene with no effect (the bare kernel), with each declared effect alone,
    and with all of them; best of ``repeat``, measured in one run so the ratios compare.

    Returns rows ``{"effects", "seconds", "ratio_to_bare", "rays_per_second", "method",
    "positions_sampled"}``. The fast path is switched off (``method="rays"``) so that the kernel
    cost is what is measured.
    """
    n = int(rays if rays is not None else scene.n_rays)
    base = replace(scene, method="rays")
    configs: list[tuple[str, Scene]] = [("none (bare kernel)", base.with_effects(Effects()))]
    declared = scene.effects.declared()
    for name in declared:
        configs.append((name, base.with_effects(scene.effects.only(name))))
    if len(declared) > 1:
        configs.append(("all declared", base))
    for _, sc in configs:  # compile / load caches before timing
        sc.run(rays=1000)
    times: dict[str, float] = {label: math.inf for label, _ in configs}
    for _ in range(repeat):  # interleaved, so a load spike hits every configuration alike
        for label, sc in configs:
            times[label] = min(times[label], sc.run(rays=n).seconds)
    bare = times[configs[0][0]]
    return [{"effects": label, "seconds": times[label], "ratio_to_bare": times[label] / bare,
             "rays_per_second": n / times[label], "method": sc.run(rays=1000).method,
             "positions_sampled": sc.needs_positions} for label, sc in configs]

"""Scene effects: a scene with no effect against the bare kernel, and each declared effect's cost.
Ratios are measured in one run, interleaved, best of several."""

from __future__ import annotations

import math
from pathlib import Path

from benchmarks.common import table
from virtual.beam import Beam
from virtual.collector import Collector
from virtual.engine import gonio_counts, measurement_seed, spectro_counts
from virtual.scene import Effects, Scene, effect_costs, load_scene
from virtual.specimens import Lambertian, OrenNayar

SCENES = Path(__file__).resolve().parent.parent / "fixtures" / "scenes"


def _bare_vs_scene(scene: Scene, n: int, repeat: int) -> tuple[float, float]:
    """Best times of the bare engine call and of Scene.run for the same work (interleaved)."""
    sp = scene.specimen
    b = scene.beam.kernel_args(*scene.incidence)
    seq = measurement_seed(scene.seed, 550_000, int(round(scene.incidence[0] * 1000)), 0)
    if scene.instrument == "spectrophotometer":
        def bare() -> object:
            return spectro_counts(sp.model, sp.params(550.0), scene.beam.code, scene.beam.disk_code, b, n, seq)
    else:
        cargs = scene.collector.kernel_args()

        def bare() -> object:
            return gonio_counts(sp.model, sp.params(550.0), scene.beam.code, scene.beam.disk_code, b, cargs, n, seq)
    import time

    bare()
    scene.run(rays=1000)
    tb = ts = math.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        bare()
        tb = min(tb, time.perf_counter() - t0)
        t0 = time.perf_counter()
        scene.run(rays=n)
        ts = min(ts, time.perf_counter() - t0)
    return tb, ts


def run(n_rays: int = 8_000_000, repeat: int = 3) -> str:
    rows = []
    cases = [
        ("spectro, collimated", Scene(Lambertian(0.6, 0.2))),
        ("spectro, conical", Scene(Lambertian(0.6, 0.2), beam=Beam("conical"))),
        ("gonio 9x36, collimated", Scene(OrenNayar(20.0, 0.8), instrument="goniophotometer",
                                         collector=Collector("equal-psa", 9, 36), method="rays")),
    ]
    import logging

    log = logging.getLogger("benchmarks")
    for name, sc in cases:
        log.info("bare vs scene: %s", name)
        tb, ts = _bare_vs_scene(sc.with_effects(Effects()), n_rays, repeat)
        rows.append([name, n_rays / tb, n_rays / ts, ts / tb, "yes" if ts / tb <= 1.10 else "NO"])
    out = table(f"Scene with no effect against the bare kernel ({n_rays:,} rays, best of {repeat}; "
                f"acceptance: within 10 %)", ["setup", "bare rays/s", "scene rays/s", "scene/bare", "<= 1.10"], rows)
    for fname in ("sphere-effects.toml", "gonio-aperture.toml"):
        sc = load_scene(SCENES / fname)
        costs = effect_costs(sc, rays=n_rays // 4, repeat=repeat)
        out += "\n\n" + table(f"Cost of each declared effect: scene {sc.name} ({n_rays // 4:,} rays, best of {repeat})",
                              ["effects", "seconds", "x bare", "rays/s", "path", "positions sampled"],
                              [[c["effects"], c["seconds"], c["ratio_to_bare"], c["rays_per_second"], c["method"],
                                c["positions_sampled"]] for c in costs])
    near = load_scene(SCENES / "gonio-aperture.toml")
    from dataclasses import replace

    from virtual.scene import Aperture

    ap = near.effects.aperture
    far_sc = near.with_effects(Effects(aperture=ap))
    near_sc = near.with_effects(Effects(aperture=Aperture(ap.half_angle_deg, ap.views, 500.0)))
    c = effect_costs(replace(near_sc, effects=Effects(aperture=near_sc.effects.aperture,
                                                      stray_light=None)), rays=n_rays // 4, repeat=repeat)
    c_far = effect_costs(far_sc, rays=n_rays // 4, repeat=repeat)
    out += (f"\n\nFinite aperture: far field {c_far[1]['ratio_to_bare']:.2f} x bare (no positions), "
            f"near field at 500 mm {c[1]['ratio_to_bare']:.2f} x bare (positions sampled)")
    return out


if __name__ == "__main__":
    print(run())

"""Virtual spectrophotometer throughput against the random-number limit."""

from __future__ import annotations

import math

import numba
import numpy as np

from benchmarks.common import best_of, numpy_uniform_rate, table
from virtual.beam import Beam
from virtual.engine import measurement_seed, spectro_counts
from virtual.specimens import Lambertian
from virtual.spectrophotometer import VirtualSpectrophotometer


def _uniforms_per_ray(beam: Beam, albedo: float) -> float:
    """Expected uniforms one ray draws: two disks, the Russian roulette and, for surviving
    rays, a rejection-sampled cosine direction (acceptance pi/4 for every rejection step)."""
    rejection = 4.0 / math.pi
    disks = 0.0 if beam.kind == "collimated" else 4.0 * (1.0 if beam.disk_sampling == "polar" else rejection)
    return disks + 1.0 + albedo * 2.0 * rejection


def run(n_rays: int = 50_000_000) -> str:
    spec = Lambertian(0.375, 0.2)
    albedo = 0.575
    rows = []
    beams = [Beam("collimated"), Beam("conical"), Beam("conical", disk_sampling="polar")]
    for beam in beams:
        args = beam.kernel_args(8.0, 0.0)

        def shoot() -> object:
            return spectro_counts(spec.model, spec.params(550.0), beam.code, beam.disk_code, args,
                                  n_rays, measurement_seed(1))

        shoot_small = spectro_counts(spec.model, spec.params(550.0), beam.code, beam.disk_code, args,
                                     1000, measurement_seed(1))  # compile / load cache
        del shoot_small
        seconds, _ = best_of(shoot, 3)
        k = _uniforms_per_ray(beam, albedo)
        limit = numpy_uniform_rate(int(min(k * n_rays, 2e8)), threads=numba.get_num_threads()) / k
        name = beam.kind + ("" if beam.kind == "collimated" else f" ({beam.disk_sampling})")
        rows.append([name, n_rays / seconds, limit, (n_rays / seconds) / limit, f"{k:.2f}"])

    sp = VirtualSpectrophotometer(spec, beam="conical", uncertainty=0.005, delta=0.01, seed=3)
    wl = np.linspace(400, 700, 31)
    sp.measure("8/d", wl[:2])
    t_reading, _ = best_of(lambda: sp.measure("8/d", wl), 3)
    out = table(
        f"Virtual spectrophotometer, Lambertian R=0.375 T=0.2 at 8 deg, {n_rays:,} rays, "
        f"{numba.get_num_threads()} threads (target >= 5e7 rays/s conical)",
        ["beam", "kernel rays/s", "numpy RNG limit rays/s", "kernel/limit", "uniforms/ray"], rows)
    out += (f"\n105,967-ray reading (eq. 3.5, v=0.005, delta=0.01) at 31 wavelengths, conical: "
            f"{t_reading * 1e3:.1f} ms")
    return out


if __name__ == "__main__":
    print(run())

"""Counts of every kernel path for fixed seeds, and their SHA-256 digests: the same on every CPU.

Run as a script (``python tests/same_bits.py``) it prints ``{case: digest}`` as JSON, so that a
test can compare the digests of this process with those of a process whose kernels numba compiled
for another instruction set (``NUMBA_CPU_NAME``). Each case draws enough rays that thousands of
them land within float32 rounding of a patch edge or a survival threshold: a kernel whose result
depended on the vector width (reciprocal estimates, fused multiply-adds, reassociated sums) would
change some of those rays' bins, and so the digest.
"""

from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path
from typing import Callable

import numpy as np

if __package__ in (None, ""):  # run as a script: the repository's packages first
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from virtual.beam import Beam
from virtual.collector import Collector
from virtual.effects import gonio_effect_counts
from virtual.engine import gonio_counts, gonio_counts_spectral, measurement_seed, spectro_counts
from virtual.goniophotometer import VirtualGoniophotometer
from virtual.specimens import parse_specimen

N_RAYS = 400_000
COLLECTOR = Collector("equal-psa", 9, 36)
CONICAL, COLLIMATED = Beam("conical"), Beam("collimated")


def digest(counts: np.ndarray) -> str:
    """SHA-256 of the counts as little-endian int64, shape included."""
    a = np.ascontiguousarray(counts, dtype="<i8")
    return hashlib.sha256(repr(a.shape).encode() + a.tobytes()).hexdigest()


def _gonio(spec: str, kernel: str, beam: Beam = CONICAL, theta_i: float = 30.0) -> Callable[[], np.ndarray]:
    sp = parse_specimen(spec)
    return lambda: gonio_counts(sp.model, sp.params(550.0), beam.code, beam.disk_code, beam.kernel_args(theta_i, 0.0),
                                COLLECTOR.kernel_args(), N_RAYS, measurement_seed(7, 1), kernel=kernel)


#: A conductor's (eta, k) at three wavelengths (gold-like): the GGX spectral batch's parameters.
CONDUCTOR = ((1.45, 1.95), (0.40, 2.40), (0.17, 3.50))


def _spectral(spec: str, rows: tuple[tuple[float, float], ...] | None = None) -> Callable[[], np.ndarray]:
    """A batch over three wavelengths: the specimen's own spectrum, or ``rows`` of (eta, k)."""
    sp = parse_specimen(spec)
    if rows is None:
        params = [sp.params(w) for w in (450.0, 550.0, 650.0)]
    else:
        params = [np.array([*sp.params(550.0)[:2], eta, k, *sp.params(550.0)[4:]]) for eta, k in rows]
    return lambda: gonio_counts_spectral(sp.model, params, CONICAL.code, CONICAL.disk_code,
                                         CONICAL.kernel_args(30.0, 0.0), COLLECTOR.kernel_args(), N_RAYS,
                                         measurement_seed(7, 2))


def _spectro(spec: str) -> Callable[[], np.ndarray]:
    sp = parse_specimen(spec)
    return lambda: np.array(list(spectro_counts(sp.model, sp.params(550.0), CONICAL.code, CONICAL.disk_code,
                                                CONICAL.kernel_args(8.0, 0.0), N_RAYS,
                                                measurement_seed(7, 3)).__dict__.values()))


def _effects(spec: str) -> Callable[[], np.ndarray]:
    sp = parse_specimen(spec)
    return lambda: gonio_effect_counts(sp.model, sp.params(550.0)[None, :], None, CONICAL.code, CONICAL.disk_code,
                                       CONICAL.kernel_args(30.0, 0.0), COLLECTOR.kernel_args(), 0, None, None, N_RAYS,
                                       measurement_seed(7, 4))


def _fast(spec: str) -> Callable[[], np.ndarray]:
    def run() -> np.ndarray:
        g = VirtualGoniophotometer(spec, collector=COLLECTOR, rays=10 ** 8, method="fast", seed=7)
        return np.asarray(g.simulate(30.0, 0.0, 550.0))
    return run


#: Every kernel path: ray by ray, float64 block, float32 block (every family with a float32
#: form), the spectral batches (float32 and float64), the effects kernel, the spectrophotometer,
#: the fast path's multinomial.
CASES: dict[str, Callable[[], np.ndarray]] = {
    "ray/ggx": _gonio("ggx:alpha=0.2,eta=1.5,k=0", "ray"),
    "ray/lambert": _gonio("lambert:albedo=0.8", "ray"),
    "block/ggx": _gonio("ggx:alpha=0.2,eta=1.5,k=0", "block"),
    "block/plastic": _gonio("plastic:alpha=0.2,eta=1.5,kd=0.5", "block"),
    "ray/roughplastic": _gonio("roughplastic:alpha=0.2,eta=1.5,kd=0.5", "ray"),
    "block/roughplastic": _gonio("roughplastic:alpha=0.2,eta=1.5,kd=0.5", "block"),
    "block/leaf": _gonio("leaf:healthy", "block"),
    "block32/lambert": _gonio("lambert:albedo=0.8", "block32"),
    "block32/ggx": _gonio("ggx:alpha=0.2,eta=1.5,k=0", "block32"),
    "block32/ggx-conductor": _gonio("ggx:alpha=0.1,eta=0.2,k=3.0", "block32", COLLIMATED, 60.0),
    "block32/aniso-ggx": _gonio("aniso-ggx:alpha_x=0.1,alpha_y=0.3,eta=1.5,k=0", "block32"),
    "block32/phong": _gonio("phong:kd=0.3,ks=0.6,n=50", "block32"),
    "block32/oren-nayar": _gonio("oren-nayar:albedo=0.7,sigma=20", "block32"),
    "block32/dielectric": _gonio("dielectric:alpha=0.2,eta=1.5", "block32"),
    "block32/plastic": _gonio("plastic:alpha=0.2,eta=1.5,kd=0.5", "block32"),
    "block32/roughplastic": _gonio("roughplastic:alpha=0.2,eta=1.5,kd=0.5", "block32"),
    "block32/leaf": _gonio("leaf:healthy", "block32"),
    "block32/roughplastic-collimated": _gonio("roughplastic:alpha=0.2,eta=1.5,kd=0.5", "block32", COLLIMATED, 60.0),
    "spectral32/lambert": _spectral("colorchecker:dark skin"),
    "spectral32/conductor": _spectral("ggx:alpha=0.2", CONDUCTOR),
    "spectral/conductor-narrow": _spectral("ggx:alpha=0.005", CONDUCTOR),
    "effects/ggx": _effects("ggx:alpha=0.2,eta=1.5,k=0"),
    "spectro/lambert": _spectro("lambert:reflectance=0.5,transmittance=0.3"),
    "fast/ggx": _fast("ggx:alpha=0.2,eta=1.5,k=0"),
}


def digests() -> dict[str, str]:
    return {name: digest(run()) for name, run in CASES.items()}


if __name__ == "__main__":
    print(json.dumps(digests()))

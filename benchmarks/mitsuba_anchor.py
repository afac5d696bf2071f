"""The anchor of the goniophotometer benchmark: the measurement written the way a
Mitsuba 3 user would write it, vectorized on Dr.Jit's LLVM back end.

``llvm_ad_rgb``, wavefronts of 10^7 rays: the conical beam (uniform points on the emitter disk
of radius r1 at distance D, rotated to the incidence, and on the specimen disk of radius r2, by
Mitsuba's concentric disk warp), ``bsdf.sample``, a survival roll on the sampled weight (the
weight of an analog estimator is the directional albedo's share, <= 1 for these BSDFs), the
equal-PSA patch index computed with Dr.Jit, and ``dr.scatter_reduce`` into the histogram.

The LLVM variant needs a libLLVM shared object: :func:`virtual.mitsuba_llvm.llvm_library` finds
Debian's ``libllvm19`` (``DRJIT_LIBLLVM_PATH`` wins when set), and :func:`available` says why
not when it is missing.
"""

from __future__ import annotations

import math
import time
from typing import Any

from benchmarks.isa import restrict_drjit
from virtual.mitsuba_llvm import llvm_library

__all__ = ["available", "MitsubaGonio", "WAVEFRONT"]

WAVEFRONT = 10_000_000


def available(variant: str = "llvm_ad_rgb") -> tuple[Any, str]:
    """``(mitsuba module switched to variant, "")`` or ``(None, why not)``."""
    if llvm_library() is None:
        return None, "not available: no libLLVM found (apt-get install libllvm19, or set DRJIT_LIBLLVM_PATH)"
    try:
        import drjit as dr
        import mitsuba as mi
    except ImportError:
        return None, "not available: mitsuba not installed (pip install goniobench[mitsuba])"
    try:
        mi.set_variant(variant)
        dr.zeros(mi.Float, 4)  # touches the LLVM back end
    except Exception as exc:  # any failure of the back end means "not available"
        return None, f"not available: {variant} failed ({type(exc).__name__}: {exc})"
    why = restrict_drjit()  # --isa avx2: Dr.Jit compiles for the ISA numba does
    return (None, f"not available: {why}") if why else (mi, "")


class MitsubaGonio:
    """A Mitsuba-LLVM goniophotometer: conical beam at ``theta_i`` (deg), equal-PSA collector
    of ``n_theta`` x ``n_phi`` patches per hemisphere; bins as :func:`virtual.engine.gonio_counts`
    (upper patches, lower patches, absorbed, missed)."""

    def __init__(self, mi: Any, bsdf: dict, theta_i: float = 30.0, r1: float = 5.0, r2: float = 12.5,
                 d: float = 76.2, n_theta: int = 30, n_phi: int = 30, threads: int = 2) -> None:
        import drjit as dr

        self.mi, self.dr = mi, dr
        dr.set_thread_count(threads)
        self.bsdf = mi.load_dict(bsdf)
        t = math.radians(theta_i)
        self.ct, self.st = math.cos(t), math.sin(t)
        self.r1, self.r2, self.d = r1, r2, d
        self.n_theta, self.n_phi = n_theta, n_phi
        self.n_bins = 2 * n_theta * n_phi

    def wavefront(self, hist: Any, n: int, seed: int) -> None:
        """Trace ``n`` rays and add them to ``hist`` (a ``mi.UInt32`` of ``n_bins + 2``)."""
        mi, dr = self.mi, self.dr
        sampler = mi.load_dict({"type": "independent"})
        sampler.seed(seed, n)
        p1 = mi.warp.square_to_uniform_disk_concentric(sampler.next_2d()) * self.r1
        p2 = mi.warp.square_to_uniform_disk_concentric(sampler.next_2d()) * self.r2
        # emitter point (x1, y1, D) rotated by Ry(theta_i), minus the target (x2, y2, 0)
        src = mi.Vector3f(self.ct * p1.x + self.st * self.d - p2.x, p1.y - p2.y, -self.st * p1.x + self.ct * self.d)
        si = dr.zeros(mi.SurfaceInteraction3f)
        si.wi = dr.normalize(src)
        hit = si.wi.z > 0
        bs, weight = self.bsdf.sample(mi.BSDFContext(), si, sampler.next_1d(), sampler.next_2d(), hit)
        alive = hit & (sampler.next_1d() < weight.x)
        wo = bs.wo
        s2 = dr.minimum(dr.fma(wo.x, wo.x, wo.y * wo.y), 1.0)
        ring = dr.minimum(mi.UInt32(s2 * self.n_theta), self.n_theta - 1)
        phi = dr.atan2(wo.y, wo.x)
        phi = dr.select(phi < 0, phi + 2 * dr.pi, phi)
        sector = dr.minimum(mi.UInt32(phi * (self.n_phi / (2 * dr.pi))), self.n_phi - 1)
        patch = ring * self.n_phi + sector + dr.select(wo.z < 0, self.n_theta * self.n_phi, 0)
        idx = dr.select(alive, patch, dr.select(hit, self.n_bins, self.n_bins + 1))
        dr.scatter_reduce(dr.ReduceOp.Add, hist, mi.UInt32(1), idx)
        dr.eval(hist)

    def counts(self, n_rays: int, seed: int = 1, wavefront: int = WAVEFRONT) -> Any:
        """Counts of ``n_rays`` rays (numpy int64), traced in wavefronts of ``wavefront``."""
        import numpy as np

        hist = self.dr.zeros(self.mi.UInt32, self.n_bins + 2)
        done, k = 0, 0
        while done < n_rays:
            m = min(wavefront, n_rays - done)
            self.wavefront(hist, m, seed * 100_003 + k)
            done, k = done + m, k + 1
        return np.asarray(hist, dtype=np.int64)

    def rate(self, n_rays: int, repeat: int = 2) -> tuple[float, Any]:
        """Best-of-``repeat`` seconds for ``n_rays`` rays (after a warm-up that compiles the
        kernels), and the last counts."""
        self.counts(min(n_rays, WAVEFRONT), seed=0)
        best, out = float("inf"), None
        for r in range(repeat):
            t0 = time.perf_counter()
            out = self.counts(n_rays, seed=r + 1)
            best = min(best, time.perf_counter() - t0)
        return best, out

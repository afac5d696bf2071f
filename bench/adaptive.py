"""The adaptive budget of ``bench spectro`` / ``bench gonio --uncertainty``: measure with the
adaptive stopping rule (:func:`virtual.bounds.run_adaptive`) instead of eq. 3.5 / 3.12, and say
how many rays it saved.

Application code: it drives a virtual instrument's kernels directly (the CLI imports it lazily).
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np

from bench.core.errors import BudgetError
from bench.core.geometry import Geometry, cie_geometry
from bench.core.parsing import parse_wavelengths
from virtual.bounds import adaptive_plan, budget_report, hoeffding_rays, run_adaptive
from virtual.engine import (SpectroTally, gonio_counts, measurement_seed, multinomial_counts,
                            spectro_counts)

__all__ = ["adaptive_measure", "AdaptiveMeasurement", "DEFAULT_MAX_SECONDS"]

#: an adaptive measurement whose eq. 3.5 cap would take longer than this is refused with its budget
DEFAULT_MAX_SECONDS = 3600.0


class AdaptiveMeasurement(dict):
    """The outcome of :func:`adaptive_measure` (a dict with stable keys, for ``--json``)."""


def adaptive_measure(instrument: Any, uncertainty: float, delta: float, *, rays_per_second: float = 2e7,
                     max_seconds: float = DEFAULT_MAX_SECONDS, progress: bool = False,
                     **measure_kw: Any) -> AdaptiveMeasurement:
    """Measure with the adaptive stopping rule instead of eq. 3.5, and say what it saved.

    Parameters
    ----------
    instrument
        A :class:`virtual.spectrophotometer.VirtualSpectrophotometer` (``measure_kw``:
        ``geometry``, ``wavelengths``) or a :class:`virtual.goniophotometer.VirtualGoniophotometer`
        (``measure_kw``: ``theta_i``, ``phi_i``, ``wavelengths``). Each wavelength runs the rule of
        :func:`virtual.bounds.run_adaptive` on its own and its reading is made from the rule's
        own counts (not re-drawn), so the guarantee holds for it: with probability at least
        ``1 - delta`` every estimated probability (R and T; every collector patch) is within
        ``v`` of its true value. A goniophotometer's simulation cache is filled with those
        counts (exact fast path draws when the instrument would use it). ``rays`` is set to
        the largest count used.
    uncertainty, delta
        ``v`` and ``delta`` of eq. 3.5 (3.12 with the collector's patches), in per-ray probability
        units as in the seed (a BRDF's uncertainty is ``v / PSA``; a ``45/0`` reflectance
        factor's is ``v / (cone PSA / pi)``).
    rays_per_second, max_seconds
        When eq. 3.5's ray count would take longer than ``max_seconds`` at ``rays_per_second``
        (e.g. ``v = 1e-6``), nothing runs: :class:`~bench.core.errors.BudgetError` reports the ray
        count and the estimated time.

    Returns
    -------
    AdaptiveMeasurement
        ``{"result": Spectrum | BSDFRecord, "N": rays used, "hoeffding_N": eq. 3.5/3.12,
        "saved_rays": ..., "saved_fraction": ..., "per_wavelength": [N, ...], "mode": plan mode,
        "message": one line for the CLI}``.
    """
    gonio = hasattr(instrument, "collector")
    m = instrument.collector.n_patches if gonio else 1
    report = budget_report(uncertainty, delta, m, rays_per_second)
    if report["seconds"] > max_seconds:
        raise BudgetError(f"v = {uncertainty:g}, delta = {delta:g}: eq. {'3.12' if gonio else '3.5'} needs "
                          f"{report['N']:,} rays (~{_human(report['seconds'])} at {rays_per_second:.3g} rays/s), "
                          f"more than --max-seconds {max_seconds:g}; the adaptive rule may stop earlier but "
                          f"cannot promise to")
    sp = instrument.specimen
    per_wl: list[int] = []
    if gonio:
        theta_i, phi_i = float(measure_kw.get("theta_i", 30.0)), float(measure_kw.get("phi_i", 0.0))
        instrument.check(Geometry(theta_i, phi_i % 360.0, 0.0, 0.0))  # refuse before any ray is cast
        wls = instrument.wavelengths if measure_kw.get("wavelengths") is None else parse_wavelengths(
            measure_kw["wavelengths"])
        b = instrument.beam.kernel_args(theta_i, phi_i)
        cargs = instrument.collector.kernel_args()
        fast = instrument.uses_fast_path()
    else:
        geometry = cie_geometry(measure_kw.get("geometry", "8/d"))
        measured = geometry.reciprocal_directional
        theta_i, phi_i = measured.theta_i, 0.0
        wls = parse_wavelengths(measure_kw.get("wavelengths", "400:700:10"))
        b = instrument.beam.kernel_args(theta_i, 0.0)
        cone, cone_psa_over_pi = instrument._cone(measured)
        directional = measured.viewing == "directional"
        excluded = not directional and not measured.specular_included
    sp.check_wavelengths(wls)
    tallies: list[Any] = []
    plan = None
    from tqdm import tqdm

    for w in tqdm(wls, disable=not progress, desc="adaptive", unit="wl", leave=False, dynamic_ncols=True):
        params = sp.params(float(w))
        total = [None]
        calls = [0]
        if gonio:
            # the fast path only where its quadrature is certified (refused under method "fast")
            fast_w = fast and instrument.fast_path_for(theta_i, phi_i, float(w))
            probs = instrument.bin_probabilities(theta_i, phi_i, float(w)) if fast_w else None
            cols = np.arange(instrument.collector.n_bins if sp.transmits(float(w)) else m)
        else:
            cols = np.array([0, 1]) if (sp.transmits(float(w)) and not directional) else np.array([0])
        plan = adaptive_plan(uncertainty, delta, len(cols))

        def draw(n_new: int, _w: float = float(w), _p: Any = params, _probs: Any = None if not gonio else probs,
                 _cols: Any = cols) -> Any:
            calls[0] += 1
            seq = measurement_seed(instrument.seed, *instrument.stream_key(theta_i, phi_i, _w), 0xADA, calls[0])
            if gonio:
                if _probs is not None:
                    c = multinomial_counts(_probs, n_new, seq)
                else:
                    c = gonio_counts(sp.model, _p, instrument.beam.code, instrument.beam.disk_code, b, cargs,
                                     n_new, seq)
                total[0] = c if total[0] is None else total[0] + c
                return c[_cols]
            t = spectro_counts(sp.model, _p, instrument.beam.code, instrument.beam.disk_code, b, n_new, seq,
                               cone)
            v = np.array([t.reflected, t.transmitted, t.absorbed, t.missed, t.cone], dtype=np.int64)
            total[0] = v if total[0] is None else total[0] + v
            r = t.cone if directional else t.reflected - (t.cone if excluded else 0)
            return np.array([r, t.transmitted], dtype=np.int64)[_cols]

        res = run_adaptive(draw, uncertainty, delta, patches=plan.patches, plan=plan)
        per_wl.append(int(res.N))
        if gonio:
            key = (round(theta_i, 9), round(phi_i % 360.0, 9), round(float(w), 9))
            instrument._cache[key] = total[0]
        else:
            tallies.append(SpectroTally(int(res.N), *(int(x) for x in total[0])))
    assert plan is not None
    n_used = max(per_wl)
    if gonio:
        instrument.rays = n_used
        result = instrument.measure_bsdf(theta_i, phi_i, wls)
        result.meta["rays_per_wavelength"] = per_wl
        result.meta["budget"] = "adaptive"
    else:
        instrument.rays = n_used
        result = instrument._spectrum(geometry, measured, wls, tallies, cone_psa_over_pi)
        result = replace(result, N=np.array(per_wl, dtype=np.int64))
        result.meta["budget"] = "adaptive"
    hoeff = hoeffding_rays(uncertainty, delta, m)
    saved = hoeff - n_used
    per = 'incidence and wavelength' if gonio else 'wavelength'
    eq = '3.12' if gonio else '3.5'
    if saved >= 0:
        msg = (f"adaptive budget: {n_used:,} rays per {per} (at most) instead of eq. {eq}'s {hoeff:,} "
               f"({saved / hoeff:.0%} saved, same v = {uncertainty:g}, delta = {delta:g})")
    else:  # ran to its cap: every tracked reading certified jointly at delta (eq. 3.5 at delta/m each)
        msg = (f"adaptive budget: {n_used:,} rays per {per} (at most), {-saved:,} more than eq. {eq}'s {hoeff:,}: "
               f"the rule certifies its {plan.patches} readings jointly (v = {uncertainty:g} for all at once with "
               f"probability 1 - delta = {1 - delta:g}; its cap is eq. 3.5 at delta/{plan.patches}), where eq. {eq} "
               f"bounds {'each patch' if gonio else 'one reading'} at a time")
    return AdaptiveMeasurement(result=result, N=n_used, hoeffding_N=hoeff, saved_rays=saved,
                               saved_fraction=saved / hoeff, per_wavelength=per_wl, mode=plan.mode, message=msg)


def _human(seconds: float) -> str:
    if not math.isfinite(seconds):
        return "forever"
    for unit, s in (("years", 3.15576e7), ("days", 86400.0), ("h", 3600.0), ("min", 60.0)):
        if seconds >= s:
            return f"{seconds / s:.3g} {unit}"
    return f"{seconds:.3g} s"

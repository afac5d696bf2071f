"""The ray budgets of ``bench spectro`` and ``bench gonio``, computed and measured (nothing here
prints: the CLI words and writes what these return).

* The adaptive budget (``--uncertainty`` of spectro, ``--patch-probability-uncertainty`` of
  gonio): measure with the adaptive stopping rule (:func:`virtual.bounds.run_adaptive`) instead
  of eq. 3.5 / 3.12, and say how many rays it saved. :func:`measure_adaptively` computes (the
  rule, wavelength by wavelength, and the reading made from its counts) and returns an
  :class:`AdaptiveOutcome`; :func:`adaptive_message` words it for the CLI;
  :func:`adaptive_measure` does both and returns the ``--json`` dict.
* ``bench gonio``'s three budgets (fixed rays, a relative BSDF uncertainty sized from a pilot
  run, eq. 3.12's patch probability): :func:`choose_gonio_budget` returns a :class:`GonioBudget`,
  :func:`measure_gonio` the :class:`GonioMeasurement` (record, budget, achieved widths).

Application code: it drives a virtual instrument's kernels directly (the CLI imports it lazily).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from bench.core.errors import BudgetError
from bench.core.geometry import Geometry, cie_geometry
from bench.core.parsing import parse_wavelengths
from virtual.bounds import adaptive_plan, budget_report, hoeffding_rays, relative_patch_rays, run_adaptive
from virtual.engine import (SpectroTally, gonio_counts, measurement_seed, multinomial_counts,
                            spectro_counts)
from virtual.goniophotometer import VirtualGoniophotometer

__all__ = ["adaptive_measure", "measure_adaptively", "adaptive_message", "AdaptiveOutcome",
           "AdaptiveMeasurement", "DEFAULT_MAX_SECONDS", "choose_gonio_budget", "measure_gonio", "GonioBudget",
           "GonioMeasurement", "relative_widths", "by_value", "INTEREST_FRACTION", "PILOT_RAYS"]

#: an adaptive measurement whose eq. 3.5 cap would take longer than this is refused with its budget
DEFAULT_MAX_SECONDS = 3600.0
#: a patch is "of interest" to ``bench gonio --relative-uncertainty`` when its pilot probability is at
#: least this fraction of the brightest patch's
INTEREST_FRACTION = 0.01
#: rays of the pilot run that estimates the patch probabilities
PILOT_RAYS = 200_000


class AdaptiveMeasurement(dict):
    """The outcome of :func:`adaptive_measure` (a dict with stable keys, for ``--json``)."""


@dataclass(frozen=True)
class AdaptiveOutcome:
    """What :func:`measure_adaptively` measured and what the rule spent.

    ``result`` is the Spectrum (spectrophotometer) or BSDFRecord (goniophotometer) made from the
    rule's own counts; ``per_wavelength`` the rays the rule used at each wavelength;
    ``hoeffding_N`` eq. 3.5's (3.12's with the collector's patches) count for the same
    ``uncertainty`` and ``delta``; ``mode`` and ``patches`` those of the rule's plan (the last
    wavelength's: how many readings it certified jointly)."""

    result: Any
    per_wavelength: list[int]
    hoeffding_N: int
    mode: str
    patches: int
    uncertainty: float
    delta: float
    gonio: bool

    @property
    def N(self) -> int:
        """The largest ray count used (the instrument's ``rays`` afterwards)."""
        return max(self.per_wavelength)

    @property
    def saved_rays(self) -> int:
        """Rays saved against eq. 3.5/3.12 (negative when the rule ran to its joint cap)."""
        return self.hoeffding_N - self.N

    @property
    def saved_fraction(self) -> float:
        return self.saved_rays / self.hoeffding_N


@dataclass
class _Setup:
    """The instrument-specific arguments of the rule's draws, fixed before any ray is cast."""

    gonio: bool
    theta_i: float
    phi_i: float
    wls: Any
    b: Any
    m: int
    cargs: Any = None
    fast: bool = False
    geometry: Any = None
    measured: Any = None
    cone: Any = None
    cone_psa_over_pi: Any = None
    directional: bool = False
    excluded: bool = False
    tallies: list[Any] = field(default_factory=list)


def measure_adaptively(instrument: Any, uncertainty: float, delta: float, *, rays_per_second: float = 2e7,
                       max_seconds: float = DEFAULT_MAX_SECONDS, progress: bool = False,
                       **measure_kw: Any) -> AdaptiveOutcome:
    """Measure with the adaptive stopping rule instead of eq. 3.5; nothing is printed.

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
    progress
        A progress bar on stderr, one step per wavelength.
    """
    gonio = hasattr(instrument, "collector")
    m = instrument.collector.n_patches if gonio else 1
    report = budget_report(uncertainty, delta, m, rays_per_second)
    if report["seconds"] > max_seconds:
        raise BudgetError(f"v = {uncertainty:g}, delta = {delta:g}: eq. {'3.12' if gonio else '3.5'} needs "
                          f"{report['N']:,} rays (~{_human(report['seconds'])} at {rays_per_second:.3g} rays/s), "
                          f"more than --max-seconds {max_seconds:g}; the adaptive rule may stop earlier but "
                          f"cannot promise to")
    setup = _setup(instrument, gonio, m, measure_kw)
    instrument.specimen.check_wavelengths(setup.wls)
    per_wl, plan = _run_rule(instrument, setup, uncertainty, delta, progress)
    instrument.rays = max(per_wl)
    if gonio:
        result = instrument.measure_bsdf(setup.theta_i, setup.phi_i, setup.wls)
        result.meta["rays_per_wavelength"] = per_wl
    else:
        result = instrument._spectrum(setup.geometry, setup.measured, setup.wls, setup.tallies,
                                      setup.cone_psa_over_pi)
        result = replace(result, N=np.array(per_wl, dtype=np.int64))
    result.meta["budget"] = "adaptive"
    return AdaptiveOutcome(result=result, per_wavelength=per_wl, hoeffding_N=hoeffding_rays(uncertainty, delta, m),
                           mode=plan.mode, patches=plan.patches, uncertainty=uncertainty, delta=delta, gonio=gonio)


def _setup(instrument: Any, gonio: bool, m: int, measure_kw: dict[str, Any]) -> _Setup:
    if gonio:
        theta_i, phi_i = float(measure_kw.get("theta_i", 30.0)), float(measure_kw.get("phi_i", 0.0))
        instrument.check(Geometry(theta_i, phi_i % 360.0, 0.0, 0.0))  # refuse before any ray is cast
        wls = instrument.wavelengths if measure_kw.get("wavelengths") is None else parse_wavelengths(
            measure_kw["wavelengths"])
        return _Setup(True, theta_i, phi_i, wls, instrument.beam.kernel_args(theta_i, phi_i), m,
                      cargs=instrument.collector.kernel_args(), fast=instrument.uses_fast_path())
    geometry = cie_geometry(measure_kw.get("geometry", "8/d"))
    measured = geometry.reciprocal_directional
    wls = parse_wavelengths(measure_kw.get("wavelengths", "400:700:10"))
    cone, cone_psa_over_pi = instrument._cone(measured)
    directional = measured.viewing == "directional"
    return _Setup(False, measured.theta_i, 0.0, wls, instrument.beam.kernel_args(measured.theta_i, 0.0), m,
                  geometry=geometry, measured=measured, cone=cone, cone_psa_over_pi=cone_psa_over_pi,
                  directional=directional, excluded=not directional and not measured.specular_included)


def _run_rule(instrument: Any, s: _Setup, uncertainty: float, delta: float, progress: bool) -> tuple[list[int], Any]:
    """The rule at each wavelength: the rays it used per wavelength and the last plan. A
    goniophotometer's cache and a spectrophotometer's ``s.tallies`` receive the counts."""
    from tqdm import tqdm

    sp = instrument.specimen
    per_wl: list[int] = []
    plan = None
    for w in tqdm(s.wls, disable=not progress, desc="adaptive", unit="wl", leave=False, dynamic_ncols=True):
        params = sp.params(float(w))
        total = [None]
        calls = [0]
        if s.gonio:
            # the fast path only where its quadrature is certified (refused under method "fast")
            fast_w = s.fast and instrument.fast_path_for(s.theta_i, s.phi_i, float(w))
            probs = instrument.bin_probabilities(s.theta_i, s.phi_i, float(w)) if fast_w else None
            cols = np.arange(instrument.collector.n_bins if sp.transmits(float(w)) else s.m)
        else:
            cols = np.array([0, 1]) if (sp.transmits(float(w)) and not s.directional) else np.array([0])
        plan = adaptive_plan(uncertainty, delta, len(cols))

        def draw(n_new: int, _w: float = float(w), _p: Any = params, _probs: Any = None if not s.gonio else probs,
                 _cols: Any = cols) -> Any:
            calls[0] += 1
            seq = measurement_seed(instrument.seed, *instrument.stream_key(s.theta_i, s.phi_i, _w), 0xADA, calls[0])
            if s.gonio:
                if _probs is not None:
                    c = multinomial_counts(_probs, n_new, seq)
                else:
                    c = gonio_counts(sp.model, _p, instrument.beam.code, instrument.beam.disk_code, s.b, s.cargs,
                                     n_new, seq)
                total[0] = c if total[0] is None else total[0] + c
                return c[_cols]
            t = spectro_counts(sp.model, _p, instrument.beam.code, instrument.beam.disk_code, s.b, n_new, seq,
                               s.cone)
            v = np.array([t.reflected, t.transmitted, t.absorbed, t.missed, t.cone], dtype=np.int64)
            total[0] = v if total[0] is None else total[0] + v
            r = t.cone if s.directional else t.reflected - (t.cone if s.excluded else 0)
            return np.array([r, t.transmitted], dtype=np.int64)[_cols]

        res = run_adaptive(draw, uncertainty, delta, patches=plan.patches, plan=plan)
        per_wl.append(int(res.N))
        if s.gonio:
            key = (round(s.theta_i, 9), round(s.phi_i % 360.0, 9), round(float(w), 9))
            instrument._cache[key] = total[0]
        else:
            s.tallies.append(SpectroTally(int(res.N), *(int(x) for x in total[0])))
    assert plan is not None
    return per_wl, plan


def adaptive_message(o: AdaptiveOutcome) -> str:
    """One line for the CLI: the rays used against eq. 3.5/3.12's, and what was saved (or why
    the rule, run to its cap, used more)."""
    n_used, hoeff, saved = o.N, o.hoeffding_N, o.saved_rays
    per = 'incidence and wavelength' if o.gonio else 'wavelength'
    eq = '3.12' if o.gonio else '3.5'
    if saved >= 0:
        return (f"adaptive budget: {n_used:,} rays per {per} (at most) instead of eq. {eq}'s {hoeff:,} "
                f"({saved / hoeff:.0%} saved, same v = {o.uncertainty:g}, delta = {o.delta:g})")
    # ran to its cap: every tracked reading certified jointly at delta (eq. 3.5 at delta/m each)
    return (f"adaptive budget: {n_used:,} rays per {per} (at most), {-saved:,} more than eq. {eq}'s {hoeff:,}: "
            f"the rule certifies its {o.patches} readings jointly (v = {o.uncertainty:g} for all at once with "
            f"probability 1 - delta = {1 - o.delta:g}; its cap is eq. 3.5 at delta/{o.patches}), where eq. {eq} "
            f"bounds {'each patch' if o.gonio else 'one reading'} at a time")


def adaptive_measure(instrument: Any, uncertainty: float, delta: float, *, rays_per_second: float = 2e7,
                     max_seconds: float = DEFAULT_MAX_SECONDS, progress: bool = False,
                     **measure_kw: Any) -> AdaptiveMeasurement:
    """:func:`measure_adaptively` as the dict the CLI reports (same parameters).

    Returns
    -------
    AdaptiveMeasurement
        ``{"result": Spectrum | BSDFRecord, "N": rays used, "hoeffding_N": eq. 3.5/3.12,
        "saved_rays": ..., "saved_fraction": ..., "per_wavelength": [N, ...], "mode": plan mode,
        "message": one line for the CLI}``.
    """
    o = measure_adaptively(instrument, uncertainty, delta, rays_per_second=rays_per_second,
                           max_seconds=max_seconds, progress=progress, **measure_kw)
    return AdaptiveMeasurement(result=o.result, N=o.N, hoeffding_N=o.hoeffding_N, saved_rays=o.saved_rays,
                               saved_fraction=o.saved_fraction, per_wavelength=o.per_wavelength, mode=o.mode,
                               message=adaptive_message(o))


@dataclass(frozen=True)
class GonioBudget:
    """How ``bench gonio`` sizes its ray count, chosen before any ray of the measurement is cast.

    ``kind`` is ``"fixed rays"``, ``"relative BSDF"`` or ``"patch probability (eq. 3.12)"``;
    ``instrument_kw`` the :class:`~virtual.goniophotometer.VirtualGoniophotometer` keywords
    (``rays`` or ``uncertainty`` among them); ``v`` and ``delta`` the uncertainty asked for;
    ``relative`` the pilot's plan (:func:`virtual.bounds.relative_patch_rays` plus
    ``unreachable_patches``, ``patches_of_interest``, ``patches``, ``pilot_rays``);
    ``adaptive`` whether the adaptive rule measures (eq. 3.12's budget unless refused)."""

    kind: str
    instrument_kw: dict[str, Any]
    delta: float
    v: float | None = None
    relative: dict[str, Any] | None = None
    adaptive: bool = False

    @property
    def bounds_its_time(self) -> bool:
        """The relative and adaptive budgets bound their own time (a fixed count is checked by the caller)."""
        return self.relative is not None or self.adaptive

    def instrument(self, specimen: str) -> VirtualGoniophotometer:
        return VirtualGoniophotometer(specimen, **self.instrument_kw)

    def describe(self, record: Any) -> dict[str, Any]:
        """The ``uncertainty`` object of ``bench gonio --json``."""
        if self.relative is not None:
            return {"mode": self.kind, "v": self.v, "delta": self.delta, **self.relative}
        if self.kind != "fixed rays":
            return {"mode": self.kind, "v": self.v, "delta": self.delta}
        return {"mode": self.kind, "N": int(record.meta["rays"])}


@dataclass(frozen=True)
class GonioMeasurement:
    """What :func:`measure_gonio` measured: the record (its meta says body, bench, plan and
    incidence), the instrument, the budget, the adaptive rule's outcome (``None`` unless the
    budget is adaptive), ``uncertainty`` (:meth:`GonioBudget.describe`) and ``achieved``
    (:func:`relative_widths`)."""

    record: Any
    instrument: VirtualGoniophotometer
    budget: GonioBudget
    adaptive: AdaptiveOutcome | None
    uncertainty: dict[str, Any]
    achieved: dict[str, Any]
    incidence: tuple[float, float]


def choose_gonio_budget(specimen: str, theta_i: float, phi_i: float, instrument_kw: dict[str, Any], *,
                        rays: int | None = None, relative_uncertainty: float | None = None,
                        patch_probability_uncertainty: float | None = None, delta: float = 0.01,
                        adaptive: bool = True, max_seconds: float = DEFAULT_MAX_SECONDS,
                        rays_per_second: float = 2e7) -> GonioBudget:
    """The budget of one goniophotometric measurement: at most one of ``rays`` (fixed),
    ``relative_uncertainty`` (a relative BSDF half-width per patch of interest: a
    :data:`PILOT_RAYS` pilot run estimates the patch probabilities and N is sized so that the
    dimmest patch of interest meets it, capped at ``max_seconds`` of ``rays_per_second``) and
    ``patch_probability_uncertainty`` (eq. 3.12's v; the adaptive rule unless ``adaptive`` is
    false). None of them: the instrument's default fixed count. ``instrument_kw`` holds the
    instrument's other keywords (collector, beam, seed, delta, wavelengths, method, ...)."""
    kw = dict(instrument_kw)
    if rays is not None:
        return GonioBudget("fixed rays", {**kw, "rays": rays}, delta)
    if relative_uncertainty is not None:
        plan = _relative_rays(specimen, theta_i, phi_i, kw, relative_uncertainty, delta,
                              int(max_seconds * rays_per_second))
        return GonioBudget("relative BSDF", {**kw, "rays": plan["N"]}, delta, relative_uncertainty, plan)
    if patch_probability_uncertainty is not None:
        return GonioBudget("patch probability (eq. 3.12)", {**kw, "uncertainty": patch_probability_uncertainty},
                           delta, patch_probability_uncertainty, adaptive=adaptive)
    return GonioBudget("fixed rays", kw, delta)


def _relative_rays(specimen: str, theta_i: float, phi_i: float, kw: dict[str, Any], v: float, delta: float,
                   cap: int) -> dict[str, Any]:
    """The ray count for a relative BSDF uncertainty ``v``, from a pilot run (see :func:`choose_gonio_budget`)."""
    seed = kw.get("seed")
    pilot_seed = None if seed is None else int(seed) + 1  # the pilot's rays are not reused
    pilot = VirtualGoniophotometer(specimen, **{**kw, "rays": PILOT_RAYS, "seed": pilot_seed})
    t = pilot.measure_bsdf(theta_i, phi_i).table
    p = t["count"].to_numpy(float) / t["N"].to_numpy(float)
    interest = p >= INTEREST_FRACTION * p.max()
    plan = relative_patch_rays(p[interest], v, delta, max_rays=cap)
    idx = np.flatnonzero(interest)[plan["unreachable"]]
    plan["unreachable_patches"] = [(float(t.theta_r.iloc[i]), float(t.phi_r.iloc[i])) for i in idx]
    plan.update(patches_of_interest=int(interest.sum()), patches=int(len(p)), pilot_rays=PILOT_RAYS)
    return plan


def measure_gonio(instrument: VirtualGoniophotometer, budget: GonioBudget, theta_i: float, phi_i: float, *,
                  max_seconds: float = DEFAULT_MAX_SECONDS, progress: bool = False) -> GonioMeasurement:
    """Measure one incidence with ``instrument`` (``budget.instrument(specimen)``) under ``budget``;
    nothing is printed (``progress``: a bar on stderr, one step per wavelength, where the
    wavelengths are counted one by one). A fixed count's time is the caller's to check first."""
    outcome = None
    if budget.adaptive:
        outcome = measure_adaptively(instrument, budget.v, budget.delta, theta_i=theta_i, phi_i=phi_i,
                                     max_seconds=max_seconds, progress=progress)
        record = outcome.result
    else:
        # one step per wavelength (a spectral batch is one step: no bar); the counts are cached per
        # (incidence, wavelength), measure_bsdf reuses them
        if progress and not instrument.uses_fast_path() and not instrument.batches_wavelengths:
            from tqdm import tqdm

            for w in tqdm(instrument.wavelengths, desc="gonio", unit="wl", leave=False, dynamic_ncols=True):
                instrument.simulate(theta_i, phi_i, float(w))
        record = instrument.measure_bsdf(theta_i, phi_i)
    achieved = relative_widths(record)
    uncertainty = budget.describe(record)
    record.meta.update(body="virtual", bench_name="virtual-gonio", plan_name="gonio", incidence=[theta_i, phi_i])
    return GonioMeasurement(record, instrument, budget, outcome, uncertainty, achieved, (theta_i, phi_i))


def by_value(t: Any, brightest_first: bool = True) -> Any:
    """Patches ordered by BSDF value, the same way on every CPU: values equal to 10 significant
    digits are ties (a Lambertian's patches of equal counts, whose exact PSAs differ in the last
    bits by CPU, as numpy's vectorized trigonometry does), in hemisphere, theta, phi order."""
    return (t.assign(_key=[float(f"{v:.10g}") for v in t.value])
            .sort_values(["_key", "hemisphere", "theta_r", "phi_r"], ascending=[not brightest_first, True, True, True],
                         kind="stable"))


def relative_widths(record: Any) -> dict[str, Any]:
    """Relative half-width ``(ci_hi - ci_lo) / (2 value)`` of the brightest patch and of the
    dimmest patch of interest (value >= INTEREST_FRACTION x brightest), first wavelength."""
    t = record.table
    t = t[(t.wavelength_nm == t.wavelength_nm.iloc[0]) & (t.value > 0)]
    top = float(t.value.max())
    sel = t[t.value >= INTEREST_FRACTION * top]
    rel = (sel.ci_hi - sel.ci_lo) / (2.0 * sel.value)
    b, d = by_value(sel).iloc[0], by_value(sel, brightest_first=False).iloc[0]
    return {"brightest": {"theta": float(b.theta_r), "phi": float(b.phi_r), "value": float(b.value),
                          "relative_half_width": float(rel[b.name])},
            "dimmest_of_interest": {"theta": float(d.theta_r), "phi": float(d.phi_r), "value": float(d.value),
                                    "relative_half_width": float(rel[d.name])},
            "patches_of_interest": int(len(sel)), "max_relative_half_width": float(rel.max())}


def _human(seconds: float) -> str:
    if not math.isfinite(seconds):
        return "forever"
    for unit, s in (("years", 3.15576e7), ("days", 86400.0), ("h", 3600.0), ("min", 60.0)):
        if seconds >= s:
            return f"{seconds / s:.3g} {unit}"
    return f"{seconds:.3g} s"

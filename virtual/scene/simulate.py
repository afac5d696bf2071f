"""The :class:`Scene`: one measurement setup run with only the effects it declares.

:meth:`Scene.run` picks the bare kernels (:mod:`virtual.engine`), the effect kernels
(:mod:`virtual.effects`) or the exact fast path, then applies the effects on readings;
:meth:`Scene.reference` is the quadrature reference the run is tested against.
"""

from __future__ import annotations

import math
import time
import zlib
from dataclasses import dataclass, field, replace
from typing import Any, Mapping, get_args

import numpy as np

from bench.core.errors import ConfigError, InputError
from bench.core.geometry import direction, gauss_legendre
from bench.core.schemas import SceneFile
from virtual import effects as fx
from virtual import engine
from virtual.beam import Beam, check_incidence
from virtual.bounds import binomial_ci, hoeffding_rays
from virtual.collector import Collector
from virtual.kernels.ray_loop import (E_DETECTOR_PORT, E_NEAR_DISTANCE, E_NEAR_RADIUS, E_PATTERN_CONTRAST, E_PATTERN_PERIOD,
                                     E_PORT_FRACTION, E_SPECIMEN_PORT, E_SPOT_RADIUS, E_STRAY_FRACTION, E_WALL_REFLECTANCE,
                                     N_EFFECT_ARGS)
from virtual.engine import NO_CONE, measurement_seed, multinomial_counts
from virtual.quadrature import integrate_patches
from virtual.scene.declared import Effects
from virtual.specimens import MODEL_PYTHON, Lambertian, Specimen

__all__ = ["Scene", "SceneResult", "cone_probability", "INSTRUMENTS", "OBSERVABLES"]

#: the instruments and observables a scene may name (declared by its schema, bench.core.schemas)
INSTRUMENTS: tuple[str, ...] = get_args(SceneFile.model_fields["instrument"].annotation)
OBSERVABLES: tuple[str, ...] = get_args(SceneFile.model_fields["observable"].annotation)


@dataclass
class SceneResult:
    """What :meth:`Scene.run` returns.

    Attributes
    ----------
    wavelengths : (w,)
    values : (w, k)
        Spectrophotometer: one column (the observable). Goniophotometer: BRDF/BTDF (1/sr) of
        every collector bin, then one column per aperture detector.
    ci : (w, k, 2)
        Two-sided ``1 - delta`` interval (Clopper-Pearson on counts, widened by declared noise).
    counts : list of int64 arrays, one per wavelength (raw kernel output)
    N, hits : rays cast and rays that met the specimen (the estimates' denominator)
    method : "bare", "effects" or "fast"
    seconds : wall time of the simulation
    effects : the declared effects' names
    """

    wavelengths: np.ndarray
    values: np.ndarray
    ci: np.ndarray
    counts: list[np.ndarray]
    N: int
    hits: np.ndarray
    method: str
    seconds: float
    effects: list[str]
    positions_sampled: bool
    probabilities: np.ndarray | None = None


# --- the scene ----------------------------------------------------------------------------------


def cone_probability(specimen: Specimen, wi: np.ndarray, axis: np.ndarray, half_angle_deg: float,
                     wavelength_nm: float, order: int = 48) -> float:
    """``int_cone f |cos theta_o| d omega`` over a cone around ``axis``: Gauss-Legendre in the
    angle from the axis, the periodic trapezoid rule in the azimuth around it."""
    a = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    t1 = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
    t1 /= np.linalg.norm(t1)
    t2 = np.cross(a, t1)
    beta = math.radians(half_angle_deg)
    x, w = gauss_legendre(order)
    al = 0.5 * beta * (x + 1.0)
    wa = 0.5 * beta * w
    psi = np.arange(4 * order) * (2.0 * math.pi / (4 * order))
    A, P = np.meshgrid(al, psi, indexing="ij")
    d = (np.cos(A)[..., None] * a + np.sin(A)[..., None] * (np.cos(P)[..., None] * t1 + np.sin(P)[..., None] * t2))
    d = d.reshape(-1, 3)
    f = np.asarray(specimen.bsdf(np.asarray(wi, float), d, wavelength_nm), float).reshape(A.shape)
    integrand = f * np.abs(d[:, 2]).reshape(A.shape) * np.sin(A)
    return float(np.sum(integrand.sum(axis=1) * (2.0 * math.pi / (4 * order)) * wa))


@dataclass(frozen=True)
class Scene:
    """A measurement setup and the effects it declares (see the module docstring)."""

    specimen: Specimen
    instrument: str = "spectrophotometer"
    beam: Beam = field(default_factory=Beam)
    collector: Collector = field(default_factory=lambda: Collector("equal-psa", 9, 36))
    wavelengths: tuple[float, ...] = (550.0,)
    incidence: tuple[float, float] = (8.0, 0.0)
    rays: int | None = None
    uncertainty: float = 0.01
    delta: float = 0.01
    seed: int = 1
    observable: str = "reflectance"
    method: str = "auto"
    effects: Effects = field(default_factory=Effects)
    name: str = "scene"
    tradeoff: Mapping[str, Any] = field(default_factory=dict)
    physical: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.instrument not in INSTRUMENTS:
            raise ConfigError(f"instrument must be one of {', '.join(INSTRUMENTS)}, got {self.instrument!r}")
        if self.observable not in OBSERVABLES:
            raise ConfigError(f"observable must be one of {', '.join(OBSERVABLES)}, got {self.observable!r}")
        if self.method not in ("auto", "rays", "fast"):
            raise ConfigError(f"method must be auto, rays or fast, got {self.method!r}")
        if self.instrument != "physical":
            check_incidence(float(self.incidence[0]))
        if self.rays is not None and (not isinstance(self.rays, (int, np.integer)) or self.rays < 1):
            raise ConfigError(f"rays must be a positive integer, got {self.rays!r}")
        e = self.effects
        if self.instrument == "spectrophotometer" and e.aperture is not None:
            raise ConfigError("effects.aperture belongs to a goniophotometer (a spectrophotometer's "
                              "bidirectional cone is its gloss_trap / geometry)")
        if self.instrument == "goniophotometer" and (e.sphere is not None or e.gloss_trap is not None):
            raise ConfigError("effects.sphere and effects.gloss_trap belong to a spectrophotometer")
        if self.specimen.model == MODEL_PYTHON and self.kernel_flags():  # before any ray, not absorbed silently
            raise ConfigError(f"specimen {getattr(self.specimen, 'name', type(self.specimen).__name__)!r} has no kernel (it samples in Python), so the "
                              f"scene's per-ray effects cannot act on its rays; drop the effects or use a "
                              f"native family")
        if self.method == "fast" and not self.fast_path_possible():
            raise ConfigError("method 'fast' needs a collimated beam, a specimen with a density and no "
                              "per-ray effect")

    # -- what is declared ----------------------------------------------------------------------
    @property
    def n_rays(self) -> int:
        if self.rays is not None:
            return int(self.rays)
        m = self.collector.n_patches if self.instrument == "goniophotometer" else 1
        return hoeffding_rays(self.uncertainty, self.delta, m)

    @property
    def needs_positions(self) -> bool:
        """Whether rays need the point where they meet the specimen: only for a non-uniform
        specimen or detectors at a finite distance."""
        e = self.effects
        return bool((e.specimen is not None and not e.specimen.uniform)
                    or (e.aperture is not None and e.aperture.near))

    def kernel_flags(self) -> int:
        e = self.effects
        flags = 0
        if e.stray_light is not None:
            flags |= fx.FX_STRAY
        if e.bandpass is not None:
            flags |= fx.FX_BANDPASS
        if e.sphere is not None:
            flags |= fx.FX_SPHERE
        if e.specimen is not None and not e.specimen.uniform:
            flags |= fx.FX_PATTERN
        if e.aperture is not None:
            flags |= fx.FX_DETECTORS | (fx.FX_NEAR if e.aperture.near else 0)
        return flags

    def fast_path_possible(self) -> bool:
        return (self.beam.kind == "collimated" and self.specimen.has_density and self.kernel_flags() == 0
                and self.effects.gloss_trap is None and self.observable != "missed")

    def uses_fast_path(self) -> bool:
        return self.method == "fast" or (self.method == "auto" and self.instrument == "goniophotometer"
                                         and self.fast_path_possible())

    def with_effects(self, effects: Effects) -> "Scene":
        return replace(self, effects=effects)

    @property
    def wi(self) -> np.ndarray:
        return direction(*self.incidence)

    def _mirror_axis(self) -> np.ndarray:
        w = self.wi
        return np.array([-w[0], -w[1], w[2]])

    def _cone(self) -> np.ndarray:
        g = self.effects.gloss_trap
        if g is None:
            return NO_CONE
        return np.array([*self._mirror_axis(), math.cos(math.radians(g.half_angle_deg))])

    def _effect_args(self) -> np.ndarray:
        e = self.effects
        v = np.zeros(N_EFFECT_ARGS)
        if e.stray_light is not None:
            v[E_STRAY_FRACTION] = e.stray_light.fraction
        if e.sphere is not None:
            s = e.sphere
            v[E_WALL_REFLECTANCE], v[E_DETECTOR_PORT] = s.wall_reflectance, s.detector_port
            v[E_SPECIMEN_PORT], v[E_PORT_FRACTION] = s.specimen_port, s.port_fraction
        v[E_PATTERN_PERIOD] = 1.0
        # the illuminated spot (positions of a collimated beam): the specimen disk by default
        v[E_SPOT_RADIUS] = self.beam.specimen_radius_mm
        if e.specimen is not None:
            v[E_PATTERN_PERIOD], v[E_PATTERN_CONTRAST] = e.specimen.period_mm, e.specimen.contrast
            v[E_SPOT_RADIUS] = e.specimen.spot_radius_mm
        if e.aperture is not None and e.aperture.near:
            d = float(e.aperture.distance_mm)  # type: ignore[arg-type]
            v[E_NEAR_DISTANCE], v[E_NEAR_RADIUS] = d, d * math.tan(math.radians(e.aperture.half_angle_deg))
        return v

    def _ptab(self, wl: float) -> tuple[np.ndarray, np.ndarray | None]:
        b = self.effects.bandpass
        if b is None:
            return self.specimen.params(wl)[None, :], None
        nodes, w = b.grid(wl)
        return np.array([self.specimen.params(float(x)) for x in nodes]), np.cumsum(w)

    # -- running ---------------------------------------------------------------------------------
    def run(self, rays: int | None = None, seed: int | None = None, method: str | None = None) -> SceneResult:
        """Simulate the scene at every wavelength with exactly the declared effects."""
        if self.instrument == "physical":
            raise InputError("a physical scene is not simulated: use `bench tradeoff` for its scan durations")
        n = int(rays if rays is not None else self.n_rays)
        sd = self.seed if seed is None else int(seed)
        scene = self if method is None else replace(self, method=method)
        wl = np.asarray(self.wavelengths, dtype=float)
        self.specimen.check_wavelengths(wl)
        flags = self.kernel_flags()
        fast = scene.uses_fast_path()
        out_method = "fast" if fast else ("effects" if flags else "bare")
        counts: list[np.ndarray] = []
        probs: list[np.ndarray] = []
        t0 = time.perf_counter()
        for w in wl:
            seq = measurement_seed(sd, int(round(w * 1000)), int(round(self.incidence[0] * 1000)),
                                   int(round((self.incidence[1] % 360.0) * 1000)))
            if fast:
                c, p = self._fast_counts(float(w), n, seq)
                probs.append(p)
            else:
                c = self._ray_counts(float(w), n, seq, flags)
            counts.append(np.asarray(c, dtype=np.int64))
        values, ci, hits = self._readings(counts, n, sd)
        seconds = time.perf_counter() - t0
        return SceneResult(wavelengths=wl, values=values, ci=ci, counts=counts, N=n, hits=hits, method=out_method,
                           seconds=seconds, effects=self.effects.declared(), positions_sampled=self.needs_positions,
                           probabilities=np.array(probs) if probs else None)

    def _ray_counts(self, wl: float, n: int, seq: np.random.SeedSequence, flags: int) -> np.ndarray:
        b = self.beam.kernel_args(*self.incidence)
        sp = self.specimen
        if sp.model == MODEL_PYTHON:  # no kernel (e.g. Mitsuba): counted in numpy, as the devices do
            return self._python_counts(wl, n, seq)
        if self.instrument == "spectrophotometer":
            if flags == 0:
                t = engine.spectro_counts(sp.model, sp.params(wl), self.beam.code, self.beam.disk_code, b, n, seq,
                                          self._cone())
                return np.array([t.reflected, t.transmitted, t.absorbed, t.missed, t.cone, 0, 0], dtype=np.int64)
            ptab, cdf = self._ptab(wl)
            return fx.spectro_effect_counts(sp.model, ptab, cdf, self.beam.code, self.beam.disk_code, b, self._cone(),
                                            flags, self._effect_args(), n, seq)
        cargs = self.collector.kernel_args()
        if flags == 0:
            return engine.gonio_counts(sp.model, sp.params(wl), self.beam.code, self.beam.disk_code, b, cargs, n, seq)
        ptab, cdf = self._ptab(wl)
        det = self.effects.aperture.rows() if self.effects.aperture is not None else None
        return fx.gonio_effect_counts(sp.model, ptab, cdf, self.beam.code, self.beam.disk_code, b, cargs, flags,
                                      self._effect_args(), det, n, seq)

    def _python_counts(self, wl: float, n: int, seq: np.random.SeedSequence) -> np.ndarray:
        """The bare kernels' counts for a specimen that samples in Python (no per-ray effect:
        :meth:`__post_init__` refuses those)."""
        from virtual.python_engine import gonio_counts_python, spectro_counts_python

        theta_i, phi_i = (float(a) for a in self.incidence)
        if self.instrument == "spectrophotometer":
            t = spectro_counts_python(self.specimen, wl, self.beam, theta_i, phi_i, n, seq, self._cone())
            return np.array([t.reflected, t.transmitted, t.absorbed, t.missed, t.cone, 0, 0], dtype=np.int64)
        return gonio_counts_python(self.specimen, wl, self.beam, theta_i, phi_i, self.collector, n, seq)

    def bin_probabilities(self, wl: float) -> np.ndarray:
        """Exact probabilities of the kernel's bins for a collimated beam and no per-ray effect
        (quadrature of the specimen's density): gonio bins + absorbed + missed, or spectro
        (reflected, transmitted, absorbed)."""
        col = self.collector if self.instrument == "goniophotometer" else Collector("equal-psa", 4, 4)
        r = integrate_patches(self.specimen, self.wi, col, wl)
        p = np.clip(r.p, 0.0, 1.0)
        absorbed = max(0.0, 1.0 - p.sum())
        if self.instrument == "goniophotometer":
            return np.concatenate([p / max(1.0, p.sum()), [absorbed, 0.0]])
        return np.array([r.reflectance, r.transmittance, absorbed]) / max(1.0, r.albedo)

    def _fast_counts(self, wl: float, n: int, seq: np.random.SeedSequence) -> tuple[np.ndarray, np.ndarray]:
        p = self.bin_probabilities(wl)
        c = multinomial_counts(p, n, seq)
        if self.instrument == "spectrophotometer":
            return np.array([c[0], c[1], c[2], 0, 0, 0, 0], dtype=np.int64), p
        return c, p

    def _readings(self, counts: list[np.ndarray], n: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        from scipy.stats import norm

        e = self.effects
        rows, cis, hits_all = [], [], []
        for c in counts:
            if self.instrument == "spectrophotometer":
                refl, trans, _, missed, cone, detected, stray = (int(x) for x in c[:7])
                hits = n - missed
                if self.observable == "missed":
                    k, denom, scale = missed, n, 1.0
                elif self.observable == "transmittance":
                    k, denom, scale = trans, hits, 1.0
                elif e.sphere is not None:
                    k, denom, scale = detected + stray, hits, e.sphere.reference_reflectance / e.sphere.reference_efficiency()
                else:
                    excl = cone if e.gloss_trap is not None and e.gloss_trap.specular == "excluded" else 0
                    k, denom, scale = refl - excl + stray, hits, 1.0
                d = max(denom, 1)
                lo, hi = binomial_ci(np.int64(k), np.int64(d), self.delta)
                rows.append(np.array([k / d * scale]))
                cis.append(np.array([[float(lo) * scale, float(hi) * scale]]))
            else:
                nb = self.collector.n_bins
                hits = n - int(c[nb + 1])
                d = max(hits, 1)
                k = c[:nb]
                psa = np.asarray(self.collector.psa)
                if e.aperture is not None:
                    k = np.concatenate([k, c[nb + 2:]])
                    psa = np.concatenate([psa, self._detector_psa()])
                lo, hi = binomial_ci(k, np.full(k.shape, d, dtype=np.int64), self.delta)
                rows.append(k / d / psa)
                cis.append(np.column_stack([lo / psa, hi / psa]))
            hits_all.append(hits)
        values = np.array(rows)
        ci = np.array(cis)
        if e.noise is not None:
            rel = e.noise.relative if e.noise.relative is not None else self.instrument == "goniophotometer"
            rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(0x4E4F49,)))
            sd = e.noise.uncertainty * (np.abs(values) if rel else np.ones_like(values))
            below, above = values - ci[..., 0], ci[..., 1] - values
            values = values + sd * rng.standard_normal(values.shape)
            z = float(norm.isf(self.delta / 2.0))
            ci = np.stack([values - np.hypot(below, z * sd), values + np.hypot(above, z * sd)], axis=-1)
        for effect in e.extra:  # installed plugins' effects on readings, each on its own stream
            stream = np.random.SeedSequence(seed, spawn_key=(0x504C47, zlib.crc32(effect.effect_name.encode())))
            values, ci = effect.apply_to_readings(values, ci, np.random.default_rng(stream), self.instrument)
        return values, ci, np.array(hits_all, dtype=np.int64)

    def _detector_psa(self) -> np.ndarray:
        ap = self.effects.aperture
        assert ap is not None
        return ap.psa()

    # -- the exact reference ---------------------------------------------------------------------
    def reference(self) -> tuple[np.ndarray, bool]:
        """The expected reading for every wavelength and column of :attr:`SceneResult.values`,
        and whether it is exact (quadrature of the model or a closed form) or approximate
        (e.g. a conical beam on a non-Lambertian specimen, near-field detectors).

        Declared noise has mean zero and does not change the reference.
        """
        if self.instrument == "physical":
            raise InputError("a physical scene has no simulated reference")
        e = self.effects
        exact = True
        lambert = isinstance(self.specimen, Lambertian)
        if self.beam.kind == "conical" and not lambert and self.observable != "missed":
            exact = False
        out = []
        for w in self.wavelengths:
            if self.observable == "missed":
                out.append([self._missed_fraction()])
                continue
            if e.bandpass is not None:
                nodes, wts = e.bandpass.grid(float(w))
            else:
                nodes, wts = np.array([float(w)]), np.array([1.0])
            acc = None
            for x, wt in zip(nodes, wts):
                v = self._reference_at(float(x))
                acc = wt * v if acc is None else acc + wt * v
            out.append(acc)
        if e.aperture is not None and e.aperture.near:
            exact = False
        if e.sphere is not None and not lambert:
            exact = False
        ref = np.array(out, dtype=float)
        for effect in e.extra:
            expected = effect.expected(ref)
            if expected is None:
                exact = False
            else:
                ref = np.asarray(expected, dtype=float)
        return ref, exact

    def _modulation(self) -> float:
        sp = self.effects.specimen
        if sp is None or sp.uniform:
            return 1.0
        r = sp.spot_radius_mm if self.beam.kind == "collimated" else self.beam.specimen_radius_mm
        return sp.mean_modulation(r)

    def _missed_fraction(self) -> float:
        """Closed form: a conical ray misses when its emitter point lies beyond the line
        x1 = D cot(theta_i) of the emitter disk (a circular segment)."""
        if self.beam.kind != "conical":
            return 0.0
        t = math.radians(self.incidence[0])
        r1, d = self.beam.emitter_radius_mm, self.beam.distance_mm
        if self.incidence[0] > 90.0:
            t = math.pi - t
        h = d * math.cos(t) / math.sin(t) if math.sin(t) > 0 else math.inf
        if h >= r1:
            return 0.0
        if h <= -r1:
            return 1.0
        return (r1 * r1 * math.acos(h / r1) - h * math.sqrt(r1 * r1 - h * h)) / (math.pi * r1 * r1)

    def _reference_at(self, wl: float) -> np.ndarray:
        e = self.effects
        m = self._modulation()
        s = e.stray_light.fraction if e.stray_light is not None else 0.0
        wi = self.wi
        if self.instrument == "spectrophotometer":
            col = Collector("equal-psa", 4, 4)
            r = integrate_patches(self.specimen, wi, col, wl)
            if self.observable == "transmittance":
                return np.array([(1.0 - s) * m * r.transmittance])
            refl = r.reflectance
            if e.sphere is not None:
                r_diff = refl  # exact for a Lambertian specimen
                # stray light reaches the detector directly (it is counted as detected)
                eff = s + (1.0 - s) * e.sphere.efficiency(m * refl, r_diff)
                return np.array([e.sphere.reference_reflectance * eff / e.sphere.reference_efficiency()])
            if e.gloss_trap is not None and e.gloss_trap.specular == "excluded":
                refl = refl - cone_probability(self.specimen, wi, self._mirror_axis(), e.gloss_trap.half_angle_deg, wl)
            return np.array([(1.0 - s) * m * refl + s])
        p = integrate_patches(self.specimen, wi, self.collector, wl).p
        psa = np.asarray(self.collector.psa)
        f = (1.0 - s) * m * p / psa
        f[: self.collector.n_patches] += s / math.pi
        if e.aperture is not None:
            ap = e.aperture
            pd = np.array([cone_probability(self.specimen, wi, a, ap.half_angle_deg, wl) for a in ap.axes()])
            fd = (1.0 - s) * m * pd / ap.psa() + s / math.pi
            f = np.concatenate([f, fd])
        return f

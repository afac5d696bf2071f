"""Scenes: a measurement setup and the effects it calls for, simulated with only those effects.

A :class:`Scene` is a specimen, an instrument (``spectrophotometer``, ``goniophotometer``, or a
``physical`` bench whose scan durations are estimated), a beam, a collector, wavelengths, an
incidence, a ray budget and a set of declared :class:`Effects`. :meth:`Scene.run` composes only
what is declared:

* nothing declared -> the bare kernels of :mod:`virtual.engine` (or the exact fast path), at
  their full speed;
* per-ray effects (stray light, bandpass, integrating sphere, non-uniform specimen, finite
  detector apertures) -> the effect kernels of :mod:`virtual.effects`, with one branch per
  declared effect;
* effects on readings (instrument noise, gloss trap) -> a few array operations after counting
  (the gloss trap's specular cone is tallied by the bare kernel anyway).

Positions on the specimen are sampled only when an effect needs them (a non-uniform specimen,
or detectors at a finite distance): a uniform specimen with far-field detectors draws exactly
the bare kernel's random numbers. :func:`effect_costs` measures what each declared effect adds.

TOML (``fixtures/scenes/*.toml``)::

    name = "lambert-8d"
    instrument = "spectrophotometer"        # or "goniophotometer", "physical"
    specimen = "lambert:reflectance=0.6"
    wavelengths = "550"                     # START:STOP:STEP, a,b,c or one number (nm)
    incidence = [8, 0]                      # theta_i, phi_i (deg)
    rays = 1000000                          # or uncertainty + delta (eq. 3.5 / 3.12)
    uncertainty = 0.01
    delta = 0.01
    seed = 1
    observable = "reflectance"              # spectro: reflectance | transmittance | missed
    method = "auto"                         # auto | rays | fast

    [beam]            # Beam fields: kind, emitter_radius_mm, specimen_radius_mm, distance_mm, disk_sampling
    [collector]       # spec = "equal-psa:9x36"
    [effects.aperture]     half_angle_deg, views = [[theta_r, phi_r], ...], distance_mm (near field)
    [effects.noise]        uncertainty, relative (default: false spectro, true gonio)
    [effects.stray_light]  fraction
    [effects.sphere]       wall_reflectance (0.970-0.985), port_fraction (<= 0.10),
                           detector_port, specimen_port, reference_reflectance
    [effects.gloss_trap]   specular = "excluded" | "included", half_angle_deg
    [effects.bandpass]     fwhm_nm, nodes (triangular slit function)
    [effects.specimen]     uniform = false, period_mm, contrast, spot_radius_mm
    [tradeoff]             see :mod:`virtual.tradeoff`
    [physical]             see :mod:`virtual.tradeoff` (scan duration vs step and averaging)
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from bench.core.errors import ConfigError, InputError
from virtual.beam import Beam, check_incidence
from virtual.collector import Collector, parse_collector
from virtual.engine import single_chunk_threads
from virtual.specimens import Lambertian, Specimen, parse_specimen

__all__ = [
    "Aperture", "Noise", "StrayLight", "Sphere", "GlossTrap", "Bandpass", "SpecimenPattern", "Effects",
    "Scene", "SceneResult", "load_scene", "scene_from_dict", "effect_costs", "cone_probability",
    "EFFECT_NAMES", "INSTRUMENTS",
]

INSTRUMENTS = ("spectrophotometer", "goniophotometer", "physical")
OBSERVABLES = ("reflectance", "transmittance", "missed")
EFFECT_NAMES = ("aperture", "noise", "stray_light", "sphere", "gloss_trap", "bandpass", "specimen")


def _num(d: Mapping[str, Any], key: str, where: str, default: Any = None, lo: float = -math.inf,
         hi: float = math.inf) -> float:
    v = d.get(key, default)
    if v is None:
        raise ConfigError(f"{where}.{key} is required")
    try:
        f = float(v)
    except (TypeError, ValueError):
        raise ConfigError(f"{where}.{key} must be a number, got {v!r}") from None
    if not (math.isfinite(f) and lo <= f <= hi):
        raise ConfigError(f"{where}.{key} must lie in [{lo:g}, {hi:g}], got {v!r}")
    return f


# --- effects ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Aperture:
    """Finite detector apertures at viewing directions ``views`` ((theta_r, phi_r) deg).

    Far field (``distance_mm`` None): the detector collects directions within ``half_angle_deg``
    of its axis. Near field: a disk of radius ``distance_mm * tan(half_angle)`` at that
    distance, hit by rays leaving from where they met the specimen (positions sampled)."""

    half_angle_deg: float = 2.0
    views: tuple[tuple[float, float], ...] = ((0.0, 0.0),)
    distance_mm: float | None = None

    def __post_init__(self) -> None:
        if not (0.0 < self.half_angle_deg < 45.0):
            raise ConfigError(f"effects.aperture.half_angle_deg must lie in (0, 45), got {self.half_angle_deg}")
        if self.distance_mm is not None and not (math.isfinite(self.distance_mm) and self.distance_mm > 0):
            raise ConfigError(f"effects.aperture.distance_mm must be > 0, got {self.distance_mm}")
        if not self.views:
            raise ConfigError("effects.aperture.views must list at least one [theta_r, phi_r]")
        for t, _ in self.views:
            if not 0.0 <= t + self.half_angle_deg < 90.0:
                raise ConfigError(f"effects.aperture: a detector at theta_r = {t} deg with half-angle "
                                  f"{self.half_angle_deg} deg reaches the horizon")

    @property
    def near(self) -> bool:
        return self.distance_mm is not None

    def axes(self) -> np.ndarray:
        from bench.core.geometry import direction

        return np.array([direction(t, p) for t, p in self.views])

    def rows(self) -> np.ndarray:
        """Detector rows for the kernel: axis (3), cos(half-angle)."""
        c = math.cos(math.radians(self.half_angle_deg))
        return np.column_stack([self.axes(), np.full(len(self.views), c)])

    def psa(self) -> np.ndarray:
        """Projected solid angle of each detector's cone: pi sin^2(beta) cos(theta_r) (exact for a
        circular cap above the horizon)."""
        s2 = math.sin(math.radians(self.half_angle_deg)) ** 2
        return np.array([math.pi * s2 * math.cos(math.radians(t)) for t, _ in self.views])


@dataclass(frozen=True)
class Noise:
    """Instrument noise: Gaussian, standard deviation ``uncertainty`` (absolute, or relative to
    the reading), added to every reading; intervals are widened accordingly."""

    uncertainty: float = 0.002
    relative: bool | None = None


@dataclass(frozen=True)
class StrayLight:
    """A fraction of the incident flux reaching the detector without meeting the specimen."""

    fraction: float = 0.001

    def __post_init__(self) -> None:
        if not 0.0 <= self.fraction < 1.0:
            raise ConfigError(f"effects.stray_light.fraction must lie in [0, 1), got {self.fraction}")


@dataclass(frozen=True)
class Sphere:
    """Integrating sphere: wall reflectance 0.970-0.985, ports <= 10 % of its area (detector and
    specimen ports included), calibrated against a Lambertian white of ``reference_reflectance``
    (single-beam substitution; the substitution error is part of the result)."""

    wall_reflectance: float = 0.98
    port_fraction: float = 0.05
    detector_port: float = 0.01
    specimen_port: float = 0.02
    reference_reflectance: float = 0.99

    def __post_init__(self) -> None:
        if not 0.970 <= self.wall_reflectance <= 0.985:
            raise ConfigError(f"effects.sphere.wall_reflectance must lie in [0.970, 0.985], got {self.wall_reflectance}")
        if not 0.0 < self.port_fraction <= 0.10:
            raise ConfigError(f"effects.sphere.port_fraction must lie in (0, 0.10], got {self.port_fraction}")
        if not (0 < self.detector_port and 0 <= self.specimen_port
                and self.detector_port + self.specimen_port <= self.port_fraction):
            raise ConfigError("effects.sphere: detector_port + specimen_port must be > 0 and fit in port_fraction")
        if not 0.0 < self.reference_reflectance <= 1.0:
            raise ConfigError(f"effects.sphere.reference_reflectance must lie in (0, 1], got {self.reference_reflectance}")

    def efficiency(self, r_dir: float, r_diffuse: float) -> float:
        """Detected fraction of the flux for a specimen of directional reflectance ``r_dir`` and
        diffuse-illumination reflectance ``r_diffuse`` (no stray light)."""
        keep = (1.0 - self.port_fraction) * self.wall_reflectance
        return r_dir * self.detector_port / (1.0 - keep - self.specimen_port * r_diffuse)

    def reference_efficiency(self) -> float:
        return self.efficiency(self.reference_reflectance, self.reference_reflectance)


@dataclass(frozen=True)
class GlossTrap:
    """Specular component excluded (``8/de``-like) or included, over a cone of ``half_angle_deg``
    around the mirror direction."""

    specular: str = "excluded"
    half_angle_deg: float = 4.0

    def __post_init__(self) -> None:
        if self.specular not in ("excluded", "included"):
            raise ConfigError(f"effects.gloss_trap.specular must be 'excluded' or 'included', got {self.specular!r}")
        if not 0.0 < self.half_angle_deg < 45.0:
            raise ConfigError(f"effects.gloss_trap.half_angle_deg must lie in (0, 45), got {self.half_angle_deg}")


@dataclass(frozen=True)
class Bandpass:
    """Triangular slit function of full width at half maximum ``fwhm_nm``, discretised in
    ``nodes`` wavelengths over +-fwhm (each ray draws its wavelength)."""

    fwhm_nm: float = 10.0
    nodes: int = 9

    def __post_init__(self) -> None:
        if not (self.fwhm_nm > 0 and math.isfinite(self.fwhm_nm)):
            raise ConfigError(f"effects.bandpass.fwhm_nm must be > 0, got {self.fwhm_nm}")
        if not 3 <= int(self.nodes) <= 257 or int(self.nodes) % 2 == 0:
            raise ConfigError(f"effects.bandpass.nodes must be odd, in [3, 257], got {self.nodes}")

    def grid(self, centre_nm: float) -> tuple[np.ndarray, np.ndarray]:
        """Node wavelengths and weights (sum 1)."""
        x = np.linspace(-self.fwhm_nm, self.fwhm_nm, int(self.nodes))
        w = np.maximum(1.0 - np.abs(x) / self.fwhm_nm, 0.0)
        w[0] = w[-1] = 0.0
        keep = w > 0
        return centre_nm + x[keep], w[keep] / w[keep].sum()


@dataclass(frozen=True)
class SpecimenPattern:
    """A spatially non-uniform specimen: its reflectance is modulated by
    ``m(x) = 1 - contrast (1 + cos(2 pi x / period)) / 2`` across the illuminated spot
    (radius ``spot_radius_mm`` for a collimated beam; the specimen disk for a conical one)."""

    uniform: bool = True
    period_mm: float = 5.0
    contrast: float = 0.5
    spot_radius_mm: float = 10.0

    def __post_init__(self) -> None:
        if not (0.0 <= self.contrast <= 1.0):
            raise ConfigError(f"effects.specimen.contrast must lie in [0, 1], got {self.contrast}")
        if not (self.period_mm > 0 and self.spot_radius_mm > 0):
            raise ConfigError("effects.specimen.period_mm and spot_radius_mm must be > 0")

    def mean_modulation(self, radius_mm: float) -> float:
        """Exact mean of m over a disk of ``radius_mm``: 1 - c/2 (1 + 2 J1(kr)/(kr))."""
        from scipy.special import j1

        kr = 2.0 * math.pi / self.period_mm * radius_mm
        return 1.0 - 0.5 * self.contrast * (1.0 + 2.0 * float(j1(kr)) / kr)


@dataclass(frozen=True)
class Effects:
    """The effects a scene declares (``None``: not declared)."""

    aperture: Aperture | None = None
    noise: Noise | None = None
    stray_light: StrayLight | None = None
    sphere: Sphere | None = None
    gloss_trap: GlossTrap | None = None
    bandpass: Bandpass | None = None
    specimen: SpecimenPattern | None = None

    def declared(self) -> list[str]:
        return [n for n in EFFECT_NAMES if getattr(self, n) is not None
                and not (n == "specimen" and self.specimen.uniform)]  # type: ignore[union-attr]

    def only(self, *names: str) -> "Effects":
        return Effects(**{n: getattr(self, n) for n in names})


def _effects_from_dict(d: Mapping[str, Any]) -> Effects:
    unknown = set(d) - set(EFFECT_NAMES)
    if unknown:
        raise ConfigError(f"unknown effect(s) {', '.join(sorted(unknown))}; known: {', '.join(EFFECT_NAMES)}")

    def table(name: str) -> Mapping[str, Any] | None:
        t = d.get(name)
        if t is None or t is False:
            return None
        if t is True:
            return {}
        if not isinstance(t, Mapping):
            raise ConfigError(f"effects.{name} must be a table")
        return t

    kw: dict[str, Any] = {}
    try:
        if (t := table("aperture")) is not None:
            views = tuple((float(v[0]), float(v[1]) if len(v) > 1 else 0.0) for v in t.get("views", [[0, 0]]))
            dist = t.get("distance_mm")
            kw["aperture"] = Aperture(_num(t, "half_angle_deg", "effects.aperture", 2.0), views,
                                      None if dist is None else float(dist))
        if (t := table("noise")) is not None:
            rel = t.get("relative")
            kw["noise"] = Noise(_num(t, "uncertainty", "effects.noise", 0.002, 0.0, 1.0),
                                None if rel is None else bool(rel))
        if (t := table("stray_light")) is not None:
            kw["stray_light"] = StrayLight(_num(t, "fraction", "effects.stray_light", 0.001))
        if (t := table("sphere")) is not None:
            kw["sphere"] = Sphere(**{k: float(v) for k, v in t.items()})
        if (t := table("gloss_trap")) is not None:
            kw["gloss_trap"] = GlossTrap(str(t.get("specular", "excluded")),
                                         _num(t, "half_angle_deg", "effects.gloss_trap", 4.0))
        if (t := table("bandpass")) is not None:
            kw["bandpass"] = Bandpass(_num(t, "fwhm_nm", "effects.bandpass", 10.0), int(t.get("nodes", 9)))
        if (t := table("specimen")) is not None:
            kw["specimen"] = SpecimenPattern(bool(t.get("uniform", False)), _num(t, "period_mm", "effects.specimen", 5.0),
                                             _num(t, "contrast", "effects.specimen", 0.5),
                                             _num(t, "spot_radius_mm", "effects.specimen", 10.0))
    except TypeError as exc:
        raise ConfigError(f"effects: {exc}") from None
    return Effects(**kw)


# --- results ------------------------------------------------------------------------------------


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
    x, w = np.polynomial.legendre.leggauss(order)
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
        if self.method == "fast" and not self.fast_path_possible():
            raise ConfigError("method 'fast' needs a collimated beam, a specimen with a density and no "
                              "per-ray effect")

    # -- what is declared ----------------------------------------------------------------------
    @property
    def n_rays(self) -> int:
        from virtual.bounds import hoeffding_rays

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
        from virtual import effects as fx

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
        from bench.core.geometry import direction

        return direction(*self.incidence)

    def _mirror_axis(self) -> np.ndarray:
        w = self.wi
        return np.array([-w[0], -w[1], w[2]])

    def _cone(self) -> np.ndarray:
        from virtual.engine import NO_CONE

        g = self.effects.gloss_trap
        if g is None:
            return NO_CONE
        return np.array([*self._mirror_axis(), math.cos(math.radians(g.half_angle_deg))])

    def _effect_args(self) -> np.ndarray:
        from virtual.effects import N_EFFECT_ARGS

        e = self.effects
        v = np.zeros(N_EFFECT_ARGS)
        if e.stray_light is not None:
            v[0] = e.stray_light.fraction
        if e.sphere is not None:
            s = e.sphere
            v[1:5] = [s.wall_reflectance, s.detector_port, s.specimen_port, s.port_fraction]
        v[5] = 1.0
        # the illuminated spot (positions of a collimated beam): the specimen disk by default
        v[7] = self.beam.specimen_radius_mm
        if e.specimen is not None:
            v[5], v[6], v[7] = e.specimen.period_mm, e.specimen.contrast, e.specimen.spot_radius_mm
        if e.aperture is not None and e.aperture.near:
            d = float(e.aperture.distance_mm)  # type: ignore[arg-type]
            v[8], v[9] = d, d * math.tan(math.radians(e.aperture.half_angle_deg))
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
        from virtual.engine import measurement_seed

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
                with single_chunk_threads(n):
                    c = self._ray_counts(float(w), n, seq, flags)
            counts.append(np.asarray(c, dtype=np.int64))
        values, ci, hits = self._readings(counts, n, sd)
        seconds = time.perf_counter() - t0
        return SceneResult(wavelengths=wl, values=values, ci=ci, counts=counts, N=n, hits=hits, method=out_method,
                           seconds=seconds, effects=self.effects.declared(), positions_sampled=self.needs_positions,
                           probabilities=np.array(probs) if probs else None)

    def _ray_counts(self, wl: float, n: int, seq: np.random.SeedSequence, flags: int) -> np.ndarray:
        from virtual import effects as fx
        from virtual import engine

        b = self.beam.kernel_args(*self.incidence)
        sp = self.specimen
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

    def bin_probabilities(self, wl: float) -> np.ndarray:
        """Exact probabilities of the kernel's bins for a collimated beam and no per-ray effect
        (quadrature of the specimen's density): gonio bins + absorbed + missed, or spectro
        (reflected, transmitted, absorbed)."""
        from virtual.quadrature import integrate_patches

        col = self.collector if self.instrument == "goniophotometer" else Collector("equal-psa", 4, 4)
        r = integrate_patches(self.specimen, self.wi, col, wl)
        p = np.clip(r.p, 0.0, 1.0)
        absorbed = max(0.0, 1.0 - p.sum())
        if self.instrument == "goniophotometer":
            return np.concatenate([p / max(1.0, p.sum()), [absorbed, 0.0]])
        return np.array([r.reflectance, r.transmittance, absorbed]) / max(1.0, r.albedo)

    def _fast_counts(self, wl: float, n: int, seq: np.random.SeedSequence) -> tuple[np.ndarray, np.ndarray]:
        from virtual.engine import multinomial_counts

        p = self.bin_probabilities(wl)
        c = multinomial_counts(p, n, seq)
        if self.instrument == "spectrophotometer":
            return np.array([c[0], c[1], c[2], 0, 0, 0, 0], dtype=np.int64), p
        return c, p

    def _readings(self, counts: list[np.ndarray], n: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        from scipy.stats import norm

        from virtual.bounds import binomial_ci

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
        return np.array(out, dtype=float), exact

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
        from virtual.quadrature import integrate_patches

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


# --- loading ------------------------------------------------------------------------------------


def scene_from_dict(d: Mapping[str, Any], name: str = "scene") -> Scene:
    """Build a :class:`Scene` from its TOML table; errors name the key."""
    from virtual.spectrophotometer import parse_wavelengths

    d = dict(d)
    known = {"name", "instrument", "specimen", "wavelengths", "incidence", "rays", "uncertainty", "delta", "seed",
             "observable", "method", "beam", "collector", "effects", "tradeoff", "physical"}
    unknown = set(d) - known
    if unknown:
        raise ConfigError(f"scene: unknown key(s) {', '.join(sorted(unknown))}; known: {', '.join(sorted(known))}")
    instrument = str(d.get("instrument", "spectrophotometer"))
    spec = d.get("specimen", "lambert:reflectance=0.5")
    if instrument == "physical" and "specimen" not in d:
        spec = "lambert:reflectance=0.5"
    specimen = parse_specimen(spec if not isinstance(spec, Mapping) else spec.get("spec", ""))
    beam_t = d.get("beam", {})
    if isinstance(beam_t, str):
        beam_t = {"kind": beam_t}
    try:
        beam = Beam(**{k: (float(v) if k.endswith("_mm") else v) for k, v in dict(beam_t).items()})
    except TypeError as exc:
        raise ConfigError(f"scene.beam: {exc}") from None
    col_t = d.get("collector", "equal-psa:9x36")
    collector = parse_collector(col_t.get("spec", "equal-psa:9x36") if isinstance(col_t, Mapping) else col_t)
    method = str(d.get("method", col_t.get("method", "auto") if isinstance(col_t, Mapping) else "auto"))
    inc = d.get("incidence", [8.0, 0.0])
    inc = [inc] if isinstance(inc, (int, float)) else list(inc)
    if not 1 <= len(inc) <= 2:
        raise ConfigError(f"scene.incidence must be [theta_i, phi_i], got {d.get('incidence')!r}")
    incidence = (float(inc[0]), float(inc[1]) if len(inc) > 1 else 0.0)
    rays = d.get("rays")
    if rays is not None:
        rays = int(float(rays))
    wl = tuple(float(x) for x in parse_wavelengths(d.get("wavelengths", "550")))
    effects = _effects_from_dict(d.get("effects", {}) or {})
    return Scene(specimen=specimen, instrument=instrument, beam=beam, collector=collector, wavelengths=wl,
                 incidence=incidence, rays=rays, uncertainty=_num(d, "uncertainty", "scene", 0.01, 0.0, 1.0),
                 delta=_num(d, "delta", "scene", 0.01, 0.0, 1.0), seed=int(d.get("seed", 1)),
                 observable=str(d.get("observable", "reflectance")), method=method, effects=effects,
                 name=str(d.get("name", name)), tradeoff=dict(d.get("tradeoff", {}) or {}),
                 physical=dict(d.get("physical", {}) or {}))


def load_scene(path: str | Path) -> Scene:
    """Read a scene TOML file (a :class:`~bench.core.errors.ConfigError` names what is wrong)."""
    from bench.config import read_toml

    p = Path(path)
    return scene_from_dict(read_toml(p), name=p.stem)


# --- costs --------------------------------------------------------------------------------------


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

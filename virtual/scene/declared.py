"""The effects a scene declares: one frozen dataclass per ``[effects.*]`` table, validated once.

:class:`Effects` gathers them; :func:`effects_from_dict` reads the TOML tables (unknown tables
and keys are refused). What each effect does to the rays is :mod:`virtual.effects`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from bench.core.errors import ConfigError
from bench.core.geometry import direction

__all__ = ["Aperture", "Noise", "StrayLight", "Sphere", "GlossTrap", "Bandpass", "SpecimenPattern", "Effects",
           "EFFECT_NAMES", "effects_from_dict", "num"]

EFFECT_NAMES = ("aperture", "noise", "stray_light", "sphere", "gloss_trap", "bandpass", "specimen")


def num(d: Mapping[str, Any], key: str, where: str, default: Any = None, lo: float = -math.inf,
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


def effects_from_dict(d: Mapping[str, Any]) -> Effects:
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
            kw["aperture"] = Aperture(num(t, "half_angle_deg", "effects.aperture", 2.0), views,
                                      None if dist is None else float(dist))
        if (t := table("noise")) is not None:
            rel = t.get("relative")
            kw["noise"] = Noise(num(t, "uncertainty", "effects.noise", 0.002, 0.0, 1.0),
                                None if rel is None else bool(rel))
        if (t := table("stray_light")) is not None:
            kw["stray_light"] = StrayLight(num(t, "fraction", "effects.stray_light", 0.001))
        if (t := table("sphere")) is not None:
            kw["sphere"] = Sphere(**{k: float(v) for k, v in t.items()})
        if (t := table("gloss_trap")) is not None:
            kw["gloss_trap"] = GlossTrap(str(t.get("specular", "excluded")),
                                         num(t, "half_angle_deg", "effects.gloss_trap", 4.0))
        if (t := table("bandpass")) is not None:
            kw["bandpass"] = Bandpass(num(t, "fwhm_nm", "effects.bandpass", 10.0), int(t.get("nodes", 9)))
        if (t := table("specimen")) is not None:
            kw["specimen"] = SpecimenPattern(bool(t.get("uniform", False)), num(t, "period_mm", "effects.specimen", 5.0),
                                             num(t, "contrast", "effects.specimen", 0.5),
                                             num(t, "spot_radius_mm", "effects.specimen", 10.0))
    except TypeError as exc:
        raise ConfigError(f"effects: {exc}") from None
    return Effects(**kw)

"""The effects a scene declares: one class per ``[effects.*]`` table.

Each class is the table's declared schema (:mod:`bench.core.schemas`: its settings, ranges and
one-line errors, the same the scene files are validated with) plus what the effect computes.
:class:`Effects` gathers them, with the effects of installed packages (:class:`ReadingEffect`,
entry point group ``goniobench.effects``); :func:`effects_from_dict` reads the ``[effects]``
tables. What each effect does to the rays is :mod:`virtual.effects`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from bench.core.errors import ConfigError
from bench.core.geometry import direction
from bench.core.schemas import (EFFECT_SCHEMAS, ApertureEffect, BandpassEffect, GlossTrapEffect,
                                NoiseEffect, SceneEffect, Settings, SpecimenEffect, SphereEffect,
                                StrayLightEffect, plugin_effects, scene_schema, validate_document)

__all__ = ["Aperture", "Noise", "StrayLight", "Sphere", "GlossTrap", "Bandpass", "SpecimenPattern", "Effects",
           "EFFECT_NAMES", "ReadingEffect", "effects_from_dict"]

#: the ``[effects.NAME]`` keys, in the order effects are listed (declared in bench.core.schemas)
EFFECT_NAMES = tuple(EFFECT_SCHEMAS)


class _Settings(Settings):
    """Built from Python, an effect takes its settings by keyword or position and refuses a bad
    value with one :class:`ConfigError` naming ``effects.NAME``, the key and the value."""

    def __init_subclass__(cls, **kw: Any) -> None:
        super().__init_subclass__(**kw)
        cls.settings_of = f"effects.{getattr(cls, 'effect_name', '')}"


# --- effects ------------------------------------------------------------------------------------


class Aperture(_Settings, ApertureEffect):
    """Finite detector apertures at viewing directions ``views`` ((theta_r, phi_r) deg).

    Far field (``distance_mm`` None): the detector collects directions within ``half_angle_deg``
    of its axis. Near field: a disk of radius ``distance_mm * tan(half_angle)`` at that
    distance, hit by rays leaving from where they met the specimen (positions sampled)."""

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


class Noise(_Settings, NoiseEffect):
    """Instrument noise: Gaussian, standard deviation ``uncertainty`` (absolute, or relative to
    the reading), added to every reading; intervals are widened accordingly."""


class StrayLight(_Settings, StrayLightEffect):
    """A fraction of the incident flux reaching the detector without meeting the specimen."""


class Sphere(_Settings, SphereEffect):
    """Integrating sphere calibrated against a Lambertian white of ``reference_reflectance``
    (single-beam substitution; the substitution error is part of the result)."""

    def efficiency(self, r_dir: float, r_diffuse: float) -> float:
        """Detected fraction of the flux for a specimen of directional reflectance ``r_dir`` and
        diffuse-illumination reflectance ``r_diffuse`` (no stray light)."""
        keep = (1.0 - self.port_fraction) * self.wall_reflectance
        return r_dir * self.detector_port / (1.0 - keep - self.specimen_port * r_diffuse)

    def reference_efficiency(self) -> float:
        return self.efficiency(self.reference_reflectance, self.reference_reflectance)


class GlossTrap(_Settings, GlossTrapEffect):
    """Specular component excluded (``8/de``-like) or included, over a cone of ``half_angle_deg``
    around the mirror direction."""


class Bandpass(_Settings, BandpassEffect):
    """Triangular slit function of full width at half maximum ``fwhm_nm``, discretised in
    ``nodes`` wavelengths over +-fwhm (each ray draws its wavelength)."""

    def grid(self, centre_nm: float) -> tuple[np.ndarray, np.ndarray]:
        """Node wavelengths and weights (sum 1)."""
        x = np.linspace(-self.fwhm_nm, self.fwhm_nm, int(self.nodes))
        w = np.maximum(1.0 - np.abs(x) / self.fwhm_nm, 0.0)
        w[0] = w[-1] = 0.0
        keep = w > 0
        return centre_nm + x[keep], w[keep] / w[keep].sum()


class SpecimenPattern(_Settings, SpecimenEffect):
    """A spatially non-uniform specimen: its reflectance is modulated by
    ``m(x) = 1 - contrast (1 + cos(2 pi x / period)) / 2`` across the illuminated spot
    (radius ``spot_radius_mm`` for a collimated beam; the specimen disk for a conical one)."""

    def mean_modulation(self, radius_mm: float) -> float:
        """Exact mean of m over a disk of ``radius_mm``: 1 - c/2 (1 + 2 J1(kr)/(kr))."""
        from scipy.special import j1

        kr = 2.0 * math.pi / self.period_mm * radius_mm
        return 1.0 - 0.5 * self.contrast * (1.0 + 2.0 * float(j1(kr)) / kr)


class ReadingEffect(SceneEffect):
    """Base of an effect a lab's package adds (entry point group ``goniobench.effects``): its
    settings are its pydantic fields (with ``effect_name``, the ``[effects.NAME]`` key), and it
    acts on the readings after counting, as instrument noise does.

    ``apply_to_readings(values, ci, rng, instrument)`` returns the new readings and intervals
    (arrays shaped like :attr:`SceneResult.values` and ``.ci``; ``rng`` is the effect's own
    stream of the scene's seed). ``expected(reference)`` returns the expected readings given
    those without the effect, or None when unknown (then :meth:`Scene.reference` is not exact).
    """

    def apply_to_readings(self, values: np.ndarray, ci: np.ndarray, rng: np.random.Generator,
                          instrument: str) -> tuple[np.ndarray, np.ndarray]:
        raise NotImplementedError(f"effect {self.effect_name} declares no apply_to_readings")

    def expected(self, reference: np.ndarray) -> np.ndarray | None:
        return None


#: the class computing each declared effect, by its ``[effects.NAME]`` key
EFFECT_CLASSES: dict[str, type[SceneEffect]] = {
    c.effect_name: c for c in (Aperture, Noise, StrayLight, Sphere, GlossTrap, Bandpass, SpecimenPattern)}
if tuple(EFFECT_CLASSES) != EFFECT_NAMES:  # pragma: no cover - a declaration without its computation
    raise ImportError(f"virtual.scene computes effects {tuple(EFFECT_CLASSES)}, the schema declares {EFFECT_NAMES}")


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
    extra: tuple[ReadingEffect, ...] = ()  # effects of installed plugins, in the order declared

    def declared(self) -> list[str]:
        return [n for n in EFFECT_NAMES if getattr(self, n) is not None
                and not (n == "specimen" and self.specimen.uniform)] + [  # type: ignore[union-attr]
            e.effect_name for e in self.extra]

    def only(self, *names: str) -> "Effects":
        return Effects(**{n: getattr(self, n) for n in names if n in EFFECT_NAMES},
                       extra=tuple(e for e in self.extra if e.effect_name in names))


def effects_from_table(table: Any) -> Effects:
    """The :class:`Effects` of a validated ``[effects]`` table (``true``: an effect's defaults);
    the table of :func:`bench.core.schemas.scene_schema` may hold installed plugins' effects."""
    kw: dict[str, Any] = {}
    for name, cls in EFFECT_CLASSES.items():
        value = getattr(table, name)
        if value is True:
            kw[name] = cls()
        elif isinstance(value, SceneEffect):
            kw[name] = cls.model_construct(value.model_fields_set, **dict(value))
    extra = []
    for name, cls in plugin_effects().items():
        value = getattr(table, name, None)
        if value is None or value is False:
            continue
        effect = cls() if value is True else value
        if not isinstance(effect, ReadingEffect):
            raise ConfigError(f"effects.{name}: a plugin's effect must derive from virtual.scene.ReadingEffect, "
                              f"got {type(effect).__module__}.{type(effect).__qualname__}")
        extra.append(effect)
    return Effects(**kw, extra=tuple(extra))


def effects_from_dict(d: Mapping[str, Any], source: str = "effects") -> Effects:
    """Read the ``[effects]`` tables (unknown effects and keys, bad values: one :class:`ConfigError`)."""
    table = scene_schema().model_fields["effects"].annotation
    return effects_from_table(validate_document(table, d, source))

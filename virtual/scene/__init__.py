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
    [effects.NAME]         an effect an installed package adds (entry points "goniobench.effects":
                           a :class:`ReadingEffect` acting on the readings, like noise)
    [tradeoff]             see :mod:`virtual.tradeoff`
    [physical]             see :mod:`virtual.tradeoff` (scan duration vs step and averaging)

Modules: :mod:`~virtual.scene.declared` (the effects' tables), :mod:`~virtual.scene.simulate`
(:class:`Scene`, :class:`SceneResult`), :mod:`~virtual.scene.loading` (TOML),
:mod:`~virtual.scene._costs` (:func:`effect_costs`).
"""

from __future__ import annotations

from virtual.scene._costs import effect_costs
from virtual.scene.declared import (EFFECT_NAMES, Aperture, Bandpass, Effects, GlossTrap, Noise, ReadingEffect,
                                    SpecimenPattern, Sphere, StrayLight)
from virtual.scene.loading import load_scene, scene_from_dict
from virtual.scene.simulate import INSTRUMENTS, OBSERVABLES, Scene, SceneResult, cone_probability

__all__ = [
    "Aperture", "Noise", "StrayLight", "Sphere", "GlossTrap", "Bandpass", "SpecimenPattern", "Effects",
    "Scene", "SceneResult", "load_scene", "scene_from_dict", "effect_costs", "cone_probability",
    "EFFECT_NAMES", "INSTRUMENTS", "OBSERVABLES", "ReadingEffect",
]

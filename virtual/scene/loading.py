"""Reading scenes: a TOML file or a mapping to a :class:`~virtual.scene.simulate.Scene`
(see :mod:`virtual.scene` for the format); every error is a :class:`ConfigError` naming the key.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

from bench.core.errors import ConfigError
from bench.core.parsing import parse_wavelengths, read_toml
from virtual.beam import Beam
from virtual.collector import parse_collector
from virtual.scene.declared import effects_from_dict, num
from virtual.scene.simulate import Scene
from virtual.specimens import parse_specimen

__all__ = ["scene_from_dict", "load_scene"]


def scene_from_dict(d: Mapping[str, Any], name: str = "scene") -> Scene:
    """Build a :class:`Scene` from its TOML table; errors name the key."""
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
    effects = effects_from_dict(d.get("effects", {}) or {})
    return Scene(specimen=specimen, instrument=instrument, beam=beam, collector=collector, wavelengths=wl,
                 incidence=incidence, rays=rays, uncertainty=num(d, "uncertainty", "scene", 0.01, 0.0, 1.0),
                 delta=num(d, "delta", "scene", 0.01, 0.0, 1.0), seed=int(d.get("seed", 1)),
                 observable=str(d.get("observable", "reflectance")), method=method, effects=effects,
                 name=str(d.get("name", name)), tradeoff=dict(d.get("tradeoff", {}) or {}),
                 physical=dict(d.get("physical", {}) or {}))


def load_scene(path: str | Path) -> Scene:
    """Read a scene TOML file (a :class:`~bench.core.errors.ConfigError` names what is wrong)."""
    p = Path(path)
    return scene_from_dict(read_toml(p), name=p.stem)

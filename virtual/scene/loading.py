"""Reading scenes: a TOML file or a mapping to a :class:`~virtual.scene.simulate.Scene`
(see :mod:`virtual.scene` for the format).

The document is validated by its declared schema (:func:`bench.core.schemas.scene_schema`:
:class:`~bench.core.schemas.SceneFile` with the installed plugins' effects), which refuses unknown keys, wrong types and
out-of-range values in one :class:`ConfigError` line naming the file, key and value; this module
only turns the validated tables into the scene's objects.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

from bench.core.parsing import parse_wavelengths, read_toml
from bench.core.schemas import SceneFile, scene_schema, validate_document
from virtual.beam import Beam
from virtual.collector import parse_collector
from virtual.scene.declared import effects_from_table
from virtual.scene.simulate import Scene
from virtual.specimens import parse_specimen

__all__ = ["scene_from_dict", "load_scene"]


def scene_from_dict(d: Mapping[str, Any], name: str = "scene", source: str = "scene") -> Scene:
    """Build a :class:`Scene` from its TOML table (``source`` names it in errors)."""
    doc: SceneFile = validate_document(scene_schema(), d, source)
    given = doc.model_fields_set
    specimen = parse_specimen(doc.specimen if isinstance(doc.specimen, str) else doc.specimen.spec)
    beam = Beam(kind=doc.beam) if isinstance(doc.beam, str) else Beam(**doc.beam.model_dump(exclude_unset=True))
    if isinstance(doc.collector, str):
        collector, method = parse_collector(doc.collector), doc.method
    else:
        collector = parse_collector(doc.collector.spec)
        method = doc.method if "method" in given else doc.collector.method
    inc = [doc.incidence] if isinstance(doc.incidence, (int, float)) else list(doc.incidence)
    return Scene(specimen=specimen, instrument=doc.instrument, beam=beam, collector=collector,
                 wavelengths=tuple(float(x) for x in parse_wavelengths(doc.wavelengths)),
                 incidence=(float(inc[0]), float(inc[1]) if len(inc) > 1 else 0.0), rays=doc.rays,
                 uncertainty=doc.uncertainty, delta=doc.delta, seed=doc.seed, observable=doc.observable,
                 method=method, effects=effects_from_table(doc.effects), name=doc.name if "name" in given else name,
                 tradeoff=doc.tradeoff.model_dump(exclude_unset=True),
                 physical=doc.physical.model_dump(exclude_unset=True))


def load_scene(path: str | Path) -> Scene:
    """Read a scene TOML file (a :class:`~bench.core.errors.ConfigError` names what is wrong)."""
    p = Path(path)
    return scene_from_dict(read_toml(p, "scene file"), name=p.stem, source=f"scene file {p}")

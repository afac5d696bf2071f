"""Specimen strings: ``name:key=value,...`` to a specimen (the CLI's and the scene files' form).

``lambert:reflectance=0.375``, ``ggx:alpha=0.2,eta=1.5,k=0`` name a registered family
(:mod:`virtual.specimens.declare`); ``colorchecker:dark skin`` (optionally ``chart/patch``) is a
Lambertian with a measured reflectance spectrum (colour-science); ``mitsuba:{json}`` a Mitsuba 3
BSDF (optional extra). Errors list the known names, or the parameters a family accepts.
A family with named presets (a ``preset(name) -> {key: value}`` classmethod, e.g. the leaf
library) also takes ``name:PRESET[,key=value,...]``: the preset, then the overrides.
"""

from __future__ import annotations

import numpy as np

from bench.core.errors import SpecimenError
from virtual.specimens.mitsuba import parse_mitsuba
from virtual.specimens.declare import (RESERVED_NAMES, SPECIMENS, Specimen, Spectral, load_specimen_plugins,
                                       specimen_family)
from virtual.specimens.diffuse import Lambertian

__all__ = ["parse_specimen", "known_specimen_names", "RESERVED_FORMS"]

#: the specimen strings :func:`parse_specimen` reads itself (not declared families): name ->
#: (the form, what it gives); ``bench specimens`` lists them after the families
RESERVED_FORMS = {
    "colorchecker": ("colorchecker:PATCH or colorchecker:CHART/PATCH",
                     "a Lambertian with a measured ColorChecker reflectance spectrum (colour-science; default chart "
                     "BabelColor Average), e.g. colorchecker:dark skin"),
    "mitsuba": ("mitsuba:{JSON BSDF dict}",
                "a Mitsuba 3 BSDF (the mitsuba extra), e.g. mitsuba:{\"type\": \"diffuse\"}"),
}


def _colorchecker(name: str, chart: str = "BabelColor Average") -> Lambertian:
    import colour  # heavy: only when a ColorChecker is asked for

    charts = colour.SDS_COLOURCHECKERS
    if chart not in charts:
        raise SpecimenError(f"unknown ColorChecker chart {chart!r}; known: {', '.join(charts)}")
    sds = charts[chart]
    key = {k.lower(): k for k in sds}.get(name.strip().lower())
    if key is None:
        raise SpecimenError(f"unknown ColorChecker patch {name!r}; known: {', '.join(sds)}")
    sd = sds[key]
    return Lambertian(reflectance=Spectral((np.asarray(sd.wavelengths, float)),
                                           np.asarray(sd.values, float), f"{key} reflectance"),
                      label=f"colorchecker:{key}")


def _kwargs(text: str, spec: str) -> dict[str, float | str]:
    """``key=value`` pairs: numbers as floats; a word (a categorical parameter's choice, e.g.
    ``masking=separable``) is passed on for the family's :class:`Param` to check."""
    out: dict[str, float | str] = {}
    for item in filter(None, (t.strip() for t in text.split(","))):
        if "=" not in item:
            raise SpecimenError(f"specimen {spec!r}: expected key=value, got {item!r}")
        k, v = (t.strip() for t in item.split("=", 1))
        if k in out:
            raise SpecimenError(f"specimen {spec!r}: parameter {k} given twice")
        try:
            out[k] = float(v)
        except ValueError:
            out[k] = v
    return out


def known_specimen_names() -> list[str]:
    """Every name a specimen string may start with (installed plugins' families included)."""
    load_specimen_plugins()
    return sorted([*SPECIMENS, *RESERVED_NAMES])


def parse_specimen(spec: str | Specimen) -> Specimen:
    """Build a specimen from ``name:key=value,...`` (or pass a Specimen through)."""
    if isinstance(spec, Specimen):
        return spec
    text = str(spec).strip()
    name, _, rest = text.partition(":")
    name = name.strip().lower()
    if name == "colorchecker":
        chart, _, patch = rest.rpartition("/")
        return _colorchecker(patch, chart) if chart else _colorchecker(patch)
    if name == "mitsuba":  # optional extra: mitsuba:{json BSDF dict}
        return parse_mitsuba(rest, text)
    family = specimen_family(name)
    if family is None:
        raise SpecimenError(f"unknown specimen {name!r}; known: {', '.join(known_specimen_names())}")
    first, _, more = rest.partition(",")
    preset = getattr(family, "preset", None)
    try:
        if preset is not None and first.strip() and "=" not in first:
            specimen = family.from_keywords({**preset(first.strip()), **_kwargs(more, text)}, text)
        else:
            specimen = family.from_keywords(_kwargs(rest, text), text)
    except SpecimenError as exc:  # name the string the value came from
        msg = str(exc)
        raise SpecimenError(msg if msg.startswith("specimen ") else f"specimen {text!r}: {msg}") from None
    object.__setattr__(specimen, "label", specimen.label or text)
    return specimen

"""Model strings of ``bench fit``: ``FAMILY:p=?,q=VALUE,r=?lo:hi``.

A model is one declared specimen family (:mod:`virtual.specimens.declare`); its parameters,
their ranges, units and defaults come from that one declaration and are not repeated here.
``p=?`` frees ``p`` over its declared range, ``r=?lo:hi`` over ``[lo, hi]`` (inside the declared
range), ``q=VALUE`` fixes ``q``; parameters not named keep their declared defaults. A family with
named presets (the leaf library) also takes ``FAMILY:PRESET,...`` for the fixed values.

Every refusal is one line naming the offending token (:class:`~bench.core.errors.InputError`,
exit 2 on the command line): no free parameter, an unknown parameter, bounds outside the
declared range or empty, a value that is not a number.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np

from bench.core.errors import InputError, SpecimenError
from virtual.specimens import DeclaredSpecimen, Param, Specimen, parse_specimen, specimen_family
from virtual.specimens.strings import known_specimen_names

__all__ = ["FreeParameter", "ModelSpec", "parse_model_spec"]


@dataclass(frozen=True)
class FreeParameter:
    """A parameter the fit estimates: its declared name and unit, and its search bounds."""

    name: str
    lo: float
    hi: float
    unit: str
    default: float
    #: the name as the model string wrote it (an alias such as ``albedo``), reported as written
    written: str = ""

    @property
    def label(self) -> str:
        return self.written or self.name

    def start(self) -> float:
        """The declared default when strictly inside the bounds; a default on a bound (a
        transmittance of 0) moved 1 % of the range inside, so that a family's joint constraint
        (reflectance + transmittance <= 1) is not broken by the start; else the bounds' midpoint."""
        if self.lo < self.default < self.hi:
            return self.default
        if self.default in (self.lo, self.hi):
            return self.default + (0.01 if self.default == self.lo else -0.01) * (self.hi - self.lo)
        return 0.5 * (self.lo + self.hi)


@dataclass(frozen=True)
class ModelSpec:
    """A parsed model string: the family, its free parameters (in the string's order) and the
    values fixed by the string (the family's defaults hold for the rest)."""

    text: str
    family: type[DeclaredSpecimen]
    free: tuple[FreeParameter, ...]
    fixed: Mapping[str, float] = field(default_factory=dict)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.free)

    @property
    def labels(self) -> dict[str, str]:
        """Declared name -> the name as written, for every free parameter."""
        return {p.name: p.label for p in self.free}

    def canonical(self, name: str) -> str | None:
        """The declared name of parameter ``name`` (itself or an alias), None when unknown."""
        for p in self.family.parameters:
            if name == p.name or name in p.aliases:
                return p.name
        return None

    @property
    def units(self) -> tuple[str, ...]:
        return tuple(p.unit for p in self.free)

    @property
    def lower(self) -> np.ndarray:
        return np.array([p.lo for p in self.free], dtype=float)

    @property
    def upper(self) -> np.ndarray:
        return np.array([p.hi for p in self.free], dtype=float)

    def start(self) -> np.ndarray:
        return np.array([p.start() for p in self.free], dtype=float)

    def specimen_string(self, values: Sequence[float] | np.ndarray) -> str:
        """The specimen string of the model at ``values`` of the free parameters (repr floats:
        parsing it back gives exactly these values)."""
        kw = {**self.fixed, **{n: float(v) for n, v in zip(self.names, values)}}
        return f"{self.family.name}:" + ",".join(f"{k}={v!r}" for k, v in kw.items())

    def specimen(self, values: Sequence[float] | np.ndarray) -> Specimen:
        """The specimen at ``values`` (one per free parameter, in :attr:`names` order)."""
        return parse_specimen(self.specimen_string(values))


def _number(token: str, text: str, where: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise InputError(f"model token {token!r}: {where} {text.strip()!r} is not a number") from None
    if not math.isfinite(v):
        raise InputError(f"model token {token!r}: {where} {text.strip()!r} is not finite")
    return v


def _free(token: str, value: str, p: Param) -> FreeParameter:
    """``?`` or ``?lo:hi`` for declared parameter ``p``."""
    if p.choices:
        raise InputError(f"model token {token!r}: {p.name} is a choice ({', '.join(p.choices)}), it cannot be fitted")
    rest = value.strip()[1:].strip()
    lo, hi = p.lo, p.hi
    if rest:
        a, sep, b = rest.partition(":")
        if not sep:
            raise InputError(f"model token {token!r}: bounds must read ?lo:hi, got {value.strip()!r}")
        lo, hi = _number(token, a, "lower bound"), _number(token, b, "upper bound")
        u = f" {p.unit}" if p.unit else ""
        if not p.lo <= lo < hi <= p.hi:
            raise InputError(f"model token {token!r}: bounds [{lo:g}, {hi:g}] must be increasing and inside "
                             f"{p.name}'s declared range [{p.lo:.10g}, {p.hi:.10g}]{u}")
    return FreeParameter(p.name, float(lo), float(hi), p.unit, float(p.default), token.partition("=")[0].strip())


def parse_model_spec(text: str) -> ModelSpec:
    """Parse ``FAMILY:p=?,q=VALUE,r=?lo:hi`` against the family's declared parameters.

    Raises
    ------
    InputError
        One line naming the token: unknown family or parameter, a parameter given twice, no
        free parameter, bounds outside the declared range, a value that is not a number.
    """
    raw = str(text).strip()
    name, colon, rest = raw.partition(":")
    family = specimen_family(name) if name.strip() else None
    if family is None:
        raise InputError(f"model {raw!r}: unknown family {name.strip()!r}; known: "
                         f"{', '.join(n for n in known_specimen_names() if specimen_family(n) is not None)}")
    keys = {p.name: p for p in family.parameters}
    keys.update({a: p for p in family.parameters for a in p.aliases})
    tokens = [t.strip() for t in rest.split(",")] if colon else []
    fixed: dict[str, float] = {}
    free: list[FreeParameter] = []
    seen: set[str] = set()
    preset = getattr(family, "preset", None)
    if tokens and tokens[0] and "=" not in tokens[0] and preset is not None:
        try:
            fixed.update(preset(tokens.pop(0)))
        except SpecimenError as exc:
            raise InputError(f"model {raw!r}: {exc}") from None
    for token in tokens:
        if not token:
            continue
        key, eq, value = (s.strip() for s in token.partition("="))
        if not eq:
            raise InputError(f"model token {token!r}: expected name=?, name=?lo:hi or name=VALUE")
        p = keys.get(key)
        if p is None:
            raise InputError(f"model token {token!r}: unknown parameter {key!r} for {family.name}; "
                             f"accepted: {', '.join(family.accepted())}")
        if p.name in seen:
            raise InputError(f"model token {token!r}: parameter {p.name} given twice")
        seen.add(p.name)
        if value.startswith("?"):
            free.append(_free(token, value, p))
            fixed.pop(p.name, None)
            continue
        try:
            fixed[p.name] = p.check(p.coerce(value) if p.choices else _number(token, value, "value"))
        except SpecimenError as exc:
            raise InputError(f"model token {token!r}: {exc}") from None
    if not free:
        raise InputError(f"model {raw!r}: no free parameter; mark at least one with ?, e.g. "
                         f"{family.name}:{family.parameters[0].name}=?")
    spec = ModelSpec(raw, family, tuple(free), fixed)
    try:
        spec.specimen(spec.start())  # combinations the family refuses (e.g. an energy bound) show now
    except SpecimenError as exc:
        raise InputError(f"model {raw!r}: {exc}") from None
    return spec

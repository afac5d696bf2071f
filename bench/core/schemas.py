"""Declared schemas of the files a user gives: plans, bench configs, sweeps, scenes (pydantic v2).

Every file goes through :func:`validate_document` before anything uses it: unknown keys are
refused (with a "did you mean" for near misses), and so are wrong types, non-finite numbers,
out-of-range values and sizes beyond the stated bounds. The error is one line naming the file,
the key (dotted path) and the value. The builders and plan expansion keep the checks that need
the devices (reachability, specimen parameters); the shape of the file is checked here, once.
"""

from __future__ import annotations

import difflib
import math
from typing import Annotated, Any, List, Literal, Mapping, Union

from pydantic import (BaseModel, BeforeValidator, ConfigDict, Field, StrictBool, ValidationError,
                      field_validator)

from bench.core.errors import ConfigError, InputError
from bench.core.parsing import check_collector_spec, parse_range, parse_wavelengths

__all__ = ["PlanFile", "BenchFile", "SweepFile", "SceneFile", "validate_document", "MAX_PLAN_POINTS", "MAX_INTEGRATION_S",
           "MAX_AVERAGES", "MAX_RAYS", "MAX_SWEEP_SERIES"]

#: the most points one plan may expand to (a plan of more is almost surely a typo in a step)
MAX_PLAN_POINTS = 200_000
#: the longest integration one reading may ask for (s): a USB2000+-class detector tops out at 65 s
MAX_INTEGRATION_S = 3600.0
#: the most scans one reading may average
MAX_AVERAGES = 100_000
#: the most rays per wavelength a file may ask for (the CLI's --max-seconds bounds the time)
MAX_RAYS = 10**15
#: the most series (specimen x collector x incidence/geometry) one sweep may hold
MAX_SWEEP_SERIES = 100_000


def _finite_number(v: Any) -> Any:
    if isinstance(v, bool):
        raise ValueError("expected a number, got a boolean")
    if isinstance(v, (int, float)) and not math.isfinite(float(v)):
        raise ValueError(f"expected a finite number, got {v!r}")
    return v


def _whole_number(v: Any) -> Any:
    if isinstance(v, bool):
        raise ValueError("expected an integer, got a boolean")
    if isinstance(v, float):
        if not math.isfinite(v) or v != int(v):
            raise ValueError(f"expected an integer, got {v!r}")
        return int(v)
    return v


Finite = Annotated[float, BeforeValidator(_finite_number)]
Whole = Annotated[int, BeforeValidator(_whole_number)]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=False, frozen=True)


def _range(v: Any) -> Any:
    """A number, a non-empty list of numbers or a ``{start, stop, step}`` table, sized within bounds."""
    try:
        parse_range(v, "range", limit=MAX_PLAN_POINTS)
    except ConfigError as exc:
        raise ValueError(str(exc).replace("range.", "").removeprefix("range: ")) from None
    return v


#: a number, a non-empty list of numbers or a {start, stop, step} table
Range = Annotated[Any, BeforeValidator(_range)]


def _collector(v: Any) -> Any:
    if not isinstance(v, str):
        raise ValueError(f"expected a collector such as 'equal-psa:9x36', got {v!r}")
    try:
        check_collector_spec(v)
    except InputError as exc:
        raise ValueError(str(exc)) from None
    return v


def _wavelengths(v: Any) -> Any:
    if isinstance(v, bool) or not isinstance(v, (str, int, float, list)):
        raise ValueError(f"expected START:STOP:STEP, a list or a number (nm), got {v!r}")
    try:
        parse_wavelengths(v)
    except InputError as exc:
        raise ValueError(str(exc)) from None
    return v


#: ``SCHEME:RINGSxSECTORS`` with a bounded number of patches
CollectorSpec = Annotated[str, BeforeValidator(_collector)]
#: ``START:STOP:STEP``, ``a,b,c``, a number or a list (nm), positive, finite, bounded in count
Wavelengths = Annotated[Any, BeforeValidator(_wavelengths)]


class SpectralTable(_Strict):
    geometries: Annotated[list[str], Field(min_length=1)]
    phi_i: Finite = 0.0


class InPlaneTable(_Strict):
    theta_i: Range = [30.0]
    theta_r: Range = {"start": -80, "stop": 80, "step": 10}
    phi_i: Finite = 0.0


class HemisphericalTable(_Strict):
    theta_i: Range = [30.0]
    theta_r: Range = {"start": 0, "stop": 80, "step": 10}
    phi_r: Range = {"start": 0, "stop": 345, "step": 15}
    phi_i: Finite = 0.0


class HalfVectorTable(_Strict):
    theta_h: Range = [0.0, 10.0, 20.0]
    theta_d: Range = [10.0, 30.0]
    phi_d: Range = [90.0]
    phi_h: Finite = 90.0


class ListTable(_Strict):
    points: Annotated[list[Annotated[list[Finite], Field(min_length=4, max_length=4)]],
                      Field(min_length=1, max_length=MAX_PLAN_POINTS)]


class PlanFile(_Strict):
    """A plan file: common keys and the table of its ``kind``."""

    name: str = "plan"
    kind: Literal["spectral", "in-plane", "hemispherical", "half-vector", "list"]
    integration_s: Annotated[Finite, Field(gt=0, le=MAX_INTEGRATION_S)] = 0.1
    averages: Annotated[Whole, Field(ge=1, le=MAX_AVERAGES)] = 1
    dark: Literal["none", "once", "per-incidence", "per-point"] = "once"
    white: Literal["none", "once"] = "once"
    order: Literal["travel", "as-given"] = "travel"
    home: StrictBool = False  # return the turntable to home before the first point
    unreachable: Literal["refuse", "skip"] = "refuse"  # skip: measure the reachable points, record the others
    description: str = ""
    spectral: SpectralTable | None = None
    in_plane: InPlaneTable | None = None
    hemispherical: HemisphericalTable | None = None
    half_vector: HalfVectorTable | None = None
    points: list[Any] | None = None  # kind = "list" may give points at the top level
    list_table: ListTable | None = Field(None, alias="list")


class GeometryTable(_Strict):
    theta_i: Finite
    phi_i: Finite = 0.0
    theta_r: Finite
    phi_r: Finite = 0.0


class WhiteTable(_Strict):
    name: str = ""
    reflectance_factor: Union[Annotated[Finite, Field(gt=0, le=1.5)],
                              Annotated[list[list[Finite]], Field(min_length=2, max_length=2)]] = 0.99
    uncertainty: Annotated[Finite, Field(ge=0, le=1)] = 0.005
    geometry: Union[Annotated[list[Finite], Field(min_length=4, max_length=4)], GeometryTable] = [0.0, 0.0, 45.0, 180.0]
    reference_file: str = ""
    operator_note: str = ""
    date: str = ""


class SpecimenTable(_Strict):
    spec: str
    name: str = ""  # what the records call the mounted specimen (default: its spec)


class VirtualTable(_Strict):
    """``[virtual]``: the virtual goniophotometer's settings (virtual.goniophotometer)."""

    collector: CollectorSpec = "equal-psa:9x36"
    rays: Annotated[Whole, Field(ge=1, le=MAX_RAYS)] | None = None
    uncertainty: Annotated[Finite, Field(gt=0, lt=1)] | None = None
    delta: Annotated[Finite, Field(gt=0, lt=1)] = 0.01
    beam: str = "collimated"
    wavelengths: Wavelengths = 550.0
    method: Literal["auto", "fast", "rays", "python"] = "auto"
    gain: Annotated[Finite, Field(gt=0)] = 1.0e4


class EmulatedTable(_Strict):
    """``[emulated]``: how the wire emulators behave."""

    time_scale: Annotated[Finite, Field(gt=0, le=1e6)] = 20.0
    bands: Wavelengths = "450:650:100"
    bandwidth_nm: Annotated[Finite, Field(gt=0, le=1000)] = 10.0
    aperture_deg: Annotated[Finite, Field(gt=0, le=90)] = 1.0
    seed: Annotated[Whole, Field(ge=0, lt=2**63)] | None = None


class BandsTable(_Strict):
    centres: Wavelengths
    bandwidth_nm: Annotated[Finite, Field(gt=0, le=1000)] = 10.0


class BenchFile(BaseModel):
    """A bench config: the roles' tables. Driver tables (``arm``, ``turntable``, ``spectrometer``,
    ``light``) are checked by the drivers' own declared settings; their presence is checked here."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str = "bench"
    kind: Literal["virtual", "emulated", "real"] = "virtual"
    description: str = ""
    seed: Annotated[Whole, Field(ge=0, lt=2**63)] | None = None
    specimen: SpecimenTable | None = None
    white: WhiteTable = WhiteTable()
    virtual: VirtualTable | None = None
    emulated: EmulatedTable | None = None
    bands: BandsTable | None = None
    arm: dict[str, Any] | None = None
    turntable: dict[str, Any] | None = None
    spectrometer: dict[str, Any] | None = None
    light: dict[str, Any] | None = None
    instrument: dict[str, Any] | None = None  # declared effects of the virtual body (bench.builders.instrument)

    @field_validator("arm", "turntable", "spectrometer", "light", "instrument", mode="before")
    @classmethod
    def _table(cls, v: Any) -> Any:
        if not isinstance(v, Mapping):
            raise ValueError("expected a table")
        return v


#: an incidence: THETA, [THETA, PHI] or "THETA,PHI" (degrees; the sweep checks the range)
Incidence = Union[Finite, Annotated[list[Finite], Field(min_length=1, max_length=2)], str]


class _SweepCommon(_Strict):
    wavelengths: Wavelengths | None = None
    rays: Annotated[Whole, Field(ge=1, le=MAX_RAYS)] | None = None
    uncertainty: Annotated[Finite, Field(gt=0, lt=1)] | None = None
    delta: Annotated[Finite, Field(gt=0, lt=1)] = 0.01
    method: Literal["auto", "rays", "fast"] | None = None
    beam: str = "collimated"
    cone_deg: Annotated[Finite, Field(gt=0, lt=90)] | None = None


def _one_or_many(item: Any) -> Any:
    """A value or a non-empty list of values (at most MAX_SWEEP_SERIES)."""
    return Union[item, Annotated[list[item], Field(min_length=1, max_length=MAX_SWEEP_SERIES)]]


class SweepTable(_SweepCommon):
    """``[sweep]``: the defaults and the product of specimens x collectors x incidences/geometries."""

    name: str = "sweep"
    seed: Annotated[Whole, Field(ge=0, lt=2**63)] | None = None
    instrument: Literal["gonio", "spectro"] = "gonio"
    specimens: _one_or_many(str) | None = None
    incidences: _one_or_many(Incidence) | None = None
    geometries: _one_or_many(str) | None = None
    collectors: _one_or_many(CollectorSpec) | None = None
    wavelengths_per_task: Annotated[Whole, Field(ge=0, le=10_000)] | None = None
    common_random_numbers: StrictBool = False  # one stream for every specimen (lower-variance model comparisons)


class TaskTable(_SweepCommon):
    """One ``[[task]]``: one series, overriding any ``[sweep]`` default."""

    specimen: str | None = None
    incidence: Incidence | None = None
    geometry: str | None = None
    collector: CollectorSpec | None = None


class SweepFile(_Strict):
    """A sweep file: ``[sweep]`` and optional ``[[task]]`` entries."""

    sweep: SweepTable
    task: Annotated[list[TaskTable], Field(min_length=1, max_length=MAX_SWEEP_SERIES)] | None = None


# --- scenes (virtual.scene; `bench tradeoff` validates with this before loading) -----------------

_Frac = Annotated[Finite, Field(ge=0, le=1)]
_Pos = Annotated[Finite, Field(gt=0)]


class ApertureEffect(_Strict):
    half_angle_deg: Annotated[Finite, Field(gt=0, le=90)] = 2.0
    views: Annotated[list[Annotated[list[Finite], Field(min_length=1, max_length=2)]],
                     Field(min_length=1, max_length=10_000)] = [[0.0, 0.0]]
    distance_mm: _Pos | None = None


class NoiseEffect(_Strict):
    uncertainty: _Frac = 0.002
    relative: StrictBool | None = None


class StrayLightEffect(_Strict):
    fraction: _Frac = 0.001


class SphereEffect(_Strict):
    wall_reflectance: _Frac = 0.98
    port_fraction: _Frac = 0.05
    detector_port: _Frac = 0.01
    specimen_port: _Frac = 0.02
    reference_reflectance: _Frac = 0.99


class GlossTrapEffect(_Strict):
    specular: Literal["excluded", "included"] = "excluded"
    half_angle_deg: Annotated[Finite, Field(gt=0, le=90)] = 4.0


class BandpassEffect(_Strict):
    fwhm_nm: _Pos = 10.0
    nodes: Annotated[Whole, Field(ge=1, le=1001)] = 9


class SpecimenEffect(_Strict):
    uniform: StrictBool = True
    period_mm: _Pos = 5.0
    contrast: _Frac = 0.5
    spot_radius_mm: _Pos = 10.0


def _effect(model: Any) -> Any:
    return Union[StrictBool, model] | None  # true: the defaults, false: not declared


class EffectsTable(_Strict):
    aperture: _effect(ApertureEffect) = None
    noise: _effect(NoiseEffect) = None
    stray_light: _effect(StrayLightEffect) = None
    sphere: _effect(SphereEffect) = None
    gloss_trap: _effect(GlossTrapEffect) = None
    bandpass: _effect(BandpassEffect) = None
    specimen: _effect(SpecimenEffect) = None


class SceneBeam(_Strict):
    kind: Literal["collimated", "conical"] = "collimated"
    emitter_radius_mm: _Pos = 5.0
    specimen_radius_mm: _Pos = 12.5
    distance_mm: _Pos = 76.2
    disk_sampling: str = "auto"


class SceneCollector(_Strict):
    spec: CollectorSpec = "equal-psa:9x36"
    method: Literal["auto", "rays", "fast"] = "auto"


class TradeoffTable(_Strict):
    rays: Annotated[list[Annotated[Whole, Field(ge=1, le=10**12)]], Field(min_length=1, max_length=50)] | None = None
    budgets: Annotated[list[str], Field(min_length=1, max_length=20)] | None = None
    repeats: Annotated[Whole, Field(ge=1, le=1000)] = 1
    strategies: Annotated[list[str], Field(min_length=1, max_length=20)] | None = None
    collectors: Annotated[list[CollectorSpec], Field(min_length=1, max_length=50)] | None = None
    fast: StrictBool = True


class PhysicalTable(_Strict):
    theta_i: Union[Annotated[Finite, Field(ge=0, lt=90)],
                   Annotated[list[Annotated[Finite, Field(ge=0, lt=90)]], Field(min_length=1, max_length=90)]] = [30.0]
    theta_r: Annotated[list[Annotated[Finite, Field(ge=-90, le=90)]], Field(min_length=2, max_length=2)] = [-75.0, 75.0]
    steps_deg: Annotated[list[Annotated[Finite, Field(ge=0.01, le=180)]], Field(min_length=1, max_length=50)] = [1, 2, 5, 10]
    averages: Annotated[list[Annotated[Whole, Field(ge=1, le=MAX_AVERAGES)]], Field(min_length=1, max_length=50)] = [1, 4, 16]
    integration_s: Annotated[Finite, Field(gt=0, le=MAX_INTEGRATION_S)] = 0.05
    velocity_deg_s: _Pos = 30.0
    acceleration_deg_s2: _Pos = 60.0
    settle_s: Annotated[Finite, Field(ge=0, le=3600)] = 0.2
    relative_noise_per_reading: Annotated[Finite, Field(ge=0, le=10)] = 0.01


class SceneFile(_Strict):
    """A scene file (:mod:`virtual.scene`): instrument, specimen, beam, collector, budget, effects,
    and the ``[tradeoff]``/``[physical]`` tables of ``bench tradeoff``."""

    name: str = "scene"
    instrument: Literal["spectrophotometer", "goniophotometer", "physical"] = "spectrophotometer"
    specimen: Union[str, SpecimenTable] = "lambert:reflectance=0.5"
    wavelengths: Wavelengths = "550"
    incidence: Union[Annotated[Finite, Field(ge=0, lt=90)],
                     Annotated[list[Finite], Field(min_length=1, max_length=2)]] = [8.0, 0.0]
    rays: Annotated[Whole, Field(ge=1, le=MAX_RAYS)] | None = None
    uncertainty: Annotated[Finite, Field(gt=0, lt=1)] = 0.01
    delta: Annotated[Finite, Field(gt=0, lt=1)] = 0.01
    seed: Annotated[Whole, Field(ge=0, lt=2**63)] = 1
    observable: Literal["reflectance", "transmittance", "missed"] = "reflectance"
    method: Literal["auto", "rays", "fast"] = "auto"
    beam: Union[Literal["collimated", "conical"], SceneBeam] = SceneBeam()
    collector: Union[CollectorSpec, SceneCollector] = "equal-psa:9x36"
    effects: EffectsTable = EffectsTable()
    tradeoff: TradeoffTable = TradeoffTable()
    physical: PhysicalTable = PhysicalTable()


def _loc(loc: tuple[Any, ...]) -> str:
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        elif isinstance(part, str) and part[:1].isupper():
            continue  # a union branch named by its model class (our keys are lower case)
        elif part in ("float", "int", "str", "list[float]", "RangeTable", "function-before[_finite_number(), float]",
                      "function-before[_whole_number(), int]") or "[" in str(part) or str(part).startswith("function"):
            continue  # union branch labels pydantic adds to the location
        else:
            out += ("." if out else "") + str(part)
    return out


def _value_at(data: Any, loc: tuple[Any, ...]) -> tuple[bool, Any]:
    cur = data
    for part in loc:
        if isinstance(cur, Mapping) and part in cur:
            cur = cur[part]
        elif isinstance(cur, list) and isinstance(part, int) and 0 <= part < len(cur):
            cur = cur[part]
        else:
            continue
    return True, cur


def _known_keys(model: type[BaseModel], loc: tuple[Any, ...]) -> list[str]:
    """The keys accepted at the table holding ``loc``'s last part (for "did you mean")."""
    current: Any = model
    for part in loc[:-1]:
        fields = getattr(current, "model_fields", None)
        if not fields or part not in fields:
            return []
        ann = fields[part].annotation
        current = next((a for a in getattr(ann, "__args__", (ann,)) if hasattr(a, "model_fields")), None)
        if current is None:
            return []
    return sorted(getattr(current, "model_fields", {}))


def validate_document(model: type[BaseModel], data: Mapping[str, Any], source: str) -> BaseModel:
    """Validate ``data`` (a parsed file) against ``model``; the first problem becomes one
    :class:`ConfigError` line: ``SOURCE: key a.b: problem (got VALUE)``."""
    if not isinstance(data, Mapping):
        raise ConfigError(f"{source}: expected a table of keys, got {type(data).__name__}")
    try:
        return model.model_validate(dict(data))
    except ValidationError as exc:
        errors = exc.errors(include_url=False)
        # a union reports one error per branch: the one reaching deepest names the real problem
        err = max(errors, key=lambda e: (e["type"] == "extra_forbidden", len(e.get("loc", ()))))
        loc = tuple(err.get("loc", ()))
        where = _loc(loc) or "(top level)"
        if err["type"] == "extra_forbidden":
            key = str(loc[-1]) if loc else where
            known = [k for k in _known_keys(model, loc)]
            near = difflib.get_close_matches(key, known, n=1, cutoff=0.6)
            hint = f"; did you mean {near[0]!r}?" if near else (f"; accepted: {', '.join(known)}" if known else "")
            raise ConfigError(f"{source}: unknown key {where!r}{hint}") from None
        value = err.get("input")
        msg = str(err.get("msg", "invalid"))
        if msg.startswith("Value error, "):  # our own validators already name the value
            raise ConfigError(f"{source}: key {where}: {msg.removeprefix('Value error, ')}") from None
        shown = repr(value)
        if len(shown) > 60:
            shown = shown[:57] + "..."
        raise ConfigError(f"{source}: key {where}: {msg[:1].lower() + msg[1:]} (got {shown})") from None

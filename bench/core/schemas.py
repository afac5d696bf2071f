"""Declared schemas of the files a user gives: plans, bench configs, sweeps, scenes (pydantic v2).

Every file goes through :func:`~bench.core.validation.validate_document` (re-exported here)
before anything uses it: unknown keys are refused (with a "did you mean" for near misses), and
so are wrong types, non-finite numbers, out-of-range values and sizes beyond the stated bounds. The error is one line naming the file,
the key (dotted path) and the value. The builders and plan expansion keep the checks that need
the devices (reachability, specimen parameters); the shape of the file is checked here, once.
"""

from __future__ import annotations

import datetime as _dt
from typing import TYPE_CHECKING, Annotated, Any, Callable, ClassVar, Literal, Mapping, TypeVar, Union, get_args

from pydantic import (AfterValidator, BaseModel, BeforeValidator, ConfigDict, Field, StrictBool, create_model,
                      field_validator, model_validator)

from bench.core.errors import ConfigError, InputError
from bench.core.parsing import check_collector_spec, parse_range, parse_wavelengths
from bench.core.plugins import EFFECT_GROUP, load_plugins
from bench.core.validation import Finite, Settings, Table, Whole, validate_document, validation_message

__all__ = ["PlanFile", "BenchFile", "SweepFile", "SceneFile", "validate_document", "validation_message", "Settings",
           "BENCH_KINDS", "UncertaintyTable", "SceneEffect", "EFFECT_SCHEMAS", "plugin_effects", "scene_schema", "MAX_PLAN_POINTS",
           "MAX_INTEGRATION_S", "MAX_AVERAGES", "MAX_WHITE_REPEATS", "DEFAULT_WHITE_REPEATS", "MAX_RAYS", "MAX_SWEEP_SERIES"]

#: the most points one plan may expand to (a plan of more is almost surely a typo in a step)
MAX_PLAN_POINTS = 200_000
#: the longest integration one reading may ask for (s): a USB2000+-class detector tops out at 65 s
MAX_INTEGRATION_S = 3600.0
#: the most scans one reading may average
MAX_AVERAGES = 100_000
#: the most rays per wavelength a file may ask for (the CLI's --max-seconds bounds the time)
MAX_RAYS = 10**15
#: the most repeated white readings a plan may ask for, and how many ``white = "repeated"`` takes
MAX_WHITE_REPEATS, DEFAULT_WHITE_REPEATS = 1000, 5
#: the most series (specimen x collector x incidence/geometry) one sweep may hold
MAX_SWEEP_SERIES = 100_000


def _range(v: Any) -> Any:
    """A number, a non-empty list of numbers or a ``{start, stop, step}`` table, sized within bounds."""
    try:
        parse_range(v, "range", limit=MAX_PLAN_POINTS)
    except ConfigError as exc:
        raise ValueError(str(exc).replace("range.", "").removeprefix("range: ")) from None
    return v


#: a number, a non-empty list of numbers or a {start, stop, step} table
Range = Annotated[Any, BeforeValidator(_range)]


def _checked_by(check: Callable[[Any], Any], v: Any) -> Any:
    """``v`` when the project's own parser ``check`` takes it; its InputError as the ValueError a
    validator raises (so the message is the parser's, with the key prefixed)."""
    try:
        check(v)
    except InputError as exc:
        raise ValueError(str(exc)) from None
    return v


def _collector(v: Any) -> Any:
    if not isinstance(v, str):
        raise ValueError(f"expected a collector such as 'equal-psa:9x36', got {v!r}")
    return _checked_by(check_collector_spec, v)


def _wavelengths(v: Any) -> Any:
    if isinstance(v, bool) or not isinstance(v, (str, int, float, list)):
        raise ValueError(f"expected START:STOP:STEP, a list or a number (nm), got {v!r}")
    return _checked_by(parse_wavelengths, v)


#: ``SCHEME:RINGSxSECTORS`` with a bounded number of patches
CollectorSpec = Annotated[str, BeforeValidator(_collector)]
#: ``START:STOP:STEP``, ``a,b,c``, a number or a list (nm), positive, finite, bounded in count
Wavelengths = Annotated[Any, BeforeValidator(_wavelengths)]


class SpectralTable(Table):
    geometries: Annotated[list[str], Field(min_length=1)]
    phi_i: Finite = 0.0


class InPlaneTable(Table):
    theta_i: Range = [30.0]
    theta_r: Range = {"start": -80, "stop": 80, "step": 10}
    phi_i: Finite = 0.0


class HemisphericalTable(Table):
    theta_i: Range = [30.0]
    theta_r: Range = {"start": 0, "stop": 80, "step": 10}
    phi_r: Range = {"start": 0, "stop": 345, "step": 15}
    phi_i: Finite = 0.0


class HalfVectorTable(Table):
    theta_h: Range = [0.0, 10.0, 20.0]
    theta_d: Range = [10.0, 30.0]
    phi_d: Range = [90.0]
    phi_h: Finite = 90.0


class ListTable(Table):
    points: Annotated[list[Annotated[list[Finite], Field(min_length=4, max_length=4)]],
                      Field(min_length=1, max_length=MAX_PLAN_POINTS)]


class PlanFile(Table):
    """A plan file: common keys and the table of its ``kind``."""

    name: str = "plan"
    kind: Literal["spectral", "in-plane", "hemispherical", "half-vector", "list"]
    #: seconds, or "auto": the longest the bench's detector takes without saturating (bench.exposure)
    integration_s: Union[Annotated[Finite, Field(gt=0, le=MAX_INTEGRATION_S)], Literal["auto"]] = 0.1
    averages: Annotated[Whole, Field(ge=1, le=MAX_AVERAGES)] = 1
    dark: Literal["none", "once", "per-incidence", "per-point"] = "once"
    white: Literal["none", "once", "repeated"] = "once"
    #: white = "repeated": white readings taken in sequence (the lamp drift's Type A estimate)
    white_repeats: Annotated[Whole, Field(ge=3, le=MAX_WHITE_REPEATS)] = DEFAULT_WHITE_REPEATS
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


class GeometryTable(Table):
    theta_i: Finite
    phi_i: Finite = 0.0
    theta_r: Finite
    phi_r: Finite = 0.0


class WhiteTable(Table):
    name: str = ""
    reflectance_factor: Union[Annotated[Finite, Field(gt=0, le=1.5)],
                              Annotated[list[list[Finite]], Field(min_length=2, max_length=2)]] = 0.99
    uncertainty: Annotated[Finite, Field(ge=0, le=1)] = 0.005
    geometry: Union[Annotated[list[Finite], Field(min_length=4, max_length=4)], GeometryTable] = [0.0, 0.0, 45.0, 180.0]
    reference_file: str = ""
    operator_note: str = ""
    date: str = ""


class SpecimenTable(Table):
    spec: str
    name: str = ""  # what the records call the mounted specimen (default: its spec)


class VirtualTable(Table):
    """``[virtual]``: the virtual goniophotometer's settings (virtual.goniophotometer)."""

    collector: CollectorSpec = "equal-psa:9x36"
    rays: Annotated[Whole, Field(ge=1, le=MAX_RAYS)] | None = None
    uncertainty: Annotated[Finite, Field(gt=0, lt=1)] | None = None
    delta: Annotated[Finite, Field(gt=0, lt=1)] = 0.01
    beam: str = "collimated"
    wavelengths: Wavelengths = 550.0
    method: Literal["auto", "fast", "rays", "python"] = "auto"
    gain: Annotated[Finite, Field(gt=0)] = 1.0e4


class EmulatedTable(Table):
    """``[emulated]``: how the wire emulators behave."""

    time_scale: Annotated[Finite, Field(gt=0, le=1e6)] = 20.0
    bands: Wavelengths = "450:650:100"
    bandwidth_nm: Annotated[Finite, Field(gt=0, le=1000)] = 10.0
    aperture_deg: Annotated[Finite, Field(gt=0, le=90)] = 1.0
    seed: Annotated[Whole, Field(ge=0, lt=2**63)] | None = None


class BandsTable(Table):
    centres: Wavelengths
    bandwidth_nm: Annotated[Finite, Field(gt=0, le=1000)] = 10.0


class UncertaintyTable(Table):
    """``[uncertainty]``: how the GUM budget of every calibrated reading is evaluated
    (:mod:`bench.core.budget`), and the type-B components that are knowledge of the detector rather
    than effects. Effects (read noise, lamp drift, positioning) are declared once, in
    ``[instrument]``: the virtual body simulates them and every body's budget counts them."""

    method: Literal["linear", "mc"] = "linear"  # GUM law of propagation, or GUM-S1 Monte Carlo
    k: Annotated[Finite, Field(gt=0, le=10)] = 2.0  # coverage factor of the expanded uncertainty
    mc_samples: Annotated[Whole, Field(ge=1000, le=10_000_000)] = 20_000
    mc_seed: Annotated[Whole, Field(ge=0, lt=2**63)] = 0
    aperture: Annotated[Finite, Field(ge=0, le=1)] = 0.0  # relative: detector solid angle / aperture
    nonlinearity: Annotated[Finite, Field(ge=0, le=1)] = 0.0  # relative: detector response


class CheckTable(Table):
    """``[[check]]``: a check standard the bench measures on a schedule (``bench check``), its
    results kept on a control chart (``bench chart``). The reference is the standard's model
    (``specimen``, evaluated at each reading's geometry and wavelength) or a certified BRDF
    (``reference``, 1/sr, the same at every geometry of the check); ``reference_uncertainty`` is
    its relative standard uncertainty. ``every``: ``"run"`` (before each scan), ``"day"``, or a
    number of scans."""

    name: Annotated[str, Field(min_length=1, max_length=80, pattern=r"^[A-Za-z0-9][A-Za-z0-9 ._:-]*$")]
    specimen: str = ""
    reference: Annotated[Finite, Field(gt=0, le=1e6)] | None = None
    reference_uncertainty: Annotated[Finite, Field(ge=0, lt=1)] = 0.005
    geometries: Annotated[list[Annotated[list[Finite], Field(min_length=4, max_length=4)]],
                          Field(min_length=1, max_length=100)] = [[30.0, 0.0, 20.0, 180.0]]
    every: Union[Literal["run", "day"], Annotated[Whole, Field(ge=1, le=100000)]] = "day"
    integration_s: Annotated[Finite, Field(gt=0, le=MAX_INTEGRATION_S)] = 0.02
    averages: Annotated[Whole, Field(ge=1, le=MAX_AVERAGES)] = 4
    #: points of the chart's baseline (its centre and limits), unless ``centre`` and ``sigma`` are declared
    baseline: Annotated[Whole, Field(ge=2, le=1000)] = 20
    centre: Finite | None = None
    sigma: Annotated[Finite, Field(gt=0)] | None = None

    @model_validator(mode="after")
    def _one_reference(self) -> "CheckTable":
        if bool(self.specimen) == (self.reference is not None):
            raise ValueError("give the check standard's specimen model or its certified reference, not both or neither")
        if (self.centre is None) != (self.sigma is None):
            raise ValueError("declare the chart's centre and sigma together, or neither")
        return self


def _iso_date(v: Any) -> Any:
    if isinstance(v, _dt.date):
        return v.isoformat()
    if not isinstance(v, str):
        raise ValueError("expected a date YYYY-MM-DD")
    try:
        return _dt.date.fromisoformat(v).isoformat()
    except ValueError:
        raise ValueError(f"expected a date YYYY-MM-DD, got {v!r}") from None


IsoDate = Annotated[str, BeforeValidator(_iso_date)]


class DriftTable(Table):
    """``[drift]``: a declared, day-by-day change of the physical bench that the virtual and
    emulated bodies simulate (the real body has its own): from ``start`` on, the working white
    standard's actual reflectance changes by ``white_per_day`` (relative) each day -- soiling or
    ageing the white calibration cannot see, its certificate unchanged. ``on``: the day simulated
    (``bench check --date`` / ``bench scan --date`` set it; default today)."""

    start: IsoDate
    white_per_day: Annotated[Finite, Field(ge=-0.1, le=0.1)] = 0.0
    on: IsoDate | None = None


#: the bodies a bench description may be built as (``kind`` of a bench file)
BenchKind = Literal["virtual", "emulated", "real"]
BENCH_KINDS: tuple[str, ...] = get_args(BenchKind)


class BenchFile(BaseModel):
    """A bench config: the roles' tables. Driver tables (``arm``, ``turntable``, ``spectrometer``,
    ``light``, ``detector``) are checked by the drivers' own declared settings; their presence is checked here."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str = "bench"
    kind: BenchKind = "virtual"
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
    uncertainty: UncertaintyTable | None = None  # the GUM budget's declared components (bench.core.budget)
    detector: dict[str, Any] | None = None  # the detector of every body (bench.builders.detector)
    check: list[CheckTable] = []  # check standards (bench check, bench chart)
    drift: DriftTable | None = None  # simulated bodies: a declared drift over days
    #: what `bench scan` does when the latest check is out of control or overdue
    assurance: Literal["off", "warn", "refuse"] = "off"

    @field_validator("arm", "turntable", "spectrometer", "light", "instrument", "detector", mode="before")
    @classmethod
    def _table(cls, v: Any) -> Any:
        if not isinstance(v, Mapping):
            raise ValueError("expected a table")
        return v


#: an incidence: THETA, [THETA, PHI] or "THETA,PHI" (degrees; the sweep checks the range)
Incidence = Union[Finite, Annotated[list[Finite], Field(min_length=1, max_length=2)], str]


class _SweepCommon(Table):
    wavelengths: Wavelengths | None = None
    rays: Annotated[Whole, Field(ge=1, le=MAX_RAYS)] | None = None
    uncertainty: Annotated[Finite, Field(gt=0, lt=1)] | None = None
    delta: Annotated[Finite, Field(gt=0, lt=1)] = 0.01
    method: Literal["auto", "rays", "fast"] | None = None
    beam: Literal["collimated", "conical"] = "collimated"
    cone_deg: Annotated[Finite, Field(gt=0, lt=90)] | None = None


_Item = TypeVar("_Item")
#: a value or a non-empty list of values (at most MAX_SWEEP_SERIES)
_OneOrMany = Union[_Item, Annotated[list[_Item], Field(min_length=1, max_length=MAX_SWEEP_SERIES)]]


class SweepTable(_SweepCommon):
    """``[sweep]``: the defaults and the product of specimens x collectors x incidences/geometries."""

    name: str = "sweep"
    seed: Annotated[Whole, Field(ge=0, lt=2**63)] | None = None
    instrument: Literal["gonio", "spectro"] = "gonio"
    specimens: _OneOrMany[str] | None = None
    incidences: _OneOrMany[Incidence] | None = None
    geometries: _OneOrMany[str] | None = None
    collectors: _OneOrMany[CollectorSpec] | None = None
    wavelengths_per_task: Annotated[Whole, Field(ge=0, le=10_000)] | None = None
    common_random_numbers: StrictBool = False  # one stream for every specimen (lower-variance model comparisons)


class TaskTable(_SweepCommon):
    """One ``[[task]]``: one series, overriding any ``[sweep]`` default."""

    specimen: str | None = None
    incidence: Incidence | None = None
    geometry: str | None = None
    collector: CollectorSpec | None = None


class SweepFile(Table):
    """A sweep file: ``[sweep]`` and optional ``[[task]]`` entries."""

    sweep: SweepTable
    task: Annotated[list[TaskTable], Field(min_length=1, max_length=MAX_SWEEP_SERIES)] | None = None


# --- scenes (virtual.scene; `bench tradeoff` validates with this before loading) -----------------

_Frac = Annotated[Finite, Field(ge=0, le=1)]
_Pos = Annotated[Finite, Field(gt=0)]


class SceneEffect(Table):
    """One ``[effects.NAME]`` table: the settings (with their ranges) a declared effect takes;
    :mod:`virtual.scene` subclasses each to add what the effect does."""

    effect_name: ClassVar[str] = ""


def _view(v: Any) -> Any:
    """``[theta_r]`` or ``[theta_r, phi_r]`` (deg) -> ``(theta_r, phi_r)``, phi_r defaulting to 0."""
    if isinstance(v, (list, tuple)) and len(v) == 1:
        return (v[0], 0.0)
    return v


class ApertureEffect(SceneEffect):
    effect_name: ClassVar[str] = "aperture"
    half_angle_deg: Annotated[Finite, Field(gt=0, lt=45)] = 2.0
    views: Annotated[tuple[Annotated[tuple[Finite, Finite], BeforeValidator(_view)], ...],
                     Field(min_length=1, max_length=10_000)] = ((0.0, 0.0),)
    distance_mm: _Pos | None = None

    @model_validator(mode="after")
    def _above_the_horizon(self) -> "ApertureEffect":
        for t, _ in self.views:
            if not 0.0 <= t + self.half_angle_deg < 90.0:
                raise ValueError(f"views: a detector at theta_r = {t!r} deg with half_angle_deg = "
                                 f"{self.half_angle_deg!r} reaches the horizon")
        return self


class NoiseEffect(SceneEffect):
    effect_name: ClassVar[str] = "noise"
    uncertainty: _Frac = 0.002
    relative: StrictBool | None = None


class StrayLightEffect(SceneEffect):
    effect_name: ClassVar[str] = "stray_light"
    fraction: Annotated[Finite, Field(ge=0, lt=1)] = 0.001


class SphereEffect(SceneEffect):
    """Wall reflectance 0.970-0.985 and ports of at most 10 % of the sphere's area (detector and
    specimen ports included): the range the single-beam substitution model holds in."""

    effect_name: ClassVar[str] = "sphere"
    wall_reflectance: Annotated[Finite, Field(ge=0.970, le=0.985)] = 0.98
    port_fraction: Annotated[Finite, Field(gt=0, le=0.10)] = 0.05
    detector_port: _Pos = 0.01
    specimen_port: Annotated[Finite, Field(ge=0)] = 0.02
    reference_reflectance: Annotated[Finite, Field(gt=0, le=1)] = 0.99

    @model_validator(mode="after")
    def _ports_fit(self) -> "SphereEffect":
        if self.detector_port + self.specimen_port > self.port_fraction:
            raise ValueError(f"detector_port + specimen_port ({self.detector_port!r} + {self.specimen_port!r}) must "
                             f"fit in port_fraction ({self.port_fraction!r})")
        return self


class GlossTrapEffect(SceneEffect):
    effect_name: ClassVar[str] = "gloss_trap"
    specular: Literal["excluded", "included"] = "excluded"
    half_angle_deg: Annotated[Finite, Field(gt=0, lt=45)] = 4.0


def _odd(v: int) -> int:
    if v % 2 == 0:
        raise ValueError(f"expected an odd number of nodes, got {v}")
    return v


class BandpassEffect(SceneEffect):
    effect_name: ClassVar[str] = "bandpass"
    fwhm_nm: _Pos = 10.0
    nodes: Annotated[Whole, Field(ge=3, le=257), AfterValidator(_odd)] = 9


class SpecimenEffect(SceneEffect):
    """A non-uniform specimen (declaring the table means a pattern unless ``uniform = true``)."""

    effect_name: ClassVar[str] = "specimen"
    uniform: StrictBool = False
    period_mm: _Pos = 5.0
    contrast: _Frac = 0.5
    spot_radius_mm: _Pos = 10.0


#: every effect a scene may declare, by its ``[effects.NAME]`` key (the order effects are listed in)
EFFECT_SCHEMAS: dict[str, type[SceneEffect]] = {m.effect_name: m for m in (
    ApertureEffect, NoiseEffect, StrayLightEffect, SphereEffect, GlossTrapEffect, BandpassEffect, SpecimenEffect)}


def _effect(model: Any) -> Any:
    return Union[StrictBool, model] | None  # true: the defaults, false: not declared


def _effects_table(schemas: Mapping[str, type[SceneEffect]]) -> type[BaseModel]:
    fields: dict[str, Any] = {name: (_effect(model), None) for name, model in schemas.items()}
    return create_model("EffectsTable", __base__=Table, **fields)


#: ``[effects]``: one optional table per declared effect (``true``: its defaults, ``false``: absent)
if TYPE_CHECKING:  # built from the declared effects at import: statically, a table
    EffectsTable = Table
else:
    EffectsTable = _effects_table(EFFECT_SCHEMAS)


class SceneBeam(Table):
    kind: Literal["collimated", "conical"] = "collimated"
    emitter_radius_mm: _Pos = 5.0
    specimen_radius_mm: _Pos = 12.5
    distance_mm: _Pos = 76.2
    disk_sampling: str = "auto"


class SceneCollector(Table):
    spec: CollectorSpec = "equal-psa:9x36"
    method: Literal["auto", "rays", "fast"] = "auto"


class TradeoffTable(Table):
    rays: Annotated[list[Annotated[Whole, Field(ge=1, le=10**12)]], Field(min_length=1, max_length=50)] | None = None
    budgets: Annotated[list[str], Field(min_length=1, max_length=20)] | None = None
    repeats: Annotated[Whole, Field(ge=1, le=1000)] = 1
    strategies: Annotated[list[str], Field(min_length=1, max_length=20)] | None = None
    collectors: Annotated[list[CollectorSpec], Field(min_length=1, max_length=50)] | None = None
    fast: StrictBool = True


class PhysicalTable(Table):
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


class SceneFile(Table):
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


# --- effects added by installed packages (entry point group goniobench.effects) -------------------

#: effects of installed plugins, by their ``[effects.NAME]`` key (filled by :func:`plugin_effects`)
_PLUGIN_EFFECTS: dict[str, type[SceneEffect]] = {}
_SCENE_SCHEMA: dict[tuple[str, ...], type[SceneFile]] = {}


def _register_effect(entry: str, obj: Any) -> None:
    if not (isinstance(obj, type) and issubclass(obj, SceneEffect) and obj.effect_name):
        raise ConfigError(f"expected a bench.core.schemas.SceneEffect subclass with an effect_name, got {obj!r}")
    if obj.effect_name in EFFECT_SCHEMAS or obj.effect_name in _PLUGIN_EFFECTS:
        raise ConfigError(f"effect name {obj.effect_name!r} is already taken")
    _PLUGIN_EFFECTS[obj.effect_name] = obj


def plugin_effects() -> dict[str, type[SceneEffect]]:
    """The effects installed ``goniobench.effects`` entry points add (loaded once)."""
    load_plugins(EFFECT_GROUP, _register_effect)
    return dict(_PLUGIN_EFFECTS)


def scene_schema() -> type[SceneFile]:
    """The scene file's schema: :class:`SceneFile`, its ``[effects]`` extended by the installed
    plugins' effects (every reader of a scene file validates with this)."""
    extra = plugin_effects()
    key = tuple(extra)
    if key not in _SCENE_SCHEMA:
        table = _effects_table({**EFFECT_SCHEMAS, **extra})
        _SCENE_SCHEMA[key] = SceneFile if not extra else create_model(
            "SceneFile", __base__=SceneFile, __doc__=SceneFile.__doc__, effects=(table, table()))
    return _SCENE_SCHEMA[key]

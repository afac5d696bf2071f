"""How a specimen family is declared: parameters stated once, and the open registry of families.

A family is a class with a CLI ``name``, a kernel ``model`` id (or
:data:`~virtual.kernels.scatter.MODEL_PYTHON` with a ``sample`` method, counted by
:mod:`virtual.python_engine`) and a tuple of :class:`Param` (name, range, unit, default, doc,
aliases). From that one declaration come the constructor (keywords or positions in the declared
order, each value a number or a spectral table), the validation of every value at every
tabulated wavelength, the parsing of ``name:key=value,...`` strings, the help text, the README
table (:func:`specimen_table_markdown`) and the listing of every family
(:func:`specimen_families`). A parameter the family does not declare is refused, naming the
accepted ones. The family itself writes only :meth:`DeclaredSpecimen.kernel_params` (the
parameter vector its kernel reads, with any check that spans several parameters) and, when it
has one, its density :meth:`~Specimen.bsdf`.

A lab adds its own model without editing this package::

    @register_specimen
    class Velvet(DeclaredSpecimen):
        "My lab's velvet."
        name = "velvet"
        model = MODEL_PYTHON
        parameters = (Param("sheen", 0.5, 0.0, 1.0, doc="sheen weight"),)
        def kernel_params(self, v): return np.array([v["sheen"]])
        def sample(self, wi, n, wavelength_nm, rng): ...

after which ``parse_specimen("velvet:sheen=0.3")`` builds it. Do not decorate a family with
``@dataclass`` yourself: :func:`register_specimen` makes it a frozen dataclass from its
parameters.
"""

from __future__ import annotations

import functools
import math
import types
from dataclasses import dataclass, field
from typing import Any, ClassVar, Mapping

import numpy as np

from bench.core.errors import SpecimenError
from bench.core.plugins import SPECIMEN_GROUP, load_plugins

__all__ = ["Spectral", "Param", "Specimen", "DeclaredSpecimen", "register_specimen", "specimen_family",
           "SPECIMENS", "RESERVED_NAMES", "load_specimen_plugins", "specimen_families", "specimen_table_markdown",
           "weighted_spectrum"]

#: Names parsed by :func:`virtual.specimens.parse_specimen` itself (not declared families).
RESERVED_NAMES = ("colorchecker", "mitsuba")


@dataclass(frozen=True)
class Spectral:
    """A quantity that may depend on wavelength: a constant, or a table interpolated linearly.

    Asking a table for a wavelength outside its range raises :class:`SpecimenError` naming it.
    """

    wavelengths: np.ndarray | None
    values: np.ndarray
    name: str = "value"

    @classmethod
    def of(cls, v: Any, name: str = "value") -> "Spectral":
        if isinstance(v, Spectral):
            return v
        if isinstance(v, (int, float, np.floating, np.integer)):
            return cls(None, np.array([float(v)]), name)
        if isinstance(v, tuple) and len(v) == 2:
            wl, val = (np.asarray(a, dtype=float) for a in v)
            if wl.ndim != 1 or wl.shape != val.shape or wl.size < 2 or np.any(np.diff(wl) <= 0):
                raise SpecimenError(f"{name}: a spectral table needs increasing wavelengths and as many values")
            return cls(wl, val, name)
        raise SpecimenError(f"{name}: expected a number or (wavelengths, values), got {type(v).__name__}")

    @property
    def range_nm(self) -> tuple[float, float] | None:
        if self.wavelengths is None:
            return None
        return float(self.wavelengths[0]), float(self.wavelengths[-1])

    def __call__(self, wavelength_nm: float) -> float:
        if self.wavelengths is None:
            return float(self.values[0])
        lo, hi = self.range_nm  # type: ignore[misc]
        wl = float(wavelength_nm)
        if not lo - 1e-9 <= wl <= hi + 1e-9:
            raise SpecimenError(f"{self.name}: wavelength {wl:g} nm is outside the data ({lo:g}..{hi:g} nm)")
        return float(np.interp(wl, self.wavelengths, self.values))


@dataclass(frozen=True)
class Param:
    """One declared parameter of a specimen family.

    Parameters
    ----------
    name : str
        The keyword (constructor and specimen strings).
    default : float
        Its value when not given (must lie in the range).
    lo, hi : float
        The closed range every value (at every wavelength) must lie in.
    unit : str
        Unit for messages and tables ("" when dimensionless).
    doc : str
        What it is, in a few words.
    aliases : tuple of str
        Other keywords accepted in specimen strings.
    choices : tuple of str
        For a categorical parameter (e.g. a convention): its names; the value is the index
        (``lo = 0``, ``hi = len(choices) - 1``) and strings may give the name.
    """

    name: str
    default: float
    lo: float
    hi: float
    unit: str = ""
    doc: str = ""
    aliases: tuple[str, ...] = ()
    choices: tuple[str, ...] = ()

    def coerce(self, v: Any) -> Any:
        """A choice's name -> its index; any other string is refused naming what is accepted."""
        if isinstance(v, str):
            key = v.strip().lower()
            if self.choices and key in self.choices:
                return float(self.choices.index(key))
            if self.choices:
                raise SpecimenError(f"{self.name} must be one of {', '.join(self.choices)}, got {v!r}")
            try:
                return float(key)
            except ValueError:
                raise SpecimenError(f"{self.name} must be a number, got {v!r}") from None
        return v

    def check(self, v: float) -> float:
        """``v`` as a float, or :class:`SpecimenError` naming the parameter and its range."""
        v = float(v)
        if self.choices and v not in range(len(self.choices)):
            raise SpecimenError(f"{self.name} must be one of {', '.join(self.choices)}, got {v:g}")
        if not (math.isfinite(v) and self.lo <= v <= self.hi):
            u = f" {self.unit}" if self.unit else ""
            raise SpecimenError(f"{self.name} must lie in [{self.lo:.10g}, {self.hi:.10g}]{u}, got {v:g}")
        return v

    def describe(self) -> str:
        """One line of help: ``name (alias a): doc, in [lo, hi] unit, default d``."""
        al = f" (alias {', '.join(self.aliases)})" if self.aliases else ""
        u = f" {self.unit}" if self.unit else ""
        doc = f": {self.doc}" if self.doc else ""
        if self.choices:
            return f"{self.name}{al}{doc}, one of {' | '.join(self.choices)}, default {self.choices[int(self.default)]}"
        return f"{self.name}{al}{doc}, in [{self.lo:.10g}, {self.hi:.10g}]{u}, default {self.default:g}"


# --- the specimen face the devices see -------------------------------------------------------


@dataclass(frozen=True)
class Specimen:
    """Base of every specimen. A device never looks inside: it asks :meth:`params` for the
    parameter vector its kernel reads (``model``), or calls ``sample`` (``MODEL_PYTHON``)."""

    model: ClassVar[int]
    has_density: ClassVar[bool] = False
    reciprocal: ClassVar[bool] = True
    isotropic: ClassVar[bool] = True
    label: str = field(default="", compare=False, kw_only=True)

    def params(self, wavelength_nm: float) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def bsdf(self, wi: np.ndarray, wo: np.ndarray, wavelength_nm: float) -> np.ndarray:
        """BSDF (1/sr) for one incident direction ``wi`` (3,) and outgoing ``wo`` (n, 3)."""
        raise SpecimenError(f"{type(self).__name__} exposes no scattering density")

    def wavelength_range(self) -> tuple[float, float] | None:
        """Where the specimen has data (nm), or ``None`` when it is defined everywhere."""
        return None

    def check_wavelengths(self, wavelengths_nm: np.ndarray) -> None:
        for wl in np.atleast_1d(wavelengths_nm):
            self.params(float(wl))  # raises SpecimenError naming the wavelength

    def transmits(self, wavelength_nm: float) -> bool:
        """Whether any light can leave on the far side (quadrature skips that hemisphere if not)."""
        return True

    def lobes(self, wi: np.ndarray, wavelength_nm: float) -> list[tuple[np.ndarray, float]]:
        """Directions where the density is concentrated, with an angular width (radians):
        hints for the quadrature references (empty for smooth densities)."""
        return []


def weighted_spectrum(specimen: Specimen, wi: np.ndarray, dirs: np.ndarray, weights: np.ndarray,
                      wavelengths_nm: np.ndarray, grid_nm: float | None = None) -> np.ndarray:
    """``weights @ bsdf(wi, dirs, w)`` at each wavelength ``w`` of ``wavelengths_nm`` (held at the
    specimen's range ends beyond it): all at once through the specimen's ``bsdf_spectrum``
    (``(wavelengths, directions)``) where it has one, else wavelength by wavelength -- at each
    wavelength, or with ``grid_nm`` on a grid of that step interpolated to them (for many
    wavelengths, e.g. a detector's pixels)."""
    wl = np.asarray(wavelengths_nm, dtype=float)
    rng = specimen.wavelength_range()
    at = np.clip(wl, rng[0], rng[1]) if rng is not None else wl
    many = getattr(specimen, "bsdf_spectrum", None)
    if many is not None:
        return np.asarray(many(wi, dirs, at), dtype=float) @ weights
    if grid_nm is None:
        return np.array([float(weights @ np.asarray(specimen.bsdf(wi, dirs, float(w)), dtype=float)) for w in at])
    step = float(grid_nm)
    grid = np.arange(step * math.floor(at.min() / step), step * math.ceil(at.max() / step) + step, step)
    if rng is not None:
        grid = np.clip(grid, rng[0], rng[1])
    f = np.array([float(weights @ np.asarray(specimen.bsdf(wi, dirs, float(w)), dtype=float)) for w in grid])
    return np.interp(at, grid, f)


@dataclass(frozen=True)
class DeclaredSpecimen(Specimen):
    """Base of the declared families (see the module docstring). Its fields are the declared
    parameters, each turned into a :class:`Spectral` and validated at construction."""

    name: ClassVar[str] = ""
    parameters: ClassVar[tuple[Param, ...]] = ()
    #: True when no light leaves on the far side at any wavelength
    opaque: ClassVar[bool] = False
    #: Which published definition the model follows (README table; "" for none in particular)
    convention: ClassVar[str] = ""

    def __post_init__(self) -> None:
        for p in self.parameters:
            s = Spectral.of(p.coerce(getattr(self, p.name)), p.name)
            object.__setattr__(self, p.name, s)
            for v in s.values:  # every table entry, also outside the overlap of the tables
                p.check(float(v))
        rng = self.wavelength_range()
        if rng is not None and rng[0] > rng[1]:
            raise SpecimenError(f"{type(self).__name__}: the spectral tables do not overlap")
        grid = sorted({float(w) for p in self.parameters
                       for w in (getattr(self, p.name).wavelengths if getattr(self, p.name).wavelengths is not None
                                 else [])})
        for w in [w for w in grid if rng is None or rng[0] <= w <= rng[1]] or [550.0]:
            self.params(w)  # the checks spanning several parameters, at every tabulated wavelength

    def kernel_params(self, v: Mapping[str, float]) -> np.ndarray:  # pragma: no cover - abstract
        """The parameter vector the kernel reads, from the checked values ``v`` (name -> float)
        at one wavelength; raises :class:`SpecimenError` for combinations out of range."""
        raise NotImplementedError

    def values(self, wavelength_nm: float) -> dict[str, float]:
        """The declared parameters at one wavelength, each checked against its range."""
        wl = float(wavelength_nm)
        return {p.name: p.check(getattr(self, p.name)(wl)) for p in self.parameters}

    def params(self, wavelength_nm: float) -> np.ndarray:
        return np.asarray(self.kernel_params(self.values(wavelength_nm)), dtype=np.float64)

    def transmits(self, wavelength_nm: float) -> bool:
        return not self.opaque

    def wavelength_range(self) -> tuple[float, float] | None:
        ranges = [getattr(self, p.name).range_nm for p in self.parameters if getattr(self, p.name).range_nm]
        if not ranges:
            return None
        return max(r[0] for r in ranges), min(r[1] for r in ranges)

    # -- the declaration's other faces ---------------------------------------------------------
    @classmethod
    def accepted(cls) -> list[str]:
        return [p.name for p in cls.parameters]

    @classmethod
    def help(cls) -> str:
        """The parameters, one per line (what error messages and ``bench specimens`` show)."""
        return "\n".join(p.describe() for p in cls.parameters)

    @classmethod
    def keyword_defaults(cls, given: Mapping[str, float]) -> dict[str, float]:
        """Defaults that depend on which keywords a specimen string gave (none by default)."""
        return {}

    @classmethod
    def from_keywords(cls, kw: Mapping[str, float], spec: str = "") -> "DeclaredSpecimen":
        """Build from keywords (aliases allowed); unknown or repeated ones are refused."""
        where = f"specimen {spec!r}: " if spec else ""
        names = {p.name: p.name for p in cls.parameters}
        names.update({a: p.name for p in cls.parameters for a in p.aliases})
        args: dict[str, float] = {}
        for key, value in kw.items():
            name = names.get(key)
            if name is None:
                raise SpecimenError(f"{where}unknown parameter {key!r} for {cls.name}; "
                                    f"accepted: {', '.join(cls.accepted())}")
            if name in args:
                raise SpecimenError(f"{where}parameter {name} given twice")
            args[name] = value
        return cls(**{**cls.keyword_defaults(args), **args})


#: name -> family; read-only view of the registry (:func:`register_specimen` adds to it).
_REGISTRY: dict[str, type[DeclaredSpecimen]] = {}
SPECIMENS: Mapping[str, type[DeclaredSpecimen]] = types.MappingProxyType(_REGISTRY)


def _refuse_unknown(cls: type[DeclaredSpecimen]) -> None:
    """Wrap the dataclass constructor so unknown keywords and extra positions name the accepted
    parameters instead of raising a bare TypeError."""
    init = cls.__init__
    accepted = cls.accepted()

    @functools.wraps(init)
    def __init__(self: Any, *args: Any, **kw: Any) -> None:
        for key in kw:
            if key not in accepted and key != "label":
                raise SpecimenError(f"unknown parameter {key!r} for {cls.name or cls.__name__}; "
                                    f"accepted: {', '.join(accepted)}")
        if len(args) > len(accepted):
            raise SpecimenError(f"{cls.name or cls.__name__} takes at most {len(accepted)} parameters "
                                f"({', '.join(accepted)}), got {len(args)}")
        init(self, *args, **kw)

    cls.__init__ = __init__  # type: ignore[method-assign]


def register_specimen(cls: type[DeclaredSpecimen]) -> type[DeclaredSpecimen]:
    """Declare a specimen family and make its ``name`` usable in specimen strings.

    Turns the class into a frozen dataclass whose fields are its :attr:`parameters` (in the
    declared order, defaults from the declaration), checks the declaration (name free, defaults
    in range, keywords unambiguous) and registers it. Returns the class (use as a decorator).
    """
    if not (isinstance(cls, type) and issubclass(cls, DeclaredSpecimen)):
        raise SpecimenError(f"register_specimen needs a DeclaredSpecimen subclass, got {cls!r}")
    name = str(cls.__dict__.get("name", "")).strip().lower()
    if not name or any(c in name for c in ":,= "):
        raise SpecimenError(f"{cls.__name__}: a family needs a name without ':', ',', '=' or spaces")
    if name in RESERVED_NAMES or (name in _REGISTRY and _REGISTRY[name].__qualname__ != cls.__qualname__):
        raise SpecimenError(f"specimen name {name!r} is already taken")
    if not isinstance(cls.__dict__.get("model", getattr(cls, "model", None)), int):
        raise SpecimenError(f"{cls.__name__}: declare its kernel model id (or MODEL_PYTHON)")
    keys: set[str] = set()
    for p in cls.parameters:
        for k in (p.name, *p.aliases):
            if k in keys or k == "label":
                raise SpecimenError(f"{cls.__name__}: keyword {k!r} declared twice")
            keys.add(k)
        p.check(p.default)
    cls.name = name
    ann = {k: v for k, v in cls.__dict__.get("__annotations__", {}).items()}
    for p in cls.parameters:
        ann[p.name] = Any
        setattr(cls, p.name, p.default)
    cls.__annotations__ = ann
    cls = dataclass(frozen=True)(cls)
    _refuse_unknown(cls)
    _REGISTRY[name] = cls
    return cls


def _register_plugin(entry: str, obj: Any) -> None:
    """A ``goniobench.specimens`` entry point: a family (registered here unless its module's
    decorator did) or a module whose import registered its families."""
    if isinstance(obj, types.ModuleType):
        return
    if not (isinstance(obj, type) and issubclass(obj, DeclaredSpecimen)):
        raise SpecimenError(f"expected a DeclaredSpecimen subclass or a module, got {obj!r}")
    if _REGISTRY.get(str(getattr(obj, "name", "")).strip().lower()) is not obj:
        register_specimen(obj)


def load_specimen_plugins() -> None:
    """Register the families of every installed ``goniobench.specimens`` entry point (once)."""
    load_plugins(SPECIMEN_GROUP, _register_plugin)


def specimen_family(name: str) -> type[DeclaredSpecimen] | None:
    """The registered family called ``name`` (case-insensitive; installed plugins are looked at
    on the first miss), or None."""
    key = name.strip().lower()
    if key not in _REGISTRY:
        load_specimen_plugins()
    return _REGISTRY.get(key)


def specimen_families(builtin_only: bool = False) -> list[dict[str, Any]]:
    """Every registered family with its parameters (for ``bench specimens`` and docs): the
    project's own and, unless ``builtin_only``, the installed plugins' and any registered since."""
    if not builtin_only:
        load_specimen_plugins()
    out = []
    for name in sorted(_REGISTRY):
        cls = _REGISTRY[name]
        if builtin_only and not cls.__module__.startswith(f"{__package__}."):
            continue
        out.append({
            "name": name, "class": f"{cls.__module__}.{cls.__qualname__}", "model": int(cls.model),
            "doc": (cls.__doc__ or "").strip().splitlines()[0] if cls.__doc__ else "",
            "convention": getattr(cls, "convention", ""),
            "parameters": [{"name": p.name, "aliases": list(p.aliases), "range": [p.lo, p.hi], "unit": p.unit,
                            "default": p.default, "doc": p.doc, "choices": list(p.choices)}
                           for p in cls.parameters],
        })
    return out


def specimen_table_markdown(builtin_only: bool = False) -> str:
    """The table of specimen families (the README's with ``builtin_only``): one row per
    parameter, the family's convention (which published definition it follows) on its first row."""
    rows = ["| specimen | convention | parameter | range | unit | default | meaning |",
            "|---|---|---|---|---|---|---|"]
    for fam in specimen_families(builtin_only):
        for i, p in enumerate(fam["parameters"]):
            key = p["name"] + (f" ({', '.join(p['aliases'])})" if p["aliases"] else "")
            lo, hi = p["range"]
            rng = " \\| ".join(p["choices"]) if p["choices"] else f"{lo:.10g} .. {hi:.10g}"
            default = p["choices"][int(p["default"])] if p["choices"] else f"{p['default']:g}"
            first = i == 0
            rows.append(f"| {fam['name'] if first else ''} | {fam['convention'] if first else ''} | `{key}` | {rng} "
                        f"| {p['unit'] or '-'} | {default} | {p['doc']} |")
    return "\n".join(rows) + "\n"

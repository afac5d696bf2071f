"""Specimens: black boxes that scatter rays.

A device never looks inside a specimen. It hands the specimen an incoming direction and a
wavelength and gets back an outgoing direction, or absorption. Two faces of the same thing:

* ``scatter(model, params, wx, wy, wz, s)`` -- one ``@njit`` function the ray kernels call. It
  dispatches on the specimen's integer ``model`` id and reads the model's parameter vector
  ``params`` (what :meth:`Specimen.params` returns for a wavelength). ``(wx, wy, wz)`` is the
  unit vector from the specimen toward the source; ``s`` the caller's xoshiro state. It returns
  ``(ox, oy, oz, alive)``: a unit outgoing direction (oz > 0 reflected, oz < 0 transmitted) or
  ``alive = False`` when the ray was absorbed. Sampling is analog: the direction density is
  ``f_s |cos theta_o| / albedo`` and the survival probability is the directional albedo, so
  counting rays estimates the BSDF without weights.
* :meth:`Specimen.bsdf` (optional, ``has_density``): the BSDF value for arrays of directions,
  used by the exact fast path and by the quadrature references.

Specimen strings (CLI): ``name:key=value,key=value``, e.g. ``lambert:reflectance=0.375``,
``colorchecker:dark skin``. :func:`parse_specimen` lists the known names on error.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable, ClassVar

import numpy as np
from numba import njit

from bench.errors import SpecimenError
from virtual.rng import next_double
from virtual.sampling import sample_cosine_hemisphere

__all__ = [
    "Spectral",
    "Specimen",
    "Lambertian",
    "scatter",
    "parse_specimen",
    "SPECIMENS",
    "MODEL_LAMBERT",
]

INV_PI = 1.0 / math.pi

# Model ids: one branch each in `scatter`. Keep them stable; kernels are cached by numba.
MODEL_LAMBERT = 0


# --- spectral parameters ---------------------------------------------------------------------


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


def _fraction(name: str, v: float) -> float:
    if not (math.isfinite(v) and 0.0 <= v <= 1.0):
        raise SpecimenError(f"{name} must lie in [0, 1], got {v}")
    return v


# --- the specimen face the devices see -------------------------------------------------------


@dataclass(frozen=True)
class Specimen:
    """Base of kernel specimens. Subclasses set ``model`` and implement :meth:`params`."""

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


@dataclass(frozen=True)
class Lambertian(Specimen):
    """Ideal diffuse reflector/transmitter: f_r = R/pi above, f_t = T/pi below, 1 - R - T absorbed."""

    model: ClassVar[int] = MODEL_LAMBERT
    has_density: ClassVar[bool] = True
    reflectance: Any = 0.5
    transmittance: Any = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "reflectance", Spectral.of(self.reflectance, "reflectance"))
        object.__setattr__(self, "transmittance", Spectral.of(self.transmittance, "transmittance"))
        for s in (self.reflectance, self.transmittance):
            for v in s.values:
                _fraction(s.name, float(v))
        both = self.reflectance.wavelengths is None and self.transmittance.wavelengths is None
        if both and self.reflectance.values[0] + self.transmittance.values[0] > 1.0 + 1e-12:
            raise SpecimenError("reflectance + transmittance must not exceed 1")

    def params(self, wavelength_nm: float) -> np.ndarray:
        r, t = self.reflectance(wavelength_nm), self.transmittance(wavelength_nm)
        if r + t > 1.0 + 1e-12:
            raise SpecimenError(f"reflectance + transmittance = {r + t:g} > 1 at {wavelength_nm:g} nm")
        return np.array([r, t], dtype=np.float64)

    def bsdf(self, wi: np.ndarray, wo: np.ndarray, wavelength_nm: float) -> np.ndarray:
        r, t = self.params(wavelength_nm)
        wo = np.atleast_2d(wo)
        same_side = np.sign(wo[:, 2]) == np.sign(wi[2] if wi[2] != 0 else 1.0)
        return np.where(same_side, r, t) * INV_PI

    def wavelength_range(self) -> tuple[float, float] | None:
        ranges = [s.range_nm for s in (self.reflectance, self.transmittance) if s.range_nm]
        if not ranges:
            return None
        return max(r[0] for r in ranges), min(r[1] for r in ranges)


# --- the kernel face --------------------------------------------------------------------------


@njit(inline="always", cache=True)
def _lambert(p, wz, s):
    u = next_double(s)
    if u >= p[0] + p[1]:
        return 0.0, 0.0, 0.0, False
    x, y, z = sample_cosine_hemisphere(s)
    # reflected rays leave on the side of the source, transmitted rays on the other side
    up = wz >= 0.0
    if u >= p[0]:
        up = not up
    return x, y, (z if up else -z), True


@njit(cache=True)
def scatter(model, p, wx, wy, wz, s):
    """Scatter one ray (see the module docstring for the contract)."""
    if model == MODEL_LAMBERT:
        return _lambert(p, wz, s)
    return 0.0, 0.0, 0.0, False


# --- specimen strings -------------------------------------------------------------------------


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


def _kwargs(text: str, spec: str) -> dict[str, float]:
    out: dict[str, float] = {}
    for item in filter(None, (t.strip() for t in text.split(","))):
        if "=" not in item:
            raise SpecimenError(f"specimen {spec!r}: expected key=value, got {item!r}")
        k, v = (t.strip() for t in item.split("=", 1))
        try:
            out[k] = float(v)
        except ValueError:
            raise SpecimenError(f"specimen {spec!r}: {k} must be a number, got {v!r}") from None
    return out


def _lambert_factory(kw: dict[str, float]) -> Lambertian:
    r = kw.pop("reflectance", kw.pop("albedo", kw.pop("R", 0.5 if "transmittance" not in kw else 0.0)))
    t = kw.pop("transmittance", kw.pop("T", 0.0))
    return Lambertian(reflectance=r, transmittance=t)


# name -> (factory taking keyword floats, parameter help)
SPECIMENS: dict[str, tuple[Callable[[dict[str, float]], Specimen], str]] = {
    "lambert": (_lambert_factory, "reflectance|albedo=R, transmittance=T"),
}


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
    if name not in SPECIMENS:
        known = ", ".join(sorted([*SPECIMENS, "colorchecker"]))
        raise SpecimenError(f"unknown specimen {name!r}; known: {known}")
    factory, help_ = SPECIMENS[name]
    kw = _kwargs(rest, text)
    try:
        specimen = factory(kw)
    except TypeError as exc:
        raise SpecimenError(f"specimen {text!r}: {exc} (parameters: {help_})") from None
    if kw:
        raise SpecimenError(f"specimen {text!r}: unknown parameter(s) {', '.join(kw)} (parameters: {help_})")
    object.__setattr__(specimen, "label", specimen.label or text)
    return specimen

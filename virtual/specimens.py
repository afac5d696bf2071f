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

Models (``model`` id, CLI name, parameter vector from :meth:`Specimen.params`):

====  ==============  =========================  ==========================================
id    CLI name        class                      params
====  ==============  =========================  ==========================================
0     lambert         :class:`Lambertian`        [R, T]
1     oren-nayar      :class:`OrenNayar`         [albedo, A, B, albedo*A, 2*albedo*B/pi]
2     phong           :class:`Phong`             [kd, ks, n, ks*(n+2)/(n+1)]
3     ggx             :class:`GGX`               [alpha, alpha, eta, k]
4     aniso-ggx       :class:`AnisoGGX`          [alpha_x, alpha_y, eta, k]
5     plastic         :class:`RoughPlastic`      [alpha, eta, kd, 1/(1 - F_avg(eta))]
6     dielectric      :class:`RoughDielectric`   [alpha, eta]
====  ==============  =========================  ==========================================

Every branch of ``scatter`` samples exactly (no weights): a proposal whose density dominates
``f_s |cos theta_o|`` with total mass <= 1, then survival with the ratio (Russian roulette on a
weight <= 1). Opaque models are two-sided (mirrored when the source is below). The class docs
state each model's formula, its sampling argument, and its parameter ranges (a parameter out of
range raises :class:`SpecimenError` naming it). ``reciprocal``/``isotropic`` are class flags.

Specimen strings (CLI): ``name:key=value,key=value``, e.g. ``lambert:reflectance=0.375``,
``ggx:alpha=0.2,eta=1.5,k=0``, ``colorchecker:dark skin``. :func:`parse_specimen` lists the
known names on error.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any, Callable, ClassVar

import numpy as np
from numba import njit

from bench.core.errors import SpecimenError
from virtual.rng import next_double
from virtual.sampling import sample_cosine_hemisphere, sincos_2pi, warp_cosine_hemisphere

__all__ = [
    "Spectral",
    "Specimen",
    "Lambertian",
    "scatter",
    "scatter_given",
    "GIVEN_MODELS",
    "GIVEN_UNIFORMS",
    "parse_specimen",
    "SPECIMENS",
    "OrenNayar",
    "Phong",
    "GGX",
    "AnisoGGX",
    "RoughPlastic",
    "RoughDielectric",
    "MODEL_LAMBERT",
    "MODEL_OREN_NAYAR",
    "MODEL_PHONG",
    "MODEL_GGX",
    "MODEL_ANISO_GGX",
    "MODEL_PLASTIC",
    "MODEL_DIELECTRIC",
    "MODEL_PYTHON",
]

INV_PI = 1.0 / math.pi

# Model ids: one branch each in `scatter`. Keep them stable; kernels are cached by numba.
MODEL_LAMBERT = 0
MODEL_OREN_NAYAR = 1
MODEL_PHONG = 2
MODEL_GGX = 3
MODEL_ANISO_GGX = 4
MODEL_PLASTIC = 5
MODEL_DIELECTRIC = 6
#: Specimens without a kernel (e.g. :class:`virtual.mitsuba.MitsubaSpecimen`): the devices count
#: their rays with :mod:`virtual.python_engine`, which calls the specimen's ``sample`` method.
MODEL_PYTHON = -1


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

    def transmits(self, wavelength_nm: float) -> bool:
        """Whether any light can leave on the far side (quadrature skips that hemisphere if not)."""
        return True

    def lobes(self, wi: np.ndarray, wavelength_nm: float) -> list[tuple[np.ndarray, float]]:
        """Directions where the density is concentrated, with an angular width (radians):
        hints for the quadrature references (empty for smooth densities)."""
        return []


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

    def transmits(self, wavelength_nm: float) -> bool:
        return bool(self.params(wavelength_nm)[1] > 0.0)

    def wavelength_range(self) -> tuple[float, float] | None:
        ranges = [s.range_nm for s in (self.reflectance, self.transmittance) if s.range_nm]
        if not ranges:
            return None
        return max(r[0] for r in ranges), min(r[1] for r in ranges)


@dataclass(frozen=True)
class _Analytic(Specimen):
    """Base of the analytic models: spectral fields listed in ``_fields``, validated parameters."""

    has_density: ClassVar[bool] = True
    _fields: ClassVar[tuple[str, ...]] = ()

    def __post_init__(self) -> None:
        _init_spectral(self, self._fields)

    def _values(self, wl: float) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def params(self, wavelength_nm: float) -> np.ndarray:
        return self._values(float(wavelength_nm))

    def transmits(self, wavelength_nm: float) -> bool:
        return False

    def wavelength_range(self) -> tuple[float, float] | None:
        ranges = [getattr(self, n).range_nm for n in self._fields if getattr(self, n).range_nm]
        if not ranges:
            return None
        return max(r[0] for r in ranges), min(r[1] for r in ranges)


# --- shared physics (numpy for densities, njit for kernels) ----------------------------------
#
# Conventions. Every analytic model below is written in the *local frame of the lit side*: when
# the source is below the specimen (w_z < 0) an opaque model is mirrored in the specimen plane
# (two-sided), and the dielectric interface swaps the media (eta -> 1/eta). Fresnel factors are
# unpolarized. GGX uses Smith's height-correlated masking-shadowing
#     G2 = 1 / (1 + L(wi) + L(wo)),  G1(w) = 1 / (1 + L(w)),
#     L(w) = (sqrt(1 + (ax^2 wx^2 + ay^2 wy^2) / wz^2) - 1) / 2,
# and D(m) = 1 / (pi ax ay (mx^2/ax^2 + my^2/ay^2 + mz^2)^2). With n(w) = sqrt(ax^2 wx^2 +
# ay^2 wy^2 + wz^2) one has G2 / (4 zi zo) = 1 / (2 (n_i zo + n_o zi)) and
# G2 / G1(wi) = (zi + n_i) zo / (n_i zo + n_o zi): no division by a grazing cosine anywhere.


def _np_fresnel_conductor(c: np.ndarray, eta: float, k: float) -> np.ndarray:
    """Exact unpolarized Fresnel reflectance of a conductor (eta + i k) for cosines ``c`` in [0, 1].

    With ``k = 0`` it is the dielectric reflectance (total internal reflection included).
    """
    c = np.clip(c, 0.0, 1.0)
    c2 = c * c
    s2 = 1.0 - c2
    e2, k2 = eta * eta, k * k
    t0 = e2 - k2 - s2
    a2b2 = np.sqrt(t0 * t0 + 4.0 * e2 * k2)
    t1 = a2b2 + c2
    a = np.sqrt(np.maximum(0.5 * (a2b2 + t0), 0.0))
    t2 = 2.0 * c * a
    rs = (t1 - t2) / np.maximum(t1 + t2, 1e-300)
    t3 = c2 * a2b2 + s2 * s2
    t4 = t2 * s2
    rp = rs * (t3 - t4) / np.maximum(t3 + t4, 1e-300)
    return 0.5 * (rp + rs)


def _np_fresnel_dielectric(c: np.ndarray, eta: float) -> np.ndarray:
    """Unpolarized dielectric reflectance for cosines ``c`` >= 0 on the incident side, eta = n_t/n_i."""
    c = np.clip(c, 0.0, 1.0)
    st2 = (1.0 - c * c) / (eta * eta)
    ct = np.sqrt(np.maximum(1.0 - st2, 0.0))
    rs = (c - eta * ct) / np.maximum(c + eta * ct, 1e-300)
    rp = (eta * c - ct) / np.maximum(eta * c + ct, 1e-300)
    return np.where(st2 >= 1.0, 1.0, 0.5 * (rs * rs + rp * rp))


def _np_ggx_d(hx, hy, hz, ax: float, ay: float) -> np.ndarray:
    q = hx * hx / (ax * ax) + hy * hy / (ay * ay) + hz * hz
    return 1.0 / (math.pi * ax * ay * q * q)


def _np_ggx_n(wx, wy, wz, ax: float, ay: float) -> np.ndarray:
    """n(w) = sqrt(ax^2 wx^2 + ay^2 wy^2 + wz^2) (see the conventions above)."""
    return np.sqrt(ax * ax * wx * wx + ay * ay * wy * wy + wz * wz)


def _np_ggx_reflection(wi: np.ndarray, wo: np.ndarray, ax: float, ay: float, fresnel) -> np.ndarray:
    """F D G2 / (4 zi zo) for wi (3,) with zi > 0 and wo (n, 3); 0 where zo <= 0."""
    zi = wi[2]
    zo = wo[:, 2]
    hx, hy, hz = wi[0] + wo[:, 0], wi[1] + wo[:, 1], zi + zo
    inv = 1.0 / np.maximum(np.sqrt(hx * hx + hy * hy + hz * hz), 1e-300)
    hx, hy, hz = hx * inv, hy * inv, hz * inv
    c = wi[0] * hx + wi[1] * hy + zi * hz
    ni = _np_ggx_n(wi[0], wi[1], zi, ax, ay)
    no = _np_ggx_n(wo[:, 0], wo[:, 1], np.maximum(zo, 0.0), ax, ay)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        f = fresnel(c) * _np_ggx_d(hx, hy, hz, ax, ay) / (2.0 * (ni * zo + no * zi))
    return np.where(zo > 0.0, np.nan_to_num(f, nan=0.0, posinf=0.0), 0.0)


def _local(wi: np.ndarray, wo: np.ndarray) -> tuple[np.ndarray, np.ndarray, bool]:
    """Mirror (wi, wo) so that wi is on the +z side; returns (wi, wo (n,3), flipped)."""
    wi = np.asarray(wi, dtype=np.float64).reshape(3)
    wo = np.atleast_2d(np.asarray(wo, dtype=np.float64))
    if wi[2] < 0.0:
        m = np.array([1.0, 1.0, -1.0])
        return wi * m, wo * m, True
    return wi, wo, False


@njit(inline="always", cache=True)
def _unit_disk(s):
    """A uniform point (a, b) of the open unit disk minus its centre, and r2 = a^2 + b^2.

    r2 is uniform in (0, 1) and independent of the direction (a, b) / sqrt(r2)."""
    while True:
        a = 2.0 * next_double(s) - 1.0
        b = 2.0 * next_double(s) - 1.0
        r2 = a * a + b * b
        if r2 < 1.0 and r2 > 0.0:
            return a, b, r2


@njit(inline="always", cache=True)
def _fresnel_conductor_ratio(c, eta, k):
    """Scalar twin of :func:`_np_fresnel_conductor` (c in [0, 1]) as ``(num, den)``, F = num / den,
    den >= 0: F = (Rs + Rp) / 2 with Rp = Rs (t3 - t4) / (t3 + t4) is Rs t3 / (t3 + t4), and Rs
    = (t1 - t2) / (t1 + t2); callers compare against F without dividing. With k = 0 it is the
    dielectric's F, total internal reflection (eta < 1) included."""
    c2 = c * c
    s2 = 1.0 - c2
    e2 = eta * eta
    k2 = k * k
    t0 = e2 - k2 - s2
    a2b2 = math.sqrt(t0 * t0 + 4.0 * e2 * k2)
    t1 = a2b2 + c2
    a = math.sqrt(max(0.5 * (a2b2 + t0), 0.0))
    t2 = 2.0 * c * a
    t3 = c2 * a2b2 + s2 * s2
    t4 = t2 * s2
    return (t1 - t2) * t3, (t1 + t2) * (t3 + t4)


@njit(inline="always", cache=True)
def _fresnel_dielectric(c, eta):
    """(F, cos_t) for incident cosine c in [0, 1] and eta = n_t / n_i; F = 1, cos_t = 0 on TIR."""
    st2 = (1.0 - c * c) / (eta * eta)
    if st2 >= 1.0:
        return 1.0, 0.0
    ct = math.sqrt(1.0 - st2)
    rs = (c - eta * ct) / max(c + eta * ct, 1e-300)
    rp = (eta * c - ct) / max(eta * c + ct, 1e-300)
    return 0.5 * (rs * rs + rp * rp), ct


@njit(inline="always", cache=True)
def _ggx_vndf_given(wx, wy, wz, ax, ay, inv_ni, ca, sa, r2):
    """A microfacet normal from GGX's distribution of visible normals for w (wz > 0), given
    ``inv_ni`` = 1 / |(ax wx, ay wy, wz)| (:func:`_ggx_n`, which G1 needs too) and a uniform
    point of the unit disk as its direction (ca, sa) (unit) and squared radius r2. Branch-free.

    Dupuy & Benyoub (2023) "spherical caps" form of Heitz (2018): in the stretched frame the
    visible normal is h = c + v with c uniform on the cap z > -v_z of the unit sphere. The cap
    point from the disk point: z = 1 - q r2 with q = 1 + v_z and sin(theta) (cos, sin)(phi) =
    (ca, sa) sqrt(r2 q (2 - q r2)) -- no trigonometric call.
    """
    vx = ax * wx * inv_ni
    vy = ay * wy * inv_ni
    vz = wz * inv_ni
    q = 1.0 + vz
    z = 1.0 - q * r2
    sc = math.sqrt(max(r2 * q * (2.0 - q * r2), 0.0))
    hx = ca * sc + vx
    hy = sa * sc + vy
    hz = max(z + vz, 0.0)
    mx = ax * hx
    my = ay * hy
    n2 = mx * mx + my * my + hz * hz
    good = n2 > 0.0
    inv = 1.0 / math.sqrt(n2 if good else 1.0)
    return (mx * inv if good else 0.0), (my * inv if good else 0.0), (hz * inv if good else 1.0)


@njit(inline="always", cache=True)
def _disk_direction(s):
    """A uniform point of the unit disk drawn by rejection from ``s``: its direction (unit) and
    its squared radius, uniform in (0, 1)."""
    a, b, r2 = _unit_disk(s)
    inv = 1.0 / math.sqrt(r2)
    return a * inv, b * inv, r2


@njit(inline="always", cache=True)
def _ggx_vndf(wx, wy, wz, ax, ay, s):
    """:func:`_ggx_vndf_given` with the disk point drawn by rejection from the stream ``s``."""
    ca, sa, r2 = _disk_direction(s)
    return _ggx_vndf_given(wx, wy, wz, ax, ay, 1.0 / _ggx_n(wx, wy, wz, ax, ay), ca, sa, r2)


@njit(inline="always", cache=True)
def _ggx_n(wx, wy, wz, ax, ay):
    return math.sqrt(ax * ax * wx * wx + ay * ay * wy * wy + wz * wz)


@njit(inline="always", cache=True)
def _g2_over_g1_ratio(wz, ni, oz, no):
    """G2(wi, wo) / G1(wi) as ``(num, den)`` from the cosines and :func:`_ggx_n` of both
    directions; den > 0 for wz, oz > 0."""
    return (wz + ni) * oz, ni * oz + no * wz


@njit(inline="always", cache=True)
def _g2_over_g1(wx, wy, wz, ox, oy, oz, ax, ay):
    """G2(wi, wo) / G1(wi) for wz, oz > 0 (<= 1)."""
    num, den = _g2_over_g1_ratio(wz, _ggx_n(wx, wy, wz, ax, ay), oz, _ggx_n(ox, oy, oz, ax, ay))
    return num / den


@njit(inline="always", cache=True)
def _frame(nx, ny, nz):
    """An orthonormal basis (t, b) around the unit vector n (Duff et al. 2017, branchless)."""
    sign = math.copysign(1.0, nz)
    a = -1.0 / (sign + nz)
    b = nx * ny * a
    return (1.0 + sign * nx * nx * a, sign * b, -sign * nx,
            b, sign + ny * ny * a, -ny)


_DEAD = (0.0, 0.0, 0.0, False)


# --- Oren-Nayar --------------------------------------------------------------------------------


@dataclass(frozen=True)
class OrenNayar(_Analytic):
    """Oren-Nayar (1994) qualitative rough-diffuse reflector (opaque, two-sided).

    f = albedo/pi (A + B max(0, cos(phi_o - phi_i)) sin(alpha) tan(beta)), alpha = max(theta_i,
    theta_o), beta = min(...), A = 1 - sigma^2 / (2 (sigma^2 + 0.33)), B = 0.45 sigma^2 / (sigma^2 +
    0.09), sigma in radians (given in degrees). Equivalently f = albedo/pi (A + B max(0, d) /
    max(cos theta_i, cos theta_o)) with d = (wi_x wo_x + wi_y wo_y) -- the form used here.

    The model is not energy conserving in general (it was fitted, not derived). It is sampled
    exactly: f cos(theta_o) <= albedo/pi (A cos(theta_o) + B max(0, cos dphi)) everywhere, a
    mixture of a cosine lobe (mass albedo A) and "uniform in cos(theta_o), density cos(dphi)/2
    in azimuth" (mass 2 albedo B / pi); a proposal from it survives with probability
    f cos / (mixture) <= 1. That needs albedo (A + 2 B / pi) <= 1, which is required here (it
    also proves the model conserves energy for such parameters).

    params: ``[albedo, A, B, albedo*A, 2*albedo*B/pi]``.
    """

    model: ClassVar[int] = MODEL_OREN_NAYAR
    has_density: ClassVar[bool] = True
    sigma: Any = 20.0
    albedo: Any = 0.8

    _fields: ClassVar[tuple[str, ...]] = ("sigma", "albedo")

    def _values(self, wl: float) -> np.ndarray:
        sig = _in_range("sigma", self.sigma(wl), 0.0, 90.0, "degrees")
        rho = _fraction("albedo", self.albedo(wl))
        s2 = math.radians(sig) ** 2
        a = 1.0 - 0.5 * s2 / (s2 + 0.33)
        b = 0.45 * s2 / (s2 + 0.09)
        if rho * (a + 2.0 * b / math.pi) > 1.0 + 1e-12:
            raise SpecimenError(f"oren-nayar: albedo = {rho:g} too large for sigma = {sig:g} deg: exact "
                                f"sampling needs albedo * (A + 2B/pi) <= 1, i.e. albedo <= "
                                f"{1.0 / (a + 2.0 * b / math.pi):.6g}")
        return np.array([rho, a, b, rho * a, 2.0 * rho * b / math.pi])

    def bsdf(self, wi: np.ndarray, wo: np.ndarray, wavelength_nm: float) -> np.ndarray:
        rho, a, b, _, _ = self.params(wavelength_nm)
        wi, wo, _ = _local(wi, wo)
        zo = wo[:, 2]
        d = np.maximum(wi[0] * wo[:, 0] + wi[1] * wo[:, 1], 0.0)
        den = np.maximum(np.maximum(wi[2], zo), 1e-300)
        f = rho / math.pi * (a + b * d / den)
        return np.where((zo > 0.0) & (wi[2] > 0.0), f, 0.0)


@njit(inline="always", cache=True)
def _oren_nayar(p, wx, wy, wz, s):
    flip = wz < 0.0
    if flip:
        wz = -wz
    if not (wz > 0.0):
        return _DEAD
    u = next_double(s)
    si2 = wx * wx + wy * wy
    if si2 > 0.0:
        inv = 1.0 / math.sqrt(si2)
        cp = wx * inv
        sp = wy * inv
    else:
        cp = 1.0
        sp = 0.0
    if u < p[3]:
        a, b, r2 = _unit_disk(s)
        ox = a
        oy = b
        oz = math.sqrt(1.0 - r2)
    elif u < p[3] + p[4]:
        oz = 1.0 - next_double(s)  # (0, 1]
        so = math.sqrt((1.0 - oz) * (1.0 + oz))
        sd = 2.0 * next_double(s) - 1.0  # sin(dphi): dphi has density cos(dphi)/2 on (-pi/2, pi/2)
        cd = math.sqrt(max(1.0 - sd * sd, 0.0))
        ox = so * (cd * cp - sd * sp)
        oy = so * (sd * cp + cd * sp)
    else:
        return _DEAD
    so2 = ox * ox + oy * oy
    d_ref = max(ox * cp + oy * sp, 0.0)
    c_term = d_ref / math.sqrt(so2) if so2 > 0.0 else 0.0
    den = p[1] * oz + p[2] * c_term
    num = p[1] * oz + p[2] * max(ox * wx + oy * wy, 0.0) * oz / max(oz, wz)
    if not (next_double(s) * den < num):
        return _DEAD
    return ox, oy, (-oz if flip else oz), True


# --- normalized Phong ---------------------------------------------------------------------------


@dataclass(frozen=True)
class Phong(_Analytic):
    """Energy-normalized modified Phong (Lafortune & Willems 1994), opaque, two-sided.

    f = kd/pi + ks (n+2)/(2 pi) max(0, r . wo)^n with r the mirror direction of wi. Its albedo
    is <= kd + ks (equality at normal incidence when the lobe fits above the horizon).

    Sampling is exact: with probability kd a cosine-weighted direction; with probability
    ks (n+2)/(n+1) a direction from the lobe (n+1)/(2 pi) cos^n(alpha) around r, kept with
    probability cos(theta_o) (killed below the horizon): that gives exactly
    ks (n+2)/(2 pi) cos^n(alpha) cos(theta_o). The two proposal masses must fit in 1:
    ``kd + ks (n+2)/(n+1) <= 1`` is required (slightly stronger than kd + ks <= 1; no single-pass
    exact sampler with mass <= 1 exists for every incidence otherwise).

    params: ``[kd, ks, n, ks*(n+2)/(n+1)]``.
    """

    model: ClassVar[int] = MODEL_PHONG
    has_density: ClassVar[bool] = True
    exponent: Any = 20.0
    ks: Any = 0.5
    kd: Any = 0.3

    _fields: ClassVar[tuple[str, ...]] = ("exponent", "ks", "kd")

    def _values(self, wl: float) -> np.ndarray:
        n = _in_range("exponent", self.exponent(wl), 0.0, 1e7)
        ks = _fraction("ks", self.ks(wl))
        kd = _fraction("kd", self.kd(wl))
        ws = ks * (n + 2.0) / (n + 1.0)
        if kd + ws > 1.0 + 1e-12:
            raise SpecimenError(f"phong: kd + ks (n+2)/(n+1) = {kd + ws:.6g} > 1 (ks <= "
                                f"{(1.0 - kd) * (n + 1.0) / (n + 2.0):.6g} for kd = {kd:g}, n = {n:g})")
        return np.array([kd, ks, n, ws])

    def bsdf(self, wi: np.ndarray, wo: np.ndarray, wavelength_nm: float) -> np.ndarray:
        kd, ks, n, _ = self.params(wavelength_nm)
        wi, wo, _ = _local(wi, wo)
        ca = np.maximum(-wi[0] * wo[:, 0] - wi[1] * wo[:, 1] + wi[2] * wo[:, 2], 0.0)
        f = kd / math.pi + ks * (n + 2.0) / (2.0 * math.pi) * ca ** n
        return np.where((wo[:, 2] > 0.0) & (wi[2] > 0.0), f, 0.0)

    def lobes(self, wi: np.ndarray, wavelength_nm: float) -> list[tuple[np.ndarray, float]]:
        kd, ks, n, _ = self.params(wavelength_nm)
        # cos^n(a) ~ exp(-n a^2 / 2): angular width ~ 1 / sqrt(n)
        return [(_mirror(wi), 2.0 / math.sqrt(n + 1.0))] if ks > 0 else []


@njit(inline="always", cache=True)
def _phong(p, wx, wy, wz, s):
    flip = wz < 0.0
    if flip:
        wz = -wz
    if not (wz > 0.0):
        return _DEAD
    u = next_double(s)
    if u < p[0]:
        a, b, r2 = _unit_disk(s)
        oz = math.sqrt(1.0 - r2)
        return a, b, (-oz if flip else oz), True
    if not (u < p[0] + p[3]):
        return _DEAD
    # lobe (n+1)/(2 pi) cos^n around r = (-wx, -wy, wz): cos(alpha) = xi^(1/(n+1)), xi = r2
    a, b, r2 = _unit_disk(s)
    ca = r2 ** (1.0 / (p[2] + 1.0))
    sa_over_r = math.sqrt(max((1.0 - ca) * (1.0 + ca), 0.0) / r2)
    t1x, t1y, t1z, t2x, t2y, t2z = _frame(-wx, -wy, wz)
    ta = a * sa_over_r
    tb = b * sa_over_r
    ox = ta * t1x + tb * t2x - ca * wx
    oy = ta * t1y + tb * t2y - ca * wy
    oz = ta * t1z + tb * t2z + ca * wz
    if not (oz > 0.0 and next_double(s) < oz):
        return _DEAD
    return ox, oy, (-oz if flip else oz), True


# --- GGX microfacet reflector (conductor or dielectric coat) ------------------------------------


@dataclass(frozen=True)
class GGX(_Analytic):
    """Cook-Torrance reflector with the GGX (Trowbridge-Reitz) distribution, opaque, two-sided.

    f = F(wi.h) D(h) G2(wi, wo) / (4 cos_i cos_o), F the exact unpolarized Fresnel reflectance of
    a conductor eta + i k (k = 0: a dielectric -- the specimen is then an opaque "specular coat
    only" reflector, everything refracted is absorbed). Single scattering: light the microfacets
    would scatter again is absorbed, so the albedo is < 1 (most visibly for rough, grazing cases).

    Sampling: a visible normal m (Heitz 2018, spherical caps of Dupuy & Benyoub 2023), mirror
    reflection about m, killed below the horizon, kept with probability F G2/G1 <= 1.

    params: ``[alpha_x, alpha_y, eta, k]`` (alpha_x along the specimen X axis).
    """

    model: ClassVar[int] = MODEL_GGX
    has_density: ClassVar[bool] = True
    alpha: Any = 0.2
    eta: Any = 1.5
    k: Any = 0.0

    _fields: ClassVar[tuple[str, ...]] = ("alpha", "eta", "k")

    def _alphas(self, wl: float) -> tuple[float, float]:
        a = _in_range("alpha", self.alpha(wl), ALPHA_MIN, ALPHA_MAX)
        return a, a

    def _values(self, wl: float) -> np.ndarray:
        ax, ay = self._alphas(wl)
        eta = _in_range("eta", self.eta(wl), 1e-3, 100.0)
        k = _in_range("k", self.k(wl), 0.0, 100.0)
        return np.array([ax, ay, eta, k])

    def bsdf(self, wi: np.ndarray, wo: np.ndarray, wavelength_nm: float) -> np.ndarray:
        ax, ay, eta, k = self.params(wavelength_nm)
        wi, wo, _ = _local(wi, wo)
        if not wi[2] > 0.0:
            return np.zeros(len(wo))
        if k == 0.0:  # as in the kernel: the dielectric form (same value, better near TIR)
            return _np_ggx_reflection(wi, wo, ax, ay, lambda c: _np_fresnel_dielectric(c, eta))
        return _np_ggx_reflection(wi, wo, ax, ay, lambda c: _np_fresnel_conductor(c, eta, k))

    def lobes(self, wi: np.ndarray, wavelength_nm: float) -> list[tuple[np.ndarray, float]]:
        ax, ay = self.params(wavelength_nm)[:2]
        return [(_mirror(wi), 2.0 * max(ax, ay))]


@dataclass(frozen=True)
class AnisoGGX(GGX):
    """Anisotropic GGX reflector: :class:`GGX` with roughness alpha_x along the specimen's X axis
    and alpha_y along Y (so the BRDF depends on the azimuths themselves, not only on their
    difference). params: ``[alpha_x, alpha_y, eta, k]``."""

    model: ClassVar[int] = MODEL_ANISO_GGX
    isotropic: ClassVar[bool] = False
    alpha: Any = None
    alpha_x: Any = 0.1
    alpha_y: Any = 0.4

    _fields: ClassVar[tuple[str, ...]] = ("alpha_x", "alpha_y", "eta", "k")

    def _alphas(self, wl: float) -> tuple[float, float]:
        return (_in_range("alpha_x", self.alpha_x(wl), ALPHA_MIN, ALPHA_MAX),
                _in_range("alpha_y", self.alpha_y(wl), ALPHA_MIN, ALPHA_MAX))


@njit(inline="always", cache=True)
def _ggx_given(p, wx, wy, wz, ca, sa, r2, u):
    """GGX reflection of the ray from w (either side: two-sided) given the VNDF's disk point
    (direction (ca, sa), squared radius r2) and the survival uniform u. Branch-free (block
    kernels vectorize it): ``(ox, oy, oz, alive)``, the ray surviving with probability
    F(w.m) G2/G1.

    u < F G2/G1 is tested as u den_F den_G < num_F num_G (both denominators are >= 0, and > 0
    when wz, oz > 0): no division. The conductor Fresnel formula with k = 0 is the dielectric
    one (total internal reflection included), so one formula serves both.
    """
    flip = wz < 0.0
    wz = abs(wz)
    ax = p[0]
    ay = p[1]
    ni = _ggx_n(wx, wy, wz, ax, ay)
    mx, my, mz = _ggx_vndf_given(wx, wy, wz, ax, ay, 1.0 / ni, ca, sa, r2)
    c = max(wx * mx + wy * my + wz * mz, 0.0)
    ox = 2.0 * c * mx - wx
    oy = 2.0 * c * my - wy
    oz = 2.0 * c * mz - wz
    f_num, f_den = _fresnel_conductor_ratio(c, p[2], p[3])
    g_num, g_den = _g2_over_g1_ratio(wz, ni, oz, _ggx_n(ox, oy, oz, ax, ay))
    alive = (wz > 0.0) & (oz > 0.0) & (u * f_den * g_den < f_num * g_num)
    return ox, oy, (-oz if flip else oz), alive


@njit(inline="always", cache=True)
def _ggx(p, wx, wy, wz, s):
    ca, sa, r2 = _disk_direction(s)
    return _ggx_given(p, wx, wy, wz, ca, sa, r2, next_double(s))


# --- rough plastic --------------------------------------------------------------------------------


@dataclass(frozen=True)
class RoughPlastic(_Analytic):
    """A GGX dielectric coat (index eta) over a Lambertian base of albedo kd; opaque, two-sided.

    What a ray does (and so, exactly, what the density is): it meets a visible microfacet m of
    the coat; with probability F(wi.m) it is reflected there (kept with probability G2/G1,
    killed below the horizon) -- the specular term F D G2 / (4 cos_i cos_o). Otherwise it enters,
    is absorbed by the base with probability 1 - kd, and else leaves diffusely with density
    (1 - F(cos_o)) cos_o / (pi (1 - F_avg)) (a cosine lobe through the smooth coat's exit
    Fresnel, normalized; F_avg = 2 int F(mu) mu dmu). Hence

        f = F(wi.h) D G2 / (4 cos_i cos_o) + kd (1 - Fbar(wi)) (1 - F(cos_o)) / (pi (1 - F_avg)),

    Fbar(wi) = the mean of F(wi.m) over the visible normals of wi (computed by quadrature for the
    density). It conserves energy by construction (albedo <= Fbar + kd (1 - Fbar) <= 1), but it
    is not reciprocal (the entry uses the rough interface, the exit the smooth one).

    params: ``[alpha, eta, kd, 1/(1 - F_avg)]``.
    """

    model: ClassVar[int] = MODEL_PLASTIC
    has_density: ClassVar[bool] = True
    reciprocal: ClassVar[bool] = False
    alpha: Any = 0.1
    eta: Any = 1.5
    kd: Any = 0.5

    _fields: ClassVar[tuple[str, ...]] = ("alpha", "eta", "kd")

    def _values(self, wl: float) -> np.ndarray:
        a = _in_range("alpha", self.alpha(wl), ALPHA_MIN, ALPHA_MAX)
        eta = _in_range("eta", self.eta(wl), 1.0, 10.0)
        kd = _fraction("kd", self.kd(wl))
        return np.array([a, eta, kd, 1.0 / (1.0 - _fresnel_hemispherical_average(eta))])

    def mean_entry_fresnel(self, wi: np.ndarray, wavelength_nm: float) -> float:
        """Fbar(wi): the mean Fresnel reflectance over wi's visible GGX normals."""
        a, eta = self.params(wavelength_nm)[:2]
        w = np.asarray(wi, dtype=float).reshape(3)
        w = w * np.array([1.0, 1.0, -1.0]) if w[2] < 0 else w
        return _vndf_mean(w, a, a, lambda c: _np_fresnel_dielectric(c, eta))

    def bsdf(self, wi: np.ndarray, wo: np.ndarray, wavelength_nm: float) -> np.ndarray:
        a, eta, kd, norm = self.params(wavelength_nm)
        wi, wo, _ = _local(wi, wo)
        if not wi[2] > 0.0:
            return np.zeros(len(wo))
        spec = _np_ggx_reflection(wi, wo, a, a, lambda c: _np_fresnel_dielectric(c, eta))
        fbar = _vndf_mean(wi, a, a, lambda c: _np_fresnel_dielectric(c, eta))
        zo = wo[:, 2]
        diff = kd * (1.0 - fbar) * norm / math.pi * (1.0 - _np_fresnel_dielectric(np.maximum(zo, 0.0), eta))
        return spec + np.where(zo > 0.0, diff, 0.0)

    def lobes(self, wi: np.ndarray, wavelength_nm: float) -> list[tuple[np.ndarray, float]]:
        return [(_mirror(wi), 2.0 * float(self.params(wavelength_nm)[0]))]


@njit(inline="always", cache=True)
def _plastic(p, wx, wy, wz, s):
    flip = wz < 0.0
    if flip:
        wz = -wz
    if not (wz > 0.0):
        return _DEAD
    a = p[0]
    eta = p[1]
    mx, my, mz = _ggx_vndf(wx, wy, wz, a, a, s)
    c = max(wx * mx + wy * my + wz * mz, 0.0)
    f, _ = _fresnel_dielectric(c, eta)
    if next_double(s) < f:
        ox = 2.0 * c * mx - wx
        oy = 2.0 * c * my - wy
        oz = 2.0 * c * mz - wz
        if not (oz > 0.0 and next_double(s) < _g2_over_g1(wx, wy, wz, ox, oy, oz, a, a)):
            return _DEAD
        return ox, oy, (-oz if flip else oz), True
    if not (next_double(s) < p[2]):
        return _DEAD
    while True:  # cosine lobe thinned by the exit transmittance 1 - F(cos_o); ends w.p. 1
        ox, oy, r2 = _unit_disk(s)
        oz = math.sqrt(1.0 - r2)
        fo, _ = _fresnel_dielectric(oz, eta)
        if next_double(s) >= fo:
            return ox, oy, (-oz if flip else oz), True


# --- rough dielectric interface -----------------------------------------------------------------


@dataclass(frozen=True)
class RoughDielectric(_Analytic):
    """A rough (GGX) interface between air above and a dielectric of index eta below
    (Walter, Marschner, Li & Torrance 2007): reflection and refraction chosen by Fresnel.

    Light from below sees the relative index 1/eta (total internal reflection included).
    Densities, with h the (generalized) half vector and eta_r = n_o / n_i:

        f_r = F D G2 / (4 |cos_i| |cos_o|),
        f_t = (1 - F) D G2 eta_r^2 |wi.h| |wo.h| / (|cos_i| |cos_o| (wi.h + eta_r wo.h)^2).

    f_t is the *flux* BTDF that ray counting measures (n_d / (N PSA)): it is not symmetric --
    f_t(wi -> wo) / n_o^2 = f_t(wo -> wi) / n_i^2 -- so ``reciprocal`` is False (the reflection
    part is reciprocal). Single scattering: rays the sampled microfacet sends to the wrong side
    are absorbed, so the albedo is < 1.

    params: ``[alpha, eta]``.
    """

    model: ClassVar[int] = MODEL_DIELECTRIC
    has_density: ClassVar[bool] = True
    reciprocal: ClassVar[bool] = False
    alpha: Any = 0.2
    eta: Any = 1.5

    _fields: ClassVar[tuple[str, ...]] = ("alpha", "eta")

    def _values(self, wl: float) -> np.ndarray:
        a = _in_range("alpha", self.alpha(wl), ALPHA_MIN, ALPHA_MAX)
        eta = _in_range("eta", self.eta(wl), 1.0 + 1e-6, 10.0)
        return np.array([a, eta])

    def transmits(self, wavelength_nm: float) -> bool:
        return True

    def bsdf(self, wi: np.ndarray, wo: np.ndarray, wavelength_nm: float) -> np.ndarray:
        a, eta = self.params(wavelength_nm)
        wi0 = np.asarray(wi, dtype=float).reshape(3)
        er = eta if wi0[2] >= 0.0 else 1.0 / eta
        wi, wo, _ = _local(wi, wo)
        out = np.zeros(len(wo))
        if not wi[2] > 0.0:
            return out
        up = wo[:, 2] > 0.0
        out[up] = _np_ggx_reflection(wi, wo[up], a, a, lambda c: _np_fresnel_dielectric(c, er))
        down = wo[:, 2] < 0.0
        o = wo[down]
        hx, hy, hz = -(wi[0] + er * o[:, 0]), -(wi[1] + er * o[:, 1]), -(wi[2] + er * o[:, 2])
        sgn = np.where(hz < 0.0, -1.0, 1.0)
        inv = sgn / np.maximum(np.sqrt(hx * hx + hy * hy + hz * hz), 1e-300)
        hx, hy, hz = hx * inv, hy * inv, hz * inv
        ci = wi[0] * hx + wi[1] * hy + wi[2] * hz
        co = o[:, 0] * hx + o[:, 1] * hy + o[:, 2] * hz
        zo = -o[:, 2]
        ni = _np_ggx_n(wi[0], wi[1], wi[2], a, a)
        no = _np_ggx_n(o[:, 0], o[:, 1], zo, a, a)
        den = ci + er * co
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            f = ((1.0 - _np_fresnel_dielectric(ci, er)) * _np_ggx_d(hx, hy, hz, a, a) * er * er
                 * ci * (-co) * 2.0 / ((ni * zo + no * wi[2]) * den * den))
        ok = (ci > 0.0) & (co < 0.0) & (hz > 0.0)
        out[down] = np.where(ok, np.nan_to_num(f, nan=0.0, posinf=0.0), 0.0)
        return out

    def lobes(self, wi: np.ndarray, wavelength_nm: float) -> list[tuple[np.ndarray, float]]:
        a, eta = self.params(wavelength_nm)
        w = np.asarray(wi, dtype=float).reshape(3)
        er = eta if w[2] >= 0.0 else 1.0 / eta
        out = [(_mirror(w), 2.0 * a)]
        c = abs(w[2])
        st2 = (1.0 - c * c) / (er * er)
        if st2 < 1.0:
            ct = math.sqrt(1.0 - st2)
            n = np.array([0.0, 0.0, 1.0 if w[2] >= 0 else -1.0])
            t = -w / er + (c / er - ct) * n
            out.append((t / np.linalg.norm(t), 2.0 * a * max(1.0, 1.0 / er)))
        return out


@njit(inline="always", cache=True)
def _dielectric(p, wx, wy, wz, s):
    a = p[0]
    flip = wz < 0.0
    if flip:
        wz = -wz
        er = 1.0 / p[1]
    else:
        er = p[1]
    if not (wz > 0.0):
        return _DEAD
    mx, my, mz = _ggx_vndf(wx, wy, wz, a, a, s)
    c = max(wx * mx + wy * my + wz * mz, 0.0)
    f, ct = _fresnel_dielectric(c, er)
    if next_double(s) < f:
        ox = 2.0 * c * mx - wx
        oy = 2.0 * c * my - wy
        oz = 2.0 * c * mz - wz
        if not (oz > 0.0 and next_double(s) < _g2_over_g1(wx, wy, wz, ox, oy, oz, a, a)):
            return _DEAD
        return ox, oy, (-oz if flip else oz), True
    inv = 1.0 / er
    k = c * inv - ct
    ox = -wx * inv + k * mx
    oy = -wy * inv + k * my
    oz = -wz * inv + k * mz
    if not (oz < 0.0 and next_double(s) < _g2_over_g1(wx, wy, wz, ox, oy, -oz, a, a)):
        return _DEAD
    return ox, oy, (-oz if flip else oz), True


# --- helpers for the Python side ----------------------------------------------------------------

ALPHA_MIN = 1e-4
ALPHA_MAX = 1.0


def _mirror(wi: np.ndarray) -> np.ndarray:
    w = np.asarray(wi, dtype=float).reshape(3)
    return np.array([-w[0], -w[1], w[2]]) / np.linalg.norm(w)


def _in_range(name: str, v: float, lo: float, hi: float, unit: str = "") -> float:
    v = float(v)
    if not (math.isfinite(v) and lo <= v <= hi):
        u = f" {unit}" if unit else ""
        raise SpecimenError(f"{name} must lie in [{lo:g}, {hi:g}]{u}, got {v:g}")
    return v


def _init_spectral(obj: Any, names: tuple[str, ...]) -> None:
    """Turn the fields into :class:`Spectral` and validate them at every tabulated wavelength."""
    for n in names:
        object.__setattr__(obj, n, Spectral.of(getattr(obj, n), n))
    grid = sorted({float(w) for n in names for w in (getattr(obj, n).wavelengths
                                                     if getattr(obj, n).wavelengths is not None else [])})
    rng = obj.wavelength_range()
    if rng is not None and rng[0] > rng[1]:
        raise SpecimenError(f"{type(obj).__name__}: the spectral tables do not overlap")
    pts = [w for w in grid if rng is None or rng[0] <= w <= rng[1]] or [550.0]
    for w in pts:
        obj.params(w)


@lru_cache(maxsize=256)
def _fresnel_hemispherical_average(eta: float) -> float:
    """F_avg = 2 int_0^1 F(mu) mu dmu for the dielectric of relative index eta (Gauss-Legendre)."""
    x, w = np.polynomial.legendre.leggauss(256)
    mu = 0.5 * (x + 1.0)
    return float(np.sum(w * 0.5 * 2.0 * mu * _np_fresnel_dielectric(mu, eta)))


_VNDF_NODES = 48


@lru_cache(maxsize=1)
def _vndf_rule() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    x, w = np.polynomial.legendre.leggauss(_VNDF_NODES)
    u = 0.5 * (x + 1.0)
    uu, vv = np.meshgrid(u, u, indexing="ij")
    ww = np.outer(w, w) * 0.25
    return uu.ravel(), vv.ravel(), ww.ravel()


def _vndf_mean(wi: np.ndarray, ax: float, ay: float, func) -> float:
    """Mean of ``func(wi . m)`` over the visible normals m of wi (wi_z > 0): Gauss-Legendre on the
    unit square mapped through the same spherical-cap construction as the sampler (phi = 2 pi u,
    r2 = v), whose Jacobian is constant -- so the integrand is smooth."""
    u, v, w = _vndf_rule()
    vx, vy, vz = ax * wi[0], ay * wi[1], wi[2]
    n = math.sqrt(vx * vx + vy * vy + vz * vz)
    vx, vy, vz = vx / n, vy / n, vz / n
    q = 1.0 + vz
    z = 1.0 - q * v
    sc = np.sqrt(np.maximum(q * (2.0 - q * v), 0.0)) * np.sqrt(v)
    phi = 2.0 * math.pi * u
    hx = sc * np.cos(phi) + vx
    hy = sc * np.sin(phi) + vy
    hz = np.maximum(z + vz, 0.0)
    mx, my = ax * hx, ay * hy
    nn = np.maximum(np.sqrt(mx * mx + my * my + hz * hz), 1e-300)
    c = (wi[0] * mx + wi[1] * my + wi[2] * hz) / nn
    return float(np.sum(w * func(np.clip(c, 0.0, 1.0))))


# --- the kernel face --------------------------------------------------------------------------


@njit(inline="always", cache=True)
def _lambert_given(p, wz, u, x, y, z):
    """Lambertian: alive when u < R + T; reflected rays (u < R) leave on the side of the source,
    transmitted ones on the other side, along the cosine-distributed (x, y, z), z >= 0."""
    up = (wz >= 0.0) != (u >= p[0])
    return x, y, (z if up else -z), u < p[0] + p[1]


@njit(inline="always", cache=True)
def _lambert(p, wz, s):
    u = next_double(s)
    if u >= p[0] + p[1]:  # absorbed: no direction drawn
        return 0.0, 0.0, 0.0, False
    x, y, z = sample_cosine_hemisphere(s)
    return _lambert_given(p, wz, u, x, y, z)


@njit(cache=True)
def _scatter_general(model, p, wx, wy, wz, s):
    """Every model but the Lambertian (called, not inlined: inlining them all into each kernel
    quadruples the compile time)."""
    if model == MODEL_LAMBERT:
        return _lambert(p, wz, s)
    if model == MODEL_GGX or model == MODEL_ANISO_GGX:
        return _ggx(p, wx, wy, wz, s)
    if model == MODEL_OREN_NAYAR:
        return _oren_nayar(p, wx, wy, wz, s)
    if model == MODEL_PHONG:
        return _phong(p, wx, wy, wz, s)
    if model == MODEL_PLASTIC:
        return _plastic(p, wx, wy, wz, s)
    if model == MODEL_DIELECTRIC:
        return _dielectric(p, wx, wy, wz, s)
    return 0.0, 0.0, 0.0, False


@njit(inline="always", cache=True)
def scatter(model, p, wx, wy, wz, s):
    """Scatter one ray (see the module docstring for the contract).

    Inlined into the kernels with the Lambertian branch, the commonest and cheapest specimen
    (1.2-1.8x the kernel's rays/s on this machine); every other model is one call away.
    """
    if model == MODEL_LAMBERT:
        return _lambert(p, wz, s)
    return _scatter_general(model, p, wx, wy, wz, s)


#: Models with a branch-free form taking their uniforms as arguments (:func:`scatter_given`):
#: the vectorized block kernel of :mod:`virtual.engine` runs them.
GIVEN_MODELS = (MODEL_LAMBERT, MODEL_GGX, MODEL_ANISO_GGX)
#: Uniforms :func:`scatter_given` consumes per ray.
GIVEN_UNIFORMS = 3


@njit(inline="always", cache=True)
def scatter_given(model, p, wx, wy, wz, u0, u1, u2):
    """:func:`scatter` for the :data:`GIVEN_MODELS`, with its three uniforms given instead of
    drawn, and no branch: the same distribution of ``(ox, oy, oz, alive)``.

    u0 decides survival (and reflection against transmission); (u1, u2) is a polar disk point
    (:func:`~virtual.sampling.warp_polar`): the Lambertian's cosine-weighted direction
    (Malley), GGX's visible-normal cap point. Callers only read the direction when ``alive``.
    """
    if model == MODEL_LAMBERT:
        x, y, z = warp_cosine_hemisphere(u2, u1)
        return _lambert_given(p, wz, u0, x, y, z)
    ca, sa = sincos_2pi(u2)
    return _ggx_given(p, wx, wy, wz, ca, sa, u1, u0)


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


def _factory(cls: type, aliases: dict[str, str] | None = None) -> Callable[[dict[str, float]], Specimen]:
    """A factory that pops ``cls._fields`` (or their aliases) from the keywords; leftovers are
    reported by :func:`parse_specimen` as unknown parameters."""
    aliases = aliases or {}

    def make(kw: dict[str, float]) -> Specimen:
        args: dict[str, float] = {}
        for key in list(kw):
            name = aliases.get(key, key)
            if name in cls._fields:
                if name in args:
                    raise SpecimenError(f"parameter {name} given twice")
                args[name] = kw.pop(key)
        return cls(**args)

    return make


# name -> (factory taking keyword floats, parameter help)
SPECIMENS: dict[str, tuple[Callable[[dict[str, float]], Specimen], str]] = {
    "lambert": (_lambert_factory, "reflectance|albedo=R, transmittance=T"),
    "oren-nayar": (_factory(OrenNayar, {"reflectance": "albedo", "R": "albedo"}),
                   "sigma=slope deviation in degrees (0..90), albedo=rho"),
    "phong": (_factory(Phong, {"n": "exponent"}), "exponent|n=n, ks=specular, kd=diffuse (kd + ks(n+2)/(n+1) <= 1)"),
    "ggx": (_factory(GGX), "alpha=roughness (1e-4..1), eta=index, k=extinction (0: dielectric coat)"),
    "aniso-ggx": (_factory(AnisoGGX), "alpha_x, alpha_y (1e-4..1), eta=index, k=extinction"),
    "plastic": (_factory(RoughPlastic), "alpha=coat roughness, eta=coat index (1..10), kd=base albedo"),
    "dielectric": (_factory(RoughDielectric), "alpha=roughness, eta=index below the interface (>1)"),
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
    if name == "mitsuba":  # optional extra: mitsuba:{json BSDF dict}
        from virtual.mitsuba import parse_mitsuba

        return parse_mitsuba(rest, text)
    if name not in SPECIMENS:
        known = ", ".join(sorted([*SPECIMENS, "colorchecker", "mitsuba"]))
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

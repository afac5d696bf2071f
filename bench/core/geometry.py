"""Measurement geometry: the bidirectional ``Geometry`` and the named CIE geometries.

Conventions (ASTM E2387): theta is the zenith angle from the specimen normal (+z), phi the
azimuth from the specimen's marked X axis, counter-clockwise seen from above. The incident
direction points *from the specimen toward the source*; the viewing direction points from the
specimen toward the detector. Degrees at every user-facing edge, radians inside.

theta in [0, 90] is the upper (reflection) hemisphere, theta in (90, 180] the lower
(transmission) hemisphere.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from bench.core.errors import GeometryError

__all__ = [
    "Geometry",
    "CIEGeometry",
    "CIE_GEOMETRIES",
    "cie_geometry",
    "direction",
    "gauss_legendre",
    "spherical",
    "cone_quadrature",
    "cone_cos_weights",
]


def direction(theta_deg: float, phi_deg: float) -> np.ndarray:
    """Unit vector for zenith ``theta_deg`` and azimuth ``phi_deg`` (degrees)."""
    t, p = math.radians(theta_deg), math.radians(phi_deg)
    st = math.sin(t)
    return np.array([st * math.cos(p), st * math.sin(p), math.cos(t)])


def spherical(v: np.ndarray) -> tuple[float, float]:
    """(theta, phi) in degrees of a (not necessarily unit) vector; phi in [0, 360).

    Stable at the pole (phi = 0 there) and for |z| that rounds past the norm.
    """
    x, y, z = (float(c) for c in v)
    rho = math.hypot(x, y)
    theta = math.degrees(math.atan2(rho, z))  # atan2 never leaves [0, pi], unlike acos(z)
    phi = math.degrees(math.atan2(y, x)) % 360.0 if rho > 0.0 else 0.0
    if phi >= 360.0:  # -tiny % 360 rounds to 360
        phi = 0.0
    return theta, phi


@functools.lru_cache(maxsize=None)
def gauss_legendre(n: int) -> tuple[np.ndarray, np.ndarray]:
    """numpy's n-point Gauss-Legendre rule, computed once per order (a fit or a design asks for
    the same rule at every point and parameter step: recomputing it was a quarter of their time).
    Read-only, as it is shared."""
    x, w = np.polynomial.legendre.leggauss(n)
    x.flags.writeable = False
    w.flags.writeable = False
    return x, w


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.cross`` of two 3-vectors with its arithmetic (same bits), without its axis handling,
    which dominates for one pair."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def cone_quadrature(axis: np.ndarray, half_angle_deg: float, rings: int = 4,
                    azimuths: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """Directions and weights (summing to 1) that average a function over the cone of
    ``half_angle_deg`` around ``axis`` by solid angle: Gauss-Legendre in ``1 - cos`` of the angle
    from the axis (uniform in solid angle) times the midpoint rule in azimuth. A cone of 0 deg is
    its axis alone. What a detector of finite aperture averages."""
    t = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    a = math.radians(half_angle_deg)
    if a == 0:
        return t[None, :], np.ones(1)
    u = _cross(t, np.array([0.0, 0.0, 1.0] if abs(t[2]) < 0.9 else [1.0, 0.0, 0.0]))
    u /= np.linalg.norm(u)
    v = _cross(t, u)
    x, w = gauss_legendre(rings)
    cap = 1.0 - math.cos(a)
    cos_off = 1.0 - (x + 1.0) / 2.0 * cap  # nodes in 1 - cos over [0, cap]
    sin_off = np.sqrt(np.maximum(1.0 - cos_off**2, 0.0))
    phi = 2.0 * math.pi * (np.arange(azimuths) + 0.5) / azimuths
    dirs = (cos_off[:, None, None] * t + sin_off[:, None, None]
            * (np.cos(phi)[None, :, None] * u + np.sin(phi)[None, :, None] * v))
    weights = np.repeat(w / w.sum() / azimuths, azimuths)
    return dirs.reshape(-1, 3), weights


def cone_cos_weights(axis: np.ndarray, half_angle_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """Directions and weights ``w`` of a detector's cone (:func:`cone_quadrature`) such that
    ``w @ f(dirs)`` is the cone mean of ``f |cos theta|``: directions on the other side of the
    specimen from the axis (past the horizon) read nothing. What the emulated spectrometer and
    the virtual body's detector read (over their gain) and what a fit predicts."""
    dirs, weights = cone_quadrature(axis, half_angle_deg)
    side = 1.0 if float(np.asarray(axis, dtype=float)[2]) >= 0.0 else -1.0
    return dirs, weights * np.clip(side * dirs[:, 2], 0.0, None)


def _check_angle(name: str, value: float, lo: float, hi: float) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise GeometryError(f"{name} must be a number of degrees, got {value!r}") from None
    if not math.isfinite(v):
        raise GeometryError(f"{name} must be finite, got {v}")
    if not lo <= v <= hi:
        raise GeometryError(f"{name} = {v} deg is outside [{lo}, {hi}] deg")
    return v


@dataclass(frozen=True)
class Geometry:
    """A bidirectional measurement geometry in degrees.

    ``theta_i, phi_i``: toward the source. ``theta_r, phi_r``: toward the detector
    (theta_r > 90 views the transmitted side). Azimuths are normalised to [0, 360).
    """

    theta_i: float
    phi_i: float
    theta_r: float
    phi_r: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "theta_i", _check_angle("theta_i", self.theta_i, 0.0, 180.0))
        object.__setattr__(self, "theta_r", _check_angle("theta_r", self.theta_r, 0.0, 180.0))
        for name in ("phi_i", "phi_r"):
            v = _check_angle(name, getattr(self, name), -1e6, 1e6) % 360.0
            object.__setattr__(self, name, 0.0 if v >= 360.0 else v)

    # -- constructors -----------------------------------------------------------------------
    @classmethod
    def in_plane(cls, theta_i: float, theta_r_signed: float, phi_i: float = 0.0) -> "Geometry":
        """Geometry in the plane of incidence.

        ``theta_r_signed > 0`` views the forward (specular) side, at phi_i + 180;
        ``theta_r_signed < 0`` views the source side (back-scatter), at phi_i.
        """
        tr = _check_angle("theta_r", theta_r_signed, -180.0, 180.0)
        phi_r = phi_i + 180.0 if tr >= 0 else phi_i
        return cls(theta_i, phi_i, abs(tr), phi_r)

    @classmethod
    def from_vectors(cls, incident: np.ndarray, view: np.ndarray) -> "Geometry":
        ti, pi_ = spherical(np.asarray(incident, dtype=float))
        tr, pr = spherical(np.asarray(view, dtype=float))
        return cls(ti, pi_, tr, pr)

    # -- derived ----------------------------------------------------------------------------
    @property
    def incident(self) -> np.ndarray:
        """Unit vector from the specimen toward the source."""
        return direction(self.theta_i, self.phi_i)

    @property
    def view(self) -> np.ndarray:
        """Unit vector from the specimen toward the detector."""
        return direction(self.theta_r, self.phi_r)

    @property
    def is_transmission(self) -> bool:
        return (self.theta_i <= 90.0) != (self.theta_r <= 90.0)

    @property
    def theta_r_signed(self) -> float:
        """In-plane signed viewing angle (positive on the forward side), see :meth:`in_plane`."""
        d = (self.phi_r - self.phi_i) % 360.0
        forward = 90.0 < d < 270.0 or self.theta_r == 0.0
        return self.theta_r if forward else -self.theta_r

    def reciprocal(self) -> "Geometry":
        """Source and detector exchanged (Helmholtz reciprocity)."""
        return Geometry(self.theta_r, self.phi_r, self.theta_i, self.phi_i)

    def angle_between_source_and_detector(self) -> float:
        """Angle in degrees between incident and viewing directions (0 at retro-reflection)."""
        c = float(np.clip(np.dot(self.incident, self.view), -1.0, 1.0))
        return math.degrees(math.acos(c))

    def as_dict(self) -> dict[str, float]:
        return {"theta_i": self.theta_i, "phi_i": self.phi_i, "theta_r": self.theta_r, "phi_r": self.phi_r}

    def __str__(self) -> str:
        return (f"(theta_i={self.theta_i:g}, phi_i={self.phi_i:g}, "
                f"theta_r={self.theta_r:g}, phi_r={self.phi_r:g})")


Kind = Literal["directional", "diffuse"]


@dataclass(frozen=True)
class CIEGeometry:
    """A CIE illuminating/viewing condition (CIE 15).

    ``illumination``/``viewing`` are ``"directional"`` (at ``theta_i``/``theta_r`` degrees,
    within ``cone_deg`` half-angle) or ``"diffuse"`` (hemispherical). ``specular_included``
    applies to hemispherical collection (a gloss trap excludes it).
    """

    name: str
    illumination: Kind
    theta_i: float
    viewing: Kind
    theta_r: float
    cone_deg: float = 5.0
    specular_included: bool = True

    @property
    def hemispherical_collection(self) -> bool:
        return self.viewing == "diffuse"

    @property
    def reciprocal_directional(self) -> "CIEGeometry":
        """The geometry measured instead by Helmholtz reciprocity when illumination is diffuse.

        d/0 has the same reflectance factor as 0/d, d/8 as 8/d: a virtual instrument shoots rays
        from the viewing direction and collects the hemisphere.
        """
        if self.illumination == "directional":
            return self
        return CIEGeometry(f"{self.theta_r:g}/d", "directional", self.theta_r, "diffuse", 0.0,
                           self.cone_deg, self.specular_included)

    def __str__(self) -> str:
        return self.name


CIE_GEOMETRIES: dict[str, CIEGeometry] = {
    "45/0": CIEGeometry("45/0", "directional", 45.0, "directional", 0.0),
    "0/45": CIEGeometry("0/45", "directional", 0.0, "directional", 45.0),
    "d/0": CIEGeometry("d/0", "diffuse", 0.0, "directional", 0.0),
    "0/d": CIEGeometry("0/d", "directional", 0.0, "diffuse", 0.0),
    "8/d": CIEGeometry("8/d", "directional", 8.0, "diffuse", 0.0),
    "d/8": CIEGeometry("d/8", "diffuse", 0.0, "directional", 8.0),
    "8/de": CIEGeometry("8/de", "directional", 8.0, "diffuse", 0.0, specular_included=False),
}

_ALIASES = {"45:0": "45/0", "0:45": "0/45", "d:0": "d/0", "0:d": "0/d", "8:d": "8/d",
            "di:8": "8/d", "de:8": "8/de", "diff/0": "d/0", "0/diff": "0/d"}


def cie_geometry(name: str | CIEGeometry) -> CIEGeometry:
    """Look up a named CIE geometry (``45/0``, ``0/45``, ``d/0``, ``0/d``, ``8/d``, ...)."""
    if isinstance(name, CIEGeometry):
        return name
    key = str(name).strip().lower().replace("°", "").replace(" ", "")
    key = _ALIASES.get(key, key)
    if key not in CIE_GEOMETRIES:
        known = ", ".join(CIE_GEOMETRIES)
        raise GeometryError(f"unknown CIE geometry {name!r}; known: {known}")
    return CIE_GEOMETRIES[key]

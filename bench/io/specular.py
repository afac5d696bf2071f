"""Specular-centred angles (the Zemax tabular BSDF frame) and back.

For incidence (theta_i, phi_i) the specular direction is s = (theta_i, phi_i + 180). The frame
about it is the one libbsdf's ``SpecularCoordinateSystem`` uses to read Zemax files: take
spherical angles (radial, azimuth) about +z, rotate by theta_i about +y (x toward z), then by
phi_i about +z. So ``e_1`` (azimuth 0) lies in the plane of incidence and points from the
specular direction *toward the specimen normal and the source*; ``e_2`` (azimuth 90) is
horizontal, perpendicular to the plane of incidence (+y when phi_i = 0); ``(e_1, e_2, s)`` is
right-handed. A viewing direction v has ``radial`` = angle(v, s) and
``azimuth`` = atan2(v . e_2, v . e_1) in [0, 360); azimuth 180 is in the plane of incidence
beyond the specular direction (toward forward grazing). At theta_i = 0 the frame still follows
phi_i. ``PlaneSymmetrical`` files hold azimuths 0..180 (the half with v . e_2 >= 0; readers
mirror it). For a BTDF the transmitted side is mirrored through the specimen plane (z -> -z)
first, so the "specular" direction is the undeviated straight-through direction -incident (no
refraction is assumed). ``SampleRotation`` is read as phi_i (as libbsdf does).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["specular_frame", "to_specular", "from_specular", "directions", "angles"]


def specular_frame(theta_i: float, phi_i: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(s, e_1, e_2)``: the specular direction of incidence (theta_i, phi_i) (degrees) and the
    unit vectors of azimuth 0 and 90 about it (see the module docstring)."""
    t, p = math.radians(theta_i), math.radians(phi_i)
    st, ct, sp, cp = math.sin(t), math.cos(t), math.sin(p), math.cos(p)
    s = np.array([-st * cp, -st * sp, ct])
    e_1 = np.array([ct * cp, ct * sp, st])
    e_2 = np.array([-sp, cp, 0.0])
    return s, e_1, e_2


def directions(theta: Any, phi: Any) -> np.ndarray:
    t, p = np.radians(np.asarray(theta, float)), np.radians(np.asarray(phi, float))
    st = np.sin(t)
    return np.stack([st * np.cos(p), st * np.sin(p), np.cos(t)], axis=-1)


def angles(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    rho = np.hypot(v[..., 0], v[..., 1])
    theta = np.degrees(np.arctan2(rho, v[..., 2]))
    phi = np.where(rho > 0, np.degrees(np.arctan2(v[..., 1], v[..., 0])) % 360.0, 0.0)
    phi = np.where(phi >= 360.0, 0.0, phi)
    return theta, phi


def to_specular(theta_i: float, phi_i: float, theta_r: Any, phi_r: Any,
                transmission: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """(radial, azimuth) in degrees about the specular direction of viewing directions
    ``(theta_r, phi_r)`` (degrees, arrays). ``transmission`` mirrors them through the specimen
    plane first (BTDF)."""
    v = directions(theta_r, phi_r)
    if transmission:
        v = v * np.array([1.0, 1.0, -1.0])
    s, e_1, e_2 = specular_frame(theta_i, phi_i)
    c = v @ s
    sin_r = np.linalg.norm(np.cross(v, s), axis=-1)
    radial = np.degrees(np.arctan2(sin_r, c))
    az = np.degrees(np.arctan2(v @ e_2, v @ e_1)) % 360.0
    az = np.where((sin_r == 0) | (az >= 360.0), 0.0, az)
    return radial, az


def from_specular(theta_i: float, phi_i: float, radial: Any, azimuth: Any,
                  transmission: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Viewing directions ``(theta_r, phi_r)`` (degrees) of specular-centred angles
    (inverse of :func:`to_specular`)."""
    r, a = np.radians(np.asarray(radial, float)), np.radians(np.asarray(azimuth, float))
    s, e_1, e_2 = specular_frame(theta_i, phi_i)
    v = (np.cos(r)[..., None] * s + np.sin(r)[..., None] * (np.cos(a)[..., None] * e_1
                                                             + np.sin(a)[..., None] * e_2))
    if transmission:
        v = v * np.array([1.0, 1.0, -1.0])
    return angles(v)


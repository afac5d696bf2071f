"""Incidence: collimated or conical beams (the kernel that emits a ray is :mod:`virtual.kernels.emit`;
the ``BEAM_*``/``DISK_*`` codes are in :mod:`virtual.kernel_codes`, which does not load numba).

Collimated (directional-hemispherical): every ray arrives from the same direction; positions on
the specimen are irrelevant to a far-field count, so none are sampled.

Conical (conical-hemispherical, seed 3.1.2): ray origins are uniform on an emitter disk of radius
``r1`` at distance ``D`` along the incidence axis, targets uniform on the specimen disk of radius
``r2`` in the z = 0 plane; the emitter point (x1, y1, D) is rotated to (theta_i, phi_i). A ray
whose origin lies on or below the specimen's plane (possible for wide beams near grazing, or
disks larger than their distance) cannot reach the specimen's front face: it is *missed*,
counted apart, and not part of the estimate's denominator.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bench.core.errors import GeometryError, InputError
from virtual.kernel_codes import BEAM_COLLIMATED, BEAM_CONICAL, DISK_AUTO, DISK_POLAR, DISK_REJECTION

__all__ = ["Beam", "rotation_to"]

DISK_CODES = {"polar": DISK_POLAR, "rejection": DISK_REJECTION, "auto": DISK_AUTO}


def rotation_to(theta_deg: float, phi_deg: float) -> np.ndarray:
    """3x3 rotation taking +z to the direction (theta, phi): Rz(phi) @ Ry(theta).

    Exact at theta = 0 (identity up to phi, which only spins the emitter disk about its axis)
    and at theta = 180 (the beam from straight below).
    """
    t, p = math.radians(theta_deg), math.radians(phi_deg)
    ct, st, cp, sp = math.cos(t), math.sin(t), math.cos(p), math.sin(p)
    if theta_deg == 180.0:
        ct, st = -1.0, 0.0
    ry = np.array([[ct, 0.0, st], [0.0, 1.0, 0.0], [-st, 0.0, ct]])
    rz = np.array([[cp, -sp, 0.0], [sp, cp, 0.0], [0.0, 0.0, 1.0]])
    return rz @ ry


@dataclass(frozen=True)
class Beam:
    """How rays reach the specimen. Lengths in mm; angles in degrees.

    ``disk_sampling`` picks how both disks are sampled; every choice is exactly uniform, so it
    changes the time, never the distribution: ``"rejection"`` (eq. 3.3, no trigonometry),
    ``"polar"`` (eq. 3.4, a fixed two uniforms per point) or ``"auto"`` (the default: the faster
    one for each kernel -- rejection in the ray-by-ray kernels, polar in the vectorized block
    kernel of the goniophotometer, which cannot reject; see ``benchmarks/``).
    """

    kind: str = "collimated"
    emitter_radius_mm: float = 5.0
    specimen_radius_mm: float = 12.5
    distance_mm: float = 76.2
    disk_sampling: str = "auto"

    def __post_init__(self) -> None:
        if self.kind not in ("collimated", "conical"):
            raise InputError(f"beam must be 'collimated' or 'conical', got {self.kind!r}")
        for name in ("emitter_radius_mm", "specimen_radius_mm", "distance_mm"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise InputError(f"beam {name} must be finite and > 0, got {v!r}")
        if self.disk_sampling not in DISK_CODES:
            raise InputError(f"beam disk_sampling must be one of {', '.join(DISK_CODES)}, got {self.disk_sampling!r}")

    @property
    def code(self) -> int:
        return BEAM_CONICAL if self.kind == "conical" else BEAM_COLLIMATED

    @property
    def disk_code(self) -> int:
        return DISK_CODES[self.disk_sampling]

    @property
    def max_half_angle_deg(self) -> float:
        """Largest angle between a ray and the beam axis (conical); 0 for collimated."""
        if self.kind == "collimated":
            return 0.0
        return math.degrees(math.atan2(self.emitter_radius_mm + self.specimen_radius_mm, self.distance_mm))

    def kernel_args(self, theta_i: float, phi_i: float) -> np.ndarray:
        """Float vector the kernels read: rotation (9), r1, r2, D, axis (3) (indices ``B_*`` of
        :mod:`virtual.kernels.emit`)."""
        check_incidence(theta_i)
        rot = rotation_to(theta_i, phi_i)
        return np.concatenate([rot.ravel(), [self.emitter_radius_mm, self.specimen_radius_mm,
                                             self.distance_mm], rot[:, 2]]).astype(np.float64)

    def describe(self) -> dict:
        d = {"kind": self.kind}
        if self.kind == "conical":
            d.update(emitter_radius_mm=self.emitter_radius_mm, specimen_radius_mm=self.specimen_radius_mm,
                     distance_mm=self.distance_mm, disk_sampling=self.disk_sampling,
                     max_half_angle_deg=self.max_half_angle_deg)
        return d


def check_incidence(theta_i: float) -> None:
    """Grazing incidence exactly at 90 deg puts no flux on the specimen: refuse it clearly."""
    if not math.isfinite(theta_i) or not 0.0 <= theta_i <= 180.0:
        raise GeometryError(f"incidence theta_i = {theta_i} deg is outside [0, 180] deg")
    if theta_i == 90.0:
        raise GeometryError("incidence theta_i = 90 deg is exactly grazing: no flux reaches the specimen")



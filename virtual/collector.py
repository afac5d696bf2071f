"""The collector sphere of the virtual goniophotometer: rings x sectors, both hemispheres.

The sphere around the specimen is cut into ``n_theta`` rings (zenith bands) and ``n_phi``
equal sectors (azimuth wedges) per hemisphere. The upper hemisphere (z >= 0, reflection, "R")
is cut by the zenith edges ``0 = t_0 < t_1 < ... < t_n = 90 deg``; the lower hemisphere
(transmission, "T") is its mirror image in the specimen plane (ring k of T lies between
180 - t_k and 180 - t_{k+1} degrees). Three schemes (Krishnaswamy, Baranoski & Rokne 2004):

``equal-angle``        t_k = k * 90 deg / n
``equal-solid-angle``  1 - cos t_k = k / n          (every patch has solid angle 2 pi / (n n_phi))
``equal-psa``          sin^2 t_k = k / n            (every patch has PSA pi / (n n_phi))

Each patch's exact projected solid angle is ``PSA = dphi/2 (cos^2 t_b - cos^2 t_e)`` and its
solid angle ``dphi (cos t_b - cos t_e)``; the BRDF estimate of a patch is ``n_d / (N PSA)``.

Bin numbering (what :func:`patch_of` returns), ``n_patches = n_theta * n_phi`` per hemisphere::

    bin = ring * n_phi + sector                  upper hemisphere (z >= 0), bins [0, n_patches)
    bin = n_patches + ring * n_phi + sector      lower hemisphere (z < 0),  bins [n_patches, 2 n_patches)

ring 0 touches the pole (+z above, -z below), ring ``n_theta - 1`` touches the horizon.

Lookup rules (exact, never NaN, never out of range):

* the ring is found from ``sin^2 theta = (x^2 + y^2) / (x^2 + y^2 + z^2)`` -- no ``acos(z)``, so
  a direction whose ``|z|`` rounds past 1, or a vector that is not unit length, is fine -- by a
  closed-form guess corrected against the stored edges ``sin2_edges`` (so the decision is
  exactly "sin2_edges[k] <= sin^2 theta < sin2_edges[k+1]", with sin^2 theta = 1 in the last ring);
* the sector j is the one with ``cross(e_j, v) >= 0 > cross(e_{j+1}, v)`` where ``e_j = (cos phi_j,
  sin phi_j)`` are the stored edge vectors (exact at quarter turns) and ``cross(e, v) = e_x y - e_y x``:
  azimuth edges are [phi_j, phi_{j+1}), and no atan2 is needed (a polynomial guess is corrected).
  A direction just below phi = 2 pi (e.g. y = -1e-300, x > 0) is in the last sector, y = -0.0
  with x > 0 in sector 0 (phi = 0);
* pole: ``x = y = 0`` (either sign of zero) is sector 0 of ring 0;
* horizon: ``z = 0`` -- also ``z = -0.0`` -- belongs to the *upper* hemisphere's outermost ring
  (the horizon is counted as reflection; analog specimens never emit exactly z = 0);
* a zero vector, or one with NaN components, is put in bin 0 (the upper pole patch); callers
  never produce such directions, the rule only guarantees a valid index. Components so large
  or small that their squares overflow/underflow are rescaled first; infinite components win
  (``(inf, 1, 1)`` is the direction (1, 0, 0)).

Kernels use :func:`patch_of` inline; :meth:`Collector.kernel_args` gives its trailing arguments.
The lookup kernels live in :mod:`virtual.kernels.patch_lookup` (``patch_of``, ``guess_bin``), the
``SCHEME_*`` codes and the atan error bounds in :mod:`virtual.kernel_codes` (which does not load
numba: listing, parsing and the fast path's quadrature never need a kernel).
Note: kernels are compiled with ``nnan`` (:data:`virtual.kernels.FASTMATH`), which lets LLVM assume
there are no NaNs and may drop the NaN rule above (the other rules do not depend on it).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bench.core.errors import InputError
from virtual.kernel_codes import (ATAN32_MAX_ERROR, ATAN_MAX_ERROR, SCHEME_EQUAL_ANGLE, SCHEME_EQUAL_PSA,
                                  SCHEME_EQUAL_SOLID_ANGLE)

__all__ = ["SCHEMES", "Collector", "guess_margins", "guess_margins32", "parse_collector"]

#: scheme name -> integer code passed to :func:`patch_of`
SCHEMES: dict[str, int] = {
    "equal-angle": SCHEME_EQUAL_ANGLE,
    "equal-solid-angle": SCHEME_EQUAL_SOLID_ANGLE,
    "equal-psa": SCHEME_EQUAL_PSA,
}
_ALIASES = {
    "equal-angles": "equal-angle",
    "angle": "equal-angle",
    "equal-area": "equal-solid-angle",
    "equal-areas": "equal-solid-angle",
    "equal-solid-angles": "equal-solid-angle",
    "solid-angle": "equal-solid-angle",
    "equal-projected-solid-angle": "equal-psa",
    "psa": "equal-psa",
}
MAX_RINGS = 100_000
MAX_SECTORS = 100_000

_TWO_PI = 2.0 * math.pi
_HALF_PI = 0.5 * math.pi


def guess_margins(n_theta: int, n_phi: int) -> tuple[float, float]:
    """``(ring_margin, sector_margin)`` of :func:`guess_bin` for ``n_theta`` rings and
    ``n_phi`` sectors: four times the polynomial atan's error bound, plus 64 ulp of the rounding
    of sin^2 theta near the edges (which grows as n^2 where sin^2 theta flattens, at the
    horizon), in ring and sector units."""
    eps = float(np.finfo(np.float64).eps)
    ring = 4.0 * ATAN_MAX_ERROR * n_theta / _HALF_PI + 64.0 * eps * n_theta * n_theta + 1e-12
    sector = 4.0 * ATAN_MAX_ERROR * n_phi / _TWO_PI + 64.0 * eps * n_phi + 1e-12
    return float(ring), float(sector)


def guess_margins32(n_theta: int, n_phi: int) -> np.ndarray:
    """float32 ``(ring_margin, sector_margin)`` of :func:`virtual.kernels.f32.guess_bin32`: four
    times the float32 atan's error bound plus 32 float32 ulp of the ring and sector coordinates
    (their rounding, approximate reciprocals included), plus the float64 lookup's own margin
    (:func:`guess_margins`), in ring and sector units."""
    eps32 = float(np.finfo(np.float32).eps)
    ring64, sector64 = guess_margins(n_theta, n_phi)
    ring = 4.0 * ATAN32_MAX_ERROR * n_theta / _HALF_PI + 32.0 * eps32 * n_theta + ring64
    sector = 4.0 * ATAN32_MAX_ERROR * n_phi / _TWO_PI + 32.0 * eps32 * n_phi + sector64
    return np.array([ring, sector], dtype=np.float32)


def _theta_edges(scheme: str, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Zenith edges (radians) and their sin^2, with exact end points."""
    k = np.arange(n + 1, dtype=np.float64)
    if scheme == "equal-angle":
        t = k * (_HALF_PI / n)
        s2 = np.sin(t) ** 2
    elif scheme == "equal-solid-angle":
        c = 1.0 - k / n
        t = np.arccos(c)
        s2 = (1.0 - c) * (1.0 + c)
    else:  # equal-psa
        s2 = k / n
        t = np.arcsin(np.sqrt(s2))
    t[0], t[-1] = 0.0, _HALF_PI
    s2[0], s2[-1] = 0.0, 1.0
    return t, s2


@dataclass(frozen=True)
class Collector:
    """A collector sphere of ``n_theta`` rings x ``n_phi`` sectors per hemisphere.

    Parameters
    ----------
    scheme : str
        ``"equal-angle"``, ``"equal-solid-angle"`` or ``"equal-psa"``.
    n_theta, n_phi : int
        Rings per hemisphere (>= 1) and sectors per ring (>= 1).

    Attributes (all arrays read-only)
    ---------------------------------
    theta_edges, theta_edges_deg : (n_theta + 1,)  zenith edges of the upper hemisphere.
    phi_edges, phi_edges_deg : (n_phi + 1,)        azimuth edges, 0 .. 2 pi.
    sin2_edges : (n_theta + 1,)                    sin^2 of the zenith edges (for :func:`patch_of`).
    psa, solid_angle : (n_bins,)                   exact PSA and solid angle of every bin.
    centres : (n_bins, 3)                          unit vector at each patch's (theta, phi) midpoint.
    centres_deg : (n_bins, 2)                      (theta, phi) of those midpoints in degrees
                                                   (theta > 90 in the lower hemisphere).
    """

    scheme: str
    n_theta: int
    n_phi: int
    scheme_code: int = field(init=False)
    theta_edges: np.ndarray = field(init=False, repr=False, compare=False)
    sin2_edges: np.ndarray = field(init=False, repr=False, compare=False)
    phi_edges: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        scheme = _ALIASES.get(str(self.scheme).strip().lower(), str(self.scheme).strip().lower())
        if scheme not in SCHEMES:
            raise InputError(f"unknown collector scheme {self.scheme!r}; known: {', '.join(SCHEMES)}")
        for name, v, hi in (("n_theta", self.n_theta, MAX_RINGS), ("n_phi", self.n_phi, MAX_SECTORS)):
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not 1 <= int(v) <= hi:
                raise InputError(f"collector {name} must be an integer in [1, {hi}], got {v!r}")
        object.__setattr__(self, "scheme", scheme)
        object.__setattr__(self, "n_theta", int(self.n_theta))
        object.__setattr__(self, "n_phi", int(self.n_phi))
        object.__setattr__(self, "scheme_code", SCHEMES[scheme])
        t, s2 = _theta_edges(scheme, self.n_theta)
        p = np.arange(self.n_phi + 1, dtype=np.float64) * (_TWO_PI / self.n_phi)
        p[-1] = _TWO_PI
        for a in (t, s2, p):
            a.setflags(write=False)
        object.__setattr__(self, "theta_edges", t)
        object.__setattr__(self, "sin2_edges", s2)
        object.__setattr__(self, "phi_edges", p)

    # -- sizes ------------------------------------------------------------------------------
    @property
    def n_patches(self) -> int:
        """Patches per hemisphere (``n_theta * n_phi``)."""
        return self.n_theta * self.n_phi

    @property
    def n_bins(self) -> int:
        """Bins over both hemispheres (``2 * n_patches``)."""
        return 2 * self.n_patches

    # -- geometry ---------------------------------------------------------------------------
    @property
    def theta_edges_deg(self) -> np.ndarray:
        return np.degrees(self.theta_edges)

    @property
    def phi_edges_deg(self) -> np.ndarray:
        return np.degrees(self.phi_edges)

    @property
    def cos2_edges(self) -> np.ndarray:
        """cos^2 of the zenith edges, computed as 1 - sin^2 (exact 1 and 0 at the ends)."""
        return 1.0 - self.sin2_edges

    def _per_bin(self, ring_values: np.ndarray) -> np.ndarray:
        """Repeat per-ring values over sectors and mirror to the lower hemisphere."""
        up = np.repeat(ring_values, self.n_phi)
        out = np.concatenate([up, up])
        out.setflags(write=False)
        return out

    @property
    def ring_psa(self) -> np.ndarray:
        """PSA of one patch of each ring: ``dphi/2 (cos^2 t_b - cos^2 t_e)``."""
        dphi = _TWO_PI / self.n_phi
        c2 = self.cos2_edges
        if self.scheme == "equal-psa":  # sin^2 edges are exactly k/n: use their differences
            return 0.5 * dphi * np.diff(self.sin2_edges)
        return 0.5 * dphi * (c2[:-1] - c2[1:])

    @property
    def ring_solid_angle(self) -> np.ndarray:
        """Solid angle of one patch of each ring: ``dphi (cos t_b - cos t_e)``."""
        dphi = _TWO_PI / self.n_phi
        t = self.theta_edges
        # cos t_b - cos t_e = 2 sin((t_e + t_b)/2) sin((t_e - t_b)/2), no cancellation
        return dphi * 2.0 * np.sin(0.5 * (t[1:] + t[:-1])) * np.sin(0.5 * (t[1:] - t[:-1]))

    @property
    def psa(self) -> np.ndarray:
        """Exact projected solid angle (sr) of every bin, in bin order."""
        return self._per_bin(self.ring_psa)

    @property
    def solid_angle(self) -> np.ndarray:
        """Solid angle (sr) of every bin, in bin order."""
        return self._per_bin(self.ring_solid_angle)

    def bin_bounds(self) -> np.ndarray:
        """``(n_bins, 4)`` radians: theta_begin, theta_end, phi_begin, phi_end of every bin.

        In the lower hemisphere theta runs from 180 deg (pole) toward 90 deg, i.e. the
        bounds are ``pi - t_k, pi - t_{k+1}``.
        """
        t, p = self.theta_edges, self.phi_edges
        tb = np.repeat(t[:-1], self.n_phi)
        te = np.repeat(t[1:], self.n_phi)
        pb = np.tile(p[:-1], self.n_theta)
        pe = np.tile(p[1:], self.n_theta)
        up = np.column_stack([tb, te, pb, pe])
        low = np.column_stack([math.pi - tb, math.pi - te, pb, pe])
        return np.vstack([up, low])

    @property
    def centres_deg(self) -> np.ndarray:
        b = self.bin_bounds()
        return np.degrees(np.column_stack([0.5 * (b[:, 0] + b[:, 1]), 0.5 * (b[:, 2] + b[:, 3])]))

    @property
    def centres(self) -> np.ndarray:
        b = self.bin_bounds()
        t = 0.5 * (b[:, 0] + b[:, 1])
        p = 0.5 * (b[:, 2] + b[:, 3])
        st = np.sin(t)
        return np.column_stack([st * np.cos(p), st * np.sin(p), np.cos(t)])

    # -- lookup -----------------------------------------------------------------------------
    @property
    def phi_cs(self) -> np.ndarray:
        """``(n_phi + 1, 2)`` cos and sin of the azimuth edges, exact (0, +-1) at quarter turns."""
        j = np.arange(self.n_phi + 1)
        cs = np.column_stack([np.cos(self.phi_edges), np.sin(self.phi_edges)])
        quarter = (4 * j) % self.n_phi == 0
        q = (4 * j[quarter]) // self.n_phi % 4
        cs[quarter] = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]])[q]
        return np.ascontiguousarray(cs)

    def kernel_args(self) -> tuple[int, int, int, np.ndarray, np.ndarray]:
        """``(scheme_code, n_theta, n_phi, sin2_edges, phi_cs)``: the trailing arguments of
        :func:`patch_of`. Compute once and pass to the kernel."""
        return (self.scheme_code, self.n_theta, self.n_phi,
                np.ascontiguousarray(self.sin2_edges, dtype=np.float64), self.phi_cs)

    def guess_margins(self) -> tuple[float, float]:
        """:func:`guess_margins` of this collector: the trailing arguments of :func:`guess_bin`."""
        return guess_margins(self.n_theta, self.n_phi)

    def guess_margins32(self) -> np.ndarray:
        """:func:`guess_margins32` of this collector (the float32 block kernel's)."""
        return guess_margins32(self.n_theta, self.n_phi)

    def index(self, dirs: np.ndarray) -> np.ndarray:
        """Bin index (int64) of each row of ``dirs`` (n, 3); rows need not be unit vectors."""
        d = np.ascontiguousarray(np.atleast_2d(np.asarray(dirs, dtype=np.float64)))
        if d.ndim != 2 or d.shape[1] != 3:
            raise InputError(f"directions must have shape (n, 3), got {np.shape(dirs)}")
        from virtual.kernels.patch_lookup import index_many  # numba only when rays are binned

        out = np.empty(d.shape[0], dtype=np.int64)
        index_many(d, *self.kernel_args(), out)
        return out

    def ring_sector(self, bins: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(upper, ring, sector)`` of bin indices (upper is a bool array)."""
        b = np.asarray(bins, dtype=np.int64)
        upper = b < self.n_patches
        local = np.where(upper, b, b - self.n_patches)
        return upper, local // self.n_phi, local % self.n_phi

    def describe(self) -> dict[str, Any]:
        """JSON-ready description with stable keys."""
        return {
            "scheme": self.scheme,
            "n_theta": self.n_theta,
            "n_phi": self.n_phi,
            "n_patches": self.n_patches,
            "n_bins": self.n_bins,
            "theta_edges_deg": [float(v) for v in self.theta_edges_deg],
            "phi_edges_deg": [float(v) for v in self.phi_edges_deg],
            "hemisphere_psa": float(self.ring_psa.sum() * self.n_phi),
            "horizon": "upper",
            "pole_sector": 0,
            "spec": f"{self.scheme}:{self.n_theta}x{self.n_phi}",
        }

    def __str__(self) -> str:
        return f"{self.scheme}:{self.n_theta}x{self.n_phi}"


_SPEC_RE = re.compile(r"^\s*([A-Za-z][A-Za-z-]*)\s*:\s*(\d+)\s*[xX*]\s*(\d+)\s*$")


def parse_collector(spec: str | Collector) -> Collector:
    """Build a :class:`Collector` from ``"scheme:RINGSxSECTORS"``, e.g. ``"equal-psa:9x36"``.

    Raises
    ------
    InputError
        When the text is not of that form, names an unknown scheme, or the counts are out of range.
    """
    if isinstance(spec, Collector):
        return spec
    if not isinstance(spec, str):
        raise InputError(f"collector: expected text like 'equal-psa:9x36', got {type(spec).__name__}")
    m = _SPEC_RE.match(spec)
    if not m:
        raise InputError(f"collector {spec!r}: expected 'scheme:RINGSxSECTORS' such as 'equal-psa:9x36' "
                         f"(schemes: {', '.join(SCHEMES)})")
    return Collector(m.group(1), int(m.group(2)), int(m.group(3)))

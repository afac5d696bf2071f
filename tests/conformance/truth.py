"""The truth a conformance cell is judged against: what an ideal bench would read for the known
specimens, computed here apart from every measuring path of the project.

* Lambertian of albedo ``a``: the closed form ``a / pi``.
* GGX (a rough conductor, separable Smith masking): Mitsuba 3's own ``roughconductor`` ``eval`` --
  an outside referee, the one ``tests/test_mitsuba.py`` checks our sampling against. When the
  ``mitsuba`` extra is missing, the project's declared density (``specimen.bsdf``) stands in.
* Rough plastic: goniobench's own model (Mitsuba's ``roughplastic`` is another model), evaluated
  from its declared closed form ``specimen.bsdf`` -- not through any body, kernel or calibration.

A detector reads a region, not a direction: the cone of half-angle ``aperture_deg`` around the
viewing direction (every body of the shipped descriptions declares 1 deg), or a collector patch
(a sweep's record). The truth of a reading is the projected-solid-angle average of the BRDF over
that region (``int f cos dw / int cos dw``), by Gauss-Legendre quadrature.
"""

from __future__ import annotations

import functools
import math
from typing import Callable

import numpy as np

#: the known specimens of the matrix: spec string (for the bench description) and fit model
SPECIMENS: dict[str, dict[str, str]] = {
    "lambert": {"spec": "lambert:albedo=0.8", "model": "lambert:reflectance=?"},
    "plastic": {"spec": "plastic:alpha=0.3,eta=1.5,kd=0.5", "model": "plastic:alpha=?,eta=1.5,kd=?"},
    "ggx": {"spec": "ggx:alpha=0.3,eta=0.2,k=3,masking=separable",
            "model": "ggx:alpha=?,eta=0.2,k=3,masking=separable"},
}
#: the true value of each free parameter of the fit models
TRUE_PARAMETERS: dict[str, dict[str, float]] = {
    "lambert": {"reflectance": 0.8}, "plastic": {"alpha": 0.3, "kd": 0.5}, "ggx": {"alpha": 0.3}}
MITSUBA_GGX = {"type": "roughconductor", "distribution": "ggx", "alpha": 0.3, "eta": 0.2, "k": 3.0}


def direction(theta_deg: np.ndarray | float, phi_deg: np.ndarray | float) -> np.ndarray:
    """Unit vector(s) (..., 3) at zenith ``theta`` from the normal, azimuth ``phi`` from X."""
    t, p = np.radians(theta_deg), np.radians(phi_deg)
    return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)


@functools.lru_cache(maxsize=None)
def brdf_function(name: str) -> Callable[[np.ndarray, np.ndarray, float], np.ndarray]:
    """``f(wi (3,), wo (n, 3), wavelength_nm) -> (n,)`` of the named known specimen."""
    if name == "lambert":
        albedo = TRUE_PARAMETERS["lambert"]["reflectance"]
        return lambda wi, wo, wl: np.where(np.asarray(wo)[:, 2] > 0, albedo / math.pi, 0.0)
    if name == "ggx":
        try:
            from virtual.specimens.mitsuba import MitsubaSpecimen

            return MitsubaSpecimen(MITSUBA_GGX).bsdf
        except Exception:  # the mitsuba extra is optional: the declared density then is the truth
            pass
    from virtual.specimens import parse_specimen

    return parse_specimen(SPECIMENS[name]["spec"]).bsdf


def _cone_nodes(aperture_deg: float, n_r: int = 5, n_phi: int = 12) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Quadrature of a cone of half-angle ``aperture_deg`` about +Z: (polar offsets rad, azimuths
    rad, solid-angle weights)."""
    x, w = np.polynomial.legendre.leggauss(n_r)
    a = math.radians(aperture_deg)
    u = 0.5 * (x + 1.0) * a  # polar offset from the axis
    wu = 0.5 * a * w * np.sin(u)
    ph = (np.arange(n_phi) + 0.5) * 2 * math.pi / n_phi
    U, P = np.meshgrid(u, ph, indexing="ij")
    W = np.repeat(wu[:, None], n_phi, axis=1) * (2 * math.pi / n_phi)
    return U.ravel(), P.ravel(), W.ravel()


def _rotate_to(axis: np.ndarray, u: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Directions at polar offset ``u`` and azimuth ``p`` about the unit vector ``axis``."""
    z = axis / np.linalg.norm(axis)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return (np.sin(u) * np.cos(p))[:, None] * x + (np.sin(u) * np.sin(p))[:, None] * y + np.cos(u)[:, None] * z


def cone_truth(name: str, theta_i: float, phi_i: float, theta_r: float, phi_r: float, wavelength_nm: float,
               aperture_deg: float) -> float:
    """The projected-solid-angle mean BRDF (1/sr) over the detector cone at (theta_r, phi_r)."""
    f = brdf_function(name)
    wi = direction(theta_i, phi_i)
    if aperture_deg <= 0:
        return float(f(wi, direction(theta_r, phi_r)[None, :], wavelength_nm)[0])
    u, p, w = _cone_nodes(aperture_deg)
    wo = _rotate_to(direction(theta_r, phi_r), u, p)
    cos_o = np.maximum(wo[:, 2], 0.0)
    return float(np.sum(f(wi, wo, wavelength_nm) * cos_o * w) / np.sum(cos_o * w))


def patch_truth(name: str, theta_i: float, phi_i: float, box: tuple[float, float, float, float],
                wavelength_nm: float, n: int = 6) -> float:
    """The projected-solid-angle mean BRDF over a collector patch ``box`` = (theta_min, theta_max,
    phi_min, phi_max) in degrees (a sweep's record)."""
    f = brdf_function(name)
    t0, t1, p0, p1 = (math.radians(v) for v in box)
    x, w = np.polynomial.legendre.leggauss(n)
    t = 0.5 * (t1 - t0) * (x + 1) + t0
    p = 0.5 * (p1 - p0) * (x + 1) + p0
    T, P = np.meshgrid(t, p, indexing="ij")
    W = np.outer(w, w) * np.sin(T) * np.cos(T)  # projected solid angle
    wo = direction(np.degrees(T.ravel()), np.degrees(P.ravel()))
    vals = f(direction(theta_i, phi_i), wo, wavelength_nm)
    return float(np.sum(vals * W.ravel()) / np.sum(W))


def truth_of(name: str, rows, aperture_deg: float) -> np.ndarray:
    """The truth of each row of a readings table (columns theta_i, phi_i, theta_r, phi_r,
    wavelength_nm; a sweep's rows also theta_min..phi_max and hemisphere)."""
    out = np.empty(len(rows))
    patches = "theta_min" in rows and rows["theta_min"].notna().all() and (rows["theta_max"] > rows["theta_min"]).all()
    for k, r in enumerate(rows.itertuples(index=False)):
        if patches:
            out[k] = patch_truth(name, r.theta_i, r.phi_i, (r.theta_min, r.theta_max, r.phi_min, r.phi_max),
                                 r.wavelength_nm)
        else:
            out[k] = cone_truth(name, r.theta_i, r.phi_i, r.theta_r, r.phi_r, r.wavelength_nm, aperture_deg)
    return out

"""Numpy face of the specimen physics: Fresnel factors, GGX densities and visible-normal means.

The densities (:meth:`virtual.specimens.Specimen.bsdf`) of the analytic models are built from
these; their kernel twins are :mod:`virtual.kernels.microfacet` and :mod:`virtual.kernels.ggx`.

Conventions. Every analytic model is written in the *local frame of the lit side*: when the
source is below the specimen (w_z < 0) an opaque model is mirrored in the specimen plane
(two-sided), and the dielectric interface swaps the media (eta -> 1/eta). Fresnel factors are
unpolarized. GGX uses Smith's height-correlated masking-shadowing
    G2 = 1 / (1 + L(wi) + L(wo)),  G1(w) = 1 / (1 + L(w)),
    L(w) = (sqrt(1 + (ax^2 wx^2 + ay^2 wy^2) / wz^2) - 1) / 2,
and D(m) = 1 / (pi ax ay (mx^2/ax^2 + my^2/ay^2 + mz^2)^2). With n(w) = sqrt(ax^2 wx^2 +
ay^2 wy^2 + wz^2) one has G2 / (4 zi zo) = 1 / (2 (n_i zo + n_o zi)) and
G2 / G1(wi) = (zi + n_i) zo / (n_i zo + n_o zi): no division by a grazing cosine anywhere.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from bench.core.geometry import gauss_legendre
from virtual.cubature import integrate_rectangle
from virtual.fresnel import np_fresnel_conductor, np_fresnel_dielectric

__all__ = ["np_fresnel_conductor", "np_fresnel_dielectric", "np_ggx_d", "np_ggx_n", "np_ggx_reflection",
           "local", "mirror", "fresnel_hemispherical_average", "vndf_mean", "vndf_normals",
           "np_g2_over_g1", "angle_between", "g2_over_4", "MASKINGS", "lobe_width",
           "fresnel_vndf_mean",
           "vndf_expectation"]



def np_ggx_d(hx, hy, hz, ax: float, ay: float) -> np.ndarray:
    q = hx * hx / (ax * ax) + hy * hy / (ay * ay) + hz * hz
    return 1.0 / (math.pi * ax * ay * q * q)


def np_ggx_n(wx, wy, wz, ax: float, ay: float) -> np.ndarray:
    """n(w) = sqrt(ax^2 wx^2 + ay^2 wy^2 + wz^2) (see the conventions above)."""
    return np.sqrt(ax * ax * wx * wx + ay * ay * wy * wy + wz * wz)


def np_ggx_reflection(wi: np.ndarray, wo: np.ndarray, ax: float, ay: float, fresnel,
                      masking: str = "correlated") -> np.ndarray:
    """F D G2 / (4 zi zo) for wi (3,) with zi > 0 and wo (n, 3); 0 where zo <= 0.
    ``masking="separable"``: G2 = G1(wi) G1(wo), so G2 / (4 zi zo) = 1 / ((zi + n_i)(zo + n_o))."""
    zi = wi[2]
    zo = wo[:, 2]
    hx, hy, hz = wi[0] + wo[:, 0], wi[1] + wo[:, 1], zi + zo
    inv = 1.0 / np.maximum(np.sqrt(hx * hx + hy * hy + hz * hz), 1e-300)
    hx, hy, hz = hx * inv, hy * inv, hz * inv
    c = wi[0] * hx + wi[1] * hy + zi * hz
    ni = np_ggx_n(wi[0], wi[1], zi, ax, ay)
    no = np_ggx_n(wo[:, 0], wo[:, 1], np.maximum(zo, 0.0), ax, ay)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        f = fresnel(c) * np_ggx_d(hx, hy, hz, ax, ay) * g2_over_4(zi, ni, zo, no, masking)
    return np.where(zo > 0.0, np.nan_to_num(f, nan=0.0, posinf=0.0), 0.0)


def np_g2_over_g1(wi: np.ndarray, wo: np.ndarray, ax: float, ay: float,
                  masking: str = "correlated") -> np.ndarray:
    """G2(wi, wo) / G1(wi) for wi (3,) with wi_z > 0 and wo (n, 3) on the same side; 0 where
    wo_z <= 0 (continuous there). ``masking``: ``"correlated"`` (height-correlated Smith,
    ``(zi + n_i) zo / (n_i zo + n_o zi)``) or ``"separable"`` (``G1(wo) = 2 zo / (zo + n_o)``)."""
    zi = wi[2]
    zo = np.maximum(wo[:, 2], 0.0)
    ni = np_ggx_n(wi[0], wi[1], zi, ax, ay)
    no = np_ggx_n(wo[:, 0], wo[:, 1], zo, ax, ay)
    with np.errstate(divide="ignore", invalid="ignore"):
        if masking == "separable":
            g = 2.0 * zo / (zo + no)
        else:
            g = (zi + ni) * zo / (ni * zo + no * zi)
    return np.where(zo > 0.0, np.nan_to_num(g, nan=0.0), 0.0)


def angle_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angles (radians) between unit vectors a (3,) and rows of b (n, 3), accurate near 0."""
    cr = np.linalg.norm(np.cross(b, a), axis=-1)
    return np.arctan2(cr, b @ a)


def lobe_width(center: np.ndarray, dirs: np.ndarray) -> float:
    """The median angle between a lobe's centre and directions drawn from it (radians): the
    width hint the quadrature resolves (> 0)."""
    c = np.asarray(center, dtype=float)
    c = c / np.linalg.norm(c)
    d = dirs / np.linalg.norm(dirs, axis=-1, keepdims=True)
    return max(float(np.median(angle_between(c, d))), 1e-12)


MASKINGS = ("correlated", "separable")


def g2_over_4(zi, ni, zo, no, masking: str = "correlated"):
    """G2 / (4 zi zo) from the cosines and n(w) of both directions (no division by a cosine):
    ``1 / (2 (n_i zo + n_o zi))`` height-correlated, ``1 / ((zi + n_i)(zo + n_o))`` separable."""
    if masking == "separable":
        return 1.0 / ((zi + ni) * (zo + no))
    return 1.0 / (2.0 * (ni * zo + no * zi))


def local(wi: np.ndarray, wo: np.ndarray) -> tuple[np.ndarray, np.ndarray, bool]:
    """Mirror (wi, wo) so that wi is on the +z side; returns (wi, wo (n,3), flipped)."""
    wi = np.asarray(wi, dtype=np.float64).reshape(3)
    wo = np.atleast_2d(np.asarray(wo, dtype=np.float64))
    if wi[2] < 0.0:
        m = np.array([1.0, 1.0, -1.0])
        return wi * m, wo * m, True
    return wi, wo, False



def mirror(wi: np.ndarray) -> np.ndarray:
    w = np.asarray(wi, dtype=float).reshape(3)
    return np.array([-w[0], -w[1], w[2]]) / np.linalg.norm(w)



@lru_cache(maxsize=256)
def fresnel_hemispherical_average(eta: float) -> float:
    """F_avg = 2 int_0^1 F(mu) mu dmu for the dielectric of relative index eta (Gauss-Legendre)."""
    x, w = gauss_legendre(256)
    mu = 0.5 * (x + 1.0)
    return float(np.sum(w * 0.5 * 2.0 * mu * np_fresnel_dielectric(mu, eta)))


def vndf_normals(wi: np.ndarray, ax: float, ay: float, u: np.ndarray,
                 t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Visible normals m (n, 3) of wi (wi_z > 0) at points (u, t) of the unit square, and the
    density of the map (so that ``E[g(m)] = int int g(m(u, t)) jac du dt``).

    The sampler's own construction (spherical caps, :func:`virtual.kernels.ggx.ggx_vndf_given`:
    disk azimuth phi = 2 pi u and squared radius r2), with r2 = sin^2(pi t / 2) so that the
    square roots sqrt(r2) and, at normal incidence, sqrt(2 - q r2) become smooth in t (a plain
    r2 = t leaves a sqrt singularity that Gauss-Legendre converges to only algebraically).
    """
    u = np.asarray(u, dtype=float)
    t = np.asarray(t, dtype=float)
    vx, vy, vz = ax * wi[0], ay * wi[1], wi[2]
    n = math.sqrt(vx * vx + vy * vy + vz * vz)
    vx, vy, vz = vx / n, vy / n, vz / n
    q = 1.0 + vz
    s = np.sin(0.5 * math.pi * t)
    c = np.cos(0.5 * math.pi * t)
    r2 = s * s
    # q (2 - q r2) = q (2 - q) + q^2 cos^2: no cancellation at normal incidence (q = 2)
    sc = s * np.sqrt(np.maximum(q * (2.0 - q) + q * q * c * c, 0.0))
    phi = 2.0 * math.pi * u
    hx = sc * np.cos(phi) + vx
    hy = sc * np.sin(phi) + vy
    hz = np.maximum(1.0 - q * r2 + vz, 0.0)
    mx, my = ax * hx, ay * hy
    nn = np.maximum(np.sqrt(mx * mx + my * my + hz * hz), 1e-300)
    jac = 0.5 * math.pi * np.sin(math.pi * t)
    return np.stack([mx / nn, my / nn, hz / nn], axis=-1), jac


def vndf_expectation(wi: np.ndarray, ax: float, ay: float, g, rtol: float = 1e-9,
                     atol: float = 1e-11) -> tuple[float, float]:
    """``E[g(m)]`` over the visible normals m of wi (wi_z > 0) by adaptive cubature on the
    sampler's unit square: ``(value, error estimate)``. ``g`` maps (n, 3) normals to (n,) values
    and should be continuous in m (kinks are fine, jumps converge slowly)."""
    w = np.asarray(wi, dtype=float).reshape(3)

    def integrand(u: np.ndarray, t: np.ndarray) -> np.ndarray:
        m, jac = vndf_normals(w, ax, ay, u, t)
        return np.asarray(g(m), dtype=float) * jac

    value, err, _ = integrate_rectangle(integrand, start=(8, 4), order=6, rtol=rtol, atol=atol)
    return value, err


def vndf_mean(wi: np.ndarray, ax: float, ay: float, func) -> float:
    """Mean of ``func(wi . m)`` over the visible normals m of wi (wi_z > 0), converged adaptively
    (:func:`vndf_expectation`; a fixed 48 x 48 rule was off by 2e-4 near grazing)."""
    w = np.asarray(wi, dtype=float).reshape(3)
    return vndf_expectation(w, ax, ay, lambda m: func(np.clip(m @ w, 0.0, 1.0)))[0]


@lru_cache(maxsize=4096)
def fresnel_vndf_mean(wx: float, wy: float, wz: float, alpha: float, eta: float) -> float:
    """Fbar(wi) = the mean dielectric Fresnel reflectance F(wi . m) over wi's visible GGX
    normals (isotropic alpha), cached: the rough-plastic density needs it at every call."""
    return vndf_mean(np.array([wx, wy, wz]), alpha, alpha, lambda c: np_fresnel_dielectric(c, eta))

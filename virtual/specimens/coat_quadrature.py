"""A rough GGX coat's albedos as Mitsuba 3 computes them for ``roughplastic``'s tables.

Mitsuba's ``eval_reflectance`` and ``eval_transmittance`` (``include/mitsuba/render/microfacet.h``)
integrate over the visible normals by a tensor Gauss-Legendre rule on the sampler's unit square
(32 x 32 nodes for a relative index eta > 1, 128 x 128 otherwise), each node mapped to a normal
by the GGX visible-normal warp (``MicrofacetDistribution::sample``: the concentric disk,
``sample_visible_11``, rotation and unstretching). The integrands have kinks (total internal
reflection, the masking cut-off), so that rule is off the converged albedo by up to ~1e-3 of the
diffuse term -- and the roughplastic's diffuse lobe *is* Mitsuba's table, so a faithful native
twin computes the table with the same rule (here in float64; Mitsuba's float32 evaluation
differs from it by a relative ~1e-7). Isotropic roughness, as ``roughplastic`` has.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from bench.core.geometry import gauss_legendre

__all__ = ["mitsuba_rough_reflectance", "mitsuba_rough_transmittance"]


@lru_cache(maxsize=4)
def _square_rule(eta: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mitsuba's nodes (u1, u2 in (0, 1)) and weights (their product / 4) for relative index eta."""
    x, w = gauss_legendre(32 if eta > 1.0 else 128)
    nx, ny = np.meshgrid(x, x)
    wx, wy = np.meshgrid(w, w)
    return 0.5 * nx.ravel() + 0.5, 0.5 * ny.ravel() + 0.5, (wx * wy).ravel() * 0.25


def _concentric_disk(u1: np.ndarray, u2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mitsuba's ``warp::square_to_uniform_disk_concentric`` (Shirley-Chiu, Cline's form)."""
    x, y = 2.0 * u1 - 1.0, 2.0 * u2 - 1.0
    q13 = np.abs(x) < np.abs(y)
    r, rp = np.where(q13, y, x), np.where(q13, x, y)
    with np.errstate(divide="ignore", invalid="ignore"):
        phi = 0.25 * math.pi * rp / r
    phi = np.where(q13, 0.5 * math.pi - phi, phi)
    phi = np.where((x == 0.0) & (y == 0.0), 0.0, phi)
    return r * np.cos(phi), r * np.sin(phi)


def _visible_normals(wi: np.ndarray, alpha: float, u1: np.ndarray, u2: np.ndarray) -> np.ndarray:
    """Mitsuba's GGX ``sample`` with visible normals, isotropic alpha: (n, 3) normals of ``wi``."""
    wp = np.array([alpha * wi[0], alpha * wi[1], wi[2]])
    wp /= np.linalg.norm(wp)
    s2 = 1.0 - wp[2] * wp[2]
    if abs(s2) <= 4.0 * np.finfo(np.float32).eps:
        sin_phi, cos_phi = 0.0, 1.0
    else:
        inv = 1.0 / math.sqrt(s2)
        cos_phi, sin_phi = min(max(wp[0] * inv, -1.0), 1.0), min(max(wp[1] * inv, -1.0), 1.0)
    ct = wp[2]
    px, py = _concentric_disk(u1, u2)
    s = 0.5 * (1.0 + ct)
    py = (1.0 - s) * np.sqrt(np.maximum(1.0 - px * px, 0.0)) + s * py  # dr::lerp(a, b, s)
    pz = np.sqrt(np.maximum(1.0 - px * px - py * py, 0.0))
    st = math.sqrt(max(1.0 - ct * ct, 0.0))
    norm = 1.0 / (st * py + ct * pz)
    sx, sy = (ct * py - st * pz) * norm, px * norm
    sx, sy = (cos_phi * sx - sin_phi * sy) * alpha, (sin_phi * sx + cos_phi * sy) * alpha
    m = np.stack([-sx, -sy, np.ones_like(sx)], axis=-1)
    return m / np.linalg.norm(m, axis=-1, keepdims=True)


def _smith_g1(v: np.ndarray, m: np.ndarray, alpha: float) -> np.ndarray:
    """Mitsuba's GGX ``smith_g1(v, m)`` for (n, 3) v and m."""
    xy = alpha * alpha * (v[:, 0] ** 2 + v[:, 1] ** 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        g = 2.0 / (1.0 + np.sqrt(1.0 + xy / v[:, 2] ** 2))
    g = np.where(xy == 0.0, 1.0, g)
    return np.where(np.sum(v * m, axis=-1) * v[:, 2] <= 0.0, 0.0, g)


def _fresnel(c: np.ndarray, eta: float) -> tuple[np.ndarray, np.ndarray, float]:
    """Mitsuba's dielectric ``fresnel(cos_theta_i, eta)`` for c >= 0: (F, cos_theta_t, eta_ti)."""
    eta_ti = 1.0 / eta
    ct2 = 1.0 - (1.0 - c * c) * eta_ti * eta_ti
    ct = np.sqrt(np.maximum(ct2, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        a_s = (c - eta * ct) / (c + eta * ct)
        a_p = (ct - eta * c) / (ct + eta * c)
    r = 0.5 * (a_s * a_s + a_p * a_p)
    r = np.where((eta == 1.0) | (c == 0.0), 0.0 if eta == 1.0 else 1.0, r)
    return r, -ct, eta_ti  # cos_theta_t carries the opposite sign of cos_theta_i (>= 0 here)


def _incident(mu: float) -> np.ndarray:
    return np.array([math.sqrt(max(1.0 - mu * mu, 0.0)), 0.0, mu])


@lru_cache(maxsize=4096)
def mitsuba_rough_reflectance(mu: float, alpha: float, eta: float) -> float:
    """``eval_reflectance``: E[F(wi.m) G1(wo)] over the visible normals of wi = (sqrt(1 - mu^2),
    0, mu), wo the mirror direction, by Mitsuba's rule."""
    wi = _incident(mu)
    u1, u2, w = _square_rule(eta)
    m = _visible_normals(wi, alpha, u1, u2)
    c = m @ wi
    wo = 2.0 * c[:, None] * m - wi
    f, _, _ = _fresnel(c, eta)
    g = _smith_g1(wo, m, alpha) * f
    g = np.where((wo[:, 2] <= 0.0) | (wi[2] <= 0.0), 0.0, g)
    return float(np.sum(g * w))


@lru_cache(maxsize=4096)
def mitsuba_rough_transmittance(mu: float, alpha: float, eta: float) -> float:
    """``eval_transmittance``: E[(1 - F(wi.m)) G1(wt)] over the visible normals, wt the refracted
    direction, by Mitsuba's rule."""
    wi = _incident(mu)
    u1, u2, w = _square_rule(eta)
    m = _visible_normals(wi, alpha, u1, u2)
    c = m @ wi
    f, ct, eta_ti = _fresnel(c, eta)
    wo = m * (c * eta_ti + ct)[:, None] - wi * eta_ti  # Mitsuba's refract(wi, m, cos_theta_t, eta_ti)
    g = _smith_g1(wo, m, alpha) * (1.0 - f)
    g = np.where(wo[:, 2] * wi[2] >= 0.0, 0.0, g)
    return float(np.sum(g * w))

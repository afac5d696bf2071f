"""Mitsuba 3's ``roughplastic`` as a native specimen (numpy density and sampler, no kernel).

Mitsuba's definition (``src/bsdfs/roughplastic.cpp``, GGX with visible-normal sampling): a
specular GGX coat of relative index eta with *separable* Smith masking, over a Lambertian base
of reflectance kd seen through the coat:

    f = F(wi.h) D(h) G1(wi) G1(wo) / (4 cos_i cos_o)
        + kd' t(cos_i) t(cos_o) / (pi eta^2),      kd' = kd / (1 - R_int)     (nonlinear = false)
                                                   kd' = kd / (1 - kd R_int)  (nonlinear = true)

t(mu) = the coat's rough transmittance at cos theta = mu (refracted rays that pass the
masking, E[(1 - F) G1(wt)] over the visible normals) is tabulated at 64 cosines
mu_i = max(1e-6, i / 63) and interpolated linearly (``lerp_gather``); R_int = 2 mean_i(R(mu_i;
1/eta) mu_i) is the coat's internal reflectance, the mean over the same 64 nodes of the
specular albedo seen from inside. The table entries are computed by Mitsuba's own fixed
quadrature (:mod:`virtual.specimens.coat_quadrature`): the converged albedos differ from them
by up to ~1e-3 of the diffuse term, which 10^8 rays detect.

The model does not conserve energy by construction; a combination whose diffuse albedo exceeds
what the coat lets through (``kd' (2 int t mu dmu) / eta^2 > 1``) is refused.

Sampling (exact, so ray counting and the fast path measure the same thing): a visible normal
m, mirror reflection, kept with probability F(wi.m) G1(wo) -- the specular term. Otherwise (the
remaining probability is exactly 1 - albedo_spec(wi), which the table's t(cos_i) interpolates)
the ray goes to the base with probability c t(cos_i) / (1 - albedo_spec(wi)) (<= 1 since
t <= 1 - albedo_spec and c <= 1), c = kd' 2 int t
mu dmu / eta^2, and leaves with a direction of density t(cos_o) cos_o / (pi 2 int t mu dmu)
(a cosine direction kept with probability t(cos_o), redrawn otherwise).
"""

from __future__ import annotations

import math
from functools import lru_cache
from typing import Mapping

import numpy as np

from bench.core.errors import SpecimenError
from virtual.model_ids import MODEL_PYTHON
from virtual.specimens.coat_quadrature import mitsuba_rough_reflectance, mitsuba_rough_transmittance
from virtual.specimens.declare import DeclaredSpecimen, Param, register_specimen
from virtual.specimens.microfacet import _LT, _LU, ALPHA_MAX, ALPHA_MIN, _lit, _reflected
from virtual.specimens.physics import (lobe_width, local, mirror, np_fresnel_dielectric, np_g2_over_g1,
                                       np_ggx_reflection, vndf_expectation, vndf_normals)

__all__ = ["MitsubaRoughPlastic", "TABLE_RES", "coat_tables"]

#: Mitsuba's MI_ROUGH_TRANSMITTANCE_RES
TABLE_RES = 64


@lru_cache(maxsize=4096)
def _specular_albedo(mu: float, alpha: float, eta: float, rtol: float = 1e-9) -> float:
    """E[F(wi.m) G1(wo)] over the visible normals of wi = (sqrt(1 - mu^2), 0, mu): the rough
    coat's specular albedo under separable masking (Mitsuba's ``eval_reflectance``)."""
    w = np.array([math.sqrt(max(1.0 - mu * mu, 0.0)), 0.0, mu])

    def g(m: np.ndarray) -> np.ndarray:
        c = np.clip(m @ w, 0.0, 1.0)
        o = 2.0 * c[:, None] * m - w
        return np_fresnel_dielectric(c, eta) * np_g2_over_g1(w, o, alpha, alpha, "separable")

    return vndf_expectation(w, alpha, alpha, g, rtol=rtol, atol=rtol * 1e-2)[0]


@lru_cache(maxsize=64)
def coat_tables(alpha: float, eta: float) -> tuple[np.ndarray, np.ndarray, float]:
    """``(mu nodes, t(mu) at the nodes, R_int)`` as Mitsuba builds them (see the module docstring)."""
    mu = np.maximum(1e-6, np.arange(TABLE_RES) / (TABLE_RES - 1))
    t = np.array([mitsuba_rough_transmittance(float(m), alpha, eta) for m in mu])
    r_int = 2.0 * float(np.mean([mitsuba_rough_reflectance(float(m), alpha, 1.0 / eta) * m for m in mu]))
    return mu, t, r_int


def _lerp_gather(table: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Mitsuba's ``lerp_gather``: linear interpolation on the uniform grid i / (size - 1)."""
    size = len(table)
    x = np.asarray(x, dtype=float) * (size - 1)
    idx = np.minimum(np.maximum(x, 0.0).astype(np.int64), size - 2)
    w1 = x - idx
    return (1.0 - w1) * table[idx] + w1 * table[idx + 1]


def _t_mu_integral(t: np.ndarray) -> float:
    """2 int_0^1 t(mu) mu dmu for the piecewise-linear interpolant on the grid i / (n - 1) (exact)."""
    n = len(t)
    h = 1.0 / (n - 1)
    a = np.arange(n - 1) * h
    t0, t1 = t[:-1], t[1:]
    # int over [a, a + h] of (t0 + (t1 - t0) (mu - a) / h) mu dmu
    seg = t0 * (a * h + h * h / 2) + (t1 - t0) * (a * h / 2 + h * h / 3)
    return 2.0 * float(seg.sum())


@register_specimen
class MitsubaRoughPlastic(DeclaredSpecimen):
    """Mitsuba 3's ``roughplastic`` (GGX, visible-normal sampling): specular coat with separable
    masking over a Lambertian base through tabulated coat transmittances (see the module
    docstring). Opaque, one-sided as in Mitsuba (mirrored for light from below, like every
    opaque model here). params: ``[alpha, eta, kd, nonlinear]``."""

    name = "roughplastic"
    model = MODEL_PYTHON
    has_density = True
    opaque = True
    reciprocal = True
    convention = "Mitsuba 3 roughplastic (GGX, separable masking, 64-node coat tables)"
    parameters = (Param("alpha", 0.1, ALPHA_MIN, ALPHA_MAX, doc="coat roughness (GGX)"),
                  Param("eta", 1.49, 1.0 + 1e-3, 10.0, doc="coat relative index (Mitsuba: int_ior / ext_ior)"),
                  Param("kd", 0.5, 0.0, 1.0, doc="diffuse_reflectance of the base"),
                  Param("nonlinear", 0.0, 0.0, 1.0, doc="Mitsuba's internal-scattering nonlinearity",
                        choices=("false", "true")))

    def kernel_params(self, v: Mapping[str, float]) -> np.ndarray:
        a, eta, kd, nl = v["alpha"], v["eta"], v["kd"], v["nonlinear"]
        _, t, r_int = coat_tables(float(a), float(eta))
        kd_eff = kd / (1.0 - (kd * r_int if nl else r_int))
        c = kd_eff * _t_mu_integral(t) / (eta * eta)
        if c > 1.0 + 1e-12:
            raise SpecimenError(f"roughplastic: kd = {kd:g} gives a diffuse albedo factor {c:.6g} > 1 for "
                                f"alpha = {a:g}, eta = {eta:g} (not energy conserving)")
        return np.array([a, eta, kd_eff, c])

    # -- density ---------------------------------------------------------------------------
    def bsdf(self, wi: np.ndarray, wo: np.ndarray, wavelength_nm: float) -> np.ndarray:
        a, eta, kd_eff, _ = self.params(wavelength_nm)
        _, t, _ = coat_tables(float(a), float(eta))
        wi, wo, _ = local(wi, wo)
        if not wi[2] > 0.0:
            return np.zeros(len(wo))
        spec = np_ggx_reflection(wi, wo, a, a, lambda c: np_fresnel_dielectric(c, eta), "separable")
        zo = np.maximum(wo[:, 2], 0.0)
        diff = kd_eff * _lerp_gather(t, wi[2]) * _lerp_gather(t, zo) / (math.pi * eta * eta)
        return spec + np.where(wo[:, 2] > 0.0, diff, 0.0)

    def lobes(self, wi: np.ndarray, wavelength_nm: float) -> list[tuple[np.ndarray, float]]:
        a = float(self.params(wavelength_nm)[0])
        w = _lit(wi)
        m, _ = vndf_normals(w, a, a, _LU, _LT)
        return [(mirror(wi), lobe_width(mirror(w), _reflected(w, m)[1]))]

    def albedo_reference(self, wi: np.ndarray, wavelength_nm: float) -> tuple[float, float]:
        """The specular albedo over the visible normals plus the diffuse albedo in closed form
        (c t(cos_i), the interpolant integrated exactly): no density evaluated."""
        a, eta, _, c = self.params(wavelength_nm)
        _, t, _ = coat_tables(float(a), float(eta))
        w = np.asarray(wi, dtype=float).reshape(3)
        w = w / np.linalg.norm(w)
        mu = abs(float(w[2]))
        spec = _specular_albedo(mu, float(a), float(eta)) if mu > 0 else 0.0
        return spec + c * float(_lerp_gather(t, mu)), 1e-9

    # -- sampler (MODEL_PYTHON) ---------------------------------------------------------------
    def sample(self, wi: np.ndarray, n: int, wavelength_nm: float,
               rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """``n`` outgoing directions and survival flags (see the module docstring)."""
        a, eta, _, c = self.params(wavelength_nm)
        _, t, _ = coat_tables(float(a), float(eta))
        w0 = np.asarray(wi, dtype=float)
        if w0.ndim == 2:  # one incidence per ray: sample each distinct one (conical beams)
            dirs = np.zeros((n, 3))
            alive = np.zeros(n, dtype=bool)
            for k in range(n):
                d, al = self.sample(w0[k], 1, wavelength_nm, rng)
                dirs[k], alive[k] = d[0], al[0]
            return dirs, alive
        flip = w0[2] < 0.0
        w = w0 * np.array([1.0, 1.0, -1.0]) if flip else w0
        dirs = np.zeros((n, 3))
        alive = np.zeros(n, dtype=bool)
        if not w[2] > 0.0 or n == 0:
            return dirs, alive
        u = rng.random((n, 4))
        m, _ = vndf_normals(w, a, a, u[:, 0], np.arccos(1.0 - 2.0 * u[:, 1]) / math.pi)  # r2 = u1
        cm = np.clip(m @ w, 0.0, 1.0)
        o = 2.0 * cm[:, None] * m - w
        keep = np_fresnel_dielectric(cm, eta) * np_g2_over_g1(w, o, a, a, "separable")
        spec = u[:, 2] < keep
        dirs[spec], alive[spec] = o[spec], True
        rest = ~spec
        # the specular path left exactly 1 - albedo_spec(wi) of the rays; send c t(cos_i) of all
        left = 1.0 - _specular_albedo(float(w[2]), float(a), float(eta))
        p_base = c * float(_lerp_gather(t, w[2])) / max(left, 1e-300)
        if p_base > 1.0 + 1e-9:
            raise SpecimenError(f"roughplastic: the base needs {p_base:.6g} > 1 of the rays the coat lets through")
        base = rest & (rng.random(n) < p_base)
        k = int(base.sum())
        out = np.zeros((k, 3))
        todo = np.arange(k)
        while len(todo):  # cosine directions thinned by t(cos_o); ends with probability 1
            x = rng.random((len(todo), 3))
            r = np.sqrt(x[:, 0])
            ph = 2.0 * math.pi * x[:, 1]
            d = np.column_stack([r * np.cos(ph), r * np.sin(ph), np.sqrt(np.maximum(1.0 - x[:, 0], 0.0))])
            ok = x[:, 2] < _lerp_gather(t, d[:, 2])
            out[todo[ok]] = d[ok]
            todo = todo[~ok]
        dirs[base], alive[base] = out, True
        if flip:
            dirs[:, 2] = -dirs[:, 2]
        return dirs, alive

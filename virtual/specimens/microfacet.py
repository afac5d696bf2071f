"""The microfacet families: GGX (isotropic and anisotropic), rough plastic, rough dielectric.

Each is a declaration (:mod:`virtual.specimens.declare`): its parameters, the vector its kernel
branch in :mod:`virtual.kernels.scatter` reads, and its density (from
:mod:`virtual.specimens.physics`).
"""

from __future__ import annotations

import math
from typing import Mapping

import numpy as np

from virtual.kernels.scatter import MODEL_ANISO_GGX, MODEL_DIELECTRIC, MODEL_GGX, MODEL_PLASTIC
from virtual.specimens.declare import DeclaredSpecimen, Param, register_specimen
from virtual.specimens.physics import (fresnel_hemispherical_average, local, mirror, np_fresnel_conductor,
                                       np_fresnel_dielectric, np_ggx_d, np_ggx_n, np_ggx_reflection, vndf_mean)

__all__ = ["GGX", "AnisoGGX", "RoughPlastic", "RoughDielectric", "ALPHA_MIN", "ALPHA_MAX"]

ALPHA_MIN = 1e-4
ALPHA_MAX = 1.0
_ETA = Param("eta", 1.5, 1e-3, 100.0, doc="real part of the index (coat or conductor)")
_K = Param("k", 0.0, 0.0, 100.0, doc="extinction coefficient (0: dielectric coat)")


class _GGXFace(DeclaredSpecimen):
    """Density and lobes shared by the GGX reflectors (params ``[alpha_x, alpha_y, eta, k]``)."""

    has_density = True
    opaque = True

    def bsdf(self, wi: np.ndarray, wo: np.ndarray, wavelength_nm: float) -> np.ndarray:
        ax, ay, eta, k = self.params(wavelength_nm)
        wi, wo, _ = local(wi, wo)
        if not wi[2] > 0.0:
            return np.zeros(len(wo))
        if k == 0.0:  # as in the kernel: the dielectric form (same value, better near TIR)
            return np_ggx_reflection(wi, wo, ax, ay, lambda c: np_fresnel_dielectric(c, eta))
        return np_ggx_reflection(wi, wo, ax, ay, lambda c: np_fresnel_conductor(c, eta, k))

    def lobes(self, wi: np.ndarray, wavelength_nm: float) -> list[tuple[np.ndarray, float]]:
        ax, ay = self.params(wavelength_nm)[:2]
        return [(mirror(wi), 2.0 * max(ax, ay))]


@register_specimen
class GGX(_GGXFace):
    """Cook-Torrance reflector with the GGX (Trowbridge-Reitz) distribution, opaque, two-sided.

    f = F(wi.h) D(h) G2(wi, wo) / (4 cos_i cos_o), F the exact unpolarized Fresnel reflectance of
    a conductor eta + i k (k = 0: a dielectric -- the specimen is then an opaque "specular coat
    only" reflector, everything refracted is absorbed). Single scattering: light the microfacets
    would scatter again is absorbed, so the albedo is < 1 (most visibly for rough, grazing cases).

    Sampling: a visible normal m (Heitz 2018, spherical caps of Dupuy & Benyoub 2023), mirror
    reflection about m, killed below the horizon, kept with probability F G2/G1 <= 1.

    params: ``[alpha_x, alpha_y, eta, k]`` (alpha_x along the specimen X axis).
    """

    name = "ggx"
    model = MODEL_GGX
    parameters = (Param("alpha", 0.2, ALPHA_MIN, ALPHA_MAX, doc="GGX roughness"), _ETA, _K)

    def kernel_params(self, v: Mapping[str, float]) -> np.ndarray:
        return np.array([v["alpha"], v["alpha"], v["eta"], v["k"]])


@register_specimen
class AnisoGGX(_GGXFace):
    """Anisotropic GGX reflector: :class:`GGX` with roughness alpha_x along the specimen's X axis
    and alpha_y along Y (so the BRDF depends on the azimuths themselves, not only on their
    difference). params: ``[alpha_x, alpha_y, eta, k]``."""

    name = "aniso-ggx"
    model = MODEL_ANISO_GGX
    isotropic = False
    parameters = (Param("alpha_x", 0.1, ALPHA_MIN, ALPHA_MAX, doc="GGX roughness along the specimen X axis"),
                  Param("alpha_y", 0.4, ALPHA_MIN, ALPHA_MAX, doc="GGX roughness along Y"), _ETA, _K)

    def kernel_params(self, v: Mapping[str, float]) -> np.ndarray:
        return np.array([v["alpha_x"], v["alpha_y"], v["eta"], v["k"]])


@register_specimen
class RoughPlastic(DeclaredSpecimen):
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

    name = "plastic"
    model = MODEL_PLASTIC
    has_density = True
    reciprocal = False
    opaque = True
    parameters = (Param("alpha", 0.1, ALPHA_MIN, ALPHA_MAX, doc="coat roughness (GGX)"),
                  Param("eta", 1.5, 1.0, 10.0, doc="coat index"),
                  Param("kd", 0.5, 0.0, 1.0, doc="albedo of the Lambertian base"))

    def kernel_params(self, v: Mapping[str, float]) -> np.ndarray:
        a, eta, kd = v["alpha"], v["eta"], v["kd"]
        return np.array([a, eta, kd, 1.0 / (1.0 - fresnel_hemispherical_average(eta))])

    def mean_entry_fresnel(self, wi: np.ndarray, wavelength_nm: float) -> float:
        """Fbar(wi): the mean Fresnel reflectance over wi's visible GGX normals."""
        a, eta = self.params(wavelength_nm)[:2]
        w = np.asarray(wi, dtype=float).reshape(3)
        w = w * np.array([1.0, 1.0, -1.0]) if w[2] < 0 else w
        return vndf_mean(w, a, a, lambda c: np_fresnel_dielectric(c, eta))

    def bsdf(self, wi: np.ndarray, wo: np.ndarray, wavelength_nm: float) -> np.ndarray:
        a, eta, kd, norm = self.params(wavelength_nm)
        wi, wo, _ = local(wi, wo)
        if not wi[2] > 0.0:
            return np.zeros(len(wo))
        spec = np_ggx_reflection(wi, wo, a, a, lambda c: np_fresnel_dielectric(c, eta))
        fbar = vndf_mean(wi, a, a, lambda c: np_fresnel_dielectric(c, eta))
        zo = wo[:, 2]
        diff = kd * (1.0 - fbar) * norm / math.pi * (1.0 - np_fresnel_dielectric(np.maximum(zo, 0.0), eta))
        return spec + np.where(zo > 0.0, diff, 0.0)

    def lobes(self, wi: np.ndarray, wavelength_nm: float) -> list[tuple[np.ndarray, float]]:
        return [(mirror(wi), 2.0 * float(self.params(wavelength_nm)[0]))]


@register_specimen
class RoughDielectric(DeclaredSpecimen):
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

    name = "dielectric"
    model = MODEL_DIELECTRIC
    has_density = True
    reciprocal = False
    parameters = (Param("alpha", 0.2, ALPHA_MIN, ALPHA_MAX, doc="interface roughness (GGX)"),
                  Param("eta", 1.5, 1.0 + 1e-6, 10.0, doc="index below the interface (> 1)"))

    def kernel_params(self, v: Mapping[str, float]) -> np.ndarray:
        return np.array([v["alpha"], v["eta"]])

    def bsdf(self, wi: np.ndarray, wo: np.ndarray, wavelength_nm: float) -> np.ndarray:
        a, eta = self.params(wavelength_nm)
        wi0 = np.asarray(wi, dtype=float).reshape(3)
        er = eta if wi0[2] >= 0.0 else 1.0 / eta
        wi, wo, _ = local(wi, wo)
        out = np.zeros(len(wo))
        if not wi[2] > 0.0:
            return out
        up = wo[:, 2] > 0.0
        out[up] = np_ggx_reflection(wi, wo[up], a, a, lambda c: np_fresnel_dielectric(c, er))
        down = wo[:, 2] < 0.0
        o = wo[down]
        hx, hy, hz = -(wi[0] + er * o[:, 0]), -(wi[1] + er * o[:, 1]), -(wi[2] + er * o[:, 2])
        sgn = np.where(hz < 0.0, -1.0, 1.0)
        inv = sgn / np.maximum(np.sqrt(hx * hx + hy * hy + hz * hz), 1e-300)
        hx, hy, hz = hx * inv, hy * inv, hz * inv
        ci = wi[0] * hx + wi[1] * hy + wi[2] * hz
        co = o[:, 0] * hx + o[:, 1] * hy + o[:, 2] * hz
        zo = -o[:, 2]
        ni = np_ggx_n(wi[0], wi[1], wi[2], a, a)
        no = np_ggx_n(o[:, 0], o[:, 1], zo, a, a)
        den = ci + er * co
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            f = ((1.0 - np_fresnel_dielectric(ci, er)) * np_ggx_d(hx, hy, hz, a, a) * er * er
                 * ci * (-co) * 2.0 / ((ni * zo + no * wi[2]) * den * den))
        ok = (ci > 0.0) & (co < 0.0) & (hz > 0.0)
        out[down] = np.where(ok, np.nan_to_num(f, nan=0.0, posinf=0.0), 0.0)
        return out

    def lobes(self, wi: np.ndarray, wavelength_nm: float) -> list[tuple[np.ndarray, float]]:
        a, eta = self.params(wavelength_nm)
        w = np.asarray(wi, dtype=float).reshape(3)
        er = eta if w[2] >= 0.0 else 1.0 / eta
        out = [(mirror(w), 2.0 * a)]
        c = abs(w[2])
        st2 = (1.0 - c * c) / (er * er)
        if st2 < 1.0:
            ct = math.sqrt(1.0 - st2)
            n = np.array([0.0, 0.0, 1.0 if w[2] >= 0 else -1.0])
            t = -w / er + (c / er - ct) * n
            out.append((t / np.linalg.norm(t), 2.0 * a * max(1.0, 1.0 / er)))
        return out

"""The microfacet families: GGX (isotropic and anisotropic), rough plastic, rough dielectric.

Each is a declaration (:mod:`virtual.specimens.declare`): its parameters, the vector its kernel
branch in :mod:`virtual.kernels.scatter` reads, and its density (from
:mod:`virtual.specimens.physics`).
"""

from __future__ import annotations

import math
from typing import Mapping

import numpy as np

from virtual.model_ids import MODEL_ANISO_GGX, MODEL_DIELECTRIC, MODEL_GGX, MODEL_PLASTIC
from virtual.specimens.declare import DeclaredSpecimen, Param, register_specimen
from virtual.specimens.physics import (fresnel_hemispherical_average, fresnel_vndf_mean, lobe_width, local, mirror,
                                       np_fresnel_conductor, np_fresnel_dielectric, np_g2_over_g1, np_ggx_d,
                                       np_ggx_n, np_ggx_reflection, vndf_expectation, vndf_normals,
                                       MASKINGS, g2_over_4)

__all__ = ["GGX", "AnisoGGX", "RoughPlastic", "RoughDielectric", "ALPHA_MIN", "ALPHA_MAX", "mirror_lobe"]

ALPHA_MIN = 1e-4
ALPHA_MAX = 1.0

# points of the sampler's unit square whose visible normals trace a lobe's extent
_LU, _LT = (a.ravel() for a in np.meshgrid((np.arange(16) + 0.5) / 16, np.linspace(0.1, 0.9, 9), indexing="ij"))


def _reflected(wi: np.ndarray, m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(cos wi.m, mirror directions of wi about each normal m)."""
    c = np.clip(m @ wi, 0.0, 1.0)
    return c, 2.0 * c[:, None] * m - wi


def _refracted(wi: np.ndarray, m: np.ndarray, er: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(cos wi.m, Fresnel reflectance, refracted directions) for relative index er = n_t / n_i
    (as the kernel's dielectric branch; the direction is meaningless where F = 1)."""
    c = np.clip(m @ wi, 0.0, 1.0)
    st2 = (1.0 - c * c) / (er * er)
    ct = np.sqrt(np.maximum(1.0 - st2, 0.0))
    k = c / er - ct
    return c, np_fresnel_dielectric(c, er), -wi / er + k[:, None] * m


def _lit(wi: np.ndarray) -> np.ndarray:
    w = np.asarray(wi, dtype=float).reshape(3)
    return w * np.array([1.0, 1.0, -1.0]) if w[2] < 0.0 else w
_ETA = Param("eta", 1.5, 1e-3, 100.0, doc="real part of the index (coat or conductor)")
_K = Param("k", 0.0, 0.0, 100.0, doc="extinction coefficient (0: dielectric coat)")
_MASKING = Param("masking", 0.0, 0.0, 1.0, doc="Smith masking-shadowing: height-correlated, or separable "
                 "G1(wi) G1(wo) as Mitsuba 3", choices=MASKINGS)



def mirror_lobe(wi: np.ndarray, ax: float, ay: float) -> tuple[np.ndarray, float]:
    """The mirror lobe of a GGX surface lit from ``wi``: its direction and its width, measured
    from the sampler's own visible normals (a specimen's ``lobes``)."""
    w = _lit(wi)
    m, _ = vndf_normals(w, ax, ay, _LU, _LT)
    return mirror(wi), lobe_width(mirror(w), _reflected(w, m)[1])

class _GGXFace(DeclaredSpecimen):
    """Density and lobes shared by the GGX reflectors (params ``[alpha_x, alpha_y, eta, k]``)."""

    has_density = True
    opaque = True

    def bsdf(self, wi: np.ndarray, wo: np.ndarray, wavelength_nm: float) -> np.ndarray:
        ax, ay, eta, k, sep = self.params(wavelength_nm)
        wi, wo, _ = local(wi, wo)
        if not wi[2] > 0.0:
            return np.zeros(len(wo))
        # k = 0 as in the kernel: the dielectric form (same value, better near TIR)
        return np_ggx_reflection(wi, wo, ax, ay, self._fresnel(wavelength_nm), MASKINGS[int(sep)])

    def _fresnel(self, wavelength_nm: float):
        ax, ay, eta, k, _ = self.params(wavelength_nm)
        if k == 0.0:
            return lambda c: np_fresnel_dielectric(c, eta)
        return lambda c: np_fresnel_conductor(c, eta, k)

    def lobes(self, wi: np.ndarray, wavelength_nm: float) -> list[tuple[np.ndarray, float]]:
        """The mirror lobe, its width measured from the sampler's own visible normals."""
        ax, ay = self.params(wavelength_nm)[:2]
        return [mirror_lobe(wi, ax, ay)]

    def albedo_reference(self, wi: np.ndarray, wavelength_nm: float) -> tuple[float, float]:
        """Directional albedo ``E[F(wi.m) G2/G1]`` over the visible normals (the sampler's
        space, not the density): ``(value, error estimate)``."""
        ax, ay, _, _, sep = self.params(wavelength_nm)
        fres = self._fresnel(wavelength_nm)
        w = _lit(wi)

        def g(m: np.ndarray) -> np.ndarray:
            c, o = _reflected(w, m)
            return fres(c) * np_g2_over_g1(w, o, ax, ay, MASKINGS[int(sep)])

        return vndf_expectation(w, ax, ay, g)


@register_specimen
class GGX(_GGXFace):
    """Cook-Torrance reflector with the GGX (Trowbridge-Reitz) distribution, opaque, two-sided.

    f = F(wi.h) D(h) G2(wi, wo) / (4 cos_i cos_o), F the exact unpolarized Fresnel reflectance of
    a conductor eta + i k (k = 0: a dielectric -- the specimen is then an opaque "specular coat
    only" reflector, everything refracted is absorbed). Single scattering: light the microfacets
    would scatter again is absorbed, so the albedo is < 1 (most visibly for rough, grazing cases).

    Sampling: a visible normal m (Heitz 2018, spherical caps of Dupuy & Benyoub 2023), mirror
    reflection about m, killed below the horizon, kept with probability F G2/G1 <= 1.

    Masking: ``masking=correlated`` (default, height-correlated Smith) or ``separable``
    (G1(wi) G1(wo), Mitsuba 3's ``roughconductor``); they agree at normal incidence.

    params: ``[alpha_x, alpha_y, eta, k, separable]`` (alpha_x along the specimen X axis).
    """

    name = "ggx"
    model = MODEL_GGX
    convention = "Walter 2007 GGX; masking correlated (default) or separable = Mitsuba 3 roughconductor"
    parameters = (Param("alpha", 0.2, ALPHA_MIN, ALPHA_MAX, doc="GGX roughness"), _ETA, _K, _MASKING)

    def kernel_params(self, v: Mapping[str, float]) -> np.ndarray:
        return np.array([v["alpha"], v["alpha"], v["eta"], v["k"], v["masking"]])


@register_specimen
class AnisoGGX(_GGXFace):
    """Anisotropic GGX reflector: :class:`GGX` with roughness alpha_x along the specimen's X axis
    and alpha_y along Y (so the BRDF depends on the azimuths themselves, not only on their
    difference). params: ``[alpha_x, alpha_y, eta, k, separable]``."""

    name = "aniso-ggx"
    model = MODEL_ANISO_GGX
    isotropic = False
    convention = GGX.convention
    parameters = (Param("alpha_x", 0.1, ALPHA_MIN, ALPHA_MAX, doc="GGX roughness along the specimen X axis"),
                  Param("alpha_y", 0.4, ALPHA_MIN, ALPHA_MAX, doc="GGX roughness along Y"), _ETA, _K, _MASKING)

    def kernel_params(self, v: Mapping[str, float]) -> np.ndarray:
        return np.array([v["alpha_x"], v["alpha_y"], v["eta"], v["k"], v["masking"]])


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
    convention = "goniobench's own (single-pass, not reciprocal; Mitsuba's is `roughplastic`); masking correlated"
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
        return fresnel_vndf_mean(float(w[0]), float(w[1]), float(w[2]), float(a), float(eta))

    def bsdf(self, wi: np.ndarray, wo: np.ndarray, wavelength_nm: float) -> np.ndarray:
        a, eta, kd, norm = self.params(wavelength_nm)
        wi, wo, _ = local(wi, wo)
        if not wi[2] > 0.0:
            return np.zeros(len(wo))
        spec = np_ggx_reflection(wi, wo, a, a, lambda c: np_fresnel_dielectric(c, eta))
        fbar = fresnel_vndf_mean(float(wi[0]), float(wi[1]), float(wi[2]), float(a), float(eta))
        zo = wo[:, 2]
        diff = kd * (1.0 - fbar) * norm / math.pi * (1.0 - np_fresnel_dielectric(np.maximum(zo, 0.0), eta))
        return spec + np.where(zo > 0.0, diff, 0.0)

    def lobes(self, wi: np.ndarray, wavelength_nm: float) -> list[tuple[np.ndarray, float]]:
        a = float(self.params(wavelength_nm)[0])
        return [mirror_lobe(wi, a, a)]

    def albedo_reference(self, wi: np.ndarray, wavelength_nm: float) -> tuple[float, float]:
        """``E[F G2/G1] + kd (1 - Fbar)`` over the visible normals (what the sampler does: a
        ray that enters and survives the base always leaves)."""
        a, eta, kd, _ = self.params(wavelength_nm)
        w = _lit(wi)

        def g(m: np.ndarray) -> np.ndarray:
            c, o = _reflected(w, m)
            f = np_fresnel_dielectric(c, eta)
            return f * np_g2_over_g1(w, o, a, a) + kd * (1.0 - f)

        return vndf_expectation(w, a, a, g)


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

    Masking: ``masking=correlated`` (default; G2 = 1 / (1 + L(wi) + L(wo)) also for
    transmission) or ``separable`` (G1(wi) G1(wo), Mitsuba 3's ``roughdielectric``).

    params: ``[alpha, eta, separable]``.
    """

    name = "dielectric"
    model = MODEL_DIELECTRIC
    has_density = True
    reciprocal = False
    convention = "Walter 2007; masking correlated (default) or separable = Mitsuba 3 roughdielectric"
    parameters = (Param("alpha", 0.2, ALPHA_MIN, ALPHA_MAX, doc="interface roughness (GGX)"),
                  Param("eta", 1.5, 1.0 + 1e-6, 10.0, doc="index below the interface (> 1)"), _MASKING)

    def kernel_params(self, v: Mapping[str, float]) -> np.ndarray:
        return np.array([v["alpha"], v["eta"], v["masking"]])

    def bsdf(self, wi: np.ndarray, wo: np.ndarray, wavelength_nm: float) -> np.ndarray:
        a, eta, sep = self.params(wavelength_nm)
        masking = MASKINGS[int(sep)]
        wi0 = np.asarray(wi, dtype=float).reshape(3)
        er = eta if wi0[2] >= 0.0 else 1.0 / eta
        wi, wo, _ = local(wi, wo)
        out = np.zeros(len(wo))
        if not wi[2] > 0.0:
            return out
        up = wo[:, 2] > 0.0
        out[up] = np_ggx_reflection(wi, wo[up], a, a, lambda c: np_fresnel_dielectric(c, er), masking)
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
                 * ci * (-co) * 4.0 * g2_over_4(wi[2], ni, zo, no, masking) / (den * den))
        ok = (ci > 0.0) & (co < 0.0) & (hz > 0.0)
        out[down] = np.where(ok, np.nan_to_num(f, nan=0.0, posinf=0.0), 0.0)
        return out

    def lobes(self, wi: np.ndarray, wavelength_nm: float) -> list[tuple[np.ndarray, float]]:
        """The reflected and the refracted lobe, each with the width its visible normals give it:
        the refracted lobe narrows to about alpha |1 - 1/eta_r| as eta_r -> 1 (a constant 2 alpha
        hint never found it at eta = 1.0001)."""
        a, eta, _ = self.params(wavelength_nm)
        w0 = np.asarray(wi, dtype=float).reshape(3)
        er = eta if w0[2] >= 0.0 else 1.0 / eta
        w = _lit(w0)
        m, _ = vndf_normals(w, a, a, _LU, _LT)
        out = [(mirror(w0), lobe_width(mirror(w), _reflected(w, m)[1]))]
        c = w[2]
        st2 = (1.0 - c * c) / (er * er)
        if st2 < 1.0:
            t = -w / er + (c / er - math.sqrt(1.0 - st2)) * np.array([0.0, 0.0, 1.0])
            _, f, o = _refracted(w, m, er)
            o = o[(f < 1.0) & (o[:, 2] < 0.0)]
            if len(o):
                width = lobe_width(t, o)
                flip = np.array([1.0, 1.0, -1.0 if w0[2] < 0.0 else 1.0])
                out.append((t / np.linalg.norm(t) * flip, width))
        return out

    def albedo_reference(self, wi: np.ndarray, wavelength_nm: float) -> tuple[float, float]:
        """``E[F G2/G1(reflected) + (1 - F) G2/G1(refracted)]`` over the visible normals, with
        the sampler's own directions (continuous: G2/G1 -> 0 at the horizon, F -> 1 at TIR)."""
        a, eta, sep = self.params(wavelength_nm)
        masking = MASKINGS[int(sep)]
        w0 = np.asarray(wi, dtype=float).reshape(3)
        er = eta if w0[2] >= 0.0 else 1.0 / eta
        w = _lit(w0)
        down = np.array([1.0, 1.0, -1.0])

        def g(m: np.ndarray) -> np.ndarray:
            _, o_r = _reflected(w, m)
            _, f, o_t = _refracted(w, m, er)
            return (f * np_g2_over_g1(w, o_r, a, a, masking)
                    + (1.0 - f) * np_g2_over_g1(w, o_t * down, a, a, masking))

        return vndf_expectation(w, a, a, g)

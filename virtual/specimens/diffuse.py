"""The diffuse and glossy families: Lambertian, Oren-Nayar, normalized Phong.

Each is a declaration (:mod:`virtual.specimens.declare`): its parameters, the vector its law reads
(:mod:`virtual.kernels.laws`: ``lambert``, ``oren_nayar``, ``phong``), and its density.
"""

from __future__ import annotations

import math
from typing import Mapping

import numpy as np

from bench.core.errors import SpecimenError
from virtual.model_ids import MODEL_LAMBERT, MODEL_OREN_NAYAR, MODEL_PHONG
from virtual.specimens.declare import DeclaredSpecimen, Param, register_specimen
from virtual.cubature import integrate_rectangle
from virtual.specimens.physics import local, mirror

__all__ = ["Lambertian", "OrenNayar", "Phong"]

INV_PI = 1.0 / math.pi


@register_specimen
class Lambertian(DeclaredSpecimen):
    """Ideal diffuse reflector/transmitter: f_r = R/pi above, f_t = T/pi below, 1 - R - T absorbed.

    params: ``[R, T]``.
    """

    name = "lambert"
    model = MODEL_LAMBERT
    convention = "ideal diffuse (Mitsuba 3 diffuse, plus a diffuse transmission)"
    has_density = True
    parameters = (
        Param("reflectance", 0.5, 0.0, 1.0, doc="reflectance R (diffuse, same side)", aliases=("albedo", "R")),
        Param("transmittance", 0.0, 0.0, 1.0, doc="transmittance T (diffuse, far side)", aliases=("T",)),
    )

    @classmethod
    def keyword_defaults(cls, given: Mapping[str, float]) -> dict[str, float]:
        """``lambert:transmittance=T`` alone is a pure transmitter (R = 0)."""
        return {"reflectance": 0.0} if "transmittance" in given and "reflectance" not in given else {}

    def kernel_params(self, v: Mapping[str, float]) -> np.ndarray:
        r, t = v["reflectance"], v["transmittance"]
        if r + t > 1.0 + 1e-12:
            raise SpecimenError(f"reflectance + transmittance must not exceed 1, got {r + t:g}")
        return np.array([r, t], dtype=np.float64)

    def bsdf(self, wi: np.ndarray, wo: np.ndarray, wavelength_nm: float) -> np.ndarray:
        r, t = self.params(wavelength_nm)
        wo = np.atleast_2d(wo)
        same_side = np.sign(wo[:, 2]) == np.sign(wi[2] if wi[2] != 0 else 1.0)
        return np.where(same_side, r, t) * INV_PI

    def transmits(self, wavelength_nm: float) -> bool:
        return bool(self.params(wavelength_nm)[1] > 0.0)


@register_specimen
class OrenNayar(DeclaredSpecimen):
    """Oren-Nayar (1994) qualitative rough-diffuse reflector (opaque, two-sided).

    f = albedo/pi (A + B max(0, cos(phi_o - phi_i)) sin(alpha) tan(beta)), alpha = max(theta_i,
    theta_o), beta = min(...), A = 1 - sigma^2 / (2 (sigma^2 + 0.33)), B = 0.45 sigma^2 / (sigma^2 +
    0.09), sigma in radians (given in degrees). Equivalently f = albedo/pi (A + B max(0, d) /
    max(cos theta_i, cos theta_o)) with d = (wi_x wo_x + wi_y wo_y) -- the form used here.

    The model is not energy conserving in general (it was fitted, not derived). It is sampled
    exactly: f cos(theta_o) <= albedo/pi (A cos(theta_o) + B max(0, cos dphi)) everywhere, a
    mixture of a cosine lobe (mass albedo A) and "uniform in cos(theta_o), density cos(dphi)/2
    in azimuth" (mass 2 albedo B / pi); a proposal from it survives with probability
    f cos / (mixture) <= 1. That needs albedo (A + 2 B / pi) <= 1, which is required here (it
    also proves the model conserves energy for such parameters).

    params: ``[albedo, A, B, albedo*A, 2*albedo*B/pi]``.
    """

    name = "oren-nayar"
    model = MODEL_OREN_NAYAR
    convention = "Oren & Nayar 1994 qualitative model (A, B form)"
    has_density = True
    opaque = True
    parameters = (
        Param("sigma", 20.0, 0.0, 90.0, "degrees", "slope deviation"),
        Param("albedo", 0.8, 0.0, 1.0, doc="albedo rho (albedo (A + 2B/pi) <= 1)", aliases=("reflectance", "R")),
    )

    def kernel_params(self, v: Mapping[str, float]) -> np.ndarray:
        sig, rho = v["sigma"], v["albedo"]
        s2 = math.radians(sig) ** 2
        a = 1.0 - 0.5 * s2 / (s2 + 0.33)
        b = 0.45 * s2 / (s2 + 0.09)
        if rho * (a + 2.0 * b / math.pi) > 1.0 + 1e-12:
            raise SpecimenError(f"oren-nayar: albedo = {rho:g} too large for sigma = {sig:g} deg: exact "
                                f"sampling needs albedo * (A + 2B/pi) <= 1, i.e. albedo <= "
                                f"{1.0 / (a + 2.0 * b / math.pi):.6g}")
        return np.array([rho, a, b, rho * a, 2.0 * rho * b / math.pi])

    def bsdf(self, wi: np.ndarray, wo: np.ndarray, wavelength_nm: float) -> np.ndarray:
        rho, a, b, _, _ = self.params(wavelength_nm)
        wi, wo, _ = local(wi, wo)
        zo = wo[:, 2]
        d = np.maximum(wi[0] * wo[:, 0] + wi[1] * wo[:, 1], 0.0)
        den = np.maximum(np.maximum(wi[2], zo), 1e-300)
        f = rho / math.pi * (a + b * d / den)
        return np.where((zo > 0.0) & (wi[2] > 0.0), f, 0.0)


@register_specimen
class Phong(DeclaredSpecimen):
    """Energy-normalized modified Phong (Lafortune & Willems 1994), opaque, two-sided.

    f = kd/pi + ks (n+2)/(2 pi) cos^n(alpha) where cos(alpha) = r . wo > 0 (r the mirror direction
    of wi), and kd/pi alone where r . wo <= 0 -- also for n = 0, where the lobe is the hemisphere
    around r, not everything (0^0 is not read as 1 behind the lobe). Its albedo is <= kd + ks (equality at normal incidence when the lobe fits above the horizon).

    Sampling is exact: with probability kd a cosine-weighted direction; with probability
    ks (n+2)/(n+1) a direction from the lobe (n+1)/(2 pi) cos^n(alpha) around r, kept with
    probability cos(theta_o) (killed below the horizon): that gives exactly
    ks (n+2)/(2 pi) cos^n(alpha) cos(theta_o). The two proposal masses must fit in 1:
    ``kd + ks (n+2)/(n+1) <= 1`` is required (slightly stronger than kd + ks <= 1; no single-pass
    exact sampler with mass <= 1 exists for every incidence otherwise).

    params: ``[kd, ks, n, ks*(n+2)/(n+1)]``.
    """

    name = "phong"
    model = MODEL_PHONG
    convention = "Lafortune & Willems 1994 energy-normalized modified Phong"
    has_density = True
    opaque = True
    parameters = (
        Param("exponent", 20.0, 0.0, 1e7, doc="lobe exponent n", aliases=("n",)),
        Param("ks", 0.5, 0.0, 1.0, doc="specular weight (kd + ks (n+2)/(n+1) <= 1)"),
        Param("kd", 0.3, 0.0, 1.0, doc="diffuse weight"),
    )

    def kernel_params(self, v: Mapping[str, float]) -> np.ndarray:
        n, ks, kd = v["exponent"], v["ks"], v["kd"]
        ws = ks * (n + 2.0) / (n + 1.0)
        if kd + ws > 1.0 + 1e-12:
            raise SpecimenError(f"phong: kd + ks (n+2)/(n+1) = {kd + ws:.6g} > 1 (ks <= "
                                f"{(1.0 - kd) * (n + 1.0) / (n + 2.0):.6g} for kd = {kd:g}, n = {n:g})")
        return np.array([kd, ks, n, ws])

    def bsdf(self, wi: np.ndarray, wo: np.ndarray, wavelength_nm: float) -> np.ndarray:
        kd, ks, n, _ = self.params(wavelength_nm)
        wi, wo, _ = local(wi, wo)
        ca = -wi[0] * wo[:, 0] - wi[1] * wo[:, 1] + wi[2] * wo[:, 2]
        # the lobe lives where cos(alpha) > 0, the only place the sampler sends rays: at n = 0,
        # max(0, ca)**0 would read 0**0 = 1 behind it
        lobe = np.where(ca > 0.0, np.maximum(ca, 0.0) ** n, 0.0)
        f = kd / math.pi + ks * (n + 2.0) / (2.0 * math.pi) * lobe
        return np.where((wo[:, 2] > 0.0) & (wi[2] > 0.0), f, 0.0)

    def albedo_reference(self, wi: np.ndarray, wavelength_nm: float) -> tuple[float, float]:
        """Directional albedo in the sampler's own space (never the density): kd + ks (n+2)/(n+1)
        E[max(cos theta_o, 0)] over the lobe's directions (cos alpha = u^(1/(n+1)), phi = 2 pi v),
        by adaptive cubature: ``(value, error estimate)``."""
        kd, ks, n, ws = self.params(wavelength_nm)
        if ws == 0.0:
            return float(kd), 0.0
        w, _, _ = local(wi, np.zeros((1, 3)))
        w = w / np.linalg.norm(w)
        r = mirror(w)
        t1 = np.cross(r, [1.0, 0.0, 0.0] if abs(r[0]) < 0.9 else [0.0, 1.0, 0.0])
        t1 /= np.linalg.norm(t1)
        t2 = np.cross(r, t1)

        def integrand(u: np.ndarray, v: np.ndarray) -> np.ndarray:
            ca = np.power(np.maximum(u, 1e-300), 1.0 / (n + 1.0))
            sa = np.sqrt(np.maximum(1.0 - ca * ca, 0.0))
            ph = 2.0 * math.pi * v
            z = ca * r[2] + sa * (np.cos(ph) * t1[2] + np.sin(ph) * t2[2])
            return np.maximum(z, 0.0)

        value, err, _ = integrate_rectangle(integrand, start=(4, 8), order=6, rtol=1e-10, atol=1e-12)
        return float(kd + ws * value), float(ws * err)

    def lobes(self, wi: np.ndarray, wavelength_nm: float) -> list[tuple[np.ndarray, float]]:
        kd, ks, n, _ = self.params(wavelength_nm)
        # cos^n(a) ~ exp(-n a^2 / 2): angular width ~ 1 / sqrt(n)
        return [(mirror(wi), 2.0 / math.sqrt(n + 1.0))] if ks > 0 else []

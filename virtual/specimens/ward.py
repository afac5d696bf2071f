"""The Ward family: an isotropic Ward lobe over a Lambertian floor (its law, sampled in every
kernel path from one source: :mod:`virtual.kernels.laws.ward`)."""

from __future__ import annotations

import math
from typing import Mapping

import numpy as np

from bench.core.errors import SpecimenError
from virtual.law_table import MODEL_WARD
from virtual.specimens.declare import DeclaredSpecimen, Param, register_specimen
from virtual.specimens.physics import local, mirror

__all__ = ["Ward"]


@register_specimen
class Ward(DeclaredSpecimen):
    """Isotropic Ward lobe over a Lambertian floor, opaque, two-sided.

    f = kd/pi + ks exp(-tan^2(theta_h) / alpha^2) / (4 pi alpha^2 cos^3(theta_h) (wi.h)), h the
    half vector of wi and wo: Ward's Gaussian-in-tan(theta_h) distribution D(h) (Beckmann's),
    normalized as the density of the reflection about a normal drawn from D(h) cos(theta_h), so
    that sampling is exact -- with probability kd a cosine-weighted direction, with probability
    ks a reflection about such a normal, kept with probability cos(theta_o). The lobe's albedo
    is at most ks (rays reflected below the horizon are absorbed); ``kd + ks <= 1`` is required.

    params: ``[kd, ks, alpha]``.
    """

    name = "ward"
    model = MODEL_WARD
    convention = "isotropic Ward lobe, half-vector (Beckmann) distribution normalized for exact sampling"
    has_density = True
    opaque = True
    parameters = (
        Param("alpha", 0.2, 1e-4, 10.0, doc="lobe width (rms slope)"),
        Param("ks", 0.5, 0.0, 1.0, doc="lobe weight (kd + ks <= 1)"),
        Param("kd", 0.3, 0.0, 1.0, doc="diffuse weight"),
    )

    def kernel_params(self, v: Mapping[str, float]) -> np.ndarray:
        a, ks, kd = v["alpha"], v["ks"], v["kd"]
        if kd + ks > 1.0 + 1e-12:
            raise SpecimenError(f"ward: kd + ks = {kd + ks:.6g} > 1")
        return np.array([kd, ks, a])

    def bsdf(self, wi: np.ndarray, wo: np.ndarray, wavelength_nm: float) -> np.ndarray:
        kd, ks, a = self.params(wavelength_nm)
        wi, wo, _ = local(wi, wo)
        wi = wi / np.linalg.norm(wi)
        h = wo + wi
        hn = np.linalg.norm(h, axis=1)
        ok = (wo[:, 2] > 0.0) & (wi[2] > 0.0) & (hn > 0.0)
        h = h / np.where(hn > 0.0, hn, 1.0)[:, None]
        c = np.where(ok, h[:, 2], 1.0)
        t2 = (h[:, 0] ** 2 + h[:, 1] ** 2) / (c * c)
        d = np.where(ok, h @ wi, 1.0)
        lobe = np.exp(-t2 / (a * a)) / (4.0 * math.pi * a * a * c ** 3 * d)
        return np.where(ok, kd / math.pi + ks * lobe, 0.0)

    def lobes(self, wi: np.ndarray, wavelength_nm: float) -> list[tuple[np.ndarray, float]]:
        kd, ks, a = self.params(wavelength_nm)
        return [(mirror(wi), 2.0 * float(a))] if ks > 0 else []

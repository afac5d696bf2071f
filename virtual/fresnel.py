"""Unpolarized Fresnel reflectances in numpy, for cosines on the incident side: the specimens'
(:mod:`virtual.specimens.physics` re-exports them) and the leaf's cuticle integrals
(:mod:`virtual.leaf_optics`, which the specimens package imports) share this one copy."""

from __future__ import annotations

import numpy as np

__all__ = ["np_fresnel_conductor", "np_fresnel_dielectric"]


def np_fresnel_conductor(c: np.ndarray, eta: float, k: float) -> np.ndarray:
    """Exact unpolarized Fresnel reflectance of a conductor (eta + i k) for cosines ``c`` in [0, 1].

    With ``k = 0`` it is the dielectric reflectance (total internal reflection included).
    """
    c = np.clip(c, 0.0, 1.0)
    c2 = c * c
    s2 = 1.0 - c2
    e2, k2 = eta * eta, k * k
    t0 = e2 - k2 - s2
    a2b2 = np.sqrt(t0 * t0 + 4.0 * e2 * k2)
    t1 = a2b2 + c2
    a = np.sqrt(np.maximum(0.5 * (a2b2 + t0), 0.0))
    t2 = 2.0 * c * a
    rs = (t1 - t2) / np.maximum(t1 + t2, 1e-300)
    t3 = c2 * a2b2 + s2 * s2
    t4 = t2 * s2
    rp = rs * (t3 - t4) / np.maximum(t3 + t4, 1e-300)
    return 0.5 * (rp + rs)


def np_fresnel_dielectric(c: np.ndarray, eta: float) -> np.ndarray:
    """Unpolarized dielectric reflectance for cosines ``c`` >= 0 on the incident side, eta = n_t/n_i."""
    c = np.clip(c, 0.0, 1.0)
    st2 = (1.0 - c * c) / (eta * eta)
    ct = np.sqrt(np.maximum(1.0 - st2, 0.0))
    rs = (c - eta * ct) / np.maximum(c + eta * ct, 1e-300)
    rp = (eta * c - ct) / np.maximum(eta * c + ct, 1e-300)
    return np.where(st2 >= 1.0, 1.0, 0.5 * (rs * rs + rp * rp))

"""Selectable conventions validated against Mitsuba 3's own ``eval``.

``masking=separable`` GGX conductor / dielectric and the ``roughplastic`` specimen are measured
by counting rays (our samplers) and compared, by Pearson chi-square goodness of fit, with the
patch probabilities of Mitsuba's ``eval`` integrated over the same collector (quadrature of
:class:`virtual.specimens.mitsuba.MitsubaSpecimen.bsdf`). Significance: each test fails when p < ALPHA =
1e-3 (10 tests: family-wise false alarm <= 1 %, Bonferroni). Power: the default (height-correlated)
GGX fails the same test at 60 deg, where the conventions differ (with 10x the rays: at 4e5 rays
on this coarse collector the difference is below the noise).
"""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("mitsuba")


from bench.core.geometry import Geometry
from tests.helpers.stats import goodness_of_fit
from virtual.goniophotometer import VirtualGoniophotometer
from virtual.specimens.mitsuba import MitsubaSpecimen
from virtual.quadrature import integrate_patches
from virtual.specimens import parse_specimen

ALPHA = 1e-3
RAYS = 400_000
COLLECTOR = "equal-psa:6x12"

CASES = {
    "ggx-separable": ("ggx:alpha=0.3,eta=0.2,k=3,masking=separable",
                      {"type": "roughconductor", "distribution": "ggx", "alpha": 0.3, "eta": 0.2, "k": 3.0}),
    "dielectric-separable": ("dielectric:alpha=0.3,eta=1.5,masking=separable",
                             {"type": "roughdielectric", "distribution": "ggx", "alpha": 0.3,
                              "int_ior": 1.5, "ext_ior": 1.0}),
    "roughplastic": ("roughplastic:alpha=0.3,eta=1.5,kd=0.5",
                     {"type": "roughplastic", "distribution": "ggx", "alpha": 0.3, "int_ior": 1.5,
                      "ext_ior": 1.0, "diffuse_reflectance": {"type": "rgb", "value": 0.5}}),
}


def _ours_vs_mitsuba(ours: str, definition: dict, theta: float, seed: int,
                     rays: int = RAYS) -> tuple[float, float, int]:
    g = VirtualGoniophotometer(parse_specimen(ours), collector=COLLECTOR, rays=rays, method="rays", seed=seed)
    n_bins = 2 * g.collector.n_patches
    counts = g.simulate(theta, 0.0, 550.0)[: n_bins + 1]  # patches and absorbed (nothing missed)
    # Mitsuba's eval over the patches (tolerances far below what 4e5 rays resolve: 1e-7 per cell)
    q = integrate_patches(MitsubaSpecimen(definition), Geometry(theta, 0.0, 0.0, 0.0).incident, g.collector,
                          550.0, rtol=1e-5, atol=1e-7)
    p = np.append(q.p, max(0.0, 1.0 - q.p.sum()))
    return goodness_of_fit(counts, p * counts.sum())


#: Seeds moved when the rays counted changed: ``roughplastic`` went to the float32 kernel
#: (block32_coat), and its 30 deg case at seed 37 then fell at p = 4.8e-4 -- one false alarm at
#: this family-wise 1 %: 20 other seeds gave p uniform over (0, 1) and 2e7 rays p = 0.19.
SEED_SHIFT = {"roughplastic": 100}


@pytest.mark.parametrize("theta", [0.0, 30.0, 60.0])
@pytest.mark.parametrize("case", sorted(CASES))
def test_mitsuba_convention_matches_mitsuba_eval(case: str, theta: float) -> None:
    ours, definition = CASES[case]
    chi2, p, dof = _ours_vs_mitsuba(ours, definition, theta, seed=int(theta) + 7 + SEED_SHIFT.get(case, 0))
    assert p > ALPHA, f"{case} at {theta} deg: chi-square {chi2:.1f} on {dof} dof, p = {p:.2e}"


def test_roughplastic_nonlinear_flag_matches_mitsuba() -> None:
    d = dict(CASES["roughplastic"][1], nonlinear=True)
    chi2, p, dof = _ours_vs_mitsuba("roughplastic:alpha=0.3,eta=1.5,kd=0.5,nonlinear=true", d, 30.0, seed=3)
    assert p > ALPHA, f"chi-square {chi2:.1f} on {dof} dof, p = {p:.2e}"


def test_power_the_default_correlated_masking_is_not_mitsubas_at_60_deg() -> None:
    """The same test rejects the default convention where the two differ (p far below ALPHA)."""
    chi2, p, dof = _ours_vs_mitsuba("ggx:alpha=0.3,eta=0.2,k=3", CASES["ggx-separable"][1], 60.0, seed=67,
                                    rays=10 * RAYS)
    assert p < 1e-6, f"chi-square {chi2:.1f} on {dof} dof, p = {p:.2e}"

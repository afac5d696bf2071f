"""The virtual spectrophotometer (seed section 3.1): count rays, R = n_r / N, T = n_t / N.

It fills the :class:`bench.core.roles.Spectrophotometer` role. Geometries:

* hemispherical collection (``8/d``, ``0/d``, ``8/de``): reflectance and transmittance are the
  fractions of rays leaving to the source's and to the other hemisphere; ``8/de`` excludes the
  specular cone (a gloss trap);
* bidirectional (``45/0``, ``0/45``): the reflectance factor is the fraction of rays leaving
  within the detector's viewing cone of half-angle ``cone_deg``, divided by the fraction a
  perfect diffuser sends there, which is the cone's projected solid angle over pi:
  RF = (n_cone / N) pi / (pi sin^2(cone) cos(theta_view));
* diffuse illumination (``d/0``, ``d/8``) is measured by Helmholtz reciprocity as ``0/d``,
  ``8/d`` (same reflectance factor), and says so in the metadata.

Intervals are two-sided at confidence ``1 - delta`` (Clopper-Pearson on the counts).
"""

from __future__ import annotations

import math
from typing import Callable, Iterable

import numpy as np

from bench.core.errors import InputError
from bench.core.parsing import parse_wavelengths
from bench.core.geometry import CIEGeometry, cie_geometry, direction
from bench.core.roles import InstrumentBase, InstrumentInfo, Spectrum
from virtual.beam import Beam
from virtual.bounds import binomial_ci, hoeffding_rays
from virtual.engine import NO_CONE, SpectroTally, measurement_seed, specimen_stream_key, spectro_counts
from virtual.python_engine import spectro_counts_python
from virtual.specimens import MODEL_PYTHON, Specimen, parse_specimen

__all__ = ["VirtualSpectrophotometer", "fresh_seed"]


def fresh_seed() -> int:
    """A new root seed from the OS entropy pool, small enough to print and type back."""
    return int(np.random.SeedSequence().entropy % (1 << 63))


class VirtualSpectrophotometer(InstrumentBase):
    """A Monte Carlo spectrophotometer measuring a black-box specimen.

    Parameters
    ----------
    specimen : Specimen or str
        What is measured (see :func:`virtual.specimens.parse_specimen`).
    rays : int, optional
        Rays per wavelength. If omitted, eq. 3.5 gives it from ``uncertainty`` and ``delta``.
    uncertainty, delta : float
        The uncertainty ``v`` of the real instrument to compare with and the confidence ``delta``
        (default 0.005 and 0.01: N = 105,967 rays per wavelength).
    beam : Beam or str
        ``"collimated"`` (directional-hemispherical) or ``"conical"`` (a sphere instrument's
        25 mm port, 6 inch sphere: r1 = 5 mm, r2 = 12.5 mm, D = 76.2 mm), or a :class:`Beam`.
    seed : int, optional
        Root seed; a fresh one is drawn (and reported) when omitted.
    cone_deg : float
        Viewing (bidirectional geometries) and gloss-trap cone half-angle.
    common_random_numbers : bool
        Draw the same stream whatever the specimen (default: the stream is keyed by a stable
        hash of the specimen's full description too, :func:`virtual.engine.specimen_stream_key`).
    """

    def __init__(self, specimen: Specimen | str, *, rays: int | None = None, uncertainty: float = 0.005,
                 delta: float = 0.01, beam: Beam | str = "collimated", seed: int | None = None,
                 cone_deg: float | None = None, common_random_numbers: bool = False) -> None:
        self.specimen = parse_specimen(specimen)
        self.beam = beam if isinstance(beam, Beam) else Beam(kind=str(beam))
        if rays is None:
            rays = hoeffding_rays(uncertainty, delta)
        if not isinstance(rays, (int, np.integer)) or rays < 1:
            raise InputError(f"rays must be a positive integer, got {rays!r}")
        if not 0.0 < delta < 1.0:
            raise InputError(f"delta must lie in (0, 1), got {delta}")
        if cone_deg is not None and not 0.0 < cone_deg < 90.0:
            raise InputError(f"cone_deg must lie in (0, 90), got {cone_deg}")
        self.rays = int(rays)
        self.uncertainty = float(uncertainty)
        self.delta = float(delta)
        self.seed = fresh_seed() if seed is None else int(seed)
        self.cone_deg = cone_deg
        self.common_random_numbers = bool(common_random_numbers)

    # -- Instrument --------------------------------------------------------------------------
    def describe(self) -> InstrumentInfo:
        rng = self.specimen.wavelength_range() or (200.0, 2500.0)
        return InstrumentInfo(
            kind="spectrophotometer", model="goniobench virtual spectrophotometer",
            serial=f"seed-{self.seed}", firmware="virtual", uncertainty=self.uncertainty,
            ranges={"wavelength_nm": rng, "theta_i": (0.0, 89.0)},
            extra={"beam": self.beam.describe(), "rays_per_wavelength": self.rays, "delta": self.delta,
                   "specimen": self.specimen.label},
        )

    def stream_key(self, theta_i: float, phi_i: float, wavelength_nm: float) -> tuple[int, ...]:
        """The spawn key of one wavelength's stream: (specimen hash,) pm, mdeg theta_i -- the
        specimen left out under ``common_random_numbers`` (``phi_i`` is not part of it)."""
        key = (int(round(wavelength_nm * 1000)), int(round(theta_i * 1000)))
        return key if self.common_random_numbers else (specimen_stream_key(self.specimen), *key)

    # -- Spectrophotometer -------------------------------------------------------------------
    def measure(self, geometry: str | CIEGeometry, wavelengths: Iterable[float] | str, *,
                progress: Callable[[Iterable[float]], Iterable[float]] | None = None) -> Spectrum:
        """Measure ``geometry`` at ``wavelengths``; ``progress`` (e.g. ``tqdm``) wraps the loop over
        wavelengths, so a caller can show how far it got."""
        g = cie_geometry(geometry)
        wl = parse_wavelengths(wavelengths)
        self.specimen.check_wavelengths(wl)  # all data present before any ray is shot
        measured = g.reciprocal_directional
        theta_i = measured.theta_i
        beam_args = self.beam.kernel_args(theta_i, 0.0)
        cone, cone_psa_over_pi = self._cone(measured)
        tallies: list[SpectroTally] = []
        for w in (progress(wl) if progress is not None else wl):
            seq = measurement_seed(self.seed, *self.stream_key(theta_i, 0.0, float(w)))
            if self.specimen.model == MODEL_PYTHON:  # no kernel (e.g. Mitsuba): count in numpy
                tallies.append(spectro_counts_python(self.specimen, float(w), self.beam, theta_i, 0.0,
                                                     self.rays, seq, cone))
                continue
            tallies.append(spectro_counts(self.specimen.model, self.specimen.params(float(w)), self.beam.code,
                                          self.beam.disk_code, beam_args, self.rays, seq, cone))
        return self._spectrum(g, measured, wl, tallies, cone_psa_over_pi)

    # -- internals ---------------------------------------------------------------------------
    def _cone(self, g: CIEGeometry) -> tuple[np.ndarray, float]:
        half = math.radians(self.cone_deg if self.cone_deg is not None else g.cone_deg)
        if g.viewing == "directional":
            axis = direction(g.theta_r, 180.0)
            return np.array([*axis, math.cos(half)]), math.sin(half) ** 2 * axis[2]
        if not g.specular_included:
            axis = direction(g.theta_i, 180.0)  # mirror direction of an incidence at phi = 0
            return np.array([*axis, math.cos(half)]), 0.0
        return NO_CONE, 0.0

    def _spectrum(self, g: CIEGeometry, measured: CIEGeometry, wl: np.ndarray,
                  tallies: list[SpectroTally], cone_psa_over_pi: float) -> Spectrum:
        hits = np.array([t.hits for t in tallies], dtype=np.int64)
        if measured.viewing == "directional":
            k_r = np.array([t.cone for t in tallies], dtype=np.int64)
            scale = 1.0 / cone_psa_over_pi
        else:
            cone = np.array([t.cone for t in tallies], dtype=np.int64) if not measured.specular_included else 0
            k_r = np.array([t.reflected for t in tallies], dtype=np.int64) - cone
            scale = 1.0
        k_t = np.array([t.transmitted for t in tallies], dtype=np.int64)
        safe = np.maximum(hits, 1)
        r_lo, r_hi = binomial_ci(k_r, safe, self.delta)
        t_lo, t_hi = binomial_ci(k_t, safe, self.delta)
        meta = {
            "specimen": self.specimen.label, "beam": self.beam.describe(), "delta": self.delta,
            "uncertainty": self.uncertainty, "common_random_numbers": self.common_random_numbers,
            "measured_as": measured.name if g.illumination == "diffuse" else g.name,
            "reciprocity": g.illumination == "diffuse",
            "counts": [t.__dict__ for t in tallies],
            "quantity": "reflectance factor" if measured.viewing == "directional" else "reflectance",
        }
        return Spectrum(
            geometry=g.name, wavelengths=wl,
            reflectance=k_r / safe * scale, transmittance=k_t / safe,
            reflectance_ci=np.column_stack([r_lo, r_hi]) * scale,
            transmittance_ci=np.column_stack([t_lo, t_hi]),
            N=np.full(wl.shape, self.rays, dtype=np.int64), seed=self.seed, delta=self.delta, meta=meta,
        )

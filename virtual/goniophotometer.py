"""The virtual goniophotometer (seed section 3.2): a collector sphere around a black-box specimen.

BRDF/BTDF of a patch = n_d / (N PSA) (eq. 3.9 with the exact projected solid angle), with a
Clopper-Pearson interval on n_d. One instance fills two roles of a virtual bench:

* Goniometer: ``move_to(geometry)`` points the virtual arms; the detector is the collector patch
  containing the viewing direction. The arms of a virtual bench reach exactly what is asked.
* Spectrometer: ``acquire`` returns, per wavelength, the detector signal of the current patch:
  ``gain * integration_s * f * |cos theta_r|`` counts (what a detector of fixed aperture sees of
  a specimen whose BSDF is f), with its Monte Carlo standard deviation.

``off()``/``on()`` (LightSource role) switch the virtual source: dark readings are zero.

A new incidence or wavelength runs one simulation of the whole sphere and caches it, so a scan
over viewing directions costs one simulation per (incidence, wavelength).

Methods: ``"rays"`` counts rays in the numba kernel; ``"fast"`` draws the same counts as one
multinomial over patch probabilities integrated from the specimen's density (statistically
identical, O(patches)); ``"auto"`` takes the fast path when the specimen has a density and the
beam is collimated (a conical beam's incidence distribution is sampled, not integrated) --
except for an instrument of several wavelengths whose specimen batches them (below) when one
batch of rays is estimated to cost less than one quadrature per wavelength
(:func:`auto_counts_rays`: a GGX's quadrature takes about a second, a Lambertian's about 1/50 s,
a batch of 10^7 rays well under one), so that 31 wavelengths cost at most a few times one. The
fast path is taken only when its quadrature is certified
(:func:`virtual.quadrature.certified_patch_integrals`: total probability within
:data:`~virtual.quadrature.CERTIFY_TOL` of an independent albedo); otherwise ``auto`` counts rays
and ``fast`` is refused with the reason. The record says, per wavelength, which method ran and the
achieved quadrature error.

Spectral batching. When the specimen's wavelengths share the angular part -- its spectral
dependence is only in the survival probability: a Lambertian (spectral reflectance and
transmittance), GGX and anisotropic GGX with one roughness and masking convention (spectral eta,
k), under a beam the block kernels sample (:func:`virtual.engine.shares_angular_part`) -- the
rays of one incidence are counted for all the instrument's wavelengths at once
(:func:`virtual.engine.gonio_counts_spectral`): each ray's direction is drawn once and each
wavelength rolls its own survival, so 31 wavelengths cost 1-3x one.

Random streams (the one rule):

* rays counted for a specimen that batches: one stream per (specimen, incidence), shared by
  every wavelength -- ``measurement_seed(seed, specimen_stream_key, mdeg theta_i, mdeg phi_i)``
  (:meth:`batch_stream_key`). The wavelengths see common random numbers (each wavelength's
  counts have exactly the single-wavelength distribution; the wavelengths are correlated), and a
  wavelength's counts do not depend on which other wavelengths are measured with it: a
  single-wavelength run is the batch of one, and a batch of 31 gives exactly the counts of 31
  single-wavelength runs;
* everything else (the fast path, specimens that do not batch): one stream per (specimen,
  wavelength, incidence), ``measurement_seed(seed, specimen_stream_key, pm, mdeg theta_i,
  mdeg phi_i)`` (:meth:`stream_key`), so wavelengths are independent.

Two specimens measured with one seed are independent; ``common_random_numbers=True`` leaves the
specimen out (every specimen sees the same stream: lower variance when comparing models).
"""

from __future__ import annotations

import math
from typing import Any, Iterable

import numpy as np

from bench.core.errors import GeometryError, InputError
from bench.core.geometry import Geometry
from bench.core.parsing import parse_wavelengths
from bench.core.roles import InstrumentBase, InstrumentInfo, Reading
from bench.core.records import BSDF_COLUMNS, BSDFRecord
from virtual.beam import Beam, check_incidence
from virtual.bounds import binomial_ci, hoeffding_rays
from virtual.collector import Collector, parse_collector
from virtual.engine import (float32_suits, gonio_counts, gonio_counts_spectral, gonio_kernel_for, measurement_seed,
                            multinomial_counts, shares_angular_part, specimen_stream_key)
from virtual.quadrature import PatchIntegrals, certified_patch_integrals
from virtual.model_ids import MODEL_ANISO_GGX, MODEL_GGX, MODEL_LAMBERT
from virtual.specimens import MODEL_PYTHON, Specimen, parse_specimen
from virtual.spectrophotometer import fresh_seed

__all__ = ["VirtualGoniophotometer", "METHODS", "auto_counts_rays", "bin_probabilities"]

METHODS = ("auto", "rays", "fast")
DEFAULT_RAYS = 10_000_000

#: Fixed estimates for ``auto``'s choice at several wavelengths (never timed at run time, so the
#: choice is the same on every machine): seconds of one wavelength's certified quadrature by
#: model (9x36 and 18x72 collectors, 2 cores), the rays/s a spectral batch is costed at, and what
#: a batch of any number of wavelengths costs in single-wavelength measurements (measured 1-3x).
QUADRATURE_SECONDS = {MODEL_LAMBERT: 0.02, MODEL_GGX: 1.0, MODEL_ANISO_GGX: 0.5}
BATCH_RAYS_PER_SECOND = 2e7
BATCH_COST = 3


def auto_counts_rays(specimen: Specimen, beam: Beam, n_wavelengths: int, rays: int) -> bool:
    """Whether ``method="auto"`` counts rays, in one spectral batch, where it would otherwise take
    the fast path: several wavelengths of a specimen whose wavelengths share the angular part
    (:func:`virtual.engine.shares_angular_part`), and the batch's estimated time
    ``rays * min(W, BATCH_COST) / BATCH_RAYS_PER_SECOND`` below the quadratures'
    ``W * QUADRATURE_SECONDS[model]``. One wavelength always keeps the fast path."""
    w = int(n_wavelengths)
    if w < 2 or not shares_angular_part(specimen, beam.disk_code):
        return False
    batch = float(rays) * min(w, BATCH_COST) / BATCH_RAYS_PER_SECOND
    return batch < w * QUADRATURE_SECONDS.get(int(specimen.model), 0.0)


def bin_probabilities(integrals: PatchIntegrals) -> np.ndarray:
    """Probabilities of every bin (R patches, T patches, absorbed, missed = 0) from a collimated
    incidence's patch integrals: clipped to [0, 1], the patches scaled down if they exceed one."""
    p = np.clip(np.asarray(integrals.p, float), 0.0, 1.0)
    absorbed = max(0.0, 1.0 - p.sum())
    return np.concatenate([p / max(1.0, p.sum()), [absorbed, 0.0]])


class VirtualGoniophotometer(InstrumentBase):
    """A Monte Carlo goniophotometer.

    Parameters
    ----------
    specimen : Specimen or str
    collector : Collector or str
        e.g. ``"equal-psa:9x36"`` (scheme:rings x sectors).
    rays : int, optional
        Rays per (incidence, wavelength). Default: eq. 3.12 when ``uncertainty`` is given, else 1e7.
    uncertainty, delta : float
        Budget (eq. 3.12 with m = patches per hemisphere) and interval confidence.
    beam : Beam or str
    wavelengths : nm, the detector's channels (default 550 nm)
    method : ``"auto"``, ``"rays"`` or ``"fast"``
    gain : detector counts per (1/sr) per second
    common_random_numbers : bool
        Draw the same random stream whatever the specimen (default: a stream per specimen).
    """

    def __init__(self, specimen: Specimen | str, *, collector: Collector | str = "equal-psa:9x36",
                 rays: int | None = None, uncertainty: float | None = None, delta: float = 0.01,
                 beam: Beam | str = "collimated", seed: int | None = None,
                 wavelengths: Any = (550.0,), method: str = "auto", gain: float = 1.0e4,
                 common_random_numbers: bool = False) -> None:
        self.specimen = parse_specimen(specimen)
        self.collector = parse_collector(collector)
        self.beam = beam if isinstance(beam, Beam) else Beam(kind=str(beam))
        if not 0.0 < delta < 1.0:
            raise InputError(f"delta must lie in (0, 1), got {delta}")
        if rays is None:
            rays = (hoeffding_rays(uncertainty, delta, self.collector.n_patches) if uncertainty is not None
                    else DEFAULT_RAYS)
        if not isinstance(rays, (int, np.integer)) or rays < 1:
            raise InputError(f"rays must be a positive integer, got {rays!r}")
        if method not in METHODS:
            raise InputError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
        if method == "fast" and not self.specimen.has_density:
            raise InputError(f"method 'fast' needs a specimen with a density; {self.specimen.label} has none")
        if method == "fast" and self.beam.kind != "collimated":  # its quadrature integrates one incidence
            raise InputError(f"method 'fast' models a collimated beam only, not a {self.beam.kind} one "
                             "(use --method rays or auto)")
        if not (math.isfinite(gain) and gain > 0):
            raise InputError(f"gain must be finite and > 0, got {gain}")
        self.rays = int(rays)
        self.delta = float(delta)
        self.uncertainty = uncertainty
        self.seed = fresh_seed() if seed is None else int(seed)
        self.method = method
        self.gain = float(gain)
        self._wavelengths = parse_wavelengths(wavelengths)
        self.specimen.check_wavelengths(self._wavelengths)
        self._geometry = Geometry(0.0, 0.0, 0.0, 0.0)
        self._light_on = True
        self._cache: dict[tuple[float, float, float], np.ndarray] = {}
        self._probabilities: dict[tuple[float, float, float], np.ndarray] = {}
        self._certificates: dict[tuple[float, float, float], PatchIntegrals] = {}
        self._ran: dict[tuple[float, float, float], str] = {}
        self.common_random_numbers = bool(common_random_numbers)
        #: whether counted rays are batched over wavelengths (the stream rule of the module docstring)
        self.batches_wavelengths = shares_angular_part(self.specimen, self.beam.disk_code)

    # -- Instrument --------------------------------------------------------------------------
    def describe(self) -> InstrumentInfo:
        return InstrumentInfo(
            kind="goniophotometer", model="goniobench virtual goniophotometer", serial=f"seed-{self.seed}",
            firmware="virtual", uncertainty=self.uncertainty,
            ranges={"theta_i": (0.0, 89.999), "theta_r": (0.0, 180.0),
                    "wavelength_nm": (float(self._wavelengths[0]), float(self._wavelengths[-1]))},
            extra={"collector": self.collector.describe(), "beam": self.beam.describe(), "rays": self.rays,
                   "method": self.method, "specimen": self.specimen.label,
                   "common_random_numbers": self.common_random_numbers},
        )

    # -- Goniometer --------------------------------------------------------------------------
    def check(self, geometry: Geometry) -> None:
        if not isinstance(geometry, Geometry):
            raise GeometryError(f"expected a Geometry, got {type(geometry).__name__}", geometry)
        if geometry.theta_i >= 90.0:
            raise GeometryError(f"source_hemisphere: {geometry} refused: the virtual source arm illuminates "
                                f"from above (theta_i < 90 deg)", geometry)

    def move_to(self, geometry: Geometry) -> Geometry:
        self.check(geometry)
        self._geometry = geometry
        return geometry

    def position(self) -> Geometry:
        return self._geometry

    def stop(self) -> None:
        pass

    # -- LightSource -------------------------------------------------------------------------
    def on(self) -> None:
        self._light_on = True

    def off(self) -> None:
        """Source off: readings are dark (zero counts: a virtual detector has no dark current
        unless a scene declares instrument noise)."""
        self._light_on = False

    # -- Spectrometer ------------------------------------------------------------------------
    @property
    def wavelengths(self) -> np.ndarray:
        return self._wavelengths.copy()

    def acquire(self, integration_s: float, averages: int = 1) -> Reading:
        if not (isinstance(integration_s, (int, float)) and math.isfinite(integration_s) and integration_s > 0):
            raise InputError(f"integration_s must be finite and > 0, got {integration_s!r}")
        if not isinstance(averages, (int, np.integer)) or averages < 1:
            raise InputError(f"averages must be an integer >= 1, got {averages!r}")
        if not self._light_on:
            zeros = np.zeros(self._wavelengths.size)
            return Reading(wavelengths=self.wavelengths, signal=zeros, saturated=np.zeros(zeros.size, dtype=bool),
                           integration_s=float(integration_s), averages=int(averages), dark=True, std=zeros.copy())
        g = self._geometry
        view = g.view
        b = int(self.collector.index(view[None, :])[0])
        signal, std = np.empty(self._wavelengths.size), np.empty(self._wavelengths.size)
        psa = self.collector.psa[b]
        for i, counts in enumerate(self.simulate_spectrum(g.theta_i, g.phi_i, self._wavelengths)):
            hits = int(counts[:-2].sum() + counts[-2])
            p = counts[b] / max(hits, 1)
            f = p / psa
            scale = self.gain * integration_s * abs(view[2])
            signal[i] = scale * f
            std[i] = scale * math.sqrt(p * (1.0 - p) / max(hits, 1)) / psa
        return Reading(wavelengths=self.wavelengths, signal=signal, saturated=np.zeros(signal.size, dtype=bool),
                       integration_s=float(integration_s), averages=int(averages), std=std)

    def bsdf_at(self, geometry: Geometry) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """BSDF (1/sr) of the patch that contains ``geometry``'s viewing direction, per detector
        wavelength, with its interval: ``(value, lo, hi)``."""
        self.check(geometry)
        b = int(self.collector.index(geometry.view[None, :])[0])
        psa = self.collector.psa[b]
        out = np.empty((3, self._wavelengths.size))
        for i, counts in enumerate(self.simulate_spectrum(geometry.theta_i, geometry.phi_i, self._wavelengths)):
            n = int(counts[:-2].sum() + counts[-2])
            lo, hi = binomial_ci(np.array([counts[b]]), np.array([n]), self.delta)
            out[:, i] = counts[b] / max(n, 1) / psa, lo[0] / psa, hi[0] / psa
        return out[0], out[1], out[2]

    # -- simulation --------------------------------------------------------------------------
    def uses_fast_path(self) -> bool:
        """Whether the fast path is *tried* (it runs only where its quadrature is certified)."""
        if self.method == "fast":
            return True
        if auto_counts_rays(self.specimen, self.beam, self._wavelengths.size, self.rays):
            return False  # one batch of rays costs less than a quadrature per wavelength
        return self.method == "auto" and self.specimen.has_density and self.beam.kind == "collimated"

    def stream_key(self, theta_i: float, phi_i: float, wavelength_nm: float) -> tuple[int, ...]:
        """The spawn key of one (incidence, wavelength)'s stream: (specimen hash,) pm, mdeg
        theta_i, mdeg phi_i -- the specimen left out under ``common_random_numbers``."""
        key = (int(round(wavelength_nm * 1000)), int(round(theta_i * 1000)), int(round((phi_i % 360.0) * 1000)))
        return key if self.common_random_numbers else (specimen_stream_key(self.specimen), *key)

    def stream(self, theta_i: float, phi_i: float, wavelength_nm: float) -> np.random.SeedSequence:
        """The random stream of one (incidence, wavelength) (:meth:`stream_key`)."""
        return measurement_seed(self.seed, *self.stream_key(theta_i, phi_i, wavelength_nm))

    def batch_stream_key(self, theta_i: float, phi_i: float) -> tuple[int, ...]:
        """The spawn key of one incidence's batch of rays, shared by every wavelength when the
        specimen batches (:attr:`batches_wavelengths`): (specimen hash,) mdeg theta_i, mdeg phi_i
        -- no wavelength; the specimen left out under ``common_random_numbers``."""
        key = (int(round(theta_i * 1000)), int(round((phi_i % 360.0) * 1000)))
        return key if self.common_random_numbers else (specimen_stream_key(self.specimen), *key)

    def fast_path_for(self, theta_i: float, phi_i: float, wavelength_nm: float) -> bool:
        """Whether this (incidence, wavelength) is counted by the fast path: tried and certified.
        Records the decision (:meth:`method_ran`); raises :class:`InputError` when
        ``method="fast"`` and the quadrature is not certified."""
        key = (round(theta_i, 9), round(phi_i % 360.0, 9), round(wavelength_nm, 9))
        fast = False
        if self.uses_fast_path():
            cert = self.quadrature(theta_i, phi_i, wavelength_nm)
            if cert.certified:
                fast = True
            elif self.method == "fast":
                raise InputError(f"method fast refused for {self.specimen.label} at theta_i = {theta_i:g} deg, "
                                 f"{wavelength_nm:g} nm: {cert.reason} (use --method rays or auto)")
        self._ran[key] = "fast" if fast else "rays"
        return fast

    def quadrature(self, theta_i: float, phi_i: float, wavelength_nm: float) -> PatchIntegrals:
        """The certified patch integrals of one collimated incidence (cached)."""
        key = (round(theta_i, 9), round(phi_i % 360.0, 9), round(wavelength_nm, 9))
        if key not in self._certificates:
            wi = Geometry(theta_i, phi_i, 0.0, 0.0).incident
            self._certificates[key] = certified_patch_integrals(self.specimen, wi, self.collector, wavelength_nm)
        return self._certificates[key]

    def method_ran(self, theta_i: float, phi_i: float, wavelength_nm: float) -> str:
        """``"fast"`` or ``"rays"``: what counted this (incidence, wavelength) (simulating it
        if needed)."""
        key = (round(theta_i, 9), round(phi_i % 360.0, 9), round(wavelength_nm, 9))
        if key not in self._ran:
            self.simulate(theta_i, phi_i, wavelength_nm)
        return self._ran[key]

    def kernel(self) -> str:
        """What counts the rays: ``"fast"`` (one multinomial), ``"block32"``, ``"block"`` or
        ``"ray"`` (the numba kernels, see :mod:`virtual.engine`; the specimen's parameters at
        550 nm decide between float32 and float64) or ``"python"`` (a specimen without a kernel)."""
        if self.uses_fast_path() and "rays" not in self._ran.values():
            return "fast"
        if self.specimen.model == MODEL_PYTHON:
            return "python"
        if self.batches_wavelengths:  # the spectral batch: float32 when every wavelength suits it
            f32 = all(float32_suits(self.specimen.model, self.specimen.params(float(w))) for w in self._wavelengths)
            return "block32" if f32 else "block"
        return gonio_kernel_for(self.specimen.model, self.beam.disk_code, params=self.specimen.params(550.0))

    def simulate(self, theta_i: float, phi_i: float, wavelength_nm: float) -> np.ndarray:
        """Counts per bin (R patches, T patches, absorbed, missed) for one incidence and
        wavelength; cached. The stream is keyed by the incidence (and the wavelength, unless the
        rays are batched over wavelengths) so a repeated or resumed measurement draws the same
        rays (see the module docstring). Counting rays for a specimen that batches, the
        instrument's other wavelengths are counted in the same batch and cached.

        Raises :class:`InputError` when ``method="fast"`` and the quadrature is not certified.
        """
        check_incidence(theta_i)
        key = (round(theta_i, 9), round(phi_i % 360.0, 9), round(wavelength_nm, 9))
        if key in self._cache:
            return self._cache[key]
        seq = self.stream(theta_i, phi_i, wavelength_nm)
        params = self.specimen.params(wavelength_nm)
        if self.fast_path_for(theta_i, phi_i, wavelength_nm):
            counts = multinomial_counts(self.bin_probabilities(theta_i, phi_i, wavelength_nm), self.rays, seq)
        elif self.batches_wavelengths:  # with the instrument's other wavelengths not yet counted here
            others = [] if self.uses_fast_path() else [float(w) for w in self._wavelengths]
            self._simulate_batch(theta_i, phi_i, [float(wavelength_nm), *others])
            return self._cache[key]
        elif self.specimen.model == MODEL_PYTHON:  # no kernel (e.g. Mitsuba): count in numpy
            from virtual.python_engine import gonio_counts_python  # its disk sampling loads numba

            counts = gonio_counts_python(self.specimen, wavelength_nm, self.beam, theta_i, phi_i, self.collector,
                                         self.rays, seq)
        else:
            counts = gonio_counts(self.specimen.model, params, self.beam.code, self.beam.disk_code,
                                  self.beam.kernel_args(theta_i, phi_i), self.collector.kernel_args(),
                                  self.rays, seq)
        self._cache[key] = counts
        return counts

    def simulate_spectrum(self, theta_i: float, phi_i: float, wavelengths: Iterable[float]) -> list[np.ndarray]:
        """:meth:`simulate` at each of ``wavelengths`` -- in one spectral batch when the specimen
        batches and no wavelength takes the fast path (the counts are those of :meth:`simulate`
        one wavelength at a time)."""
        wl = [float(w) for w in wavelengths]
        if self.batches_wavelengths and not self.uses_fast_path():
            check_incidence(theta_i)
            self._simulate_batch(theta_i, phi_i, wl)
        return [self.simulate(theta_i, phi_i, w) for w in wl]

    def _simulate_batch(self, theta_i: float, phi_i: float, wavelengths: list[float]) -> None:
        """Count rays for those of ``wavelengths`` not yet simulated at this incidence in one
        spectral batch on the incidence's shared stream (:meth:`batch_stream_key`), and cache
        each row. A row is what a batch of that wavelength alone gives: the batch's make-up
        changes no count."""
        phi = round(phi_i % 360.0, 9)
        todo: dict[tuple[float, float, float], float] = {}
        for w in wavelengths:
            key = (round(theta_i, 9), phi, round(w, 9))
            if key not in self._cache:
                todo.setdefault(key, w)
        if not todo:
            return
        seq = measurement_seed(self.seed, *self.batch_stream_key(theta_i, phi_i))
        rows = gonio_counts_spectral(self.specimen.model, [self.specimen.params(w) for w in todo.values()],
                                     self.beam.code, self.beam.disk_code, self.beam.kernel_args(theta_i, phi_i),
                                     self.collector.kernel_args(), self.rays, seq)
        for key, counts in zip(todo, rows):
            self._ran[key] = "rays"
            self._cache[key] = counts

    def bin_probabilities(self, theta_i: float, phi_i: float, wavelength_nm: float) -> np.ndarray:
        """Probabilities of every bin (R patches, T patches, absorbed, missed = 0) for a
        collimated beam, by quadrature of the specimen's density over each patch (certified or
        not: see :meth:`quadrature` for the check)."""
        key = (round(theta_i, 9), round(phi_i % 360.0, 9), round(wavelength_nm, 9))
        if key in self._probabilities:  # a new seed or N redraws from the same integrals
            return self._probabilities[key]
        probabilities = bin_probabilities(self.quadrature(theta_i, phi_i, wavelength_nm))
        self._probabilities[key] = probabilities
        return probabilities

    def measure_bsdf(self, theta_i: float, phi_i: float = 0.0,
                     wavelengths: Iterable[float] | None = None) -> BSDFRecord:
        """The whole sphere for one incidence: a tidy BRDF/BTDF record (see :mod:`bench.core.records`)."""
        import pandas as pd

        check_incidence(theta_i)
        if theta_i >= 90.0:
            raise GeometryError(f"incidence theta_i = {theta_i} deg: the virtual source illuminates from above")
        wl = self._wavelengths if wavelengths is None else parse_wavelengths(wavelengths)
        self.specimen.check_wavelengths(wl)
        col = self.collector
        bounds = col.bin_bounds()  # radians: theta_min, theta_max, phi_min, phi_max per bin
        centres = col.centres_deg
        psa = col.psa
        th_lo = np.degrees(np.minimum(bounds[:, 0], bounds[:, 1]))
        th_hi = np.degrees(np.maximum(bounds[:, 0], bounds[:, 1]))
        n_bins = 2 * col.n_patches
        frames = []
        totals = []
        for w, counts in zip(wl, self.simulate_spectrum(theta_i, phi_i, wl)):
            k = counts[:n_bins]
            hits = int(k.sum() + counts[n_bins])
            n = max(hits, 1)
            lo, hi = binomial_ci(k, np.full(k.shape, n, dtype=np.int64), self.delta)
            p = k / n
            frames.append(pd.DataFrame({
                "wavelength_nm": float(w), "theta_i": float(theta_i), "phi_i": float(phi_i % 360.0),
                "theta_r": centres[:, 0], "phi_r": centres[:, 1],
                "hemisphere": np.where(np.arange(n_bins) < col.n_patches, "R", "T"),
                "value": p / psa, "std": np.sqrt(p * (1 - p) / n) / psa,
                "ci_lo": lo / psa, "ci_hi": hi / psa,
                "theta_min": th_lo, "theta_max": th_hi,
                "phi_min": np.degrees(bounds[:, 2]), "phi_max": np.degrees(bounds[:, 3]),
                "psa": psa, "count": k.astype(np.int64), "N": np.int64(hits),
            }))
            ran = self.method_ran(theta_i, phi_i, float(w))
            tot = {"wavelength_nm": float(w), "reflectance": float(k[:col.n_patches].sum() / n),
                   "transmittance": float(k[col.n_patches:].sum() / n),
                   "absorbed": int(counts[n_bins]), "missed": int(counts[n_bins + 1]), "N": hits, "method": ran}
            if self.uses_fast_path():
                cert = self.quadrature(theta_i, phi_i, float(w))
                tot["quadrature_error"] = float(cert.achieved_error)
                tot["quadrature_certified"] = bool(cert.certified)
                if not cert.certified:
                    tot["fallback_reason"] = cert.reason
            totals.append(tot)
        table = pd.concat(frames, ignore_index=True)[BSDF_COLUMNS]
        methods = {t["method"] for t in totals}
        ran_all = methods.pop() if len(methods) == 1 else "mixed"
        meta = {"source": "virtual", "specimen": self.specimen.label, "collector": col.describe(),
                "beam": self.beam.describe(), "rays": self.rays, "seed": self.seed, "delta": self.delta,
                "method": ran_all, "method_requested": self.method, "kernel": self.kernel(), "totals": totals,
                "common_random_numbers": self.common_random_numbers,
                "reciprocal": self.specimen.reciprocal, "isotropic": self.specimen.isotropic}
        return BSDFRecord(table, meta)

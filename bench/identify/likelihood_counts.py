"""The likelihood of virtual counts (:class:`GonioCounts`, :class:`SpectroCounts`).

The counts of a virtual record are one multinomial draw per (incidence, wavelength) over the
collector's bins plus "absorbed" (a goniophotometer), or over reflected / transmitted / absorbed
(a spectrophotometer with hemispherical collection). The residuals are the deviance residuals
``sign(k - m) sqrt(2 (k ln(k/m) - (k - m)))``, ``m = N p``; with the probabilities summing to
one, ``sum(r**2)`` is the multinomial deviance ``2 sum k ln(k / (N p))``. The probabilities come
from the certified fast path -- the goniophotometer's own
:meth:`~virtual.goniophotometer.VirtualGoniophotometer.bin_probabilities` once
:meth:`~virtual.goniophotometer.VirtualGoniophotometer.fast_path_for` certifies them (a fit
searches with the certificate deferred -- the same first quadrature attempt without its
independent albedo, nine tenths of the cost -- and certifies at its optimum,
:meth:`GonioCounts.certify`), the specimen's directional (R, T) for a spectrophotometer -- and,
where that cannot be certified (a conical beam, a gloss trap, a density the quadrature cannot
bound), from rays counted with common random numbers (one fixed seed for every evaluation,
:data:`CRN_SEED`, and :data:`RAY_FACTOR` times the record's rays), so the likelihood surface
stays smooth in the parameters.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, Mapping, Sequence

import numpy as np

from bench.core.errors import InputError
from bench.core.geometry import Geometry, cie_geometry
from bench.core.records import BSDFRecord
from bench.core.roles import Spectrum
from bench.identify.likelihood_base import Group, Likelihood, spectra_of
from bench.identify.prediction import directional_rt
from virtual.beam import Beam
from virtual.collector import SCHEMES, Collector
from virtual.specimens import Specimen

if TYPE_CHECKING:  # annotations only: the goniophotometer (its kernels) is imported where a fit counts rays
    from virtual.goniophotometer import VirtualGoniophotometer

__all__ = ["GonioCounts", "SpectroCounts", "multinomial_residuals", "CRN_SEED", "RAY_FACTOR", "P_FLOOR"]

#: the one seed of the rays counted where the fast path cannot certify (common random numbers)
CRN_SEED = 20261202
#: rays counted per evaluation, as a multiple of the record's rays, where the fast path cannot certify
RAY_FACTOR = 10
#: probabilities below this are raised to it (a count in a bin the model gives nothing stays finite)
P_FLOOR = 1e-15


def multinomial_residuals(k: np.ndarray, n: float, p: np.ndarray) -> np.ndarray:
    """Deviance residuals of counts ``k`` (every category, summing to ``n``) under
    probabilities ``p`` (floored at :data:`P_FLOOR` and renormalized): ``sum(r**2)`` is the
    multinomial deviance ``2 sum k ln(k / (n p))``."""
    p = np.maximum(np.asarray(p, float), P_FLOOR)
    m = n * (p / p.sum())
    k = np.asarray(k, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        term = np.where(k > 0, k * np.log(np.where(k > 0, k, 1.0) / m), 0.0) - (k - m)
    return np.sign(k - m) * np.sqrt(2.0 * np.maximum(term, 0.0))



# --- virtual counts: goniophotometer ------------------------------------------------------


def _beam(meta: Mapping[str, Any]) -> Beam:
    b = meta.get("beam") or {"kind": "collimated"}
    if isinstance(b, str):
        return Beam(b)
    keep = ("kind", "emitter_radius_mm", "specimen_radius_mm", "distance_mm", "disk_sampling")
    return Beam(**{k: b[k] for k in keep if k in b})


def _collector(record: BSDFRecord) -> Collector:
    """The record's collector: from its metadata, else the scheme whose patch bounds match the
    table's (a CSV written without its metadata)."""
    c = record.meta.get("collector")
    if isinstance(c, dict) and {"scheme", "n_theta", "n_phi"} <= set(c):
        return Collector(c["scheme"], int(c["n_theta"]), int(c["n_phi"]))
    t = record.table
    if not {"theta_min", "theta_max", "phi_min", "phi_max"} <= set(t.columns):
        raise InputError("record: counts without a collector (no metadata and no patch bounds)")
    first = t[(t.wavelength_nm == t.wavelength_nm.iloc[0]) & (t.theta_i == t.theta_i.iloc[0])]
    r = first[first.hemisphere == "R"]
    n_theta = len(np.unique(np.round(r.theta_min.to_numpy(float), 4)))
    n_phi = max(1, len(r) // max(n_theta, 1))
    edges = np.unique(np.round(np.concatenate([r.theta_min, r.theta_max]).astype(float), 4))
    for scheme in SCHEMES:
        col = Collector(scheme, n_theta, n_phi)
        if col.n_patches == len(r) and np.allclose(np.degrees(col.theta_edges), edges, atol=1e-3):
            return col
    raise InputError(f"record: its {len(r)} patches match no collector scheme ({', '.join(SCHEMES)})")


class GonioCounts(Likelihood):
    """Multinomial counts of a virtual goniophotometric record (see the module docstring)."""

    kind = "multinomial"
    xlabel = "collector bin (R patches, T patches, absorbed)"

    def __init__(self, record: BSDFRecord) -> None:
        t = record.table
        for key in ("specimen", "collector", "quantity"):  # a sweep's record holds several measurements
            if key in t.columns and t[key].nunique(dropna=True) > 1:
                raise InputError(f"record holds several {key} values ({', '.join(map(str, t[key].unique()[:4]))}"
                                 f"...); fit one measurement: select its rows first")
        self.collector = _collector(record)
        self.beam = _beam(record.meta)
        col = self.collector
        nb = col.n_bins
        centres = col.centres_deg
        index = {(h, round(float(a), 3), round(float(b), 3) % 360.0): i
                 for i, (h, (a, b)) in enumerate(zip(np.where(np.arange(nb) < col.n_patches, "R", "T"), centres))}
        self.blocks: list[tuple[float, float, float, np.ndarray, int]] = []
        groups = []
        start = 0
        for (wl, ti, pi), g in t.groupby(["wavelength_nm", "theta_i", "phi_i"], sort=True):
            if len(g) != nb:
                raise InputError(f"record: theta_i = {ti:g} deg, {wl:g} nm has {len(g)} of the collector's {nb} "
                                 "bins; the counts' likelihood needs the whole sphere")
            k = np.zeros(nb + 1)
            for h, tr, pr, c in zip(g.hemisphere, g.theta_r, g.phi_r, g["count"]):
                i = index.get((str(h), round(float(tr), 3), round(float(pr), 3) % 360.0))
                if i is None:
                    raise InputError(f"record: patch ({h}, {tr:g}, {pr:g}) is not a bin of collector {col}")
                k[i] = float(c)
            n = float(g["N"].iloc[0])
            if not (math.isfinite(n) and n >= k.sum() > 0):
                raise InputError(f"record: ray total N = {n:g} at theta_i = {ti:g}, {wl:g} nm is below its counts")
            k[nb] = n - k[:nb].sum()  # absorbed
            self.blocks.append((float(wl), float(ti), float(pi), k, int(n)))
            groups.append(Group(f"theta_i {ti:g} deg, {wl:g} nm", start, start + nb + 1, np.arange(nb + 1)))
            start += nb + 1
        self.groups = tuple(groups)

    def _instrument(self, specimen: Specimen, wl: float, n: int) -> VirtualGoniophotometer:
        from virtual.goniophotometer import VirtualGoniophotometer

        return VirtualGoniophotometer(specimen, collector=self.collector, beam=self.beam, wavelengths=(wl,),
                                      rays=RAY_FACTOR * n, seed=CRN_SEED, common_random_numbers=True)

    def _deferred(self, specimen: Specimen, ti: float, pi: float, wl: float) -> np.ndarray | None:
        """The fast path's probabilities from the certification's first attempt, uncertified
        (``None`` where the fast path does not apply or that attempt fails)."""
        from bench.core.errors import SimulationError
        from virtual.goniophotometer import bin_probabilities
        from virtual.quadrature import CERTIFY_ATTEMPTS, integrate_patches

        if not (specimen.has_density and self.beam.kind == "collimated"):
            return None
        try:
            integrals = integrate_patches(specimen, Geometry(ti, pi, 0.0, 0.0).incident, self.collector, wl,
                                          **CERTIFY_ATTEMPTS[0])
        except SimulationError:
            return None
        return bin_probabilities(integrals)

    def probabilities(self, specimen: Specimen) -> list[np.ndarray]:
        """Per block, the probabilities of every bin and "absorbed": certified quadrature, else
        rays with common random numbers. Under :attr:`defer_certification` the quadrature's
        certificate (an independent albedo, 90 % of its cost) is skipped: :meth:`certify`
        checks it at the optimum."""
        nb = self.collector.n_bins
        out = []
        for wl, ti, pi, _k, n in self.blocks:
            p = self._deferred(specimen, ti, pi, wl) if self.defer_certification else None
            if p is None:
                g = self._instrument(specimen, wl, n)
                if g.fast_path_for(ti, pi, wl):
                    p = g.bin_probabilities(ti, pi, wl)
                else:  # rays: the fractions of those that reached the specimen (the record's N counts only these)
                    self.counted_rays = True
                    c = g.simulate(ti, pi, wl)[:nb + 1].astype(float)
                    p = c / max(c.sum(), 1.0)
            out.append(p[:nb + 1])
        return out

    def certify(self, specimen: Specimen) -> bool:
        """Whether the deferred probabilities at ``specimen`` are exactly the certified fast
        path's (its first attempt certified), so a fit found with them stands."""
        for wl, ti, pi, _k, n in self.blocks:
            p = self._deferred(specimen, ti, pi, wl)
            if p is None:
                continue  # evaluated the certified way already
            g = self._instrument(specimen, wl, n)
            if not (g.fast_path_for(ti, pi, wl) and np.array_equal(g.bin_probabilities(ti, pi, wl), p)):
                return False
        return True

    def residuals(self, specimen: Specimen) -> np.ndarray:
        return np.concatenate([multinomial_residuals(b[3], b[4], p)
                               for b, p in zip(self.blocks, self.probabilities(specimen))])

    def n_data(self, specimen: Specimen) -> int:
        return sum(int(np.count_nonzero((b[3] > 0) | (p > P_FLOOR))) - 1
                   for b, p in zip(self.blocks, self.probabilities(specimen)))


# --- virtual counts: spectrophotometer ----------------------------------------------------


class SpectroCounts(Likelihood):
    """Multinomial (reflected, transmitted, absorbed) counts per wavelength of virtual spectra
    measured with hemispherical collection (see the module docstring)."""

    kind = "multinomial"
    xlabel = "wavelength (nm)"

    def __init__(self, record: Spectrum | Sequence[Spectrum]) -> None:
        self.spectra = spectra_of(record)
        groups = []
        start = 0
        self.blocks = []
        for s in self.spectra:
            g = cie_geometry(s.geometry)
            measured = g.reciprocal_directional
            if measured.viewing != "diffuse":
                raise InputError(f"spectrum {s.geometry}: counts of a directional viewing geometry are fitted as "
                                 "calibrated readings, not counts")
            n = np.asarray(s.N, float)
            k_r = np.rint(np.asarray(s.reflectance, float) * n)
            k_t = np.rint(np.asarray(s.transmittance, float) * n)
            k = np.column_stack([k_r, k_t, n - k_r - k_t])
            beam = _beam(s.meta or {})
            self.blocks.append((g, measured, np.asarray(s.wavelengths, float), k, n, beam))
            m = len(n)  # residuals of a spectrum: its R block, T block, absorbed block (one per wavelength)
            for name, col in (("R", 0), ("T", 1), ("absorbed", 2)):
                groups.append(Group(f"{s.geometry} {name}", start + col * m, start + (col + 1) * m,
                                    np.asarray(s.wavelengths, float)))
            start += 3 * m
        self.groups = tuple(groups)

    def probabilities(self, specimen: Specimen) -> list[np.ndarray]:
        """Per spectrum, (n_wavelengths, 3) probabilities of reflected, transmitted, absorbed."""
        out = []
        for g, measured, wl, _k, n, beam in self.blocks:
            rt = None
            if beam.kind == "collimated" and measured.specular_included:
                rt = [directional_rt(specimen, measured.theta_i, float(w)) for w in wl]
            if rt is None or any(v is None for v in rt):
                from virtual.spectrophotometer import VirtualSpectrophotometer

                self.counted_rays = True
                rays = int(RAY_FACTOR * n.max())
                s = VirtualSpectrophotometer(specimen, rays=rays, beam=beam, seed=CRN_SEED,
                                             common_random_numbers=True).measure(g, wl)
                rt = list(zip(s.reflectance, s.transmittance))
            p = np.array(rt, dtype=float)
            out.append(np.column_stack([p, np.clip(1.0 - p.sum(axis=1), 0.0, 1.0)]))
        return out

    def residuals(self, specimen: Specimen) -> np.ndarray:
        parts = []
        for b, p in zip(self.blocks, self.probabilities(specimen)):
            k, n = b[3], b[4]
            r = np.array([multinomial_residuals(k[i], n[i], p[i]) for i in range(len(n))])
            parts.append(r.T.ravel())  # R block, T block, absorbed block
        return np.concatenate(parts)

    def n_data(self, specimen: Specimen) -> int:
        return sum(int(np.count_nonzero((b[3] > 0) | (p > P_FLOOR))) - len(b[4])
                   for b, p in zip(self.blocks, self.probabilities(specimen)))

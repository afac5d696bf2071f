"""What a calibrated bench reading estimates, as a function of the specimen: the one prediction
of the fit (:mod:`bench.identify.likelihood`) and the design (:mod:`bench.identify.design`).

A detector of half-angle ``a`` (the description's
:func:`bench.builders.instrument.declared_aperture`) reads ``S = G mean_cone(f |cos|)`` -- the
emulated spectrometer and the virtual body alike -- and the white standard (Lambertian,
``f_w = R_w / pi``) ``S_w = G (R_w / pi) mean_cone_w(|cos|)``. The calibration
(:mod:`bench.core.calibration`) divides by ``S_w`` and multiplies by
``(R_w / pi) cos(theta_w) / cos(theta_r)``, so the calibrated BRDF estimates::

    mean_cone(f |cos|) / |cos theta_r|  *  cos(theta_w) / mean_cone_w(|cos|)

(:func:`cone_nodes`; ``a = 0``: the BSDF at the viewing direction). A virtual body without an
aperture reads the collector patch of the viewing direction: its reading estimates the patch's
projected-solid-angle average (:func:`patch_nodes`).

A band reading is the mean of the detector's pixels within ``centre +- bandwidth/2``
(:class:`bench.bands.SpectralBands`), so a spectral specimen's band is predicted as the mean of
the prediction over those pixels' wavelengths (:func:`band_mean`), not at the centre: on a curved
spectrum (a leaf's red edge) the centre value is off by up to ~1.4 % at diffuse geometries, a
geometry-dependent bias no per-band scale absorbs. Without the pixels, a Gauss-Legendre rule of
:data:`BAND_ORDER` nodes over the band. A non-spectral specimen: one evaluation serves all.
"""

from __future__ import annotations

import functools
import math
from typing import Any, Mapping, NamedTuple, Sequence

import numpy as np

from bench.bands import band_pixel_indices
from bench.core.errors import ConfigError, InputError
from bench.core.geometry import Geometry, cie_geometry, cone_cos_weights, direction, gauss_legendre
from drivers.ocean import wavelength_polynomial
from virtual.collector import Collector
from virtual.specimens import Specimen, weighted_spectrum

__all__ = ["predicted_brdf", "Band", "band_mean", "band_pixels", "record_bands", "cone_nodes", "patch_nodes", "record_aperture", "white_geometry",
           "virtual_body_patches", "directional_rt", "ideal_rf", "PATCH_BOUNDS", "PATCH_ORDER"]

#: a record's patch columns: a reading with them is the BSDF averaged over that patch
PATCH_BOUNDS = ("theta_min", "theta_max", "phi_min", "phi_max")
#: Gauss-Legendre order per axis of a patch average
PATCH_ORDER = 8
#: Gauss-Legendre nodes of a band's mean when its pixels' wavelengths are unknown
BAND_ORDER = 8


class Band(NamedTuple):
    """The wavelengths (nm) a band's reading averages and their weights (summing to 1)."""

    nodes: np.ndarray
    weights: np.ndarray


def band_pixels(centres: Sequence[float] | np.ndarray, bandwidth_nm: float, pixel_nm: np.ndarray | None = None
                ) -> tuple[Band, ...]:
    """Each band's :class:`Band`: the detector's pixels within ``centre +- bandwidth/2`` (as
    :class:`bench.bands.SpectralBands` selects them), equally weighted as it averages them, or
    without them :data:`BAND_ORDER` Gauss-Legendre nodes over the band with the rule's weights."""
    half = float(bandwidth_nm) / 2.0
    if pixel_nm is not None:
        wl = np.asarray(pixel_nm, dtype=float)
        pixels = [wl[band_pixel_indices(wl, float(c), float(bandwidth_nm))] for c in centres]
        if all(p.size for p in pixels):
            return tuple(Band(p, np.full(p.size, 1.0 / p.size)) for p in pixels)
    x, w = gauss_legendre(BAND_ORDER)
    return tuple(Band(float(c) + half * x, w / 2.0) for c in centres)


def band_mean(specimen: Specimen, wi: np.ndarray, dirs: np.ndarray, weights: np.ndarray, band: Band) -> float:
    """``band.weights @ (weights @ f(dirs))`` over the band's wavelengths: what a band of a
    spectral specimen reads (held at the specimen's range ends beyond it, as the emulated detector is)."""
    values = weighted_spectrum(specimen, wi, dirs, weights, np.asarray(band.nodes, dtype=float))
    return float(np.asarray(band.weights, dtype=float) @ values)


def record_bands(meta: Mapping[str, Any]) -> dict[float, Band] | None:
    """Each band centre's :class:`Band` (:func:`band_pixels`) from a record's bench
    description (``spectrometer.extra``: ``bands_nm``, ``bandwidth_nm`` and the detector's
    ``wavelength_coeffs`` / ``pixels``); None when the record read no bands."""
    extra = _mapping(_mapping(_mapping(meta.get("bench_description")).get("spectrometer")).get("extra"))
    try:
        centres = [float(c) for c in extra["bands_nm"]]
        bw = float(extra["bandwidth_nm"])
    except (KeyError, TypeError, ValueError):
        return None
    pixel_nm = None
    try:
        pixel_nm = wavelength_polynomial([float(c) for c in extra["wavelength_coeffs"]], int(extra["pixels"]))
    except (KeyError, TypeError, ValueError):
        pass
    if not (math.isfinite(bw) and bw > 0):
        return None
    return dict(zip(centres, band_pixels(centres, bw, pixel_nm)))


def white_factor(white: Geometry | None, aperture_deg: float) -> float:
    """``cos(theta_w) / mean_cone_w(|cos|)``: the white reading's cone, as the calibration sees it
    (1 without a white geometry or an aperture)."""
    if white is None or aperture_deg <= 0:
        return 1.0
    _, w_cos = cone_cos_weights(white.view, aperture_deg)
    return abs(float(white.view[2])) / float(w_cos.sum())


@functools.lru_cache(maxsize=4096)
def cone_nodes(geometry: Geometry, aperture_deg: float, white: Geometry | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Directions and weights such that ``weights @ f(dirs)`` is the calibrated reading of a
    specimen of BSDF ``f`` at ``geometry`` through a detector of half-angle ``aperture_deg``,
    calibrated against a white read at ``white`` (see the module docstring). Remembered (read-only):
    a fit or a design asks for the same points at every parameter step."""
    dirs, w_cos = cone_cos_weights(geometry.view, aperture_deg)
    cos_axis = abs(float(geometry.view[2]))
    if cos_axis < 1e-9:  # at the horizon: no calibrated BRDF; the plain cone mean
        weights = w_cos / max(float(w_cos.sum()), 1e-300)
    else:
        weights = w_cos / cos_axis * white_factor(white, aperture_deg)
    dirs.flags.writeable = False
    weights.flags.writeable = False
    return dirs, weights


def predicted_brdf(specimen: Specimen, geometries: Sequence[Geometry], wavelengths: np.ndarray,
                   aperture_deg: float = 0.0, white: Geometry | None = None,
                   bands: Sequence[Band] | None = None) -> np.ndarray:
    """The calibrated BRDF (1/sr) a bench reads at each geometry and wavelength,
    ``(points, wavelengths)``: :func:`cone_nodes` applied to the specimen's density; with
    ``bands`` (each wavelength's :class:`Band`, :func:`band_pixels`) a spectral specimen's
    band is their weighted mean (:func:`band_mean`)."""
    wavelengths = np.asarray(wavelengths, dtype=float)
    spectral = specimen.wavelength_range() is not None
    todo = wavelengths if spectral else wavelengths[:1]  # a non-spectral density: one evaluation
    out = np.empty((len(geometries), len(todo)))
    for k, g in enumerate(geometries):
        dirs, w = cone_nodes(g, aperture_deg, white)
        for b, wl in enumerate(todo):
            if spectral and bands is not None:
                out[k, b] = band_mean(specimen, g.incident, dirs, w, bands[b])
            else:
                out[k, b] = float(w @ np.asarray(specimen.bsdf(g.incident, dirs, float(wl)), dtype=float))
    return out if spectral else np.repeat(out, len(wavelengths), axis=1)


def patch_nodes(theta_min: float, theta_max: float, phi_min: float, phi_max: float,
                order: int = PATCH_ORDER) -> tuple[np.ndarray, np.ndarray]:
    """Directions and weights (summing to 1) of the projected-solid-angle average over a
    collector patch (degrees): what a patch reading ``n / (N * PSA)`` estimates. In
    ``u = sin^2(theta)`` the projected solid angle is uniform (``dPSA = du dphi / 2``), so a
    Gauss-Legendre product rule in (u, phi) averages with equal measure."""
    x, w = gauss_legendre(order)
    lo, hi = math.sin(math.radians(theta_min)) ** 2, math.sin(math.radians(theta_max)) ** 2
    u = lo + (hi - lo) * (x + 1.0) / 2.0
    phi = math.radians(phi_min) + math.radians(phi_max - phi_min) * (x + 1.0) / 2.0
    st = np.sqrt(np.clip(u, 0.0, 1.0))
    ct = np.sqrt(np.clip(1.0 - u, 0.0, 1.0))
    if min(theta_min, theta_max) >= 90.0:  # a transmission patch: below the specimen
        ct = -ct
    dirs = np.stack([np.outer(st, np.cos(phi)).ravel(), np.outer(st, np.sin(phi)).ravel(),
                     np.repeat(ct, order)], axis=1)
    weights = np.outer(w, w).ravel() / 4.0
    return dirs, weights


def _mapping(v: Any) -> Mapping[str, Any]:
    return v if isinstance(v, Mapping) else {}


def _body(meta: Mapping[str, Any]) -> Any:
    return meta.get("bench_kind", _mapping(meta.get("bench_description")).get("kind"))


def record_aperture(meta: Mapping[str, Any]) -> float:
    """The detector half-angle (deg) a record's readings were taken through (0: none).

    A virtual body's detector says what it read in the run's bench description
    (``spectrometer.extra``: ``aperture_deg`` and ``detector_reads``, "cone" or "patch"); one
    that does not say read the collector patch (0). Another body read the aperture its bench
    description declares (:func:`bench.builders.instrument.declared_aperture` of the stored
    ``bench``); a record without that description, none."""
    from bench.builders.instrument import declared_aperture

    extra = _mapping(_mapping(_mapping(meta.get("bench_description")).get("spectrometer")).get("extra"))
    if _body(meta) == "virtual":
        return float(extra.get("aperture_deg", 0.0)) if extra.get("detector_reads") == "cone" else 0.0
    bench = meta.get("bench")
    if not isinstance(bench, Mapping):
        return 0.0
    try:
        return declared_aperture(bench, "record's bench description")
    except ConfigError:
        return 0.0


def white_geometry(meta: Mapping[str, Any]) -> Geometry | None:
    """Where the record's white standard was read (its calibration's), or None."""
    g = _mapping(_mapping(_mapping(meta.get("calibration")).get("standard")).get("geometry"))
    try:
        return Geometry(float(g["theta_i"]), float(g["phi_i"]), float(g["theta_r"]), float(g["phi_r"]))
    except (KeyError, TypeError, ValueError, InputError):
        return None


def virtual_body_patches(meta: Mapping[str, Any], theta_r: np.ndarray, phi_r: np.ndarray) -> np.ndarray:
    """Patch bounds (deg) of readings a virtual body took without an aperture: its detector reads
    the collector patch that holds the viewing direction (the collector the run's bench
    description names), so the reading is that patch's average, not the BSDF at the direction.
    NaN rows elsewhere (another body, or a virtual detector that read its aperture's cone)."""
    out = np.full((len(theta_r), 4), np.nan)
    desc = _mapping(meta.get("bench_description"))
    c = _mapping(_mapping(desc.get("goniometer")).get("extra")).get("collector")
    if _body(meta) != "virtual" or not c or record_aperture(meta) > 0 or len(theta_r) == 0:
        return out
    try:
        col = Collector(str(c["scheme"]), int(c["n_theta"]), int(c["n_phi"]))
    except (KeyError, TypeError, ValueError, InputError):
        return out
    dirs = np.array([direction(a, b) for a, b in zip(theta_r, phi_r)])
    return np.degrees(col.bin_bounds()[col.index(dirs)])


def directional_rt(specimen: Specimen, theta_deg: float, wavelength_nm: float) -> tuple[float, float] | None:
    """The specimen's directional-hemispherical (R, T) at incidence ``theta_deg``: its own
    ``directional_rt`` when it has one, else the certified quadrature of its density; ``None``
    when neither is available or certified."""
    own = getattr(specimen, "directional_rt", None)
    if own is not None:
        r, t = own(theta_deg, wavelength_nm)
        return float(r), float(t)
    if not specimen.has_density:
        return None
    from virtual.quadrature import certified_patch_integrals

    cert = certified_patch_integrals(specimen, direction(theta_deg, 0.0), Collector("equal-psa", 1, 1), wavelength_nm)
    return (cert.reflectance, cert.transmittance) if cert.certified else None


def ideal_rf(specimen: Specimen, geometry: str, wavelength_nm: float) -> float:
    """Reflectance factor of a bidirectional geometry ``"THETA_I/THETA_R"``: pi f_r, viewed in the
    plane of incidence on the far side."""
    a, _, b = geometry.partition("/")
    try:
        ti, tr = float(a), float(b)
    except ValueError:
        g = cie_geometry(geometry)
        ti, tr = g.theta_i, g.theta_r
    f = specimen.bsdf(direction(ti, 0.0), direction(tr, 180.0)[None, :], wavelength_nm)
    return math.pi * float(np.asarray(f)[0])

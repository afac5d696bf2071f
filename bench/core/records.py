"""Records: the tidy data every device, store, export and comparison shares.

:class:`Reading` is one detector acquisition, :class:`Spectrum` a spectrophotometric result,
:class:`BSDFRecord` a goniophotometric table; :func:`json_default` is the one JSON fallback for
their metadata.

A :class:`BSDFRecord` is a ``pandas.DataFrame`` with one row per (wavelength, incidence,
viewing patch or direction) and a metadata dict. Columns (angles in degrees):

=================  ============================================================================
wavelength_nm      wavelength
theta_i, phi_i     incidence (toward the source)
theta_r, phi_r     viewing direction (patch centre for a virtual collector)
hemisphere         ``"R"`` (reflection side) or ``"T"`` (transmission side)
value              BRDF or BTDF (1/sr)
std                standard uncertainty of ``value`` (1/sr)
ci_lo, ci_hi       interval at confidence ``1 - meta["delta"]`` (1/sr)
theta_min ...      patch bounds ``theta_min, theta_max, phi_min, phi_max`` (virtual collectors;
                   a physical detector gives its aperture instead)
psa                projected solid angle of the patch or aperture (sr)
count, N           rays in the patch and rays that reached the specimen (virtual)
u_c, U, k          a calibrated scan's GUM budget: combined and expanded uncertainty, coverage
                   factor; ``uncertainty_budget`` the budget itself as JSON (bench.core.budget)
=================  ============================================================================

Keys. Besides the geometry and wavelength columns above, a record carries the *identity* key
columns :data:`IDENTITY_KEYS` -- ``specimen``, ``collector`` (the patch scheme, e.g.
``equal-psa:9x36``, or the physical detector), ``geometry`` (CIE geometry of a spectrum) -- and
``quantity`` (``BSDF``, ``reflectance``, ``reflectance factor``, ``transmittance``).
:func:`with_keys` adds the ones a table lacks from the record's metadata (one value for the
whole record), so a single-specimen virtual record, a scan, a sweep (one value per row) and an
imported file all carry the same columns. :data:`COLUMN_UNITS` is the unit of every column,
written into file headers (CSV ``# units:`` line, Parquet metadata).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
import re
from typing import Any, Mapping

import numpy as np

__all__ = ["Reading", "Spectrum", "BSDFRecord", "BSDF_COLUMNS", "json_default", "IDENTITY_KEYS", "KEY_COLUMNS",
           "COLUMN_UNITS", "record_identity", "record_provenance", "value_unit", "with_keys", "hardware_name",
           "GEOMETRY_COLUMNS"]

BSDF_COLUMNS = ["wavelength_nm", "theta_i", "phi_i", "theta_r", "phi_r", "hemisphere", "value", "std",
                "ci_lo", "ci_hi", "theta_min", "theta_max", "phi_min", "phi_max", "psa", "count", "N"]

#: what a record is *of*: rows that differ in one of these are different measurements
IDENTITY_KEYS = ("specimen", "collector", "geometry")
#: every key column of a tidy record (identity, incidence, viewing/patch, wavelength, quantity)
KEY_COLUMNS = ("specimen", "collector", "geometry", "theta_i", "phi_i", "theta_r", "phi_r", "theta_min",
               "theta_max", "phi_min", "phi_max", "hemisphere", "wavelength_nm", "quantity")
#: units of the columns (``value``/``std``/``ci_*`` in 1/sr for a BSDF, 1 for reflectance)
COLUMN_UNITS = {"wavelength_nm": "nm", "theta_i": "deg", "phi_i": "deg", "theta_r": "deg", "phi_r": "deg",
                "theta_min": "deg", "theta_max": "deg", "phi_min": "deg", "phi_max": "deg", "psa": "sr",
                "value": "1/sr", "std": "1/sr", "ci_lo": "1/sr", "ci_hi": "1/sr", "count": "rays", "N": "rays",
                "u_c": "1/sr", "U": "1/sr", "k": "1", "hemisphere": "R|T", "specimen": "", "collector": "", "geometry": "", "quantity": ""}


#: the columns a goniometer's read-back gives (the rest of a reading, the spectrometer's)
GEOMETRY_COLUMNS = ("theta_i", "phi_i", "theta_r", "phi_r")

_UNSAFE = re.compile(r"[^A-Za-z0-9._+-]+")


def hardware_name(body: Any, bench: Any, role: str, model: Any = None, serial: Any = None) -> str:
    """``BODY://BENCH/ROLE/MODEL/SERIAL``: the instrument a value came from, as a Bluesky data
    key's ``source`` names it (a live device's and a stored run's alike)."""
    parts = [p for p in (role, model, serial) if p]
    return f"{body}://{_UNSAFE.sub('_', str(bench))}/" + "/".join(_UNSAFE.sub("_", str(p)) for p in parts)


def _label(v: Any) -> str | None:
    """A key value as text: a string as is, a mapping by its ``spec``/``label``/``scheme`` (with
    the patch counts of a collector description), None when absent."""
    if v is None:
        return None
    if isinstance(v, Mapping):
        for k in ("spec", "label", "name"):
            if v.get(k):
                return str(v[k])
        if v.get("scheme"):
            nt, npf = v.get("n_theta"), v.get("n_phi")
            return f"{v['scheme']}:{nt}x{npf}" if nt and npf else str(v["scheme"])
        return None
    return str(v)


def record_identity(meta: Mapping[str, Any]) -> dict[str, str | None]:
    """The identity keys a record's metadata states: ``specimen`` (``meta["specimen"]`` or the
    bench's ``specimen.spec``), ``collector`` (``meta["collector"]`` or the bench's detector) and
    ``quantity`` (``meta["quantity"]``, default ``BSDF``)."""
    bench = meta.get("bench") if isinstance(meta.get("bench"), Mapping) else {}
    specimen = _label(meta.get("specimen")) or _label((bench or {}).get("specimen"))
    collector = _label(meta.get("collector")) or _label((bench or {}).get("collector"))
    return {"specimen": specimen, "collector": collector, "quantity": str(meta.get("quantity") or "BSDF")}


def record_provenance(meta: Mapping[str, Any]) -> dict[str, str]:
    """Where a record comes from, as text: ``run_id``, ``bench`` (its name), ``body`` (virtual,
    emulated or real), ``plan`` (its name) and ``sample_name`` (the lab's name of the mounted
    specimen, ``[specimen] name``, when it differs from the specimen's model); keys the metadata
    does not state are left out."""
    def mapping(key: str) -> Mapping[str, Any]:
        v = meta.get(key)
        return v if isinstance(v, Mapping) else {}

    bench, desc, plan = mapping("bench"), mapping("bench_description"), mapping("plan")
    specimen = bench.get("specimen")
    mounted = specimen if isinstance(specimen, Mapping) else {}
    found = {"run_id": meta.get("run_id"),
             "bench": meta.get("bench_name") or desc.get("name") or bench.get("name"),
             "body": meta.get("body") or meta.get("bench_kind") or desc.get("kind") or bench.get("kind"),
             "plan": meta.get("plan_name") or plan.get("name"),
             "sample_name": meta.get("sample_name") or meta.get("specimen_name") or mounted.get("name")}
    if found["sample_name"] is not None and str(found["sample_name"]) == record_identity(meta)["specimen"]:
        found["sample_name"] = None  # no name besides the model: the specimen column says it
    return {k: str(v) for k, v in found.items() if v not in (None, "")}


def value_unit(meta: Mapping[str, Any]) -> str:
    """The unit of a record's ``value`` (and ``std``, ``ci_*``): ``1/sr`` for a BSDF, ``1`` for a
    reflectance or transmittance (``meta["quantity"]``, default BSDF)."""
    q = str(meta.get("quantity") or "BSDF").lower()
    return "1/sr" if q in ("bsdf", "brdf", "btdf", "1/sr") else "1"


def with_keys(record: "BSDFRecord") -> "BSDFRecord":
    """``record`` with every identity key column present: a column the table lacks (or leaves
    empty) is filled from :func:`record_identity` of its metadata (None when the metadata does
    not say either). Returns a new record; the input is not modified."""
    t = record.table.copy()
    ident = record_identity(record.meta)
    for k in ("specimen", "collector", "quantity"):
        if k not in t.columns or t[k].isna().all():
            t[k] = ident[k]
    if "geometry" not in t.columns:
        t["geometry"] = record.meta.get("geometry") if isinstance(record.meta.get("geometry"), str) else None
    for k in ("specimen", "collector", "quantity", "geometry"):  # text keys; an absent value is None
        col = t[k].astype(object)
        t[k] = col.where(col.notna(), None)
    return BSDFRecord(t, dict(record.meta))


def json_default(o: Any) -> Any:
    """``json.dumps`` fallback for record metadata: numpy scalars and arrays, sets and tuples,
    objects with ``as_dict``; anything else as its string."""
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (set, frozenset, tuple)):
        return list(o)
    if hasattr(o, "as_dict"):
        return o.as_dict()
    return str(o)


@dataclass(frozen=True)
class Reading:
    """One detector acquisition: signal per wavelength (counts, averaged over ``averages``).

    ``saturated`` flags pixels that hit full scale in any averaged scan (never calibrate them);
    ``dark`` says whether the light was off (a dark reading). ``std`` is the standard deviation
    of the mean per pixel when the device knows it.
    """

    wavelengths: np.ndarray
    signal: np.ndarray
    saturated: np.ndarray
    integration_s: float
    averages: int
    timestamp: float = field(default_factory=time.time)
    dark: bool = False
    std: np.ndarray | None = None


@dataclass(frozen=True)
class Spectrum:
    """Reflectance and/or transmittance per wavelength with two-sided confidence intervals.

    ``*_ci`` arrays have shape (n, 2) (lo, hi) at confidence ``1 - delta``; ``N`` is the number
    of rays per wavelength (virtual) or 0 for a physical measurement; ``seed`` the root seed.
    """

    geometry: str
    wavelengths: np.ndarray
    reflectance: np.ndarray
    transmittance: np.ndarray
    reflectance_ci: np.ndarray
    transmittance_ci: np.ndarray
    N: np.ndarray
    seed: int | None
    delta: float
    meta: Mapping[str, Any] = field(default_factory=dict)

    @property
    def absorptance(self) -> np.ndarray:
        return 1.0 - self.reflectance - self.transmittance


@dataclass
class BSDFRecord:
    """A goniophotometric record: ``table`` (pandas DataFrame, :data:`BSDF_COLUMNS`) and ``meta``."""

    table: Any
    meta: dict[str, Any] = field(default_factory=dict)

    def reflection(self) -> "BSDFRecord":
        return BSDFRecord(self.table[self.table.hemisphere == "R"].reset_index(drop=True), dict(self.meta))

    def transmission(self) -> "BSDFRecord":
        return BSDFRecord(self.table[self.table.hemisphere == "T"].reset_index(drop=True), dict(self.meta))

    def __len__(self) -> int:
        return len(self.table)

"""Sweep specs: ``SWEEP.toml`` validated and cut into tasks (:class:`SweepSpec`,
:class:`SweepTask`), each with its task key and series seed; the per-task table stored with a run.

See :mod:`bench.sweep` for the format, the determinism contract and where the work runs.
"""

from __future__ import annotations

import hashlib
import json
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, get_args

import numpy as np

from bench.core.errors import ConfigError, InputError
from bench.core.geometry import cie_geometry
from bench.core.parsing import parse_wavelengths, read_toml
from bench.core.schemas import MAX_SWEEP_SERIES, SweepFile, SweepTable, TaskTable, validate_document
from virtual.beam import Beam
from virtual.bounds import hoeffding_rays
from virtual.collector import parse_collector
from virtual.goniophotometer import auto_counts_rays
from virtual.specimens import parse_specimen
from virtual.spectrophotometer import fresh_seed

__all__ = ["SweepSpec", "SweepTask", "load_sweep", "sweep_from_dict", "task_key", "series_seed", "task_table",
           "INSTRUMENTS", "TASK_COLUMNS", "RUN_COLUMNS"]

#: the instruments a sweep may name (declared by the sweep schema)
INSTRUMENTS: tuple[str, ...] = get_args(SweepTable.model_fields["instrument"].annotation)
#: the keys a ``[[task]]`` may give, any of which it takes from ``[sweep]`` when it does not
_TASK_KEYS = frozenset(TaskTable.model_fields)
#: per-task columns of :func:`sweep_readings` that differ between executions (who ran it, how long)
RUN_COLUMNS = ("worker", "compute_s")
#: per-task columns fixed by the spec (stored once, in the run's meta, at creation)
TASK_COLUMNS = ("specimen", "collector", "geometry", "quantity", "method", "rays", "beam", "task_key", "series_seed")


# --- the spec --------------------------------------------------------------------------------


@dataclass(frozen=True)
class SweepTask:
    """One unit of work: a series (specimen, incidence or CIE geometry, collector) at some
    wavelengths. Self-contained and small: a worker needs nothing else to run it."""
    idx: int
    instrument: str
    specimen: str
    theta_i: float
    phi_i: float
    geometry: str | None
    collector: str | None
    wavelengths: tuple[float, ...]
    rays: int
    method: str
    beam: str
    delta: float
    cone_deg: float | None
    key: int
    seed: int
    common_random_numbers: bool = False  # the series' seed and streams leave the specimen out

    def label(self) -> str:
        where = self.geometry if self.instrument == "spectro" else f"({self.theta_i:g},{self.phi_i:g})"
        col = f" {self.collector}" if self.collector else ""
        wl = self.wavelengths
        span = f"{wl[0]:g}" if len(wl) == 1 else f"{wl[0]:g}..{wl[-1]:g} nm ({len(wl)})"
        return f"#{self.idx} {self.specimen} {where}{col} {span}"


@dataclass(frozen=True)
class SweepSpec:
    """A validated sweep: its name, root seed, instrument, tasks and the dict it came from
    (``source``, stored as the run's plan so that :func:`resume_sweep` rebuilds the same tasks)."""
    name: str
    seed: int
    instrument: str
    tasks: tuple[SweepTask, ...]
    source: dict[str, Any] = field(repr=False, default_factory=dict)

    def __len__(self) -> int:
        return len(self.tasks)


def _canonical_specimen(text: str) -> str:
    return re.sub(r"\s*([:,=])\s*", r"\1", str(text).strip())


def task_key(params: Mapping[str, Any]) -> int:
    """The 64-bit key of a series: BLAKE2b-64 of its canonical parameters as sorted JSON.

    ``params`` holds what defines the random draw: instrument, specimen, incidence (or
    geometry), collector, beam, method, rays, cone -- not the wavelengths (those key the
    per-wavelength streams inside the instrument) and not the task's index.
    """
    text = json.dumps(dict(params), sort_keys=True, separators=(",", ":"))
    return int.from_bytes(hashlib.blake2b(text.encode(), digest_size=8).digest(), "big")


def series_seed(sweep_seed: int, key: int) -> int:
    """The instrument seed of a series: ``SeedSequence(sweep_seed, spawn_key=(key,))`` as a
    63-bit integer (small enough for ``bench gonio --seed``)."""
    ss = np.random.SeedSequence(int(sweep_seed), spawn_key=(int(key),))
    return int(ss.generate_state(1, dtype=np.uint64)[0] & np.uint64((1 << 63) - 1))


def _incidence(v: Any, where: str) -> tuple[float, float]:
    try:
        if isinstance(v, (int, float)) and not isinstance(v, bool):
            parts = [float(v)]
        elif isinstance(v, str):
            parts = [float(p) for p in v.split(",")]
        else:
            parts = [float(p) for p in v]
    except (TypeError, ValueError):
        raise ConfigError(f"{where}: incidence {v!r} must be THETA, [THETA, PHI] or 'THETA,PHI' (deg)") from None
    if len(parts) not in (1, 2) or not all(math.isfinite(p) for p in parts):
        raise ConfigError(f"{where}: incidence {v!r} must be THETA, [THETA, PHI] or 'THETA,PHI' (deg)")
    theta, phi = parts[0], parts[1] if len(parts) == 2 else 0.0
    if not 0.0 <= theta < 90.0:
        raise ConfigError(f"{where}: incidence theta_i = {theta:g} deg must lie in [0, 90)")
    return round(theta, 6), round(phi % 360.0, 6)


def _list(d: Mapping[str, Any], key: str) -> list[Any]:
    """A one-or-many setting as a list (the schema checked it is a value or a non-empty list)."""
    v = d.get(key)
    return [] if v is None else list(v) if isinstance(v, list) else [v]


def load_sweep(path: str | Path) -> SweepSpec:
    """Read and validate a ``SWEEP.toml`` (see :func:`sweep_from_dict`)."""
    d = read_toml(path, "sweep file")
    return sweep_from_dict(d, default_name=Path(path).stem, source=f"sweep file {path}")


def sweep_from_dict(d: Mapping[str, Any], default_name: str = "sweep", source: str = "sweep") -> SweepSpec:
    """Validate a sweep description and cut it into tasks.

    Format (TOML shown; a dict of the same shape works)::
        [sweep]
        name = "ggx-roughness"          # default: the file name
        seed = 20261122                 # default: a fresh seed, stored with the run
        instrument = "gonio"            # "gonio" or "spectro"
        specimens = ["lambert:albedo=0.5", "colorchecker:dark skin"]
        incidences = [0, 30, [60, 90]]  # gonio: THETA or [THETA, PHI] in degrees
        geometries = ["8/d", "45/0"]    # spectro: CIE geometries
        collectors = ["equal-psa:9x36"] # gonio (default equal-psa:9x36)
        wavelengths = "450:650:50"      # START:STOP:STEP, a list, or a number (nm)
        wavelengths_per_task = 1        # 0 = all in one task (the default)
        rays = 2_000_000                # per wavelength; or uncertainty = v (eq. 3.5/3.12)
        delta = 0.01
        method = "rays"                 # gonio: auto | rays | fast
        beam = "collimated"             # or "conical"
        cone_deg = 5.0                  # spectro: viewing / gloss-trap cone (optional)

        [[task]]                        # optional: an explicit list instead of the product;
        specimen = "lambert:albedo=0.9" # each entry is one series and may override any
        incidence = [45, 0]             # [sweep] default (wavelengths, rays, collector, ...)

    Raises
    ------
    ConfigError
        Unknown keys, bad values, specimens that lack a wavelength, duplicate series.
    """
    # the declared shape (bench.core.schemas.SweepFile), checked once: unknown keys with "did you
    # mean", types, non-finite and out-of-range numbers, bounded rays, collectors and wavelengths;
    # what follows reads the validated tables (only the keys the file gave)
    doc: SweepFile = validate_document(SweepFile, d, source)
    s = doc.sweep.model_dump(exclude_unset=True)
    instrument = doc.sweep.instrument
    seed = s["seed"] = fresh_seed() if doc.sweep.seed is None else doc.sweep.seed
    crn = doc.sweep.common_random_numbers
    name = doc.sweep.name if "name" in s else default_name
    # default: a whole spectrum per task -- a goniophotometer's Lambertian or GGX counts its
    # wavelengths in one spectral batch (31 cost 1-3x one), which tasks of one wavelength would forgo
    per_task = doc.sweep.wavelengths_per_task or 0

    entries = None if doc.task is None else [t.model_dump(exclude_unset=True) for t in doc.task]
    if entries is not None:
        series = []
        for j, e in enumerate(entries):
            series.append(({**{k: v for k, v in s.items() if k in _TASK_KEYS}, **e}, f"[[task]] {j}"))
        # a [[task]] may leave specimen/incidence to [sweep] singletons
        for e, where in series:
            for one, many in (("specimen", "specimens"), ("incidence", "incidences"), ("geometry", "geometries"),
                              ("collector", "collectors")):
                if one not in e and many in s:
                    vals = _list(s, many)
                    if len(vals) != 1:
                        raise ConfigError(f"{where}: no {one}, and [sweep] {many} has {len(vals)} values")
                    e[one] = vals[0]
    else:
        specimens = _list(s, "specimens")
        if not specimens:
            raise ConfigError("[sweep]: specimens is required (or give an explicit [[task]] list)")
        series = []
        if instrument == "gonio":
            if "geometries" in s:
                raise ConfigError("[sweep]: geometries are for instrument = 'spectro'; a goniophotometer "
                                  "sweep takes incidences")
            incidences = _list(s, "incidences") or [0.0]
            collectors = _list(s, "collectors") or ["equal-psa:9x36"]
            n = len(specimens) * len(collectors) * len(incidences)
            if n > MAX_SWEEP_SERIES:
                raise ConfigError(f"{source}: {len(specimens)} specimens x {len(collectors)} collectors x "
                                  f"{len(incidences)} incidences = {n:,} series, more than the limit of "
                                  f"{MAX_SWEEP_SERIES:,}")
            for sp in specimens:
                for col in collectors:
                    for inc in incidences:
                        series.append(({**s, "specimen": sp, "collector": col, "incidence": inc}, "[sweep]"))
        else:
            if "incidences" in s or "collectors" in s:
                raise ConfigError("[sweep]: a spectrophotometer sweep takes geometries (CIE names), not "
                                  "incidences or collectors")
            geometries = _list(s, "geometries") or ["8/d"]
            if len(specimens) * len(geometries) > MAX_SWEEP_SERIES:
                raise ConfigError(f"{source}: {len(specimens)} specimens x {len(geometries)} geometries, more "
                                  f"than the limit of {MAX_SWEEP_SERIES:,} series")
            for sp in specimens:
                for g in geometries:
                    series.append(({**s, "specimen": sp, "geometry": g}, "[sweep]"))

    tasks: list[SweepTask] = []
    seen: dict[int, str] = {}
    checked: dict[tuple, Any] = {}
    for e, where in series:
        params, wl = _series(instrument, e, where, parse_wavelengths, checked)
        delta = params.pop("delta")  # intervals only: not part of the random draw
        key = task_key(params)
        label = f"{where}: {params['specimen']} {params.get('incidence') or params.get('geometry')}"
        if key in seen:
            raise ConfigError(f"{label}: the same measurement as {seen[key]} (equal parameters draw the same "
                              f"rays); remove the duplicate or merge their wavelengths")
        seen[key] = label
        # by default each specimen draws its own rays; with common random numbers every specimen of
        # an otherwise equal series shares them (the seed's key and the streams leave it out)
        seed_i = series_seed(seed, task_key({k: v for k, v in params.items() if k != "specimen"}) if crn else key)
        group = len(wl) if per_task == 0 else per_task
        for start in range(0, len(wl), group):
            theta, phi = params.get("incidence") or (params["theta_i"], 0.0)
            tasks.append(SweepTask(
                idx=len(tasks), instrument=instrument, specimen=params["specimen"], theta_i=float(theta),
                phi_i=float(phi), geometry=params.get("geometry"), collector=params.get("collector"),
                wavelengths=tuple(float(w) for w in wl[start:start + group]), rays=params["rays"],
                method=params.get("method", "rays"), beam=params["beam"], delta=delta,
                cone_deg=params.get("cone_deg"), key=key, seed=seed_i, common_random_numbers=crn))
    plan = {"sweep": s, **({"task": [dict(e) for e in entries]} if entries is not None else {})}
    return SweepSpec(name=name, seed=seed, instrument=instrument, tasks=tuple(tasks), source=plan)


def _series(instrument: str, e: Mapping[str, Any], where: str, parse_wavelengths: Callable,
            checked: dict) -> tuple[dict[str, Any], np.ndarray]:
    """Validate one series (building its instrument once per distinct specimen/collector) and
    return its canonical parameters and wavelengths."""
    if "specimen" not in e:
        raise ConfigError(f"{where}: no specimen")
    specimen = _canonical_specimen(e["specimen"])
    try:
        wl = parse_wavelengths(e.get("wavelengths", "550" if instrument == "gonio" else "400:700:10"))
    except InputError as exc:
        raise ConfigError(f"{where}: {exc}") from None
    if len(set(wl.tolist())) != wl.size:
        raise ConfigError(f"{where}: wavelengths repeat")
    beam = e.get("beam", "collimated")
    delta = float(e.get("delta", 0.01))
    try:
        spec = checked.get(("specimen", specimen))
        if spec is None:
            spec = checked[("specimen", specimen)] = parse_specimen(specimen)
        spec.check_wavelengths(wl)
    except InputError as exc:
        raise ConfigError(f"{where}: {exc}") from None
    rays = e.get("rays")
    params: dict[str, Any] = {"instrument": instrument, "specimen": specimen, "beam": beam}
    if instrument == "gonio":
        if "geometry" in e:
            raise ConfigError(f"{where}: 'geometry' is for spectro sweeps; use incidence")
        params["incidence"] = list(_incidence(e.get("incidence", 0.0), where))
        try:
            col = parse_collector(str(e.get("collector", "equal-psa:9x36")))
        except InputError as exc:
            raise ConfigError(f"{where}: {exc}") from None
        params["collector"] = str(col)
        method = e.get("method") or "auto"
        if method == "fast" and not spec.has_density:
            raise ConfigError(f"{where}: method 'fast' needs a specimen with a density; {specimen} has none")
        if rays is None:
            u = e.get("uncertainty")
            rays = hoeffding_rays(float(u), delta, col.n_patches) if u is not None else 10_000_000
        if method == "auto":  # resolve now: the key and the stored rows name the method really used
            # as VirtualGoniophotometer resolves it for the whole series (auto_counts_rays), so that
            # however the wavelengths are cut into tasks, each runs the same method
            batch = isinstance(rays, (int, np.integer)) and auto_counts_rays(spec, Beam(kind=beam), wl.size, int(rays))
            method = "fast" if spec.has_density and beam == "collimated" and not batch else "rays"
        params["method"] = method
    else:
        if "incidence" in e or "collector" in e:
            raise ConfigError(f"{where}: a spectro series takes a geometry, not an incidence or collector")
        try:
            g = cie_geometry(str(e.get("geometry", "8/d")))
        except InputError as exc:
            raise ConfigError(f"{where}: {exc}") from None
        params["geometry"] = g.name
        params["theta_i"] = float(g.reciprocal_directional.theta_i)
        params["cone_deg"] = None if e.get("cone_deg") is None else float(e["cone_deg"])
        if rays is None:
            rays = hoeffding_rays(float(e.get("uncertainty", 0.005)), delta)
    params["rays"] = int(rays)
    params["delta"] = delta
    return params, wl


def task_table(spec: SweepSpec) -> dict[str, list[Any]]:
    """The per-task metadata fixed by the spec, column-wise (lists aligned with the task index):
    :data:`TASK_COLUMNS`. Stored in the run's meta as ``tasks``; :func:`sweep_readings` joins it."""
    def quantity(t: SweepTask) -> str | None:
        if t.geometry is None:
            return None
        directional = cie_geometry(t.geometry).reciprocal_directional.viewing == "directional"
        return "reflectance factor" if directional else "reflectance"

    cols: dict[str, list[Any]] = {c: [] for c in TASK_COLUMNS}
    for t in spec.tasks:
        for c, v in (("specimen", t.specimen), ("collector", t.collector), ("geometry", t.geometry),
                     ("quantity", quantity(t)), ("method", t.method), ("rays", t.rays), ("beam", t.beam),
                     ("task_key", f"{t.key:016x}"), ("series_seed", t.seed)):
            cols[c].append(v)
    return cols

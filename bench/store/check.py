"""Records that refuse to be misread: every field of a stored run is checked as it is read back.

A run store is a file anyone can edit, copy half or damage; a value that does not parse or is out
of range must never be dropped, coerced to NaN or ignored on the way to an export, a catalog or a
fit (a garbled ``uncertainty_budget`` ignored would shrink a fit's interval; a text in a REAL column
coerced to NaN would drop a reading without a word). Each check here raises
:class:`DamagedRun` (a :class:`~bench.core.errors.StoreError`: exit 2) naming the run, the point,
the wavelength and the field, in one line.

* :func:`run_field` -- a JSON column of ``runs`` (``plan``, ``bench``, ``versions``,
  ``calibration``, ``meta``): JSON of the expected type, or refused;
* :func:`check_frame` -- the tidy readings of a run, before any column is coerced: numbers that
  parse, finite, within their ranges (angles in degrees, wavelengths > 0, uncertainties >= 0,
  counts 0 <= count <= N, a value present whenever the reading carries an uncertainty);
* :func:`reading_extra` -- a reading's ``extra`` JSON and the GUM budget it holds;
* :func:`valid_run_id` -- the store's own run-id format (what may become a file name or a URL).
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Mapping
from typing import Any, TypeGuard

import numpy as np

from bench.core.errors import StoreError
from bench.core.parsing import json_problem
from bench.store.schema import RUN_KINDS, RUN_STATUSES

__all__ = ["DamagedRun", "RUN_ID_PATTERN", "valid_run_id", "run_field", "check_run_row", "check_frame",
           "reading_extra", "check_budget"]

#: run ids as the store makes them (``YYYYMMDD-HHMM-xxxx``) or a caller chose them: letters,
#: digits and ``._:-``, starting with a letter or digit, at most 128 characters -- never a ``/``,
#: so an id can name a file or a URL path segment as it is
RUN_ID_PATTERN = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._:-]{0,127}$")

#: the JSON columns of ``runs`` and the type each holds when present
RUN_JSON_FIELDS: dict[str, type] = {"plan": dict, "bench": dict, "versions": dict, "calibration": dict, "meta": dict}

#: numeric reading columns: (lowest, highest) allowed; None = any finite number
_RANGES: dict[str, tuple[float | None, float | None]] = {
    "theta_i": (0.0, 180.0), "theta_r": (0.0, 180.0), "phi_i": (-1e6, 1e6), "phi_r": (-1e6, 1e6),
    "wavelength_nm": (0.0, 1e6), "signal": (None, None), "dark": (None, None), "white": (None, None),
    "value": (None, None), "std": (0.0, None), "ci_lo": (None, None), "ci_hi": (None, None),
    "saturated": (0.0, 1.0), "theta_min": (0.0, 180.0), "theta_max": (0.0, 180.0), "phi_min": (-1e6, 1e6),
    "phi_max": (-1e6, 1e6), "psa": (0.0, None), "count": (0.0, None), "N": (0.0, None),
    "t_start": (None, None), "t_end": (None, None),
}
_INTEGERS = ("saturated", "count", "N")
_REQUIRED = ("theta_i", "phi_i", "wavelength_nm")


class DamagedRun(StoreError):
    """A stored run whose record does not parse or is out of range (named: run, point, field)."""


def valid_run_id(text: Any) -> bool:
    """Whether ``text`` is a run id of the store's own format (:data:`RUN_ID_PATTERN`)."""
    return isinstance(text, str) and RUN_ID_PATTERN.match(text) is not None


def _shown(v: Any, n: int = 40) -> str:
    s = repr(v.item() if isinstance(v, np.generic) else v)
    return s if len(s) <= n else s[:n] + "..."


def _where(run_id: str, idx: Any = None, wl: Any = None) -> str:
    out = f"run {run_id}"
    if idx is not None:
        out += f" point {idx}"
    if wl is not None:
        try:
            out += f" ({float(wl):g} nm)"
        except (TypeError, ValueError):
            pass
    return out


def damaged(run_id: str, what: str, idx: Any = None, wl: Any = None) -> DamagedRun:
    """The one-line error of a damaged field."""
    return DamagedRun(f"{_where(run_id, idx, wl)}: {what}; the stored record is damaged (`bench runs` lists "
                      f"the runs that are not)")


def run_field(run_id: str, field: str, text: Any) -> Any:
    """The JSON column ``field`` of run ``run_id`` decoded (None when NULL); refused when it is not
    JSON or not of the type the store writes there."""
    if text is None:
        return None
    if not isinstance(text, str):
        raise damaged(run_id, f"runs.{field} is {type(text).__name__} {_shown(text)}, not JSON text")
    try:
        value = json.loads(text)
    except ValueError as exc:
        raise damaged(run_id, f"runs.{field} is not JSON ({json_problem(exc, at=True)}: {_shown(text)})") from None
    want = RUN_JSON_FIELDS.get(field)
    if value is not None and want is not None and not isinstance(value, want):
        raise damaged(run_id, f"runs.{field} holds a JSON {type(value).__name__}, not an object")
    return value


def check_run_row(run_id: str, row: Mapping[str, Any]) -> None:
    """The scalar columns of a ``runs`` row: ``kind`` and ``status`` among the store's own, epochs
    finite numbers (or NULL where allowed), ``n_planned`` an integer >= 0, ``seed`` an integer."""
    for key in ("kind", "status", "created_utc"):
        if not isinstance(row.get(key), str):
            raise damaged(run_id, f"runs.{key} is {_shown(row.get(key))}, not text")
    if row["kind"] not in RUN_KINDS:
        raise damaged(run_id, f"runs.kind is {_shown(row['kind'])}, not one of {', '.join(RUN_KINDS)}")
    if row["status"] not in RUN_STATUSES:
        raise damaged(run_id, f"runs.status is {_shown(row['status'])}, not one of {', '.join(RUN_STATUSES)}")
    for key in ("created_epoch", "started_epoch", "finished_epoch"):
        v = row.get(key)
        if (v is not None or key == "created_epoch") and not _finite(v):
            raise damaged(run_id, f"runs.{key} is {_shown(v)}, not a finite number of seconds")
    for key, lo in (("n_planned", 0), ("seed", None)):
        v = row.get(key)
        if v is not None and (not isinstance(v, int) or isinstance(v, bool) or (lo is not None and v < lo)):
            raise damaged(run_id, f"runs.{key} is {_shown(v)}, not an integer" + (f" >= {lo}" if lo is not None else ""))


def _finite(x: Any) -> TypeGuard[float]:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


_INF = math.inf


def _fine(x: Any, lo: float) -> bool:
    """The fast path's test: a float in [lo, inf) (NaN fails); anything else goes the slow way."""
    return type(x) is float and lo <= x < _INF


def _check_components(run_id: str, idx: Any, wl: Any, field: str, comps: list[Any]) -> None:
    """Name the first component of a budget that is not an object with text ``name`` and finite
    numbers (``standard_uncertainty`` and ``contribution`` >= 0)."""
    for j, c in enumerate(comps):
        if not isinstance(c, Mapping):
            raise damaged(run_id, f"{field}.components[{j}] is {_shown(c)}, not an object", idx, wl)
        for key in ("standard_uncertainty", "sensitivity", "contribution"):
            if not _finite(c.get(key)) or (key != "sensitivity" and c[key] < 0):
                raise damaged(run_id, f"{field}.components[{j}].{key} is {_shown(c.get(key))}, not a finite number"
                              + ("" if key == "sensitivity" else " >= 0"), idx, wl)
        if not isinstance(c.get("name"), str):
            raise damaged(run_id, f"{field}.components[{j}].name is {_shown(c.get('name'))}, not text", idx, wl)


def check_budget(run_id: str, idx: Any, wl: Any, budget: Any, std: Any = None) -> dict[str, Any] | None:
    """A reading's GUM budget as stored (:meth:`bench.core.budget.Budget.as_dict`), checked: an
    object with components (each with finite numbers, ``standard_uncertainty >= 0``), finite
    ``combined >= 0``, ``expanded >= 0`` and ``k > 0``, and a ``combined`` equal to the reading's
    ``std`` (the runner stores the budget's u_c as the std). Returns it (None stays None)."""
    if budget is None:
        return None
    field = "extra.uncertainty_budget"
    if not isinstance(budget, Mapping):
        raise damaged(run_id, f"{field} is {_shown(budget)}, not a budget object", idx, wl)
    comps = budget.get("components")
    if not isinstance(comps, list):
        raise damaged(run_id, f"{field}.components is {_shown(comps)}, not a list", idx, wl)
    if not all(type(c) is dict and type(c.get("name")) is str and _fine(c.get("standard_uncertainty"), 0.0)
               and _fine(c.get("sensitivity"), -_INF) and _fine(c.get("contribution"), 0.0) for c in comps):
        _check_components(run_id, idx, wl, field, comps)  # the slow path names what is wrong
    for key, positive in (("combined", False), ("expanded", False), ("k", True)):
        v = budget.get(key)
        if not _finite(v) or v < 0 or (positive and v == 0):
            raise damaged(run_id, f"{field}.{key} is {_shown(v)}, not a finite number {'> 0' if positive else '>= 0'}",
                          idx, wl)
    if std is not None and _finite(std) and not math.isclose(float(budget["combined"]), float(std),
                                                             rel_tol=1e-9, abs_tol=1e-300):
        raise damaged(run_id, f"{field}.combined {budget['combined']!r} disagrees with the reading's std {std!r}",
                      idx, wl)
    return dict(budget)


def reading_extra(run_id: str, idx: Any, wl: Any, text: Any, std: Any = None) -> dict[str, Any]:
    """A reading's ``extra`` JSON decoded ({} when NULL) with its budget checked
    (:func:`check_budget`); refused when it is not a JSON object."""
    if text is None or (isinstance(text, float) and math.isnan(text)):  # NULL (pandas may give NaN)
        return {}
    if not isinstance(text, str):
        raise damaged(run_id, f"readings.extra is {type(text).__name__} {_shown(text)}, not JSON text", idx, wl)
    try:
        extra = json.loads(text)
    except ValueError as exc:
        raise damaged(run_id, f"readings.extra is not JSON ({json_problem(exc)}: {_shown(text)})", idx, wl) from None
    if not isinstance(extra, dict):
        raise damaged(run_id, f"readings.extra holds a JSON {type(extra).__name__}, not an object", idx, wl)
    if "uncertainty_budget" in extra:
        std = None if std is None or (isinstance(std, float) and math.isnan(std)) else std
        extra["uncertainty_budget"] = check_budget(run_id, idx, wl, extra["uncertainty_budget"], std)
    return extra


def check_frame(run_id: str, df: Any) -> None:
    """Check the raw readings frame of a run (columns as SQLite returned them, before coercion):
    every number parses, is finite and in range; integer columns hold integers; the geometry and
    wavelength are present; a reading with an uncertainty has a value; ``count <= N``."""
    import pandas as pd

    if not len(df):
        return
    idx = df["idx"].to_numpy()
    wl = df["wavelength_nm"].to_numpy(object)
    nums: dict[str, np.ndarray] = {}
    for col, (lo, hi) in _RANGES.items():
        if col not in df.columns:
            continue
        raw = df[col]
        num = pd.to_numeric(raw, errors="coerce").to_numpy(float)
        nums[col] = num
        present = raw.notna().to_numpy()
        bad = present & ~np.isfinite(num)
        reason = "not a finite number"
        if col in _REQUIRED:
            missing = ~present
            if missing.any():
                i = int(np.argmax(missing))
                raise damaged(run_id, f"{col} is missing (NULL)", idx[i], wl[i])
        if not bad.any() and col in _INTEGERS:
            bad = present & (num != np.round(num))
            reason = "not an integer"
        if not bad.any():
            with np.errstate(invalid="ignore"):
                out = present & (((num < lo) if lo is not None else False) | ((num > hi) if hi is not None else False))
            if col == "wavelength_nm":
                out = out | (present & (num <= 0))
            bad = out
            reason = (f"outside [{'-inf' if lo is None else f'{lo:g}'}, {'inf' if hi is None else f'{hi:g}'}]"
                      if col != "wavelength_nm" else "not a wavelength > 0 nm")
        if bad.any():
            i = int(np.argmax(bad))
            raise damaged(run_id, f"{col} is {_shown(raw.iloc[i])}, {reason}", idx[i], wl[i])
    if "count" in nums and "N" in nums:
        with np.errstate(invalid="ignore"):
            over = np.isfinite(nums["count"]) & np.isfinite(nums["N"]) & (nums["count"] > nums["N"])
        if over.any():
            i = int(np.argmax(over))
            raise damaged(run_id, f"count {nums['count'][i]:g} exceeds the ray total N {nums['N'][i]:g}", idx[i], wl[i])
    if "value" in nums and "std" in nums:
        lost = ~np.isfinite(nums["value"]) & np.isfinite(nums["std"])
        if lost.any():
            i = int(np.argmax(lost))
            raise damaged(run_id, "value is missing (NULL) though the reading has a std: not a masked reading",
                          idx[i], wl[i])

"""White reference files: a stored reading of the white standard, with its date and the
operator's note, so a run can be calibrated without an operator at the bench.

Owns :class:`WhiteReference`, :func:`write_white_reference` and :func:`read_white_reference`.
The file is a CSV (written by :func:`bench.io.files.write_csv`, atomically)::

    # goniobench-white 1
    # date: 2026-11-30T14:02:11Z
    # operator_note: Spectralon SRS-99 #4471, cleaned, lamp warm 30 min
    # meta: {"date": ..., "operator_note": ..., "bench": ..., "standard": {...}, "white": {...}, "dark": {...}}
    wavelength_nm,signal,std,saturated,dark,dark_std

``meta`` (one line of JSON) is what is read back; its ``origin`` says what measured the white
(body, bench and detector: :func:`bench.calibration_chain.white_origin`), and a run applies the
file only on that body and detector. Files written before origins were recorded read as before
(``origin`` None, :attr:`WhiteReference.lacks` names what they lack); a run refuses them in one
line saying how to take them again; the ``date`` and ``operator_note`` lines are
for people. ``white`` / ``dark`` hold ``integration_s``, ``averages`` and ``timestamp`` of the
two readings (``dark`` is null when the bench has no switchable light; its columns are then
empty). Bad files raise :class:`bench.core.errors.InputError` naming file and line.

Repeated whites (``bench white --repeats N``, a plan's ``white = "repeated"``): the first line is
``# goniobench-white 2``, ``signal``/``std`` are the repeats' mean, the columns ``signal_1, std_1
.. signal_N, std_N`` keep each repeat in the order taken, and ``meta`` has ``"repeats": [{...},
...]`` (their ``integration_s``, ``averages``, ``timestamp``). A repeat is flagged saturated
where the mean is (any repeat saturated). Files of one white (version 1) read as before.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from bench.core.calibration import Calibration, WhiteStandard
from bench.core.errors import InputError
from bench.core.records import json_default
from bench.core.roles import Reading
from bench.io.files import write_csv
from bench.io.reading import bad, read_lines

__all__ = ["WhiteReference", "write_white_reference", "read_white_reference", "WHITE_MAGIC", "WHITE_MAGIC_REPEATS"]

#: the first line of a white reference file (one white), and of one with repeated whites
WHITE_MAGIC = "# goniobench-white 1"
WHITE_MAGIC_REPEATS = "# goniobench-white 2"
_COLUMNS = ["wavelength_nm", "signal", "std", "saturated", "dark", "dark_std"]


@dataclass(frozen=True)
class WhiteReference:
    """A stored white reading (and the dark taken with it), its date and the operator's note."""

    white: Reading
    dark: Reading | None
    date: str
    operator_note: str = ""
    standard: Mapping[str, Any] = field(default_factory=dict)
    bench: str = ""
    path: str = ""
    repeats: tuple[Reading, ...] = ()  # the repeated white readings ``white`` is the mean of
    origin: Mapping[str, Any] | None = None  # body, bench and detector that measured it (None: not recorded)

    @classmethod
    def from_calibration(cls, cal: Calibration, operator_note: str = "", bench: str = "",
                         date: str | None = None) -> "WhiteReference":
        """The reference of a calibration (a fresh one, or a completed run's)."""
        when = date or _dt.datetime.fromtimestamp(cal.white.timestamp, _dt.timezone.utc).strftime(
            "%Y-%m-%dT%H:%M:%SZ")
        return cls(cal.white, cal.white_dark, when, operator_note, cal.standard.as_dict(), bench,
                   repeats=tuple(cal.white_repeats), origin=cal.origin)

    def calibration(self, standard: WhiteStandard) -> Calibration:
        """The calibration of ``standard`` (the bench's ``[white]``) with this stored reading.

        Raises :class:`InputError` when the file was taken at another viewing angle than the
        standard's geometry (its cosine enters every calibrated value)."""
        g = self.standard.get("geometry") if isinstance(self.standard, Mapping) else None
        if isinstance(g, Mapping) and "theta_r" in g and abs(float(g["theta_r"]) - standard.geometry.theta_r) > 1e-6:
            raise InputError(f"{self.path or 'white reference'}: taken at theta_r = {float(g['theta_r']):g} deg, "
                             f"the bench's [white] geometry has theta_r = {standard.geometry.theta_r:g} deg")
        return Calibration(standard, self.white, self.dark, self.repeats, self.origin)

    @property
    def lacks(self) -> list[str]:
        """What an older file does not record (empty for a current one)."""
        o = self.origin
        return [k for k in ("body", "detector") if not isinstance(o, Mapping) or not o.get(k)]

    def provenance(self) -> dict[str, Any]:
        """What a run records about the reference it used."""
        out = {"file": self.path, "date": self.date, "operator_note": self.operator_note, "bench": self.bench,
               "white_integration_s": self.white.integration_s, "white_averages": self.white.averages,
               "body": None if self.origin is None else self.origin.get("body")}
        if self.repeats:
            out["white_repeats"] = len(self.repeats)
        return out


def _reading_meta(r: Reading | None) -> dict[str, Any] | None:
    if r is None:
        return None
    return {"integration_s": r.integration_s, "averages": r.averages, "timestamp": r.timestamp}


def write_white_reference(path: str | Path, ref: WhiteReference) -> Path:
    """Write ``ref`` to ``path`` (CSV, atomically); return the path."""
    import pandas as pd

    w, d = ref.white, ref.dark
    n = w.signal.size
    nan = np.full(n, np.nan)
    table = pd.DataFrame({
        "wavelength_nm": np.asarray(w.wavelengths, float), "signal": np.asarray(w.signal, float),
        "std": nan if w.std is None else np.asarray(w.std, float),
        "saturated": np.asarray(w.saturated, bool).astype(int),
        "dark": nan if d is None else np.asarray(d.signal, float),
        "dark_std": nan if (d is None or d.std is None) else np.asarray(d.std, float)})
    for j, r in enumerate(ref.repeats, start=1):
        table[f"signal_{j}"] = np.asarray(r.signal, float)
        table[f"std_{j}"] = nan if r.std is None else np.asarray(r.std, float)
    meta: dict[str, Any] = {"date": ref.date, "operator_note": ref.operator_note, "bench": ref.bench,
            "standard": dict(ref.standard), "white": _reading_meta(w), "dark": _reading_meta(d)}
    if ref.repeats:
        meta["repeats"] = [_reading_meta(r) for r in ref.repeats]
    if ref.origin is not None:
        meta["origin"] = dict(ref.origin)
    note = " ".join(ref.operator_note.split())  # one line for people; meta keeps it exactly
    header = [WHITE_MAGIC_REPEATS if ref.repeats else WHITE_MAGIC, f"# date: {ref.date}", f"# operator_note: {note}",
              f"# meta: {json.dumps(meta, default=json_default)}"]
    return write_csv(table, path, header_lines=header)


def _float(text: str, p: Path, lineno: int, col: str) -> float:
    try:
        return float(text) if text.strip() != "" else math.nan
    except ValueError:
        raise bad(p, lineno, f"column {col}: not a number: {text!r}") from None


def _positive(meta: Mapping[str, Any], key: str, p: Path, kind: type) -> Any:
    v = meta.get(key)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
        raise bad(p, 4, f"meta: {key} must be a number > 0, got {v!r}")
    return kind(v)


def read_white_reference(path: str | Path) -> WhiteReference:
    """Read a white reference file written by :func:`write_white_reference`.

    Raises
    ------
    InputError
        Missing or unreadable file, not a white reference, a bad number, a negative or
        non-finite white signal, a dark column half filled, no wavelengths.
    """
    p, lines = read_lines(path)
    if not lines or lines[0].strip() not in (WHITE_MAGIC, WHITE_MAGIC_REPEATS):
        raise bad(p, 1, f"not a goniobench white reference (first line must be {WHITE_MAGIC!r} or "
                        f"{WHITE_MAGIC_REPEATS!r})")
    n_rep = 0
    if lines[0].strip() == WHITE_MAGIC_REPEATS:
        n_rep = _repeat_count(p, lines)
    meta_line = next((i for i, ln in enumerate(lines) if ln.startswith("# meta:")), None)
    if meta_line is None:
        raise bad(p, None, "no '# meta:' line")
    try:
        meta = json.loads(lines[meta_line].removeprefix("# meta:"))
    except ValueError as exc:
        raise bad(p, meta_line + 1, f"meta is not JSON ({exc})") from None
    if not isinstance(meta, dict) or not isinstance(meta.get("white"), dict):
        raise bad(p, meta_line + 1, "meta must be a JSON object with a 'white' object")
    columns = _COLUMNS + [f"{c}_{j}" for j in range(1, n_rep + 1) for c in ("signal", "std")]
    body = [(i + 1, ln) for i, ln in enumerate(lines) if ln.strip() and not ln.startswith("#")]
    if not body or [c.strip() for c in body[0][1].split(",")] != columns:
        raise bad(p, body[0][0] if body else None, f"the column header must be {','.join(columns)}")
    rows = []
    for lineno, ln in body[1:]:
        cells = ln.split(",")
        if len(cells) != len(columns):
            raise bad(p, lineno, f"expected {len(columns)} columns, got {len(cells)}")
        rows.append([_float(c, p, lineno, col) for c, col in zip(cells, columns)])
    if not rows:
        raise bad(p, None, "no wavelengths")
    a = np.array(rows, dtype=float)
    wl, sig, std, sat, dark, dstd = a.T[:6]
    if not (np.all(np.isfinite(wl)) and np.all(np.diff(wl) > 0)):
        raise bad(p, None, "wavelength_nm must be finite and increasing")
    if not (np.all(np.isfinite(sig)) and np.all(sig >= 0)):
        raise bad(p, None, "signal must be finite counts >= 0 on every row")
    if not np.all(np.isin(sat, (0.0, 1.0))):
        raise bad(p, None, "saturated must be 0 or 1")
    wm = meta["white"]
    white = Reading(wavelengths=wl, signal=sig, saturated=sat.astype(bool),
                    integration_s=_positive(wm, "integration_s", p, float), averages=_positive(wm, "averages", p, int),
                    timestamp=float(wm.get("timestamp") or 0.0),
                    std=None if np.all(np.isnan(std)) else std)
    dark_reading = None
    if np.any(np.isfinite(dark)):
        dm = meta.get("dark")
        if not np.all(np.isfinite(dark)) or not isinstance(dm, dict):
            raise bad(p, None, "the dark column must be filled on every row (with a 'dark' object in meta) or empty")
        dark_reading = Reading(wavelengths=wl, signal=dark, saturated=np.zeros(wl.size, bool),
                               integration_s=_positive(dm, "integration_s", p, float),
                               averages=_positive(dm, "averages", p, int),
                               timestamp=float(dm.get("timestamp") or 0.0), dark=True,
                               std=None if np.all(np.isnan(dstd)) else dstd)
    date = meta.get("date")
    if not isinstance(date, str) or not date:
        raise bad(p, meta_line + 1, "meta: date is required (when the standard was read)")
    given = meta.get("standard")
    standard: dict[str, Any] = given if isinstance(given, dict) else {}
    repeats = []
    for j in range(n_rep):
        rm = meta["repeats"][j]  # a list of n_rep entries: _repeat_count checked it
        s_j, u_j = a[:, 6 + 2 * j], a[:, 7 + 2 * j]
        if not (isinstance(rm, dict) and np.all(np.isfinite(s_j)) and np.all(s_j >= 0)):
            raise bad(p, None, f"signal_{j + 1} must be finite counts >= 0 on every row (with meta repeats[{j}])")
        repeats.append(Reading(wavelengths=wl, signal=s_j, saturated=sat.astype(bool),
                               integration_s=_positive(rm, "integration_s", p, float),
                               averages=_positive(rm, "averages", p, int), timestamp=float(rm.get("timestamp") or 0.0),
                               std=None if np.all(np.isnan(u_j)) else u_j))
    origin = meta.get("origin")
    if origin is not None and not (isinstance(origin, dict) and isinstance(origin.get("body"), str)
                                   and isinstance(origin.get("detector"), dict)):
        raise bad(p, meta_line + 1, "meta: origin must be an object with a 'body' string and a 'detector' object")
    return WhiteReference(white, dark_reading, date, str(meta.get("operator_note", "")), standard,
                          str(meta.get("bench", "")), str(p), tuple(repeats), origin)


def _repeat_count(p: Path, lines: list[str]) -> int:
    """How many repeats a version-2 file's meta line lists (at least 3)."""
    meta_line = next((i for i, ln in enumerate(lines) if ln.startswith("# meta:")), None)
    try:
        meta = json.loads(lines[meta_line].removeprefix("# meta:")) if meta_line is not None else None
    except ValueError:
        return 0  # the meta check below names it
    reps = meta.get("repeats") if isinstance(meta, dict) else None
    if not isinstance(reps, list) or len(reps) < 3:
        raise bad(p, None if meta_line is None else meta_line + 1,
                  "meta: repeats must list at least 3 repeated white readings in a version 2 file")
    return len(reps)

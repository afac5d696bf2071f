"""Reading a run store back: runs, one run, points, tidy readings, a run as a
:class:`~bench.core.records.BSDFRecord`, and a run's summary (``bench runs``, ``show``, ``export``).

:class:`RunReader` is the read half of :class:`bench.store.RunStore` (a mixin over its connection).
"""

from __future__ import annotations

import json
import sqlite3
from typing import Any, Callable

import numpy as np

from bench.core.errors import StoreError
from bench.core.records import BSDF_COLUMNS, BSDFRecord
from bench.store.owner import owner_state
from bench.store.check import (RUN_JSON_FIELDS, DamagedRun, check_frame, check_run_row, damaged, reading_extra, run_field,
                               valid_run_id)
from bench.store.schema import READING_COLUMNS


__all__ = ["RunReader"]


class RunReader:
    """Read-only queries of a run store; mixed into :class:`bench.store.RunStore`."""

    # what the store this is mixed into provides (declared for the type checker; no code here)
    _db: sqlite3.Connection
    _unknown: Callable[[str], StoreError]
    _status: Callable[[str], str]
    done_indices: Callable[[str], set[int]]

    def _run_row(self, run_id: str) -> dict[str, Any]:
        cur = self._db.execute("SELECT * FROM runs WHERE run_id=?", (run_id,))
        row = cur.fetchone()
        if row is None:
            raise self._unknown(run_id)
        d = dict(zip([c[0] for c in cur.description], row))
        check_run_row(run_id, d)
        for k in RUN_JSON_FIELDS:  # a field that is not JSON of its type names the run and field
            d[k] = run_field(run_id, k, d[k])
        return d

    def runs(self) -> list[dict[str, Any]]:
        """All runs, oldest first: id, kind, status, reason, created/finished (UTC ISO),
        points done and planned (for ``bench runs``)."""
        cur = self._db.execute(
            "SELECT r.run_id, r.kind, r.status, r.reason, r.created_utc, r.finished_utc, r.n_planned, "
            "r.seed, (SELECT COUNT(*) FROM points p WHERE p.run_id = r.run_id) "
            "FROM runs r ORDER BY r.created_epoch, r.run_id")
        keys = ("run_id", "kind", "status", "reason", "created_utc", "finished_utc", "n_planned", "seed",
                "points_done")
        out = [dict(zip(keys, r)) for r in cur.fetchall()]
        for r in out:  # a "running" run whose process was killed: say so (resume still works)
            r["process_gone"] = r["status"] == "running" and owner_state(self._db, r["run_id"]) == "gone"
            r["damaged"] = self._damage(r["run_id"])
        return out

    def _damage(self, run_id: Any) -> str | None:
        """Why a run's own row cannot be read (its id, or a JSON field), or None; a damaged run
        is listed with the reason, never hiding the others."""
        if not valid_run_id(run_id):
            shown = str(run_id).encode("utf-8", "backslashreplace").decode("ascii", "backslashreplace")[:60]
            return f"run id {shown!r} is not of the store's format (letters, digits, '._:-'; no '/')"
        try:
            self._run_row(run_id)
        except DamagedRun as exc:
            return str(exc).split(": ", 1)[-1].split("; the stored record", 1)[0]
        return None

    def run(self, run_id: str) -> dict[str, Any]:
        """A run's metadata (JSON fields decoded), status history and counts
        (``points_done``, ``readings``)."""
        d = self._run_row(run_id)
        d["points_done"] = self._db.execute("SELECT COUNT(*) FROM points WHERE run_id=?", (run_id,)).fetchone()[0]
        d["readings"] = self._db.execute("SELECT COUNT(*) FROM readings WHERE run_id=?", (run_id,)).fetchone()[0]
        d["events"] = [dict(zip(("t_utc", "t_epoch", "status", "reason"), r)) for r in self._db.execute(
            "SELECT t_utc, t_epoch, status, reason FROM run_events WHERE run_id=? ORDER BY rowid", (run_id,))]
        return d

    def points(self, run_id: str) -> Any:
        """The points table of a run (one row per point) as a ``pandas.DataFrame``."""
        import pandas as pd  # lazily: neither a scan loop nor `bench runs` needs pandas

        self._status(run_id)
        return pd.read_sql_query("SELECT idx, theta_i, phi_i, theta_r, phi_r, t_start, t_end, status, n_readings "
                                 "FROM points WHERE run_id=? ORDER BY idx", self._db, params=(run_id,))

    def readings(self, run_id: str, *, expand_extra: bool = True) -> Any:
        """Tidy ``pandas.DataFrame``: one row per point x wavelength (x viewing direction).

        Columns: ``idx, theta_i, phi_i, theta_r, phi_r`` (a row's own viewing direction when it
        has one, else the point's), ``wavelength_nm``, the value columns, ``t_start, t_end,
        point_status``; ``extra`` keys become columns when ``expand_extra`` (else one JSON column).
        Ordered by point index, then insertion order.
        """
        import pandas as pd  # lazily: neither a scan loop nor `bench runs` needs pandas

        df = self._checked_rows(run_id)
        float_cols = [c for c in ("theta_i", "phi_i", "theta_r", "phi_r", "wavelength_nm", "signal", "dark",
                                  "white", "value", "std", "ci_lo", "ci_hi", "theta_min", "theta_max",
                                  "phi_min", "phi_max", "psa", "t_start", "t_end")]
        for c in float_cols:
            df[c] = pd.to_numeric(df[c], errors="coerce").astype(float)
        for c in ("count", "N", "saturated"):
            col = df[c]
            df[c] = col.astype("int64") if len(col) and col.notna().all() else col.astype("Int64")
        if expand_extra:
            extra = df.pop("extra")
            present = extra.notna()
            if present.any():
                parsed = pd.DataFrame([reading_extra(run_id, i, w, x, u) for i, w, x, u in
                                       zip(df["idx"], df["wavelength_nm"], extra, df["std"])], index=df.index)
                for c in parsed.columns:
                    if c not in df.columns:
                        df[c] = parsed[c]
        return df

    def to_record(self, run_id: str) -> BSDFRecord:
        """The run as a :class:`BSDFRecord`: readings mapped onto :data:`BSDF_COLUMNS` (missing
        columns NaN; ``hemisphere`` from ``theta_r`` when not stored) plus the extra columns
        ``idx``, ``signal``, ``dark``, ``white``, ``saturated`` when they hold data. ``meta`` is the
        run's meta with ``run_id, kind, status, seed, plan, bench, calibration, versions`` added."""
        import pandas as pd  # lazily: neither a scan loop nor `bench runs` needs pandas

        df = self.readings(run_id)
        out = pd.DataFrame(index=df.index)
        for c in BSDF_COLUMNS:
            out[c] = df[c] if c in df.columns else np.nan
        if len(df):
            hemi = np.where(df["theta_r"].to_numpy(float) > 90.0, "T", "R")
            out["hemisphere"] = df["hemisphere"].where(df["hemisphere"].notna(), pd.Series(hemi, index=df.index))
        for c in ("idx", "signal", "dark", "white", "saturated"):
            if c in df.columns and (c == "idx" or df[c].notna().any()):
                out[c] = df[c]
        if "uncertainty_budget" in df.columns and df["uncertainty_budget"].notna().any():
            budgets = [b if isinstance(b, dict) else None for b in df["uncertainty_budget"]]
            for col, key in (("u_c", "combined"), ("U", "expanded"), ("k", "k")):
                out[col] = [np.nan if b is None else float(b[key]) for b in budgets]
            out["uncertainty_budget"] = [None if b is None else json.dumps(b) for b in budgets]
        info = self._run_row(run_id)
        meta = dict(info.get("meta") or {})
        for k in ("run_id", "kind", "status", "reason", "seed", "plan", "bench", "calibration", "versions",
                  "created_utc", "finished_utc"):
            meta.setdefault(k, info.get(k))
        return BSDFRecord(out, meta)

    def _check_points(self, run_id: str) -> None:
        """Refuse a run whose readings do not match its points: a point whose stored count of
        readings differs from the rows it has (rows lost or added), or readings of no point."""
        row = self._db.execute(
            "SELECT p.idx, p.n_readings, (SELECT COUNT(*) FROM readings r WHERE r.run_id = p.run_id AND r.idx = p.idx) "
            "AS n FROM points p WHERE p.run_id = ? AND p.n_readings IS NOT (SELECT COUNT(*) FROM readings r "
            "WHERE r.run_id = p.run_id AND r.idx = p.idx) ORDER BY p.idx LIMIT 1", (run_id,)).fetchone()
        if row is not None:
            raise damaged(run_id, f"points.n_readings says {row[1]!r} readings, {row[2]} are stored", row[0])
        row = self._db.execute("SELECT r.idx FROM readings r WHERE r.run_id = ? AND NOT EXISTS (SELECT 1 FROM points p "
                               "WHERE p.run_id = r.run_id AND p.idx = r.idx) LIMIT 1", (run_id,)).fetchone()
        if row is not None:
            raise damaged(run_id, "readings are stored for a point that is not (no points row)", row[0])

    def masked_readings(self, run_id: str) -> dict[str, int]:
        """How many readings of a run have no value, by the mask reason stored with them
        ("no value" for those stored without one)."""
        self._status(run_id)
        rows = self._db.execute(
            "SELECT CASE WHEN json_valid(extra) THEN json_extract(extra, '$.extra.mask') END, COUNT(*) FROM readings "
            "WHERE run_id = ? AND value IS NULL GROUP BY 1", (run_id,)).fetchall()
        return {("no value" if why is None else str(why)): int(n) for why, n in rows}

    def _checked_rows(self, run_id: str) -> Any:
        """The raw readings rows of a run (a DataFrame, columns as SQLite returned them), the
        points and every number checked before any coercion: a text or an out-of-range number
        is named (:func:`bench.store.check.check_frame`), never turned into NaN."""
        import pandas as pd

        self._status(run_id)
        value_cols = [c for c in READING_COLUMNS if c not in ("wavelength_nm", "theta_r", "phi_r")]
        sql = ("SELECT r.idx AS idx, p.theta_i AS theta_i, p.phi_i AS phi_i, "
               "COALESCE(r.theta_r, p.theta_r) AS theta_r, COALESCE(r.phi_r, p.phi_r) AS phi_r, "
               "r.wavelength_nm AS wavelength_nm, "
               + ", ".join(f"r.{c} AS {c}" for c in value_cols)
               + ", p.t_start AS t_start, p.t_end AS t_end, p.status AS point_status, r.extra AS extra "
               "FROM readings r JOIN points p ON p.run_id = r.run_id AND p.idx = r.idx "
               "WHERE r.run_id = ? ORDER BY r.idx, r.rowid")
        df = pd.read_sql_query(sql, self._db, params=(run_id,))
        self._check_points(run_id)
        check_frame(run_id, df)
        return df

    def check_run(self, run_id: str) -> None:
        """Read every field of a run and refuse it (:class:`bench.store.check.DamagedRun`, one line
        naming run, point and field) if anything does not parse or is out of range (its
        ``extra`` JSON and budgets are checked as :meth:`reading_budgets` reads them)."""
        self._run_row(run_id)
        df = self._checked_rows(run_id)
        for i, w, x, u in zip(df["idx"], df["wavelength_nm"], df["extra"], df["std"]):
            reading_extra(run_id, i, w, x, u)

    def reading_budgets(self, run_id: str) -> list[dict[str, Any]]:
        """Each reading's geometry, wavelength, value and ``uncertainty_budget`` (None for a reading
        stored without one: masked, uncalibrated, or from a store older than the budgets)."""
        self._status(run_id)
        rows = self._db.execute(
            "SELECT r.idx, p.theta_i, p.phi_i, COALESCE(r.theta_r, p.theta_r), COALESCE(r.phi_r, p.phi_r), "
            "r.wavelength_nm, r.value, r.std, r.extra FROM readings r JOIN points p ON p.run_id = r.run_id "
            "AND p.idx = r.idx WHERE r.run_id = ? ORDER BY r.idx, r.rowid", (run_id,)).fetchall()
        out = []
        for idx, ti, pi_, tr, pr, wl, value, std, extra in rows:
            budget = reading_extra(run_id, idx, wl, extra, std).get("uncertainty_budget")
            out.append({"idx": idx, "theta_i": ti, "phi_i": pi_, "theta_r": tr, "phi_r": pr, "wavelength_nm": wl,
                        "value": value, "std": std, "uncertainty_budget": budget})
        return out

    def summary(self, run_id: str) -> dict[str, Any]:
        """What ``bench show`` prints: status, reason, points done / planned, wavelengths,
        geometry ranges, timings and value range with its smallest standard uncertainty (all
        JSON-serialisable)."""
        info = self._run_row(run_id)
        db = self._db
        n_pts, n_read = db.execute(
            "SELECT COUNT(*), COALESCE(SUM(n_readings), 0) FROM points WHERE run_id=?", (run_id,)).fetchone()
        first, last, t_sum, t_max = db.execute(
            "SELECT MIN(t_start), MAX(t_end), SUM(t_end - t_start), MAX(t_end - t_start) FROM points "
            "WHERE run_id=?", (run_id,)).fetchone()
        geo = {}
        for k in ("theta_i", "phi_i"):
            lo, hi = db.execute(f"SELECT MIN({k}), MAX({k}) FROM points WHERE run_id=?", (run_id,)).fetchone()
            geo[k] = [lo, hi]
        for k in ("theta_r", "phi_r"):
            lo, hi = db.execute(f"SELECT MIN(COALESCE(r.{k}, p.{k})), MAX(COALESCE(r.{k}, p.{k})) FROM readings r "
                                f"JOIN points p ON p.run_id=r.run_id AND p.idx=r.idx WHERE r.run_id=?",
                                (run_id,)).fetchone()
            geo[k] = [lo, hi]
        wl = [r[0] for r in db.execute("SELECT DISTINCT wavelength_nm FROM readings WHERE run_id=? "
                                       "ORDER BY wavelength_nm", (run_id,))]
        vmin, vmax, n_val, n_sat, std_min = db.execute(
            "SELECT MIN(value), MAX(value), COUNT(value), COALESCE(SUM(saturated), 0), MIN(NULLIF(std, 0)) "
            "FROM readings WHERE run_id=?", (run_id,)).fetchone()
        missing = None
        if info["n_planned"] is not None:
            done = self.done_indices(run_id)
            planned = (info.get("meta") or {}).get("order")  # a plan that skips unreachable points lists the rest
            missing = sorted(set(planned if planned is not None else range(info["n_planned"])) - done)
        end = info["finished_epoch"] if info["finished_epoch"] is not None else last
        return {
            "run_id": run_id, "kind": info["kind"], "status": info["status"], "reason": info["reason"],
            "points_done": n_pts, "points_planned": info["n_planned"],
            "points_missing": None if missing is None else len(missing),
            "first_missing": None if not missing else missing[0],
            "readings": n_read,
            "wavelengths": {"n": len(wl), "min": wl[0] if wl else None, "max": wl[-1] if wl else None},
            "geometry": geo,
            "timing": {"created_utc": info["created_utc"], "started_utc": info["started_utc"],
                       "finished_utc": info["finished_utc"],
                       "elapsed_s": None if end is None else end - info["started_epoch"],
                       "first_point_epoch": first, "last_point_epoch": last,
                       "mean_point_s": None if not n_pts or t_sum is None else t_sum / n_pts,
                       "max_point_s": t_max},
            "value": {"min": vmin, "max": vmax, "n": n_val, "n_missing": n_read - n_val, "std_min": std_min},
            "saturated": n_sat, "seed": info["seed"],
            "calibration_steps": (info.get("meta") or {}).get("calibration_steps"),
        }



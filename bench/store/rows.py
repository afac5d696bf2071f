"""Store rows: turning a point's readings (dicts or a DataFrame) into the tuples one
``executemany`` inserts, fast for the common numeric case, with a clear error for a bad value.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Mapping
from typing import Any

import numpy as np

from bench.core.errors import InputError
from bench.store.schema import _INT_COLUMNS, _POINT_LEVEL, READING_COLUMNS, _dumps, _py


_INSERT_READING = (f"INSERT INTO readings (run_id, idx, {', '.join(READING_COLUMNS)}, extra) "
                   f"VALUES ({', '.join('?' * (len(READING_COLUMNS) + 3))})")


_FAST_TYPES = frozenset({float, int, bool, type(None), np.float64})
_NUMERIC = READING_COLUMNS[:-1]  # hemisphere (text) is last
_KNOWN_KEYS = frozenset(READING_COLUMNS) | _POINT_LEVEL


def _reading_tuples(run_id: str, idx: int, rows: Any) -> list[tuple]:
    """Rows (list of mappings or a DataFrame) as tuples for ``_INSERT_READING``.

    The common case (plain floats/ints/bools, a string hemisphere, no other keys) takes a fast
    path; anything else (numpy scalars, extra keys) is converted value by value. NaN is bound
    as is: SQLite stores a NaN as NULL.
    """
    pd = sys.modules.get("pandas")  # a DataFrame implies pandas is loaded; a scan loop needn't load it
    if pd is not None and isinstance(rows, pd.DataFrame):
        return _frame_tuples(run_id, idx, rows)
    if isinstance(rows, Mapping):
        raise InputError(f"run {run_id!r} point {idx}: rows must be a list of dicts or a DataFrame, "
                         f"got one mapping")
    out = []
    fast = _FAST_TYPES
    for j, r in enumerate(rows):
        if type(r) is not dict and not isinstance(r, Mapping):
            raise InputError(f"run {run_id!r} point {idx}: reading {j} is {type(r).__name__}, not a mapping")
        nums = tuple(map(r.get, _NUMERIC))
        hem = r.get("hemisphere")
        if (fast.issuperset(map(type, nums)) and (hem is None or type(hem) is str)
                and _KNOWN_KEYS.issuperset(r.keys())):
            if nums[0] is None:
                raise InputError(f"run {run_id!r} point {idx}: reading {j} has no wavelength_nm")
            out.append((run_id, idx, *nums, hem, None))
            continue
        vals: list[Any] = []
        for c, v in zip(_NUMERIC, nums):
            v = _py(v)
            if v is not None:
                v = int(v) if c in _INT_COLUMNS else _num(run_id, idx, c, v)
            vals.append(v)
        if vals[0] is None:
            raise InputError(f"run {run_id!r} point {idx}: reading {j} has no wavelength_nm")
        hem = _py(hem)
        extra = {k: _py(v) for k, v in r.items() if k not in _KNOWN_KEYS}
        out.append((run_id, idx, *vals, None if hem is None else str(hem), _dumps(extra) if extra else None))
    return out


def _frame_tuples(run_id: str, idx: int, rows: Any) -> list[tuple]:
    names = [str(c) for c in rows.columns]
    if "wavelength_nm" not in names:
        raise InputError(f"run {run_id!r} point {idx}: readings have no wavelength_nm column")
    n = len(rows)
    columns: list[list[float | int | str | None]] = []  # one list per reading column
    for c in READING_COLUMNS:
        if c not in rows.columns:
            columns.append([None] * n)
            continue
        v = rows[c]
        if c in _INT_COLUMNS:
            columns.append([None if x is None or (isinstance(x, float) and math.isnan(x)) else int(x)
                            for x in v.tolist()])
        elif c == "hemisphere":
            columns.append([None if x is None or (isinstance(x, float) and math.isnan(x)) else str(x)
                            for x in v.tolist()])
        else:
            try:
                vals = v.to_numpy(dtype=float, na_value=np.nan)
            except (TypeError, ValueError):
                vals = np.asarray([_num(run_id, idx, c, x) for x in v.tolist()], dtype=float)
            columns.append(vals.tolist())
    extra_names = [c for c in names if c not in _KNOWN_KEYS]
    if extra_names:
        recs = rows[extra_names].to_dict("records")
        extras = [_dumps({k: _py(v) for k, v in r.items()}) for r in recs]
    else:
        extras = [None] * n
    if any(x is None or x != x for x in columns[0]):
        raise InputError(f"run {run_id!r} point {idx}: a reading has no wavelength_nm")
    return [(run_id, idx, *vals, ex) for *vals, ex in zip(*columns, extras)]


def _num(run_id: str, idx: int, col: str, v: Any) -> float | None:
    if v is None:
        return None
    try:
        f = float(v)
    except (TypeError, ValueError):
        raise InputError(f"run {run_id!r} point {idx}: {col} must be a number, got {v!r}") from None
    return None if math.isnan(f) else f

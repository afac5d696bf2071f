"""Parsing of user inputs shared by every layer: TOML files, ranges, wavelength lists.

One place for each: :func:`read_toml` (every file the user gives goes through it, so an
unreadable, non-UTF-8 or malformed file is one :class:`ConfigError` naming it),
:func:`json_problem` (what ``json.loads`` refused, for the one line naming the file or field),
:func:`parse_range` (a number, a list or a ``{start, stop, step}`` table) and
:func:`parse_wavelengths` (``START:STOP:STEP``, ``a,b,c`` or one number, in nm). Sizes are
bounded (:data:`MAX_RANGE_POINTS`) so a typo cannot ask for an unbounded amount of work.
"""

from __future__ import annotations

import json
import math
import re
import sys
import tomllib
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from bench.core.errors import ConfigError, InputError

__all__ = ["read_toml", "read_text", "json_problem", "parse_range", "parse_wavelengths", "check_collector_spec",
           "MAX_RANGE_POINTS", "MAX_WAVELENGTHS", "MAX_COLLECTOR_PATCHES", "WAVELENGTH_RANGE_NM",
           "check_wavelength_units", "looks_like_radians"]

#: the most values one range may expand to (a plan axis, a wavelength grid)
MAX_RANGE_POINTS = 100_000
#: the most wavelengths one measurement may ask for
MAX_WAVELENGTHS = 10_000
#: the most patches one collector may have (rings x sectors per hemisphere)
MAX_COLLECTOR_PATCHES = 1_000_000

_LONG_INT = re.compile(r"value has (\d+) digits")
_COLLECTOR_SPEC = re.compile(r"^\s*([A-Za-z][A-Za-z-]*)\s*:\s*(\d{1,9})\s*[xX*]\s*(\d{1,9})\s*$")


def read_text(path: str | Path, what: str = "file") -> str:
    """The text of a user-given file; every way of failing to read it is one :class:`InputError`
    naming the file (missing, a directory, no permission, a symlink loop, not UTF-8)."""
    p = Path(path)
    try:
        return p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(f"{what} {p} does not exist") from None
    except IsADirectoryError:
        raise InputError(f"{what} {p} is a directory, not a file") from None
    except PermissionError:
        raise InputError(f"{what} {p}: permission denied") from None
    except UnicodeDecodeError as exc:
        raise InputError(f"{what} {p} is not UTF-8 text (byte {exc.start}: {exc.object[exc.start]:#04x})") from None
    except OSError as exc:
        raise InputError(f"{what} {p}: {exc.strerror or exc}") from None


def json_problem(exc: ValueError, at: bool = False) -> str:
    """What ``json.loads`` refused: its message (and position, ``at``). A number longer than
    ``int()`` takes (Python's 4300-digit limit) is a plain ValueError without either, and bytes
    that are not UTF-8 a UnicodeDecodeError: so every reader of JSON catches ValueError, not only
    JSONDecodeError, and words it with this."""
    if isinstance(exc, UnicodeDecodeError):
        return f"not UTF-8 (byte {exc.start}: {exc.object[exc.start]:#04x})"
    if not isinstance(exc, json.JSONDecodeError):
        long = _LONG_INT.search(str(exc))
        return (f"an integer of {long.group(1)} digits, more than the {sys.get_int_max_str_digits()} "
                f"Python reads" if long else str(exc))
    return f"{exc.msg} at character {exc.pos}" if at else exc.msg


def read_toml(path: str | Path, what: str = "config file") -> dict[str, Any]:
    """Read a TOML file; a missing, unreadable or malformed file is a :class:`ConfigError` naming it."""
    p = Path(path)
    try:
        text = read_text(p, what)
    except InputError as exc:
        raise ConfigError(str(exc)) from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{what} {p}: {exc}") from None


def _finite(x: Any, where: str) -> float:
    try:
        v = float(x)
    except (TypeError, ValueError, OverflowError):
        raise ConfigError(f"{where}: expected a number, got {x!r}") from None
    if isinstance(x, bool) or not math.isfinite(v):
        raise ConfigError(f"{where}: expected a finite number, got {x!r}")
    return v


def _grid(start: float, stop: float, step: float, where: str, limit: int) -> np.ndarray:
    if step <= 0 or stop < start:
        raise ConfigError(f"{where}: need start <= stop and step > 0, got start={start:g}, stop={stop:g}, step={step:g}")
    n = int(math.floor((stop - start) / step + 1e-9)) + 1
    if n > limit:
        raise ConfigError(f"{where}: start={start:g}, stop={stop:g}, step={step:g} gives {n:,} values, "
                          f"more than the limit of {limit:,}")
    return start + step * np.arange(n)


def parse_range(value: Any, where: str, limit: int = MAX_RANGE_POINTS) -> list[float]:
    """A number, a list of numbers or a ``{start, stop, step}`` table (stop included when on the
    grid) as a list of floats; anything else is a :class:`ConfigError` naming ``where``."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return [_finite(value, where)]
    if isinstance(value, Mapping):
        missing = [k for k in ("start", "stop", "step") if k not in value]
        if missing:
            raise ConfigError(f"{where}: a range table needs start, stop and step (missing {', '.join(missing)})")
        extra = sorted(set(value) - {"start", "stop", "step"})
        if extra:
            raise ConfigError(f"{where}: unknown key {extra[0]!r} in a range table (accepted: start, stop, step)")
        start, stop, step = (_finite(value[k], f"{where}.{k}") for k in ("start", "stop", "step"))
        return [round(float(v), 10) for v in _grid(start, stop, step, where, limit)]
    if isinstance(value, Sequence) and not isinstance(value, str):
        if len(value) == 0:
            raise ConfigError(f"{where}: an empty list gives no values")
        if len(value) > limit:
            raise ConfigError(f"{where}: {len(value):,} values, more than the limit of {limit:,}")
        return [_finite(v, f"{where}[{i}]") for i, v in enumerate(value)]
    raise ConfigError(f"{where}: expected a number, a list or a {{start, stop, step}} table, got {value!r}")


def parse_wavelengths(text: Any, limit: int = MAX_WAVELENGTHS) -> np.ndarray:
    """``START:STOP:STEP`` (inclusive of STOP when on the grid), ``a,b,c``, one number or a list (nm)."""
    where = f"wavelengths {text!r}"
    try:
        if isinstance(text, (list, tuple, np.ndarray)):
            wl = np.asarray([_finite(v, where) for v in np.ravel(np.asarray(text, dtype=object))], dtype=float)
            if wl.size > limit:
                raise ConfigError(f"{where}: {wl.size:,} wavelengths, more than the limit of {limit:,}")
        else:
            s = str(text).strip()
            if ":" in s:
                parts = s.split(":")
                if len(parts) != 3:
                    raise ConfigError(f"{where}: expected START:STOP:STEP, a list a,b,c or one number (nm)")
                start, stop, step = (_finite(p, where) for p in parts)
                wl = _grid(start, stop, step, where, limit)
            else:
                items = [p for p in s.split(",") if p.strip()]
                if len(items) > limit:
                    raise ConfigError(f"{where}: {len(items):,} wavelengths, more than the limit of {limit:,}")
                wl = np.array([_finite(p, where) for p in items], dtype=float)
    except ConfigError as exc:
        raise InputError(str(exc)) from None
    if wl.ndim != 1 or wl.size == 0 or np.any(wl <= 0):
        raise InputError(f"wavelengths must be a non-empty list of positive numbers (nm), got {text!r}")
    check_wavelength_units(wl, where)
    return wl


#: the wavelengths (nm) any input may name: far UV to far IR; outside is a unit slip
WAVELENGTH_RANGE_NM = (100.0, 1e5)


def check_wavelength_units(wl: np.ndarray, where: str) -> None:
    """Refuse wavelengths outside :data:`WAVELENGTH_RANGE_NM` with a hint at the unit they look
    like (``0.55`` is um, ``5.5e-7`` is m): wavelengths are in nm everywhere."""
    lo, hi = WAVELENGTH_RANGE_NM
    bad = wl[(wl < lo) | (wl > hi)]
    if not bad.size:
        return
    x = float(bad[0])
    if x < 1e-3:
        hint = f"{x:g} looks like metres ({x * 1e9:g} nm)"
    elif x <= 30:
        hint = f"{x:g} looks like um ({x * 1e3:g} nm)"
    elif x > hi:
        hint = f"{x:g} is beyond the far infrared; pm or Angstrom? ({x / 1e3:g} or {x / 10:g} nm)"
    else:
        hint = f"{x:g} nm is below the vacuum ultraviolet"
    raise InputError(f"{where}: wavelengths are in nm, {lo:g} to {hi:g}; {hint}")


def looks_like_radians(angles: Any) -> bool:
    """Whether angles meant in degrees all look like radians: every one within 2 pi, not all
    zero, and one at least not a whole number (0.5, 1.2 ...; whole small degrees are common)."""
    a = np.abs(np.asarray([float(x) for x in np.ravel(np.asarray(angles, dtype=object))], dtype=float))
    a = a[np.isfinite(a)]
    return bool(a.size and a.max() > 0 and a.max() <= 2 * np.pi and np.any(a != np.round(a)))


def check_collector_spec(text: Any) -> tuple[str, int, int]:
    """``SCHEME:RINGSxSECTORS`` as ``(scheme, rings, sectors)``, with at most
    :data:`MAX_COLLECTOR_PATCHES` patches (the scheme name itself is checked by the collector)."""
    m = _COLLECTOR_SPEC.match(text) if isinstance(text, str) else None
    if not m:
        raise InputError(f"collector {text!r}: expected SCHEME:RINGSxSECTORS such as equal-psa:9x36")
    rings, sectors = int(m.group(2)), int(m.group(3))
    if rings < 1 or sectors < 1 or rings * sectors > MAX_COLLECTOR_PATCHES:
        raise InputError(f"collector {text!r}: {rings:,} x {sectors:,} = {rings * sectors:,} patches; expected "
                         f"1 to {MAX_COLLECTOR_PATCHES:,}")
    return m.group(1), rings, sectors

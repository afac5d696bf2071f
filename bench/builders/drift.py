"""The declared drift of a simulated bench (``[drift]``, :class:`bench.core.schemas.DriftTable`):
what the virtual and emulated bodies make of it on the day they simulate. Only declared effects
are simulated; a description without ``[drift]`` is the bench of every day (the real body refuses
one: :func:`bench.config.load_description`)."""

from __future__ import annotations

import datetime as dt
import hashlib
from typing import Any, Mapping

from bench.core.schemas import DriftTable
from bench.core.validation import validate_document

__all__ = ["white_factor", "actual_white", "on_day", "day_seed"]


def _table(d: Mapping[str, Any]) -> DriftTable | None:
    raw = d.get("drift")
    return None if raw is None else validate_document(DriftTable, raw, "bench config [drift]")


def white_factor(d: Mapping[str, Any]) -> float:
    """The working white's actual reflectance over its certificate's on the simulated day."""
    t = _table(d)
    if t is None or not t.white_per_day:
        return 1.0
    day = dt.date.fromisoformat(t.on) if t.on else dt.datetime.now(dt.timezone.utc).date()
    days = max(0, (day - dt.date.fromisoformat(t.start)).days)
    return max(0.0, 1.0 + t.white_per_day * days)


def actual_white(reflectance_factor: Any, d: Mapping[str, Any]) -> Any:
    """The white a simulated body shows its detector: the certificate's factor (a number or
    ``[[nm...], [factor...]]``) times :func:`white_factor`."""
    f = white_factor(d)
    if f == 1.0:
        return reflectance_factor
    if isinstance(reflectance_factor, (int, float)):
        return float(reflectance_factor) * f
    nm, rf = reflectance_factor
    return [list(nm), [float(x) * f for x in rf]]


def on_day(d: Mapping[str, Any], day: str | None) -> dict[str, Any]:
    """``d`` simulated on ``day`` (ISO date): its ``[drift]`` told the day; unchanged without either."""
    out = dict(d)
    if day is not None and out.get("drift") is not None:
        out["drift"] = {**dict(out["drift"]), "on": day}
    return out


def day_seed(d: Mapping[str, Any], day: str | None, seed: int | None) -> int | None:
    """The noise seed of a simulated day: ``seed`` when given; else, for a ``--date``, one derived
    from the bench's own seed (``seed`` or ``[emulated] seed``) and the day, so each simulated day
    draws noise of its own (a bench with a fixed seed would otherwise repeat one day's noise every
    day, and a chart of those days has no spread) and the same day draws the same again."""
    if seed is not None or day is None:
        return seed
    base = d.get("seed", (d.get("emulated") or {}).get("seed", 0))
    digest = hashlib.sha256(f"{base}:{day}".encode()).digest()
    return int.from_bytes(digest[:8], "little") >> 1  # 63 bits, as every seed

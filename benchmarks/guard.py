"""The performance-regression guard: ratios measured in one run against the last accepted ones.

Ratios (ours against the Mitsuba-LLVM anchor, or against our own Lambertian kernel) rather than
rays/s, so a slower or busier machine does not trip it; a ratio more than :data:`TOLERANCE`
below its accepted value fails. Ratios absent from either side are listed, not judged (e.g. the
Mitsuba rows on a machine without libLLVM).
"""

from __future__ import annotations

import json
from pathlib import Path

__all__ = ["ACCEPTED", "TOLERANCE", "check", "accept", "load"]

ACCEPTED = Path(__file__).with_name("accepted_ratios.json")
#: A ratio may fall this much (relative) before the guard fails.
TOLERANCE = 0.25


def load(path: Path = ACCEPTED) -> dict[str, float]:
    """The accepted ratios (empty when the file does not exist)."""
    if not path.exists():
        return {}
    return {k: float(v) for k, v in json.loads(path.read_text())["ratios"].items()}


def check(ratios: dict[str, float], accepted: dict[str, float] | None = None,
          tolerance: float = TOLERANCE) -> tuple[int, str]:
    """``(exit code, report)``: 1 when any ratio is below ``(1 - tolerance)`` x its accepted value."""
    acc = load() if accepted is None else accepted
    lines, failed = [], 0
    for name in sorted(set(acc) | set(ratios)):
        old, new = acc.get(name), ratios.get(name)
        if old is None or new is None:
            lines.append(f"  {name}: {'not measured now' if new is None else 'new (no accepted value)'}")
            continue
        bad = new < (1.0 - tolerance) * old
        failed += bad
        lines.append(f"  {'FAIL' if bad else 'ok  '} {name}: {new:.3g} (accepted {old:.3g}, {new / old - 1:+.0%})")
    head = (f"perf guard: {failed} ratio(s) fell more than {tolerance:.0%}" if failed
            else f"perf guard: no ratio fell more than {tolerance:.0%}")
    return (1 if failed else 0), "\n".join([head, *lines])


def accept(ratios: dict[str, float], path: Path = ACCEPTED) -> Path:
    """Write ``ratios`` as the accepted ones."""
    path.write_text(json.dumps({"ratios": dict(sorted(ratios.items()))}, indent=2) + "\n")
    return path

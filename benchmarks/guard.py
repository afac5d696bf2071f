"""The performance-regression guard: ratios measured in one run against the last accepted ones
*for the same family of CPU*.

Ratios (ours against the Mitsuba-LLVM anchor, or against our own Lambertian kernel) rather than
rays/s, so a slower or busier machine does not trip it; a ratio more than :data:`TOLERANCE`
below its accepted value fails. The accepted ratios are kept per CPU family (:func:`family`):
Intel and AMD cores with AVX-512 and code for AVX2 run the same kernels at different ratios to
Dr.Jit's, so one machine's values would fail another's honest run. Ratios absent from either
side are listed, not judged (e.g. the Mitsuba rows on a machine without libLLVM, or a family
nobody has accepted yet).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

__all__ = ["ACCEPTED", "TOLERANCE", "FAMILIES", "family", "check", "accept", "load"]

ACCEPTED = Path(__file__).with_name("accepted_ratios.json")
#: A ratio may fall this much (relative) before the guard fails.
TOLERANCE = 0.25
#: The CPU families ratios are accepted for.
FAMILIES = ("intel-avx512", "amd-avx512", "avx2")


def family(cpu: dict[str, Any]) -> str:
    """The family of a benchmark's ``cpu`` (its JSON's ``cpu``): the code's ISA (``compiled_isa``,
    which ``--isa avx2`` narrows) and, for AVX-512 code, the vendor."""
    isa = cpu.get("compiled_isa") or cpu.get("vector_isa")
    if isa == "avx512":
        return "amd-avx512" if cpu.get("vendor") == "AuthenticAMD" else "intel-avx512"
    return "avx2"


def _families(path: Path) -> dict[str, dict[str, float]]:
    if not path.exists():
        return {}
    return {f: {k: float(v) for k, v in ratios.items()}
            for f, ratios in json.loads(path.read_text())["families"].items()}


def load(fam: str, path: Path = ACCEPTED) -> dict[str, float]:
    """The accepted ratios of CPU family ``fam`` (empty when none were accepted for it)."""
    return _families(path).get(fam, {})


def check(ratios: dict[str, float], accepted: dict[str, float],
          tolerance: float = TOLERANCE) -> tuple[int, str]:
    """``(exit code, report)``: 1 when any ratio is below ``(1 - tolerance)`` x its accepted value."""
    lines, failed = [], 0
    for name in sorted(set(accepted) | set(ratios)):
        old, new = accepted.get(name), ratios.get(name)
        if old is None or new is None:
            lines.append(f"  {name}: {'not measured now' if new is None else 'new (no accepted value)'}")
            continue
        bad = new < (1.0 - tolerance) * old
        failed += bad
        lines.append(f"  {'FAIL' if bad else 'ok  '} {name}: {new:.3g} (accepted {old:.3g}, {new / old - 1:+.0%})")
    head = (f"perf guard: {failed} ratio(s) fell more than {tolerance:.0%}" if failed
            else f"perf guard: no ratio fell more than {tolerance:.0%}")
    return (1 if failed else 0), "\n".join([head, *lines])


def accept(ratios: dict[str, float], fam: str, path: Path = ACCEPTED) -> Path:
    """Write ``ratios`` as the accepted ones of CPU family ``fam`` (the other families kept)."""
    if fam not in FAMILIES:
        raise ValueError(f"CPU family must be one of {', '.join(FAMILIES)}, got {fam!r}")
    families = _families(path)
    families[fam] = dict(sorted(ratios.items()))
    path.write_text(json.dumps({"families": dict(sorted(families.items()))}, indent=2) + "\n")
    return path

"""The JSON of ``bench gonio --json`` read back as a record: one incidence, the first wavelength,
every patch with its count and the ray total (so a fit can use the counts' likelihood).

The JSON carries each patch's bounds and centre, the collector, the beam and the specimen; the
patches' ray total is ``N - missed`` (what the tidy record's ``N`` column holds).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from bench.core.records import BSDF_COLUMNS, BSDFRecord
from bench.io.reading import bad, read_lines

__all__ = ["read_gonio_json", "is_gonio_json"]

_NEEDED = ("N", "incidence", "wavelength_nm", "collector", "missed", "patches")


def is_gonio_json(first_line: str) -> bool:
    """Whether a file's first line starts the JSON of ``bench gonio --json``."""
    return first_line.lstrip().startswith('{"N":')


def read_gonio_json(path: str | Path) -> BSDFRecord:
    """Read ``bench gonio --json`` output into a :class:`BSDFRecord` (one wavelength)."""
    import pandas as pd

    p, lines = read_lines(path)
    try:
        doc: Any = json.loads("\n".join(lines))
    except json.JSONDecodeError as e:
        raise bad(p, e.lineno, f"not JSON ({e.msg})") from None
    except ValueError as e:  # a number longer than int() takes: a plain ValueError, no line
        raise bad(p, None, f"not JSON ({e})") from None
    missing = [k for k in _NEEDED if not isinstance(doc, dict) or k not in doc]
    if missing:
        raise bad(p, None, f"not the JSON of bench gonio: no key(s) {', '.join(missing)}")
    theta_i, phi_i = (float(v) for v in doc["incidence"])
    hits = int(doc["N"]) - int(doc["missed"])
    try:
        rows = [{"wavelength_nm": float(doc["wavelength_nm"]), "theta_i": theta_i, "phi_i": phi_i,
                 "theta_r": float(q["theta"]), "phi_r": float(q["phi"]), "hemisphere": str(q["hemisphere"]),
                 "value": float(q["value"]), "std": float("nan"), "ci_lo": float(q["ci"][0]),
                 "ci_hi": float(q["ci"][1]), "theta_min": float(q["theta_min"]), "theta_max": float(q["theta_max"]),
                 "phi_min": float(q["phi_min"]), "phi_max": float(q["phi_max"]), "psa": float(q["psa"]),
                 "count": int(q["count"]), "N": hits} for q in doc["patches"]]
    except (KeyError, TypeError, ValueError, IndexError) as e:
        raise bad(p, None, f"a patch of bench gonio's JSON is malformed ({type(e).__name__}: {e})") from None
    meta = {k: doc[k] for k in ("specimen", "collector", "beam", "seed", "delta", "method") if k in doc}
    meta.update(source="virtual", rays=int(doc["N"]), format="gonio-json", source_file=str(p))
    return BSDFRecord(pd.DataFrame(rows, columns=BSDF_COLUMNS), meta)

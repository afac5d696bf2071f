"""Reading helpers shared by the importers of :mod:`bench.io`: typed errors naming the file and
line, UTF-8 text reading, completing a table to the BSDF columns."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from bench.core.errors import InputError
from bench.core.records import BSDF_COLUMNS

__all__ = ["bad", "read_lines", "complete", "is_float"]


def bad(path: Path, lineno: int | None, what: str) -> InputError:
    where = f"{path}:{lineno}" if lineno is not None else str(path)
    return InputError(f"{where}: {what}")


def read_lines(path: str | Path) -> tuple[Path, list[str]]:
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(f"{p}: no such file") from None
    except UnicodeDecodeError as e:
        raise InputError(f"{p}: not a UTF-8 text file ({e})") from None
    return p, text.splitlines()


def complete(df: Any) -> Any:
    """Columns of BSDF_COLUMNS first (missing ones NaN), any others after."""
    import pandas as pd

    out = pd.DataFrame(index=df.index)
    for c in BSDF_COLUMNS:
        out[c] = df[c] if c in df.columns else np.nan
    for c in df.columns:
        if c not in out.columns:
            out[c] = df[c]
    return out



def is_float(text: str) -> bool:
    """Whether ``text`` parses as a float."""
    try:
        float(text)
        return True
    except ValueError:
        return False

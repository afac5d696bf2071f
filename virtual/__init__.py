"""Virtual devices: Monte Carlo spectrophotometer and goniophotometer behind the bench interface.

numba's on-disk cache (``cache=True``) is keyed by the source file of each compiled function,
not by the functions it inlines from other files: after an edit of ``specimens.py`` a kernel in
``engine.py`` would load stale machine code that still scatters the old way. So, before any
kernel module is imported, the cached kernels of this package are dropped whenever the source of
any kernel module here changed (a hash of the modules that use ``@njit`` is kept beside the cache).
"""

from __future__ import annotations

import hashlib
from pathlib import Path


def _drop_stale_kernel_cache() -> None:
    here = Path(__file__).resolve().parent
    cache = here / "__pycache__"
    digest = hashlib.sha256()
    for src in sorted(here.glob("*.py")):
        text = src.read_bytes()
        if b"@njit" not in text:  # only modules that compile kernels can leave stale machine code
            continue
        digest.update(src.name.encode())
        digest.update(text)
    stamp = cache / "goniobench-kernels.sha256"
    current = digest.hexdigest()
    try:
        if stamp.read_text() == current:
            return
    except OSError:
        pass
    try:
        for f in list(cache.glob("*.nbi")) + list(cache.glob("*.nbc")):
            f.unlink(missing_ok=True)
        cache.mkdir(exist_ok=True)
        stamp.write_text(current)
    except OSError:  # a read-only install: numba then compiles in memory, which is still correct
        pass


_drop_stale_kernel_cache()

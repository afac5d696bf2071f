"""Shared helpers: best-of timing, plain-text tables, and the CPU the figures come from."""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from typing import Any, Callable, Sequence

import numpy as np

from bench.machine import cpu_info  # noqa: F401  (the studies' tables state it)


def best_of(fn: Callable[[], Any], repeat: int = 3) -> tuple[float, Any]:
    """Smallest wall time of ``repeat`` calls (s) and the last result."""
    best, out = float("inf"), None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def numpy_uniform_rate(n_doubles: int, threads: int = 2, seed: int = 0) -> float:
    """Doubles per second numpy's default generator (PCG64) makes, split over ``threads``
    generators in threads (``Generator.random`` releases the GIL): the practical limit for a
    kernel that needs that many uniforms."""
    children = np.random.SeedSequence(seed).spawn(threads)
    gens = [np.random.default_rng(c) for c in children]
    per = n_doubles // threads
    bufs = [np.empty(per) for _ in range(threads)]

    def run() -> None:
        with ThreadPoolExecutor(threads) as ex:
            list(ex.map(lambda i: gens[i].random(out=bufs[i]), range(threads)))

    seconds, _ = best_of(run)
    return per * threads / seconds


def table(title: str, header: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    """A fixed-width text table."""
    cells = [[_fmt(c) for c in r] for r in rows]
    widths = [max(len(h), *(len(r[i]) for r in cells)) for i, h in enumerate(header)]
    line = "  ".join(h.ljust(w) for h, w in zip(header, widths))
    out = [title, line, "-" * len(line)]
    out += ["  ".join(c.ljust(w) for c, w in zip(r, widths)) for r in cells]
    return "\n".join(out)


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        if v == 0 or 1e-3 <= abs(v) < 1e6:
            return f"{v:.4g}"
        return f"{v:.3e}"
    return str(v)

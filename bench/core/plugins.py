"""Extensions from outside the project: Python entry points, loaded once and lazily.

A lab's package adds to goniobench's registries by declaring entry points in its own
``pyproject.toml``, with no edit to ours::

    [project.entry-points."goniobench.specimens"]
    velvet = "labmodels.velvet:Velvet"          # a DeclaredSpecimen subclass (or a module
                                                # whose import registers its families)
    [project.entry-points."goniobench.formats"]
    labcsv = "labmodels.io:LAB_CSV"             # a bench.io.registry.FileFormat

    [project.entry-points."goniobench.effects"]
    veiling = "labmodels.effects:Veiling"       # a bench.core.schemas.SceneEffect subclass

Each registry calls :func:`load_plugins` the first time it misses a name or lists its entries,
so ``bench --help`` and look-ups of built-in names never scan the installed packages, and every
process -- the CLI, a Dask worker, an emulator -- sees the same families as the environment it
runs in. A plugin that cannot be loaded is one :class:`ConfigError` naming its entry point.
"""

from __future__ import annotations

import threading
from typing import Any, Callable

from bench.core.errors import BenchError, ConfigError

__all__ = ["SPECIMEN_GROUP", "FORMAT_GROUP", "EFFECT_GROUP", "load_plugins"]

SPECIMEN_GROUP = "goniobench.specimens"
FORMAT_GROUP = "goniobench.formats"
EFFECT_GROUP = "goniobench.effects"

_LOADED: set[str] = set()
_LOCK = threading.Lock()  # a Dask worker's threads may miss a name at the same time


def load_plugins(group: str, register: Callable[[str, Any], None]) -> None:
    """Load every entry point of ``group`` once per process, handing each (name, object) to
    ``register``; later calls return at once."""
    if group in _LOADED:
        return
    with _LOCK:
        if group in _LOADED:
            return
        from importlib.metadata import entry_points  # ~20 ms: only when a registry misses

        for ep in sorted(entry_points(group=group), key=lambda e: e.name):
            try:
                obj = ep.load()
            except Exception as exc:  # whatever a third-party import raises
                raise ConfigError(f"entry point {ep.name} = {ep.value!r} in group {group}: cannot load it "
                                  f"({type(exc).__name__}: {exc})") from None
            try:
                register(ep.name, obj)
            except BenchError as exc:
                raise ConfigError(f"entry point {ep.name} = {ep.value!r} in group {group}: {exc}") from None
        _LOADED.add(group)

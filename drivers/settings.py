"""Reading a device's settings table (a bench-config section): the keys a settings dataclass
declares and nothing else, and the ``port``/``name`` every device table carries."""

from __future__ import annotations

from dataclasses import fields
from typing import Any, Callable, Mapping, TypeVar

from bench.core.errors import ConfigError

__all__ = ["settings_from_mapping", "port_and_name"]

T = TypeVar("T")


def settings_from_mapping(cls: type[T], d: Mapping[str, Any], what: str,
                          tuples: Mapping[str, Callable[[Any], Any] | None] | None = None) -> T:
    """``cls(**d)`` once every key of ``d`` is a field of ``cls``; ``tuples`` names the list-valued
    keys to freeze as tuples (TOML gives lists), each with a converter for its items or None."""
    known = {f.name for f in fields(cls)}  # type: ignore[arg-type]
    unknown = sorted(set(d) - known)
    if unknown:
        raise ConfigError(f"{what}: unknown key(s) {', '.join(unknown)}; known: {', '.join(sorted(known))}")
    kw = dict(d)
    for key, item in (tuples or {}).items():
        if kw.get(key) is not None:
            kw[key] = tuple(kw[key]) if item is None else tuple(item(x) for x in kw[key])
    return cls(**kw)


def port_and_name(cfg: Mapping[str, Any], what: str, default_name: str) -> tuple[str, str, dict[str, Any]]:
    """``(port, name, the other keys)`` of a device table; ``port`` is required."""
    d = dict(cfg)
    if "port" not in d:
        raise ConfigError(f"{what} needs 'port'")
    port = str(d.pop("port"))
    return port, str(d.pop("name", default_name)), d

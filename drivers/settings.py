"""Reading a device's settings table (a bench-config section): the keys a settings dataclass
declares and nothing else, and the ``port``/``name`` every device table carries."""

from __future__ import annotations

from dataclasses import fields
from typing import Any, Callable, Mapping, TypeVar

from bench.core.errors import ConfigError

__all__ = ["settings_from_mapping", "settings_with_overrides", "port_and_name"]

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


def settings_with_overrides(cls: Any, config: Any, overrides: Mapping[str, Any], what: str) -> Any:
    """``config`` (an instance of the settings class ``cls``, a mapping or None) with the keyword
    ``overrides`` a device constructor was given; an override ``cls`` does not declare is refused."""
    base = config if isinstance(config, cls) else cls.from_dict(config or {})
    if not overrides:
        return base
    merged = {f.name: getattr(base, f.name) for f in fields(cls)}
    unknown = sorted(set(overrides) - set(merged))
    if unknown:
        raise ConfigError(f"{what}: unknown setting(s) {', '.join(unknown)}")
    merged.update(overrides)
    return cls.from_dict(merged)


def port_and_name(cfg: Mapping[str, Any], what: str, default_name: str) -> tuple[str, str, dict[str, Any]]:
    """``(port, name, the other keys)`` of a device table; ``port`` is required."""
    d = dict(cfg)
    if "port" not in d:
        raise ConfigError(f"{what} needs 'port'")
    port = str(d.pop("port"))
    return port, str(d.pop("name", default_name)), d

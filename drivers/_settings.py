"""Reading a device's settings table (a bench-config section): a settings model
(:class:`bench.core.validation.Settings`) with a constructor's keyword overrides, and the
``port``/``name`` every device table carries."""

from __future__ import annotations

from typing import Any, Mapping

from bench.core.errors import ConfigError

__all__ = ["settings_with_overrides", "port_and_name"]


def settings_with_overrides(cls: Any, config: Any, overrides: Mapping[str, Any], what: str) -> Any:
    """``config`` (an instance of the settings class ``cls``, a mapping or None) with the keyword
    ``overrides`` a device constructor was given; an override ``cls`` does not declare is refused."""
    base = config if isinstance(config, cls) else cls.from_dict(config or {})
    if not overrides:
        return base
    merged = base.model_dump()
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

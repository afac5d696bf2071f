"""How user input is validated: finite numbers, tables that refuse unknown keys, settings
declared once, and every problem turned into one :class:`ConfigError` line naming the file (or
device, or effect), the key (dotted path) and the value. The schemas themselves are
:mod:`bench.core.schemas`.
"""

from __future__ import annotations

import difflib
import math
from typing import Annotated, Any, ClassVar, Mapping, TypeVar

from pydantic import BaseModel, BeforeValidator, ConfigDict, ValidationError

from bench.core.errors import ConfigError

__all__ = ["Finite", "Whole", "Table", "Settings", "validate_document", "validation_message"]


def _finite_number(v: Any) -> Any:
    if isinstance(v, bool):
        raise ValueError("expected a number, got a boolean")
    if isinstance(v, (int, float)) and not math.isfinite(float(v)):
        raise ValueError(f"expected a finite number, got {v!r}")
    return v


def _whole_number(v: Any) -> Any:
    if isinstance(v, bool):
        raise ValueError("expected an integer, got a boolean")
    if isinstance(v, float):
        if not math.isfinite(v) or v != int(v):
            raise ValueError(f"expected an integer, got {v!r}")
        return int(v)
    return v


Finite = Annotated[float, BeforeValidator(_finite_number)]
Whole = Annotated[int, BeforeValidator(_whole_number)]


class Table(BaseModel):
    """The model of a TOML table: unknown keys refused, values frozen once validated."""

    model_config = ConfigDict(extra="forbid", strict=False, frozen=True)


class Settings(BaseModel):
    """A device's or an effect's settings, each declared once with its type and range (the idea
    of PyMeasure's ``Instrument.control``, validated by pydantic like every user file).

    Built from Python by keyword or by position (the declared order), a bad value is one
    :class:`ConfigError` line naming :attr:`settings_of`, the key and the value; a TOML table
    goes through :meth:`from_dict` (unknown keys refused with a "did you mean"). A model nested
    in a file schema must not derive from this class: its own ``__init__`` would run inside the
    file's validation."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    #: what the settings belong to, as errors name it (``stage axis config``, ``effects.noise``)
    settings_of: ClassVar[str] = "settings"

    def __init__(self, *args: Any, _source: str | None = None, **kw: Any) -> None:
        model = type(self)
        where = _source or model.settings_of
        fields = list(model.model_fields)
        if len(args) > len(fields):
            raise ConfigError(f"{where}: takes at most {len(fields)} settings ({', '.join(fields)}), got {len(args)}")
        for name, value in zip(fields, args):
            if name in kw:
                raise ConfigError(f"{where}: {name} given twice")
            kw[name] = value
        try:
            super().__init__(**kw)
        except ValidationError as exc:
            raise ConfigError(validation_message(model, exc, where)) from None

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], source: str | None = None) -> Any:
        """Validate a table (a TOML table, a mapping) into these settings; errors name ``source``."""
        if not isinstance(d, Mapping):
            raise ConfigError(f"{source or cls.settings_of}: expected a table of keys, got {type(d).__name__}")
        return cls(_source=source, **{str(k): v for k, v in d.items()})


def _model_names() -> set[str]:
    """Class names of every pydantic model defined so far: pydantic labels a union branch in an
    error's location with its model's class name."""
    seen: set[type] = set()  # by class, not name: two models may share a name, not their subclasses
    todo = list(BaseModel.__subclasses__())
    while todo:
        cls = todo.pop()
        if cls not in seen:
            seen.add(cls)
            todo.extend(cls.__subclasses__())
    return {cls.__name__ for cls in seen}


def _loc(loc: tuple[Any, ...]) -> str:
    out = ""
    models = _model_names() if any(isinstance(p, str) and p[:1].isupper() for p in loc) else set()
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        elif isinstance(part, str) and part in models:
            continue  # a union branch named by its model class (a key such as START is kept)
        elif part in ("bool", "float", "int", "str", "list[float]", "RangeTable", "function-before[_finite_number(), float]",
                      "function-before[_whole_number(), int]") or "[" in str(part) or str(part).startswith("function"):
            continue  # union branch labels pydantic adds to the location
        else:
            out += ("." if out else "") + str(part)
    return out


def _known_keys(model: type[BaseModel], loc: tuple[Any, ...]) -> list[str]:
    """The keys accepted at the table holding ``loc``'s last part (for "did you mean")."""
    current: Any = model
    for part in loc[:-1]:
        fields = getattr(current, "model_fields", None)
        if fields and part not in fields and not _loc((part,)):
            continue  # a union branch's label (the model's class name, a type)
        if not fields or part not in fields:
            return []
        ann = fields[part].annotation
        current = next((a for a in getattr(ann, "__args__", (ann,)) if hasattr(a, "model_fields")), None)
        if current is None:
            return []
    return sorted(getattr(current, "model_fields", {}))


_Model = TypeVar("_Model", bound=BaseModel)


def validate_document(model: type[_Model], data: Mapping[str, Any], source: str) -> _Model:
    """Validate ``data`` (a parsed file) against ``model``; the first problem becomes one
    :class:`ConfigError` line: ``SOURCE: key a.b: problem (got VALUE)``."""
    if not isinstance(data, Mapping):
        raise ConfigError(f"{source}: expected a table of keys, got {type(data).__name__}")
    try:
        return model.model_validate(dict(data))
    except ValidationError as exc:
        raise ConfigError(validation_message(model, exc, source)) from None


def validation_message(model: type[BaseModel], exc: ValidationError, source: str) -> str:
    """The first problem of ``exc`` as ``SOURCE: key a.b: problem (got VALUE)`` (unknown keys
    with a "did you mean" for near misses)."""
    errors = exc.errors(include_url=False)
    # a union reports one error per branch: the one reaching deepest names the real problem, and
    # of equals a wrong value (a table's own check) rather than a wrong type (another branch's)
    err = max(errors, key=lambda e: (e["type"] == "extra_forbidden", len(e.get("loc", ())),
                                     not e["type"].endswith("_type")))
    loc = tuple(err.get("loc", ()))
    where = _loc(loc) or "(top level)"
    if err["type"] == "extra_forbidden":
        key = str(loc[-1]) if loc else where
        known = [k for k in _known_keys(model, loc)]
        near = difflib.get_close_matches(key, known, n=1, cutoff=0.6)
        hint = f"; did you mean {near[0]!r}?" if near else (f"; accepted: {', '.join(known)}" if known else "")
        return f"{source}: unknown key {where!r}{hint}"
    if err["type"] == "missing":
        return f"{source}: key {where} is required"
    value = err.get("input")
    msg = str(err.get("msg", "invalid"))
    if msg.startswith("Value error, "):  # our own validators already name the value
        msg = msg.removeprefix("Value error, ")
        return f"{source}: {msg}" if where == "(top level)" else f"{source}: key {where}: {msg}"
    shown = repr(value)
    if len(shown) > 60:
        shown = shown[:57] + "..."
    return f"{source}: key {where}: {msg[:1].lower() + msg[1:]} (got {shown})"

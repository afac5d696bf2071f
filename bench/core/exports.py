"""The public names of a package, imported on first use.

Each of the project's packages (``bench``, ``virtual``, ``drivers``, ``compare``) exports the names
its users import from its ``__init__`` (its ``__all__``), while the modules behind them load only
when a name is first asked for: ``import bench`` stays as cheap as the command line needs (``bench
--help`` loads no numpy), and ``from bench import RunStore`` loads the store and no more.

    __all__ = [...]
    __getattr__, __dir__ = lazy_exports(__name__, {"RunStore": "bench.store", ...})

A name is looked up in its module on first use and kept in the package's namespace after that.
"""

from __future__ import annotations

import sys
from importlib import import_module
from typing import Any, Callable, Mapping

__all__ = ["lazy_exports"]


def lazy_exports(package: str, where: Mapping[str, str]) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """The module-level ``__getattr__`` and ``__dir__`` (PEP 562) of ``package``, whose public
    names are the keys of ``where``, each defined in the module its value names."""
    table = dict(where)

    def __getattr__(name: str) -> Any:
        if name not in table:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(import_module(table[name]), name)
        setattr(sys.modules[package], name, value)  # the next lookup is an ordinary attribute
        return value

    def __dir__() -> list[str]:
        return sorted(set(vars(sys.modules[package])) | set(table))

    return __getattr__, __dir__

"""The public names of a package, imported on first use.

Each of the project's packages (``bench``, ``virtual``, ``drivers``, ``compare``) exports the names
its users import from its ``__init__`` (its ``__all__``), while the modules behind them load only
when a name is first asked for: ``import bench`` stays as cheap as the command line needs (``bench
--help`` loads no numpy), and ``from bench import RunStore`` loads the store and no more. The names
are written once, as imports under ``if TYPE_CHECKING:`` (what type checkers, editors and
import-linter read); at run time the package reads that block from its own file::

    if TYPE_CHECKING:
        from bench.store import RunStore
    _WHERE = type_checking_imports(__file__)
    __all__ = list(_WHERE)
    __getattr__, __dir__ = lazy_exports(__name__, _WHERE)

A name is looked up in its module on first use and kept in the package's namespace after that.
"""

from __future__ import annotations

import ast
import sys
from importlib import import_module
from pathlib import Path
from typing import Any, Callable, Mapping

__all__ = ["lazy_exports", "type_checking_imports"]


def type_checking_imports(path: str | Path) -> dict[str, str]:
    """The names the module at ``path`` imports with ``from MODULE import NAME`` in its top-level
    ``if TYPE_CHECKING:`` block, each mapped to its MODULE, in order."""
    out: dict[str, str] = {}
    for node in ast.parse(Path(path).read_text(encoding="utf-8")).body:
        if isinstance(node, ast.If) and isinstance(node.test, ast.Name) and node.test.id == "TYPE_CHECKING":
            for imp in node.body:
                if isinstance(imp, ast.ImportFrom) and imp.module and not imp.level:
                    out.update({alias.asname or alias.name: imp.module for alias in imp.names})
    return out


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

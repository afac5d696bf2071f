"""The public surface: the names users import, exported from the packages' ``__init__`` (their
``__all__``), each importable; the examples of the README and of the docs import only from it; the
docs' API reference documents every name of it; and ``import bench`` stays cheap (the names load
on first use, :mod:`bench.core.exports`)."""

from __future__ import annotations

import ast
import importlib
import inspect
import json
import os
import pkgutil
import re
import subprocess
import sys
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest

from bench.core.exports import lazy_exports, type_checking_imports
from tests.test_readme import DOCUMENTS, python_blocks

ROOT = Path(__file__).resolve().parents[1]
API_PAGES = sorted((ROOT / "docs" / "reference").glob("api*.md"))
#: the packages whose ``__all__`` is the public surface
PUBLIC = ("bench", "bench.bluesky", "virtual", "drivers", "compare")
#: single public names of otherwise internal modules: the console script's entry point
ENTRY_POINTS = {"bench.cli": ("main",)}
PROJECT = ("bench", "virtual", "drivers", "compare")


def _public(package: str) -> list[str]:
    return list(importlib.import_module(package).__all__)


def _surface() -> list[tuple[str, str]]:
    return [(p, n) for p in PUBLIC for n in _public(p)] + [(m, n) for m, names in ENTRY_POINTS.items() for n in names]


def test_every_package_exports_a_surface():
    for package in PUBLIC:
        names = _public(package)
        assert len(names) >= 5 and len(set(names)) == len(names), package


@pytest.mark.parametrize("package,name", _surface(), ids=[f"{p}.{n}" for p, n in _surface()])
def test_every_exported_name_imports(package, name):
    """``from PACKAGE import NAME`` works, in this process where other modules are loaded too."""
    namespace: dict[str, Any] = {}
    exec(f"from {package} import {name}", namespace)
    assert namespace[name] is getattr(importlib.import_module(package), name)


def test_a_name_not_exported_is_an_attribute_error():
    import bench

    with pytest.raises(AttributeError, match="module 'bench' has no attribute 'RunStor'"):
        bench.RunStor  # noqa: B018
    assert "RunStore" in dir(bench)


@pytest.mark.parametrize("package", PUBLIC)
def test_no_exported_name_is_shadowed_by_a_submodule(package):
    """A lazily exported name spelled as a submodule becomes the module once that submodule is
    imported anywhere (``compare.align`` was the module, not the function): each such name is
    still the exported object after its submodule is imported (``bench.bluesky`` binds its names
    after importing their modules, so ``connect`` stays the function)."""
    module = importlib.import_module(package)
    exported = {name: getattr(module, name) for name in module.__all__}
    for sub in {m.name for m in pkgutil.iter_modules(module.__path__)} & set(exported):
        importlib.import_module(f"{package}.{sub}")
        assert getattr(module, sub) is exported[sub], f"{package}.{sub} is shadowed by its submodule"


def _home(package: str, name: str) -> str:
    """The module whose code defines an exported name (a constant: the module the package's
    lazy table names, or the package itself)."""
    obj = getattr(importlib.import_module(package), name)
    if inspect.isclass(obj) or inspect.isfunction(obj):
        return obj.__module__
    return getattr(importlib.import_module(package), "_WHERE", {}).get(name, package)


@pytest.mark.parametrize("package", ["bench", "virtual", "drivers", "compare"])
def test_each_root_exports_from_below_the_entry_points(package):
    """The roots load their names lazily (no import statement import-linter could see), so their
    targets are checked here: no name comes from the CLI, and ``virtual``, ``drivers`` and
    ``compare`` export only their own code or the contract's (``bench.core``)."""
    for name in _public(package):
        home = _home(package, name)
        assert not (home == "bench.cli" or home.startswith("bench.cli.")), f"{package}.{name} comes from {home}"
        if package != "bench":
            assert home.split(".")[0] == package or home.startswith("bench.core."), f"{package}.{name}: {home}"


def test_lazy_exports_load_on_first_use_and_keep_the_name():
    module = ModuleType("lab_package")
    sys.modules["lab_package"] = module
    try:
        module.__getattr__, module.__dir__ = lazy_exports("lab_package", {"dumps": "json"})
        assert "dumps" not in vars(module) and "dumps" in dir(module)
        assert module.dumps is json.dumps and vars(module)["dumps"] is json.dumps
        with pytest.raises(AttributeError, match="module 'lab_package' has no attribute 'loads'"):
            module.loads  # noqa: B018
    finally:
        del sys.modules["lab_package"]


def test_the_surface_is_read_from_the_type_checking_imports(tmp_path):
    """One list per package: the names imported under ``if TYPE_CHECKING:`` (what type checkers and
    import-linter read) are the lazy table and the ``__all__``."""
    for package in ("bench", "virtual", "drivers", "compare"):
        module = importlib.import_module(package)
        assert module._WHERE == type_checking_imports(module.__file__)
        assert [n for n in module.__all__ if not n.startswith("__")] == list(module._WHERE)
    init = tmp_path / "lab.py"
    init.write_text("import os\nfrom typing import TYPE_CHECKING\nif TYPE_CHECKING:\n"
                    "    from json import dumps as dumps, loads\n    import sys\nfrom csv import reader\n")
    assert type_checking_imports(init) == {"dumps": "json", "loads": "json"}


def test_import_bench_loads_no_application_module():
    """``import bench`` (what ``bench --help`` starts with) loads the contract's export helper and
    nothing heavy; the first use of a name loads its module."""
    code = ("import sys, json\nimport bench, virtual, drivers, compare\n"
            "before = sorted(sys.modules)\nbench.RunStore\n"
            "print(json.dumps([before, sorted(sys.modules)]))\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT,
                       env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert r.returncode == 0, r.stderr
    before, after = (set(x) for x in json.loads(r.stdout))
    project = sorted(m for m in before if m.split(".")[0] in PROJECT)
    assert project == ["bench", "bench.core", "bench.core.exports", "compare", "drivers", "virtual"]
    assert "numpy" not in before and "bench.store" in after


# --- the examples import only from the public surface -------------------------------------------

def _imports(source: str) -> list[tuple[str, list[str]]]:
    """``(module, names)`` of every import of the project in a block (``names`` empty for ``import M``)."""
    out = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] in PROJECT:
            out.append((node.module, [a.name for a in node.names]))
        elif isinstance(node, ast.Import):
            out += [(a.name, []) for a in node.names if a.name.split(".")[0] in PROJECT]
    return out


def outside_surface(source: str) -> list[str]:
    """The imports of a block that reach past the public surface."""
    bad = []
    for module, names in _imports(source):
        allowed = _public(module) if module in PUBLIC else ENTRY_POINTS.get(module, ())
        if not names and module not in PUBLIC:
            bad.append(f"import {module}")
        bad += [f"from {module} import {n}" for n in names if n not in allowed]
    return bad


_BLOCKS = [(p.relative_to(ROOT).as_posix(), n, src) for p in DOCUMENTS for n, src in python_blocks(p)]


def test_the_documents_have_python_examples():
    assert len(_BLOCKS) >= 5 and any(_imports(src) for _, _, src in _BLOCKS)


@pytest.mark.parametrize("page,line,source", _BLOCKS, ids=[f"{p}:{n}" for p, n, _ in _BLOCKS])
def test_examples_import_only_the_public_surface(page, line, source):
    assert outside_surface(source) == [], f"{page} line {line}"


def test_an_import_past_the_surface_is_found():
    """Power: a module path, a name the package does not export and a bare internal import."""
    assert outside_surface("from bench.io.registry import read_record\nfrom bench import read_record\n"
                           "from bench import _WHERE\nimport virtual.collector\nfrom bench.cli import main\n"
                           "import numpy\n") == [
        "from bench.io.registry import read_record", "from bench import _WHERE", "import virtual.collector"]


# --- the API reference documents the surface ----------------------------------------------------

def _directives() -> list[str]:
    return [m for page in API_PAGES for m in re.findall(r"^::: *([\w.]+)", page.read_text(encoding="utf-8"), re.M)]


def _resolve(path: str) -> Any:
    """The object a dotted path names (its longest importable prefix, then attributes)."""
    parts = path.split(".")
    for k in range(len(parts), 0, -1):
        try:
            obj: Any = importlib.import_module(".".join(parts[:k]))
        except ImportError:
            continue
        for attr in parts[k:]:
            obj = getattr(obj, attr)
        return obj
    raise ImportError(path)


def undocumented(directives: list[str]) -> list[str]:
    """The exported names no directive renders: one naming the object itself, or its module."""
    objects = [_resolve(d) for d in directives]
    modules = {d for d, o in zip(directives, objects) if inspect.ismodule(o)}
    out = []
    for package, name in _surface():
        if name.startswith("__"):
            continue
        obj = getattr(importlib.import_module(package), name)
        if not (any(o is obj for o in objects) or _home(package, name) in modules):
            out.append(f"{package}.{name}")
    return out


def test_the_api_reference_documents_every_exported_name():
    assert API_PAGES and undocumented(_directives()) == []


def test_a_missing_directive_is_found():
    """Power: without the store's and the Dynamixel arm's directives, those names are reported."""
    directives = [d for d in _directives() if d not in ("bench.store.runstore.RunStore", "drivers.dynamixel.arm.DynamixelArm")]
    assert undocumented(directives) == ["bench.RunStore", "drivers.DynamixelArm"]


# --- private modules stay inside their package ---------------------------------------------------

def _private_prefix(module: str) -> str | None:
    """The package that owns a private module (``drivers._faultlog`` -> ``drivers``), or None."""
    parts = module.split(".")
    for k, part in enumerate(parts):
        if part.startswith("_") and not part.startswith("__"):
            return ".".join(parts[:k])
    return None


def _is_module(dotted: str) -> bool:
    path = ROOT.joinpath(*dotted.split("."))
    return path.with_suffix(".py").is_file() or (path / "__init__.py").is_file()


def private_imports_from_outside(files: dict[str, str]) -> list[str]:
    """``importer -> module`` for each import of a private module (a leading underscore) from
    outside the package that holds it. ``files`` maps module names to sources."""
    out = []
    for importer, source in files.items():
        for node in ast.walk(ast.parse(source)):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
                # `from compare import _grid` imports a module; `from m import _name` a module's
                # private name, which its siblings may share (not checked here)
                names = [node.module] + [f"{node.module}.{a.name}" for a in node.names
                                         if _is_module(f"{node.module}.{a.name}")]
            else:
                names = []
            for name in names:
                owner = _private_prefix(name)
                if owner is not None and not (importer == owner or importer.startswith(owner + ".")):
                    out.append(f"{importer} -> {name}")
    return out


def _project_sources() -> dict[str, str]:
    out = {}
    for package in (*PROJECT, "benchmarks"):
        for path in sorted((ROOT / package).rglob("*.py")):
            parts = path.relative_to(ROOT).with_suffix("").parts
            out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path.read_text(encoding="utf-8")
    return out


def test_private_modules_are_imported_only_inside_their_package():
    """A module named with a leading underscore (``drivers._faultlog``, ``compare._grid``) is a
    helper of its package: the rest of the project does not import it (the tests may)."""
    sources = _project_sources()
    assert any(_private_prefix(m) for m in sources)  # the convention is in use
    assert private_imports_from_outside(sources) == []


def test_a_private_import_from_outside_is_found():
    files = {"drivers.ocean._link": "from drivers._faultlog import FaultLog\n",
             "bench.runner": "import drivers._faultlog\nfrom compare import _grid\nfrom bench.core import errors\n"}
    assert private_imports_from_outside(files) == ["bench.runner -> drivers._faultlog", "bench.runner -> compare._grid"]


def private_names_in_all(files: dict[str, str]) -> list[str]:
    """``module.name`` for each private name a module's literal ``__all__`` lists (a leading
    underscore says the name is not for import from outside; ``__all__`` says it is)."""
    out = []
    for module, source in files.items():
        for node in ast.parse(source).body:
            if isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id == "__all__" for t in node.targets) \
                    and isinstance(node.value, (ast.List, ast.Tuple)):
                out += [f"{module}.{e.value}" for e in node.value.elts if isinstance(e, ast.Constant)
                        and isinstance(e.value, str) and e.value.startswith("_") and not e.value.startswith("__")]
    return out


def test_no_all_lists_a_private_name():
    assert private_names_in_all(_project_sources()) == []
    assert private_names_in_all({"m": "__all__ = ['run', '_Sink', '__version__']\n"}) == ["m._Sink"]  # power

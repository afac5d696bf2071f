"""The layers of the architecture hold: import-linter's contracts (pyproject.toml) pass, every
package of the repository is one of its root packages, and every module of them sits in a layer of
the layers contract, so a new module or package cannot escape the contracts."""

from __future__ import annotations

import ast
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: repository packages the contracts leave out, and why
NOT_LAYERED = {"tests": "the suite imports every layer to test it"}


def _config() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]


def _contracts() -> dict[str, dict]:
    return {c["id"]: c for c in _config()["contracts"]}


def _layer_modules() -> list[str]:
    """Every module named in the layers contract (layers split at ``:`` and ``|``)."""
    return [m.strip() for layer in _contracts()["layers"]["layers"]
            for part in layer.split("|") for m in part.split(":")]


def _modules(package: str) -> list[str]:
    """Dotted names of every module of ``package`` on disk (packages by their ``__init__``)."""
    out = []
    for path in sorted((ROOT / package).rglob("*.py")):
        parts = path.relative_to(ROOT).with_suffix("").parts
        if "__pycache__" in parts:
            continue
        out.append(".".join(parts[:-1] if parts[-1] == "__init__" else parts))
    return out


def uncovered(modules: list[str], layers: list[str], roots: list[str], tree: Path = ROOT) -> list[str]:
    """The modules in no layer. A root package's own ``__init__`` (the container of its layers)
    counts as covered only when it imports nothing of the project at run time but ``bench.core``
    (the bottom layer, which imports nothing else). Its public names, imported under ``if
    TYPE_CHECKING:`` and loaded on first use (:mod:`bench.core.exports`), are arrows the contracts
    see: the forbidden contract keeps the CLI out of them."""
    out = []
    for mod in modules:
        if any(mod == m or mod.startswith(m + ".") for m in layers):
            continue
        imported = _imports_of_project(tree / mod / "__init__.py", roots) if mod in roots else ["?"]
        if not [n for n in imported if not n.startswith("bench.core.")]:
            continue
        out.append(mod)
    return out


def _imports_of_project(path: Path, roots: list[str]) -> list[str]:
    """The project modules ``path`` imports at run time (not under ``if TYPE_CHECKING:``)."""
    names = []
    for node in _runtime_nodes(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module:
            names.append("." if node.level else node.module)
    return [n for n in names if n == "." or n.split(".")[0] in roots]


def _runtime_nodes(tree: ast.AST) -> list[ast.AST]:
    out = []
    for node in ast.iter_child_nodes(tree):
        if isinstance(node, ast.If) and isinstance(node.test, ast.Name) and node.test.id == "TYPE_CHECKING":
            out += [n for child in node.orelse for n in [child, *_runtime_nodes(child)]]
            continue
        out += [node, *_runtime_nodes(node)]
    return out


def test_every_package_of_the_repository_is_a_root_package():
    on_disk = {p.parent.name for p in ROOT.glob("*/__init__.py")} - set(NOT_LAYERED)
    assert set(_config()["root_packages"]) == on_disk


def test_every_module_sits_in_a_layer():
    roots = _config()["root_packages"]
    modules = [m for r in roots for m in _modules(r)]
    assert len(modules) > 150  # the walk really reached the tree
    assert uncovered(modules, _layer_modules(), roots) == []


def _layer_index(module: str) -> int:
    layers = _contracts()["layers"]["layers"]
    return next(i for i, layer in enumerate(layers)
                if module in [m.strip() for part in layer.split("|") for m in part.split(":")])


def test_identification_is_an_application_package():
    """bench.identify (fit) builds on virtual and compare, so it sits in the application layer,
    above them: virtual, drivers, compare and bench.core cannot import it."""
    layers = _contracts()["layers"]["layers"]
    app = _layer_index("bench.identify")
    assert app == _layer_index("bench.plans")
    assert any("virtual" in layer for layer in layers[app + 1:])


def test_the_cli_is_on_top_and_nothing_imports_it():
    """The CLI sits in the entry-point layer, right under benchmarks and above the whole
    application, independent of the other entry points; and a forbidden contract says that no
    module of the project (the root ``bench`` package included) imports it."""
    layers = _contracts()["layers"]["layers"]
    cli = _layer_index("bench.cli")
    assert layers[cli - 1] == "benchmarks" and cli == _layer_index("bench.identify") - 1
    assert ":" not in layers[cli]  # the entry points are independent of each other
    assert _layer_index("bench.pytest_plugin") == _layer_index("bench.docs") == cli
    forbidden = _contracts()["nothing-imports-the-cli"]
    assert forbidden["type"] == "forbidden" and forbidden["forbidden_modules"] == ["bench.cli", "bench.cli.**"]
    roots = set(_config()["root_packages"]) - {"benchmarks"}
    assert set(forbidden["source_modules"]) == roots | {r + ".**" for r in roots}
    assert forbidden["as_packages"] is False  # else the root `bench` contains bench.cli and is skipped
    # only the CLI's own imports of itself are ignored
    assert all(rule.split("->")[0].strip() in ("bench.cli", "bench.cli.**") for rule in forbidden["ignore_imports"])


@pytest.mark.parametrize("module", ["bench.new_command", "benchmarks_extra", "plants.leaf"])
def test_a_module_outside_the_layers_is_found(module):
    """Power: a module of bench/ the application list does not name, or a new package, is reported."""
    roots = _config()["root_packages"]
    assert uncovered([module], _layer_modules(), roots) == [module]


def test_a_package_root_that_imports_the_project_is_not_covered(tmp_path):
    layers = _layer_modules()
    assert uncovered(["bench"], layers, ["bench"]) == []  # today's bench/__init__: bench.core at run time
    (tmp_path / "bench").mkdir()
    (tmp_path / "bench" / "__init__.py").write_text("from bench.store import RunStore\n")
    assert uncovered(["bench"], layers, ["bench"], tree=tmp_path) == ["bench"]
    # an import for type checkers only is not one at run time (the contracts see it); its else is
    typed = "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from bench.store import RunStore\n"
    (tmp_path / "bench" / "__init__.py").write_text(typed)
    assert uncovered(["bench"], layers, ["bench"], tree=tmp_path) == []
    (tmp_path / "bench" / "__init__.py").write_text(typed + "else:\n    import bench.runner\n")
    assert uncovered(["bench"], layers, ["bench"], tree=tmp_path) == ["bench"]


def test_import_linter_contracts_hold():
    exe = Path(sys.executable).with_name("lint-imports")
    proc = subprocess.run([str(exe), str(ROOT / "pyproject.toml")], cwd=ROOT,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout[-4000:] + proc.stderr[-2000:]
    assert "0 broken" in proc.stdout


@pytest.mark.parametrize("module, arrow", [
    ("bench/core/errors.py", "bench.store"),  # the contract imports the application
    ("bench/plans.py", "bench.cli.common"),  # the application imports the CLI
    ("bench/__init__.py", "bench.cli"),  # the root package imports the CLI
])
def test_a_back_arrow_breaks_the_contract(tmp_path, module, arrow):
    """Power: the same contracts, run on a copy of the tree where a module imports a layer above
    it, fail, naming the arrow."""
    import shutil

    for pkg in _config()["root_packages"]:
        shutil.copytree(ROOT / pkg, tmp_path / pkg, ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(ROOT / "pyproject.toml", tmp_path / "pyproject.toml")
    path = tmp_path / module
    path.write_text(path.read_text() + f"\nimport {arrow}  # a back-arrow\n")
    exe = Path(sys.executable).with_name("lint-imports")
    proc = subprocess.run([str(exe), str(tmp_path / "pyproject.toml")], cwd=tmp_path,
                          capture_output=True, text=True, timeout=300,
                          env={"PYTHONPATH": str(tmp_path), "PATH": "/usr/bin:/bin"})
    assert proc.returncode != 0
    importer = module.removesuffix(".py").removesuffix("/__init__").replace("/", ".")
    assert f"{importer} -> {arrow}" in proc.stdout  # broken for the back-arrow, not a setup error

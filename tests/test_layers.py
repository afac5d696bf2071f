"""The layers of the architecture hold: import-linter's contracts (pyproject.toml) pass, and the
application layer of the contract names every module of bench/ outside bench.core."""

from __future__ import annotations

import subprocess
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _contracts() -> dict[str, dict]:
    cfg = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]
    return {c["id"]: c for c in cfg["contracts"]}


def test_application_layer_names_every_module_of_bench():
    top = _contracts()["layers"]["layers"][0]
    declared = {m.strip() for m in top.split(":")}
    on_disk = {f"bench.{p.stem if p.is_file() else p.name}" for p in (ROOT / "bench").iterdir()
               if (p.suffix == ".py" and p.stem != "__init__") or (p.is_dir() and (p / "__init__.py").exists())}
    on_disk.discard("bench.core")
    assert declared == on_disk, f"missing from the contract: {sorted(on_disk - declared)}; " \
                                f"no longer in bench/: {sorted(declared - on_disk)}"


def test_import_linter_contracts_hold():
    exe = Path(sys.executable).with_name("lint-imports")
    proc = subprocess.run([str(exe), str(ROOT / "pyproject.toml")], cwd=ROOT,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout[-4000:] + proc.stderr[-2000:]
    assert "0 broken" in proc.stdout


def test_a_back_arrow_breaks_the_contract(tmp_path):
    """Power: the same contracts, run on a copy of the tree where bench.core imports the
    application, fail."""
    import shutil

    for pkg in ("bench", "virtual", "drivers", "compare"):
        shutil.copytree(ROOT / pkg, tmp_path / pkg, ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(ROOT / "pyproject.toml", tmp_path / "pyproject.toml")
    errors = tmp_path / "bench" / "core" / "errors.py"
    errors.write_text(errors.read_text() + "\nimport bench.store  # a back-arrow\n")
    exe = Path(sys.executable).with_name("lint-imports")
    proc = subprocess.run([str(exe), str(tmp_path / "pyproject.toml")], cwd=tmp_path,
                          capture_output=True, text=True, timeout=300,
                          env={"PYTHONPATH": str(tmp_path), "PATH": "/usr/bin:/bin"})
    assert proc.returncode != 0
    assert "BROKEN" in proc.stdout or "broken" in proc.stdout

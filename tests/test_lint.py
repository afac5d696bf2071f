"""ruff passes over the whole tree with the rules of pyproject.toml ([tool.ruff]), so the suite
(and so CI) enforces them; a perturbed file shows the same call does catch a violation."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def ruff_check(*args: str, cwd: Path = ROOT) -> subprocess.CompletedProcess[str]:
    """``ruff check`` from this interpreter's environment (ruff is in the ``test`` extra)."""
    exe = Path(sys.executable).with_name("ruff")
    assert exe.exists(), f"{exe} missing: install the test extra (pip install -e '.[test]')"
    return subprocess.run([str(exe), "check", "--no-cache", *args], cwd=cwd, capture_output=True, text=True,
                          timeout=300)


def test_ruff_passes_over_the_tree():
    proc = ruff_check(str(ROOT))
    assert proc.returncode == 0, proc.stdout[-4000:] + proc.stderr[-2000:]


def test_ruff_catches_a_perturbed_file(tmp_path):
    shutil.copy(ROOT / "pyproject.toml", tmp_path / "pyproject.toml")
    (tmp_path / "module.py").write_text('import os\n\n\ndef f(x):\n    return x == None\n')
    proc = ruff_check(str(tmp_path), cwd=tmp_path)
    assert proc.returncode == 1
    assert "F401" in proc.stdout and "E711" in proc.stdout

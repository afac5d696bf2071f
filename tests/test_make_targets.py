"""The split of the suite between ``make test`` and ``make test-all`` loses no test from CI.

``make test`` deselects the tests marked ``slow``; ``make test-slow`` runs exactly those and
``make test-all`` both. CI (``.ci/run``) must run both halves: a test moved to ``slow`` is then
still run on every submission. Checked from the Makefile's recipes as ``make -n`` prints them.
"""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def _recipe(target: str) -> list[str]:
    """The commands ``make -n TARGET`` would run, as if the project were installed (no venv made)."""
    if shutil.which("make") is None:
        pytest.skip("make is not installed")
    proc = subprocess.run(["make", "-n", "-o", ".venv/.goniobench-installed", "-o", "llvm", target], cwd=ROOT,
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    return [line for line in proc.stdout.splitlines() if " -m pytest " in line]


def test_make_test_leaves_out_exactly_the_slow_tests_and_test_slow_runs_them():
    (test,) = _recipe("test")
    (slow,) = _recipe("test-slow")
    assert test.endswith('-m "not slow"') and slow.endswith("-m slow")
    assert test.removesuffix('-m "not slow"') == slow.removesuffix("-m slow")  # same options otherwise
    assert _recipe("test-all") == [test, slow]


def test_ci_runs_make_test_and_then_the_slow_tests():
    lines = [line.strip() for line in (ROOT / ".ci" / "run").read_text().splitlines()]
    runs = [line for line in lines if re.match(r"make\b", line)]
    assert runs in (["make test", "make test-slow"], ["make test-all"]), runs


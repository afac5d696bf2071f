"""The kernel cache policy of :mod:`virtual.kernels` never serves machine code of an old source.

A copy of the package is made in a temporary directory; a probe kernel calls a kernel of another
file (``virtual/kernels/warps.py``). Fresh processes share one ``NUMBA_CACHE_DIR``: after the
called kernel's source is edited, the kernel compiled with :func:`virtual.kernels.jit` returns
the new result, while a plain ``numba.njit(cache=True)`` twin in the same process still serves
the stale one -- what the policy exists to prevent, and proof that the test can fail. An edit of
a kernel file the probe does not import leaves the probe's cache valid.
"""

from __future__ import annotations

import ast
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from virtual.kernels import MARK, jit

ROOT = Path(__file__).resolve().parent.parent

PROBE = '''
import json
from numba import njit
from virtual.kernels import jit
from virtual.kernels.warps import warp_square

@jit
def with_policy():
    return warp_square(0.75, 0.25, 1.0)[0]

@njit(cache=True)
def plain():
    return warp_square(0.75, 0.25, 1.0)[0]

a, b = with_policy(), plain()
print(json.dumps({"policy": a, "plain": b,
                  "policy_hits": sum(with_policy.stats.cache_hits.values()),
                  "plain_hits": sum(plain.stats.cache_hits.values())}))
'''

OLD = "return r * (2.0 * u1 - 1.0), r * (2.0 * u2 - 1.0)"
NEW = "return r * (2.0 * u1 - 1.0) + 1.0, r * (2.0 * u2 - 1.0)"


def _copy_package(dest: Path) -> None:
    ignore = shutil.ignore_patterns("__pycache__", "*.nbi", "*.nbc")
    shutil.copytree(ROOT / "virtual", dest / "virtual", ignore=ignore)
    shutil.copytree(ROOT / "bench" / "core", dest / "bench" / "core", ignore=ignore)
    (dest / "bench" / "__init__.py").write_text('"""copy for the cache test"""\n')
    (dest / "probe.py").write_text(PROBE)


def _run(where: Path, cache: Path) -> dict:
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_")}
    env.update(PYTHONPATH=str(where), NUMBA_CACHE_DIR=str(cache), PYTHONDONTWRITEBYTECODE="1")
    proc = subprocess.run([sys.executable, str(where / "probe.py")], cwd=where, env=env, capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1])


@pytest.mark.slow  # recompiles a kernel family twice (~15 CPU-s); the staleness test, run by CI
def test_editing_a_called_kernel_recompiles_its_callers(tmp_path):
    where, cache = tmp_path / "copy", tmp_path / "numba-cache"
    _copy_package(where)
    first = _run(where, cache)
    assert first == {"policy": 0.5, "plain": 0.5, "policy_hits": 0, "plain_hits": 0}
    assert list(cache.rglob("probe.with_policy-*.nbi")), "the policy caches under NUMBA_CACHE_DIR"
    assert not list(where.rglob("*.nbi")), "nothing is cached beside the sources when NUMBA_CACHE_DIR is set"

    again = _run(where, cache)  # unchanged sources: both served from the cache
    assert again == {"policy": 0.5, "plain": 0.5, "policy_hits": 1, "plain_hits": 1}

    src = where / "virtual" / "kernels" / "warps.py"
    text = src.read_text()
    assert text.count(OLD) == 1
    src.write_text(text.replace(OLD, NEW))
    edited = _run(where, cache)
    assert edited["policy"] == 1.5 and edited["policy_hits"] == 0  # recompiled from the new source
    assert edited["plain"] == 0.5 and edited["plain_hits"] == 1  # numba's default: stale code served

    settled = _run(where, cache)  # and the new code is cached in its turn
    assert settled["policy"] == 1.5 and settled["policy_hits"] == 1

    # an edit of a kernel file the probe cannot reach (it imports sampling, not spectral32) leaves
    # its cache valid: one file's edit does not recompile every kernel
    other = where / "virtual" / "kernels" / "spectral32.py"
    other.write_text(other.read_text() + "\n# edited\n")
    untouched = _run(where, cache)
    assert untouched["policy"] == 1.5 and untouched["policy_hits"] == 1


def test_jit_marks_and_refuses_a_cache_option():
    with pytest.raises(TypeError, match="cache"):
        jit(cache=False)
    with pytest.raises(TypeError, match="fastmath"):
        jit(fastmath=True)

    def f(x):
        return x + 1

    k = jit(f)
    assert getattr(f, MARK) is True and k(1) == 2


def _decorated(path: Path, test) -> list[str]:
    """Functions of ``path`` with a decorator whose source passes ``test``."""
    tree = ast.parse(path.read_text())
    return [f"{path.name}:{node.name}" for node in ast.walk(tree) if isinstance(node, ast.FunctionDef)
            for d in node.decorator_list if test(ast.unparse(d))]


def test_every_kernel_is_compiled_under_the_policy():
    """Kernels of virtual/, tests/ and benchmarks/ use virtual.kernels.jit, never numba's decorators
    with an on-disk cache (an explicit ``cache=False`` kernel, compiled afresh in every process,
    cannot serve stale code; this file's probe is a string, compiled in the copy only)."""
    files = [*(ROOT / "virtual").rglob("*.py"), *(ROOT / "tests").glob("*.py"), *(ROOT / "benchmarks").glob("*.py")]
    assert [f for p in files for f in _decorated(p, lambda d: ("njit" in d or "numba." in d) and "cache=False" not in d)] == []
    kernel_files = [p for p in (ROOT / "virtual").rglob("*.py") if _decorated(p, lambda d: d.startswith("jit"))]
    assert kernel_files and all(ROOT / "virtual" / "kernels" in p.parents for p in kernel_files)  # laws/ included

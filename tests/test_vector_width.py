"""The kernels' vector width is the project's declared choice, checked on explicit LLVM targets.

Every check here names the target it compiles for (``NUMBA_CPU_NAME``) and only compiles --
nothing runs the code -- so it passes or fails the same way on any x86-64 host, whatever LLVM
would choose for the host's own CPU. The power of each check is shown on a target that has the
property: Intel's server tuning (``skylake-avx512``, ``sapphirerapids``) prefers 256-bit vectors,
so a kernel *without* the declared width gets no 512-bit register there, and one with it does.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from virtual.kernels import vector_width

ROOT = Path(__file__).resolve().parent.parent

PROBE = '''
import json, sys
import numba
from virtual.kernels import jit, vector_width

@jit(family="block32")
def declared(a, b):
    for i in range(a.size):
        a[i] = a[i] * b[i] + numba.float32(1.0)

@jit
def tuned(a, b):
    for i in range(a.size):
        a[i] = a[i] * b[i] + numba.float32(1.0)

sig = (numba.types.float32[::1], numba.types.float32[::1])
for f in (declared, tuned):
    f.compile(sig)  # compiled for the named target, never run
print(json.dumps({"target": vector_width.target(), "declared": vector_width.compiled_width(declared),
                  "tuned": vector_width.compiled_width(tuned)}))
'''


def _compile_for(cpu: str, tmp_path: Path, width: str = "", cache: str | None = None) -> dict:
    probe = tmp_path / "probe_kernels.py"
    probe.write_text(PROBE)
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_") and k != vector_width.ENV}
    env.update(NUMBA_CPU_NAME=cpu, NUMBA_CPU_FEATURES="", PYTHONPATH=str(ROOT),
               NUMBA_CACHE_DIR=str(tmp_path / (cache or f"cache-{cpu}-{width}")))
    if width:
        env[vector_width.ENV] = width
    proc = subprocess.run([sys.executable, str(probe)], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("cpu", ["skylake-avx512", "sapphirerapids"])
def test_the_declared_width_overrides_intels_256_bit_tuning(cpu, tmp_path):
    got = _compile_for(cpu, tmp_path)
    assert got["target"]["cpu"] == cpu
    assert got["declared"] == 512, got  # the table's choice
    assert got["tuned"] == 256, got     # power: what LLVM's tuning for this target picks by itself


def test_the_width_override_narrows_an_avx512_target_and_cached_code_is_read(tmp_path):
    first = _compile_for("x86-64-v4", tmp_path, cache="shared")  # compiled here: numba's own assembly
    assert first["declared"] == 512, first
    if shutil.which("objdump") is not None:  # a cached kernel's width is read by binutils' objdump
        assert _compile_for("x86-64-v4", tmp_path, cache="shared") == first
        assert any((tmp_path / "shared").rglob("*.nbi"))
    assert _compile_for("x86-64-v4", tmp_path, width="256")["declared"] == 256  # the override


def test_the_avx2_target_gets_no_512_bit_register_whatever_the_table_says(tmp_path):
    """What ``python -m benchmarks gonio --isa avx2`` compiles for (x86-64-v3): a family declared
    512 bits wide still gets 256-bit registers at most (the power is the x86-64-v4 case above)."""
    from benchmarks.isa import TARGETS

    got = _compile_for(TARGETS["avx2"], tmp_path)
    assert got["declared"] == 256 and got["tuned"] == 256, got


def test_the_width_in_force_is_part_of_the_cache_stamp(monkeypatch):
    monkeypatch.delenv(vector_width.ENV, raising=False)
    table = vector_width.stamp()
    monkeypatch.setenv(vector_width.ENV, "256")
    assert vector_width.stamp() != table and "block32=256" in vector_width.stamp()
    monkeypatch.setenv(vector_width.ENV, "384")
    with pytest.raises(ValueError, match="must be one of 256, 512, got '384'"):
        vector_width.stamp()


def test_an_unknown_family_is_refused_at_decoration():
    from virtual.kernels import jit

    with pytest.raises(ValueError, match="unknown kernel family 'wide'"):
        @jit(family="wide")
        def f(x):
            return x

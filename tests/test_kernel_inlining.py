"""The inlining policy of :func:`virtual.kernels.jit`: a per-ray helper (``inline="llvm"``) is
compiled on its own, marked ``alwaysinline``, and LLVM inlines it into its caller's loop, so the
loop keeps no call to it; a plain ``@jit`` function is not marked, even when compiled from inside
an ``alwaysinline`` helper (numba would otherwise inherit the flag from the caller). Inspected in a
fresh process with an empty kernel cache (numba cannot show the IR of code loaded from its cache),
compiled for the explicit baseline target ``x86-64``, never the host's choice.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from virtual.kernels import jit

ROOT = Path(__file__).resolve().parent.parent

PROBE = '''
import json, re
import numpy as np
from virtual.kernels import jit
from virtual.kernels.warps import sincos_2pi

@jit
def plain_callee(x):
    return x * 0.5

@jit(inline="llvm")
def helper(u):
    c, s = sincos_2pi(u)
    return plain_callee(c * s)

@jit(error_model="numpy")
def kernel(u):
    t = 0.0
    for i in range(u.size):
        t += helper(u[i])
    return t

kernel(np.linspace(0.0, 1.0, 8))

def attributes(dispatcher, name):
    """The attribute groups of the definitions of ``name`` in the dispatcher's own LLVM IR."""
    ir = next(iter(dispatcher.inspect_llvm().values()))
    groups = dict(re.findall(r"^attributes (#\\d+) = \\{(.*)\\}", ir, re.M))
    out = []
    for line in ir.splitlines():
        m = re.match(r'define [^@]*@"?([^"(]+)', line)
        if m and name in m.group(1) and "cpython" not in m.group(1) and not m.group(1).startswith("cfunc"):
            out += [groups.get(g, "") for g in re.findall(r"#\\d+", line)]
    return " ".join(out)

kernel_ir = next(iter(kernel.inspect_llvm().values()))
calls = [l for l in kernel_ir.splitlines() if re.search(r"\\bcall\\b.*(helper|sincos_2pi)", l)]
print(json.dumps({"helper": attributes(helper, "helper"), "sincos": attributes(sincos_2pi, "sincos_2pi"),
                  "plain": attributes(plain_callee, "plain_callee"), "calls": calls}))
'''


@pytest.fixture(scope="module")
def probe(tmp_path_factory) -> dict:
    tmp = tmp_path_factory.mktemp("inlining")
    (tmp / "probe_inlining.py").write_text(PROBE)
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_")}
    # an explicit target (the baseline every x86-64 CPU runs), not the host's: the inlining
    # decisions asserted here must not depend on which CPU the suite runs on
    env.update(NUMBA_CACHE_DIR=str(tmp / "cache"), PYTHONPATH=os.pathsep.join([str(ROOT), str(tmp)]),
               NUMBA_CPU_NAME="x86-64", NUMBA_CPU_FEATURES="")
    proc = subprocess.run([sys.executable, "-c", "import probe_inlining"], cwd=tmp, env=env, capture_output=True,
                          text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test_llvm_inlined_helpers_are_marked_alwaysinline(probe):
    assert "alwaysinline" in probe["helper"], probe
    assert "alwaysinline" in probe["sincos"], probe  # a project helper, as declared in warps.py


def test_a_plain_function_called_from_an_inlined_helper_is_not_marked(probe):
    assert probe["plain"] and "alwaysinline" not in probe["plain"], probe


def test_the_callers_loop_keeps_no_call_to_an_inlined_helper(probe):
    assert probe["calls"] == [], probe["calls"]


def test_jit_refuses_forceinline_and_maps_llvm_inlining():
    with pytest.raises(TypeError, match="forceinline"):
        jit(forceinline=True)

    def f(x):
        return x

    assert jit(inline="llvm")(f).targetoptions["forceinline"] is True
    assert jit(f).targetoptions["forceinline"] is False

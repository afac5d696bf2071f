"""Kernel compilation is shown while it happens and done ahead by the install step's warm-up."""

from __future__ import annotations

import io
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import numba
import pytest

from bench.compilation import KERNEL_FAMILIES, compile_progress

ROOT = Path(__file__).resolve().parent.parent


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_a_terminal_sees_elapsed_seconds_and_an_estimate():
    def gonio_block32_chunk():  # what a compile event names: a dispatcher of a kernel family
        pass

    dispatcher = type("Dispatcher", (), {"py_func": staticmethod(gonio_block32_chunk)})()
    out = _Terminal()
    with compile_progress(out) as progress:
        assert progress.interactive
        progress._start(dispatcher)
        time.sleep(1.2)  # the ticker redraws every 0.5 s
        progress._end()
    text = out.getvalue()
    label, estimate = KERNEL_FAMILIES["gonio_block32_chunk"]
    assert text.startswith("compiling kernels (first run only)...\n")
    ticks = re.findall(rf"\r  compiling the {re.escape(label)}: +(\d+) s, about (\d+) s left", text)
    assert ticks and all(abs(int(a) + int(b) - estimate) <= 1 for a, b in ticks)  # elapsed + left
    assert re.search(rf"\r  compiled the {re.escape(label)} in \d+ s", text)


def test_families_other_than_kernels_and_nested_compiles_are_not_shown():
    out = io.StringIO()
    with compile_progress(out, interactive=False):
        @numba.njit(cache=False)
        def inner(x):
            return x + 1

        @numba.njit(cache=False)
        def spectro_fx_chunk(x):
            return inner(x)  # compiles inside: one line, for the outer family

        assert spectro_fx_chunk(1) == 2
    lines = out.getvalue().splitlines()
    assert lines == ["compiling kernels (first run only)...",
                     f"  compiling the {KERNEL_FAMILIES['spectro_fx_chunk'][0]} (about "
                     f"{KERNEL_FAMILIES['spectro_fx_chunk'][1]:.0f} s)"]


LATE_NUMBA = """
import io, sys
from bench.compilation import KERNEL_FAMILIES, compile_progress
out = io.StringIO()
with compile_progress(out, interactive=False):
    assert "numba" not in sys.modules  # nothing loaded yet: the listener waits for numba's event bus
    import numba

    @numba.njit(cache=False)
    def gonio_fx_chunk(x):
        return x + 1

    assert gonio_fx_chunk(1) == 2
assert out.getvalue().splitlines() == ["compiling kernels (first run only)...",
    f"  compiling the {KERNEL_FAMILIES['gonio_fx_chunk'][0]} (about {KERNEL_FAMILIES['gonio_fx_chunk'][1]:.0f} s)"]
print("ok")
"""


def test_progress_set_up_before_numba_is_imported_still_sees_the_compiles():
    """A command on the certified fast path never imports numba, so the progress listener must not
    import it either -- yet a command that falls back to rays later must still show its compiles."""
    r = subprocess.run([sys.executable, "-c", LATE_NUMBA], capture_output=True, text=True, cwd=ROOT,
                       env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert r.returncode == 0 and r.stdout.strip() == "ok", r.stderr


COMPILES = """
import json, sys
from numba.core import event
seen = []

class L(event.Listener):
    def on_start(self, ev):
        seen.append(ev.data["dispatcher"].py_func.__name__)
    def on_end(self, ev):
        pass

event.register("numba:compile", L())
from bench.cli import main
for argv in (["gonio", "--specimen", "ggx:alpha=0.2", "--method", "rays", "--rays", "100000", "--seed", "1",
              "--beam", "conical"],
             ["gonio", "--specimen", "lambert:albedo=0.8", "--method", "rays", "--rays", "100000", "--seed", "1"],
             ["spectro", "--specimen", "lambert:reflectance=0.5,transmittance=0.3", "--wavelengths", "450:650:100",
              "--beam", "conical", "--seed", "1"],
             ["spectro", "--specimen", "colorchecker:dark skin", "--geometry", "45/0", "--wavelengths", "450:650:100",
              "--rays", "20000", "--seed", "1"]):
    assert main(argv) == 0, argv
print(json.dumps(seen))
"""


@pytest.mark.slow
def test_after_the_warm_up_the_first_commands_compile_nothing(tmp_path):
    """The install step's warm-up (``python -m bench.compilation``) into an empty cache, then the
    first gonio and spectro commands of docs/commands.md in a new process: numba compiles nothing."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_")}
    env.update(NUMBA_CACHE_DIR=str(tmp_path / "cache"), PYTHONPATH=str(ROOT))
    warm = subprocess.run([sys.executable, "-m", "bench.compilation"], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=3000)
    assert warm.returncode == 0, warm.stderr[-3000:]
    assert "kernels ready" in warm.stderr
    proc = subprocess.run([sys.executable, "-c", COMPILES], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert json.loads(proc.stdout.strip().splitlines()[-1]) == []

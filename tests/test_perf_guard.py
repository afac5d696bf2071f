"""The perf-regression guard's logic (``python -m benchmarks --check``; the timing itself is
not part of ``make test``)."""

from __future__ import annotations

import json

from benchmarks import guard
from benchmarks.__main__ import main


def test_a_ratio_more_than_25_percent_down_fails_and_others_pass():
    accepted = {"ggx / mitsuba-llvm-ggx": 1.0, "lambert / mitsuba-llvm-diffuse": 2.0}
    code, report = guard.check({"ggx / mitsuba-llvm-ggx": 0.76, "lambert / mitsuba-llvm-diffuse": 2.5}, accepted)
    assert code == 0 and "no ratio fell" in report
    code, report = guard.check({"ggx / mitsuba-llvm-ggx": 0.74, "lambert / mitsuba-llvm-diffuse": 2.5}, accepted)
    assert code == 1 and "FAIL ggx / mitsuba-llvm-ggx" in report


def test_ratios_missing_on_either_side_are_listed_not_judged():
    code, report = guard.check({"new one": 1.0}, {"gone": 3.0})
    assert code == 0 and "not measured now" in report and "new (no accepted value)" in report


def test_accept_writes_what_load_reads(tmp_path):
    path = guard.accept({"b": 2.0, "a": 1.0}, tmp_path / "r.json")
    assert guard.load(path) == {"a": 1.0, "b": 2.0}
    assert list(json.loads(path.read_text())["ratios"]) == ["a", "b"]


def test_the_committed_ratios_file_is_readable():
    assert guard.load(), "benchmarks/accepted_ratios.json must hold the last accepted ratios"


def test_bad_options_exit_2(capsys):
    assert main(["--fast"]) == 2
    assert main(["store", "--json"]) == 2
    assert "unknown option" in capsys.readouterr().err


def test_isa_option_is_checked_before_anything_runs(capsys):
    assert main(["gonio", "--isa", "sse9"]) == 2
    assert main(["store", "--isa=avx2"]) == 2
    err = capsys.readouterr().err
    assert "--isa must be one of native, avx2, got 'sse9'" in err and "gonio study only" in err


def test_the_avx2_environment_makes_numba_emit_no_512_bit_register(tmp_path):
    """What ``--isa avx2`` sets up (numba's target from the environment, in a fresh process)
    compiles a vectorizable loop without a zmm register; without it, on an AVX-512 CPU, the
    same loop uses them (power: the check can fail)."""
    import os
    import subprocess
    import sys

    from bench.machine import cpu_info
    from benchmarks.isa import ENV, TARGETS

    script = ("import numba, numpy as np\n"
              "@numba.njit\n"
              "def f(a, b):\n"
              "    for i in range(a.size):\n"
              "        a[i] = a[i] * b[i] + 1.0\n"
              "x = np.ones(4096, np.float32); f(x, x)\n"
              "print('zmm' in f.inspect_asm(f.signatures[0]))\n")
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path))
    narrow = dict(env, **{ENV: "avx2"}, NUMBA_CPU_NAME=TARGETS["avx2"], NUMBA_CPU_FEATURES="")
    run = [sys.executable, "-c", script]
    assert subprocess.run(run, env=narrow, capture_output=True, text=True, check=True).stdout.strip() == "False"
    if cpu_info()["vector_isa"] == "avx512":
        assert subprocess.run(run, env=env, capture_output=True, text=True, check=True).stdout.strip() == "True"

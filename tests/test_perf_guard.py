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


def test_accept_writes_what_load_reads_per_cpu_family(tmp_path):
    path = guard.accept({"b": 2.0, "a": 1.0}, "avx2", tmp_path / "r.json")
    guard.accept({"a": 5.0}, "intel-avx512", path)
    assert guard.load("avx2", path) == {"a": 1.0, "b": 2.0}  # another family's accept keeps it
    assert guard.load("intel-avx512", path) == {"a": 5.0} and guard.load("amd-avx512", path) == {}
    assert list(json.loads(path.read_text())["families"]["avx2"]) == ["a", "b"]


def test_a_cpu_belongs_to_one_family_by_its_code_and_vendor():
    amd = {"vendor": "AuthenticAMD", "vector_isa": "avx512", "compiled_isa": "avx512"}
    intel = {"vendor": "GenuineIntel", "vector_isa": "avx512", "compiled_isa": "avx512"}
    assert guard.family(amd) == "amd-avx512" and guard.family(intel) == "intel-avx512"
    assert guard.family({**intel, "compiled_isa": "avx2"}) == "avx2"  # --isa avx2 on an AVX-512 core
    assert guard.family({"vendor": "AuthenticAMD", "vector_isa": "avx2", "compiled_isa": "avx2"}) == "avx2"


def test_the_committed_ratios_file_is_readable():
    assert guard.load("amd-avx512"), "benchmarks/accepted_ratios.json must hold the last accepted ratios"


def test_bad_options_exit_2(capsys):
    assert main(["--fast"]) == 2
    assert main(["store", "--json"]) == 2
    assert "unknown option" in capsys.readouterr().err


def test_isa_option_is_checked_before_anything_runs(capsys):
    assert main(["gonio", "--isa", "sse9"]) == 2
    assert main(["store", "--isa=avx2"]) == 2
    err = capsys.readouterr().err
    assert "--isa must be one of native, avx2, got 'sse9'" in err and "gonio study only" in err

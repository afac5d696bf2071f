"""Import discipline of the CLI, without timing anything: each command imports the heavy
libraries it needs and no other (the speed they buy is measured by ``python -m benchmarks cli``).

Every check runs the command in a fresh interpreter and reads ``sys.modules`` afterwards.
"""

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from bench.cli import COMMAND_MODULES, build_parser
from bench.cli.commands import COMMANDS

ROOT = Path(__file__).resolve().parents[1]

#: libraries that cost from a tenth of a second to seconds to import
HEAVY = ("numba", "llvmlite", "scipy", "pandas", "pyarrow", "matplotlib", "mitsuba", "drjit", "colour", "dask",
         "distributed", "bluesky", "ophyd", "ophyd_async", "tqdm", "serial", "dynamixel_sdk", "pymodbus")


def imported_by(argv: list[str]) -> set[str]:
    """Top-level packages and project modules in ``sys.modules`` after ``bench ARGV``."""
    code = ("import json, sys\nfrom bench.cli import main\n"
            f"code = main({argv!r})\n"
            "sys.stdout.flush()\n"
            "print('\\nMODULES ' + json.dumps(sorted(sys.modules)), file=sys.stderr)\n"
            "sys.exit(code)\n")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=ROOT)
    assert r.returncode == 0, r.stderr
    return set(json.loads(r.stderr.rsplit("MODULES ", 1)[1]))


def heavy(modules: set[str]) -> list[str]:
    return sorted(m for m in modules if m.split(".")[0] in HEAVY)


def command_modules(modules: set[str]) -> list[str]:
    return sorted(m for m in modules if m in COMMAND_MODULES)


@pytest.fixture(scope="module")
def store_with_run(tmp_path_factory):
    """The path of a store holding one (empty) run, as a string."""
    from bench.store import RunStore

    path = tmp_path_factory.mktemp("imports") / "runs.sqlite"
    with RunStore(path) as s:
        s.create_run("scan", n_planned=1)
    return str(path)


def test_help_imports_no_command_module_and_nothing_heavy():
    mods = imported_by(["--help"])
    assert heavy(mods) == [] and "numpy" not in mods
    assert command_modules(mods) == []


@pytest.mark.parametrize("argv", [["rays", "-u", "0.005", "-d", "0.01"],
                                  ["rays", "-u", "0.005", "-d", "0.01", "--patches", "900", "--json"]])
def test_rays_imports_its_own_module_and_nothing_heavy(argv):
    mods = imported_by(argv)
    assert heavy(mods) == []
    assert command_modules(mods) == ["bench.cli.measure"]


def test_specimens_lists_without_kernels_or_scipy():
    mods = imported_by(["specimens"])
    assert heavy(mods) == []
    assert not [m for m in mods if m.startswith("virtual.kernels")]
    assert command_modules(mods) == ["bench.cli.specimens"]


def test_runs_reads_the_store_without_heavy_imports(store_with_run):
    mods = imported_by(["runs", "--store", store_with_run])
    assert heavy(mods) == []
    assert not [m for m in mods if m.split(".")[0] in ("virtual", "drivers", "compare")]
    assert command_modules(mods) == ["bench.cli.scans"]


@pytest.mark.parametrize("specimen", ["lambert:albedo=0.8", "ggx:alpha=0.3"])
def test_gonio_fast_path_imports_what_it_uses_only(specimen):
    """pandas (the record) and scipy.special (the intervals) are needed; no kernel is loaded
    (the certified fast path draws one multinomial), so neither numba nor a kernel module is;
    nor are scipy.stats, plotting, colour, Mitsuba, Dask and Bluesky."""
    mods = imported_by(["gonio", "--specimen", specimen, "--incidence", "30", "--rays", "1000000", "--seed", "1"])
    assert not [m for m in mods if m == "scipy.stats" or m.startswith("scipy.stats.")]
    assert [m for m in heavy(mods) if m.split(".")[0] in ("numba", "llvmlite", "matplotlib", "colour", "mitsuba",
                                                          "drjit", "dask", "distributed", "bluesky", "ophyd",
                                                          "ophyd_async")] == []
    assert not [m for m in mods if m.startswith("virtual.kernels")]
    assert command_modules(mods) == ["bench.cli.measure"]


def test_gonio_on_rays_loads_the_kernels():
    """The power of the check above: the same command counting rays does import numba."""
    mods = imported_by(["gonio", "--specimen", "lambert:albedo=0.8", "--incidence", "30", "--rays", "1000",
                        "--method", "rays", "--seed", "1"])
    assert "numba" in mods and "virtual.kernels.block32" in mods


def test_the_command_table_matches_what_the_modules_register():
    """``bench --help`` is drawn from bench.cli.commands alone: the same commands, in the same
    order, with the same help, as the modules register in full."""
    def listing(parser: argparse.ArgumentParser) -> list[tuple[str, str]]:
        sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        return [(a.dest, a.help) for a in sub._choices_actions]

    full = build_parser()
    assert listing(full) == [(name, c.help) for name, c in COMMANDS.items()]
    assert build_parser(load=[]).format_help() == full.format_help()
    for name in COMMANDS:
        assert build_parser(load=[name]).format_help() == full.format_help()

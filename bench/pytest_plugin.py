"""pytest plugin for hardware-in-the-loop tests: one suite for the lab's CI and its bench day.

Installed with goniobench (entry point ``pytest11``). It adds ``--bench-config FILE.toml`` and
the session fixture ``hil_bench``: the bench that file describes (real hardware), or, without
the option, the embedded emulated bench (real drivers over wire-level emulators). Tests written
against ``hil_bench`` run unchanged on both::

    def test_my_driver_settles(hil_bench):
        g = Geometry(30, 0, 20, 180)
        assert angular_distance_deg(hil_bench.goniometer.move_to(g), g) < 0.5

``--bench-config`` may also name a virtual bench. Tests marked ``@pytest.mark.hil`` are the
ones that need a bench; ``-m "not hil"`` skips them.
"""

from __future__ import annotations

from typing import Any, Iterator

import pytest


def pytest_addoption(parser: Any) -> None:
    group = parser.getgroup("goniobench")
    group.addoption("--bench-config", action="store", default=None, metavar="FILE.toml",
                    help="run hardware-in-the-loop tests on this bench (default: the embedded emulated bench)")


def pytest_configure(config: Any) -> None:
    config.addinivalue_line("markers", "hil: hardware-in-the-loop test (runs on --bench-config or the emulators)")


@pytest.fixture(scope="session")
def bench_config(request: Any) -> dict[str, Any]:
    """The bench config dict in use (from ``--bench-config`` or the embedded emulated bench)."""
    from bench.builders.emulated import DEFAULT_EMULATED_CONFIG
    from bench.core.parsing import read_toml

    path = request.config.getoption("--bench-config")
    return read_toml(path) if path else dict(DEFAULT_EMULATED_CONFIG)


@pytest.fixture(scope="session")
def hil_bench(bench_config: dict[str, Any]) -> Iterator[Any]:
    """The bench, built once per session and closed (emulators stopped) at the end."""
    from bench.config import load_bench

    bench = load_bench(bench_config)
    try:
        yield bench
    finally:
        bench.close()

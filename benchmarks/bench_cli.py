"""CLI responsiveness: wall seconds of a warm ``bench`` command against its target.

Targets: ``bench --help``, ``bench rays``, ``bench specimens`` and ``bench runs`` answer in at
most 0.5 s; ``bench gonio --rays 1e6`` (a Lambertian, the exact fast path) in at most 1.5 s.
Each command runs as the user runs it, in a fresh interpreter (``python -m bench.cli``) on this
source tree; one unmeasured run first makes it warm (numba's kernel cache built), then the best
and the median of ``repeat`` runs are reported, with the CPU seconds (user + system) of the
best-CPU run: on a loaded machine those leave out the time spent waiting for a CPU, so they
estimate what an idle one reaches.

Most of these seconds are imports (see ``tests/test_cli_imports.py`` for which each command may
load) and, when Python may not write bytecode caches (``PYTHONDONTWRITEBYTECODE``, and no
``__pycache__`` of the project's sources), compiling the project's own sources on every run:
the table says which.

``python -m benchmarks cli --json`` prints the rows as JSON.
"""

from __future__ import annotations

import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from statistics import median

from benchmarks.common import table

ROOT = Path(__file__).resolve().parents[1]

#: (label, arguments after ``bench``, target seconds); ``{store}`` is a small run store
COMMANDS: list[tuple[str, list[str], float]] = [
    ("bench --help", ["--help"], 0.5),
    ("bench rays", ["rays", "--uncertainty", "0.005", "--delta", "0.01"], 0.5),
    ("bench rays --patches 900", ["rays", "--uncertainty", "0.005", "--delta", "0.01", "--patches", "900"], 0.5),
    ("bench specimens", ["specimens"], 0.5),
    ("bench runs", ["runs", "--store", "{store}"], 0.5),
    ("bench gonio --rays 1e6", ["gonio", "--specimen", "lambert:albedo=0.8", "--rays", "1000000", "--seed", "1"], 1.5),
]


def _make_store(path: Path) -> None:
    """A store of two small runs (what ``bench runs`` lists)."""
    from bench.store import RunStore

    with RunStore(path) as s:
        for _ in range(2):
            rid = s.create_run("scan", n_planned=3)
            for i in range(3):
                s.add_point(rid, i, {"theta_i": 30.0, "phi_i": 0.0, "theta_r": 10.0 * i, "phi_r": 0.0},
                            [{"wavelength_nm": 550.0, "signal": 1.0, "value": 0.5}])
            s.set_status(rid, "completed")


def _once(argv: list[str]) -> tuple[float, float]:
    """Wall and CPU (user + system) seconds of one ``bench ARGV`` in a fresh interpreter."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "bench.cli", *argv], env=env, cwd=ROOT,
                       stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if r.returncode != 0:
        raise RuntimeError(f"bench {' '.join(argv)} exited {r.returncode}: {r.stderr.strip()}")
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def _bytecode_cached() -> bool:
    """Whether the project's sources have compiled bytecode next to them (else every run compiles them)."""
    from importlib.util import cache_from_source

    src = ROOT / "bench" / "cli" / "measure.py"
    return Path(cache_from_source(str(src))).exists()


def measure(repeat: int = 5) -> dict:
    """Rows (command, target, best / median wall seconds, best CPU seconds) and the conditions."""
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench-cli-") as tmp:
        store = Path(tmp) / "runs.sqlite"
        _make_store(store)
        for label, argv, target in COMMANDS:
            argv = [a.replace("{store}", str(store)) for a in argv]
            _once(argv)  # warm: kernel cache built, bytecode written when Python may
            walls, cpus = zip(*(_once(argv) for _ in range(repeat)))
            rows.append({"command": label, "argv": argv, "target_s": target, "wall_s_best": min(walls),
                         "wall_s_median": median(walls), "cpu_s_best": min(cpus),
                         "meets_target": min(walls) <= target})
    return {"rows": rows, "repeat": repeat, "load_average": os.getloadavg()[0] if hasattr(os, "getloadavg") else None,
            "cpus": os.cpu_count(), "python": sys.version.split()[0],
            "writes_bytecode": not sys.dont_write_bytecode, "bytecode_cached": _bytecode_cached()}


def run(repeat: int = 5) -> str:
    m = measure(repeat)
    rows = [[r["command"], r["target_s"], r["wall_s_best"], r["wall_s_median"], r["cpu_s_best"],
             r["wall_s_best"] / r["target_s"], "yes" if r["meets_target"] else "NO"] for r in m["rows"]]
    load = m["load_average"]
    return table(f"CLI: warm wall seconds of one command in a fresh interpreter, best and median of {m['repeat']} "
                 f"(load average {load if load is None else f'{load:.1f}'} on {m['cpus']} CPUs; Python "
                 f"{m['python']}; project bytecode cached: {'yes' if m['bytecode_cached'] else 'no'}, "
                 f"written: {'yes' if m['writes_bytecode'] else 'no (PYTHONDONTWRITEBYTECODE)'})",
                 ["command", "target s", "best s", "median s", "CPU s", "best/target", "met"], rows)


if __name__ == "__main__":
    import json

    if "--json" in sys.argv[1:]:
        print(json.dumps(measure(), indent=2))
    else:
        print(run())

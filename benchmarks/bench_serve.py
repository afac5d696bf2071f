"""``bench serve`` start-up: wall seconds from the command's start until it answers.

Two moments of one start, for a store of ``runs`` virtual in-plane scans (the README's plan):

- *answers*: the Tiled server responds on its URI (``GET /api/v1/``);
- *ready*: ``bench serve --json`` printed its line: every stored run is in the catalog.

Three starts: with ``--no-cache`` (every run written anew), the first start with the kept
catalog (the same), and a restart (the kept catalog already holds every run: nothing written).
Target: a restart ready within 5 s on 2 cores. Each row also gives the CPU seconds (user + system)
of the process until ready: on a loaded machine those leave out the time spent waiting for a CPU.

``python -m benchmarks serve``; ``--json`` as the other studies via :func:`measure`.
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

from benchmarks.common import table

ROOT = Path(__file__).resolve().parents[1]
TARGET_S = 5.0


def _make_store(folder: Path, runs: int) -> Path:
    store = folder / "runs.sqlite"
    plan, bench = ROOT / "fixtures" / "plans" / "in-plane.toml", ROOT / "fixtures" / "benches" / "virtual.toml"
    for seed in range(1, runs + 1):
        subprocess.run([sys.executable, "-m", "bench.cli", "scan", str(plan), "--bench", str(bench), "--store",
                        str(store), "--seed", str(seed)], check=True, capture_output=True, cwd=folder)
    return store


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _start(store: Path, env: dict[str, str], *extra: str) -> dict:
    """One start: seconds until the server answers and until the JSON line, the CPU seconds then."""
    port = _free_port()
    t0 = time.perf_counter()
    p = subprocess.Popen([sys.executable, "-m", "bench.cli", "serve", "--store", str(store), "--port", str(port),
                          "--json", *extra], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, env=env)
    try:
        answers = None
        while answers is None and p.poll() is None:
            try:
                urllib.request.urlopen(f"http://127.0.0.1:{port}/api/v1/", timeout=1).read()
                answers = time.perf_counter() - t0
            except OSError:
                time.sleep(0.02)
        line = p.stdout.readline() if p.stdout else ""
        ready = time.perf_counter() - t0
        cpu = _cpu_seconds(p.pid)
        info = json.loads(line)
    finally:
        p.terminate()
        p.wait(30)
    return {"answers_s": answers, "ready_s": ready, "cpu_s": cpu, "written": len(info["runs"]),
            "served": len(info.get("served", info["runs"]))}


def measure(runs: int = 3) -> dict:
    with tempfile.TemporaryDirectory(prefix="bench-serve-") as tmp:
        folder = Path(tmp)
        env = {**os.environ, "PYTHONPATH": str(ROOT), "GONIOBENCH_CACHE_DIR": str(folder / "cache")}
        store = _make_store(folder, runs)
        rows = {"--no-cache": _start(store, env, "--no-cache"), "first start": _start(store, env),
                "restart (kept catalog)": _start(store, env)}
    return {"rows": rows, "runs": runs, "target_s": TARGET_S, "cpus": os.cpu_count(),
            "load_average": os.getloadavg()[0]}


def run(runs: int = 3) -> str:
    m = measure(runs)
    rows = [[name, r["written"], r["served"], r["answers_s"], r["ready_s"], r["cpu_s"]] for name, r in m["rows"].items()]
    restart = m["rows"]["restart (kept catalog)"]["ready_s"]
    return table(f"bench serve: seconds from start until it answers and until every one of {m['runs']} runs is served "
                 f"(load average {m['load_average']:.1f} on {m['cpus']} CPUs; target: a restart ready within "
                 f"{m['target_s']:g} s: {'met' if restart <= m['target_s'] else 'NOT met'})",
                 ["start", "written", "served", "answers s", "ready s", "CPU s"], rows)


if __name__ == "__main__":
    print(json.dumps(measure(), indent=2) if "--json" in sys.argv[1:] else run())

"""No emulator outlives its owner: a process that started an emulated bench is SIGKILLed at
random moments (fixed seed), during start-up and after, and afterwards none of its emulator
processes remains (each exits once its starting process is gone, virtual.wire._pty.exit_with_parent).

The emulators are found by a marker in their environment (inherited from the owner), so one
killed before it could say their pids is searched as well.
"""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import time
import uuid
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MARK = "GONIOBENCH_ORPHAN_TEST"
GIVE_UP_S = 60.0  # a guard against a test that would wait for ever, not a speed bound

OWNER = """
from bench.builders.emulated import DEFAULT_EMULATED_CONFIG
from bench.config import load_bench
import time
bench = load_bench(DEFAULT_EMULATED_CONFIG)
print("ready", flush=True)
time.sleep(600)
"""

#: an owner that starts an emulator and is killed before it connects to it: the emulator then
#: waits in accept() for a parent that will never come, unless it notices the parent is gone
OWNER_BEFORE_CONNECT = """
import os, pickle, time
from virtual.wire._pty import EmulatorProcess
p = EmulatorProcess("virtual.wire._spawned", stdin_data=pickle.dumps((b"k" * 32, os.getcwd(), print, (), ())))
print("ready", flush=True)
time.sleep(600)
"""


def _marked(mark: str) -> list[int]:
    """Pids of the processes whose environment carries ``MARK=mark``."""
    needle = f"{MARK}={mark}".encode()
    pids = []
    for p in Path("/proc").iterdir():
        if p.name.isdigit():
            try:
                if needle in (p / "environ").read_bytes().split(b"\0"):
                    pids.append(int(p.name))
            except OSError:
                continue
    return pids


def _owner(mark: str, code: str = OWNER) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                            text=True, cwd=ROOT, env={**os.environ, MARK: mark, "PYTHONPATH": str(ROOT)})


def _left_after_kill(owner: subprocess.Popen, mark: str) -> list[int]:
    owner.send_signal(signal.SIGKILL)
    owner.wait()
    end = time.monotonic() + GIVE_UP_S
    while (left := _marked(mark)) and time.monotonic() < end:
        time.sleep(0.1)
    for pid in left:  # leave nothing behind for the next test, whatever the verdict
        try:
            os.kill(pid, signal.SIGKILL)
        except OSError:
            pass
    return left


@pytest.mark.skipif(not Path("/proc/self/environ").exists(), reason="needs /proc")
def test_a_killed_owner_after_start_up_leaves_no_emulator():
    mark = uuid.uuid4().hex
    owner = _owner(mark)
    assert owner.stdout.readline().strip() == "ready"
    emulators = [p for p in _marked(mark) if p != owner.pid]
    assert len(emulators) >= 3  # bus, stage, spectrometer: the search sees them (power of the check)
    assert _left_after_kill(owner, mark) == []


@pytest.mark.skipif(not Path("/proc/self/environ").exists(), reason="needs /proc")
def test_an_emulator_whose_owner_dies_before_connecting_exits():
    mark = uuid.uuid4().hex
    owner = _owner(mark, OWNER_BEFORE_CONNECT)
    assert owner.stdout.readline().strip() == "ready"
    assert len([p for p in _marked(mark) if p != owner.pid]) == 1
    assert _left_after_kill(owner, mark) == []


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/environ").exists(), reason="needs /proc")
def test_an_owner_killed_at_random_moments_of_start_up_leaves_no_emulator():
    rng = random.Random(44)
    for delay in [rng.uniform(0.2, 3.0) for _ in range(5)]:
        mark = uuid.uuid4().hex
        owner = _owner(mark)
        time.sleep(delay)
        assert _left_after_kill(owner, mark) == [], f"an emulator outlived its owner killed {delay:.2f} s in"

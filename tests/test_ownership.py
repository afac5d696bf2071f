"""One owner per instrument: device identities, the per-device locks of a bench, refusal of a
second owner in one line naming the first, and take-over of a lock whose owner was killed."""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
import textwrap

import pytest

from bench.builders.ownership import DeviceBusy, LOCK_DIR_ENV, lock_devices, note_run, read_owner
from drivers.identity import device_identity

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


@pytest.fixture(autouse=True)
def lock_dir(tmp_path, monkeypatch):
    d = tmp_path / "locks"
    monkeypatch.setenv(LOCK_DIR_ENV, str(d))
    return d


def test_identity_is_the_device_not_its_spelling(tmp_path):
    node = tmp_path / "ttyUSB0"
    node.write_text("")
    link = tmp_path / "by-id-usb-FTDI"
    link.symlink_to(node)
    assert device_identity(str(link)) == device_identity(str(node)) == f"tty:{node}"
    assert device_identity("tcp://localhost:502") == device_identity("tcp://127.0.0.1:502") == "tcp:127.0.0.1:502"
    assert device_identity("socket://127.0.0.1:502") == "tcp:127.0.0.1:502"
    assert device_identity("tcp://127.0.0.1:503") != device_identity("tcp://127.0.0.1:502")
    assert device_identity("loop://") is None


def _holder(port: str, run: str | None = None) -> subprocess.Popen:
    """A child process that locks ``port``, says so, and waits (to be killed)."""
    code = textwrap.dedent(f"""
        import sys, time
        from bench.builders.ownership import lock_devices, note_run
        locks = lock_devices({{"arm": {port!r}}})
        note_run({run!r})
        print("locked", flush=True)
        time.sleep(600)
    """)
    p = subprocess.Popen([sys.executable, "-c", code, "scan-like"], stdout=subprocess.PIPE, text=True, cwd=ROOT,
                         env={**os.environ, "PYTHONPATH": ROOT})
    assert p.stdout.readline().strip() == "locked"
    return p


def test_a_second_owner_is_refused_naming_the_first_and_a_killed_owner_is_taken_over(tmp_path, caplog, lock_dir):
    port = str(tmp_path / "ttyS9")
    holder = _holder(port, run="20261206-000000-abcd")
    try:
        with pytest.raises(DeviceBusy) as exc:
            lock_devices({"arm": port, "spectrometer": "loop://"})
        msg = str(exc.value)
        assert "\n" not in msg and f"pid {holder.pid}" in msg and "scan-like" in msg
        assert "run 20261206-000000-abcd" in msg and f"arm device {os.path.realpath(port)}" in msg
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait()
    # the kernel dropped the flock with the process; its record is left and taken over with a note
    assert read_owner(device_identity(port))["pid"] == holder.pid
    with caplog.at_level(logging.WARNING, logger="bench.builders.ownership"):
        locks = lock_devices({"arm": port})
    assert any(f"pid {holder.pid}" in r.getMessage() and "no longer runs" in r.getMessage() for r in caplog.records)
    assert read_owner(device_identity(port))["pid"] == os.getpid()
    note_run("run-x")
    assert read_owner(device_identity(port))["run"] == "run-x"
    locks.release()
    note_run(None)
    # a clean release leaves no record (no file): the next owner takes it silently
    assert read_owner(device_identity(port)) is None and not list(lock_dir.glob("*.lock"))
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="bench.builders.ownership"):
        lock_devices({"arm": port}).release()
    assert not caplog.records


def test_all_or_none_a_busy_device_releases_the_ones_already_taken(tmp_path):
    free, busy = str(tmp_path / "a"), "tcp://127.0.0.1:5999"
    holder = _holder(busy)
    try:
        with pytest.raises(DeviceBusy, match=r"turntable device tcp://127\.0\.0\.1:5999 is in use by pid"):
            lock_devices({"arm": free, "turntable": busy})
        lock_devices({"arm": free}).release()  # not left held by the refused attempt
    finally:
        holder.kill()
        holder.wait()


def test_one_process_opening_a_device_twice_is_refused_too(tmp_path):
    port = str(tmp_path / "ttyS1")
    locks = lock_devices({"spectrometer": port})
    try:
        with pytest.raises(DeviceBusy, match=f"pid {os.getpid()}"):
            lock_devices({"spectrometer": port})
    finally:
        locks.release()


def test_a_process_s_own_new_devices_take_a_stale_record_over_silently(tmp_path, caplog):
    """An emulated body's emulators are new devices of this process: a record left on the same pty
    number by a killed process is of another device, not worth a warning."""
    port = str(tmp_path / "pts7")
    holder = _holder(port)
    holder.kill()
    holder.wait()
    with caplog.at_level(logging.WARNING, logger="bench.builders.ownership"):
        lock_devices({"arm": port}, note_stale=False).release()
    assert not caplog.records


def test_the_runner_notes_runs_without_loading_the_drivers():
    """Every scan imports the lock registry; a virtual one must not pull pyserial, the Dynamixel
    SDK or pymodbus in with it (the power: the transports package does load pyserial)."""
    code = ("import sys, bench.runner\nprint(sorted({m.split('.')[0] for m in sys.modules} & "
            "{'serial', 'dynamixel_sdk', 'pymodbus'}))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, check=True).stdout
    assert out.strip() == "[]"
    code = "import sys, drivers.transport\nprint('serial' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, check=True).stdout
    assert out.strip() == "True"

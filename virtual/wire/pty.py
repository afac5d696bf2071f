"""Pseudo-terminal pairs and emulator processes (shared by the wire-level emulators).

An emulator runs in its *own process* (the Dynamixel SDK busy-polls; a thread of the same
process would fight it for the GIL) and owns the master side of a pty. It announces itself by
printing one JSON line on stdout, e.g. ``{"port": "/dev/pts/7", "control": "127.0.0.1:40123",
"pid": 1234}``; :class:`EmulatorProcess` starts ``python -m <module> ...``, waits for that line
and terminates (then kills) the process on :meth:`EmulatorProcess.close`.
"""

from __future__ import annotations

import json
import logging
import os
import select
import signal
import subprocess
import sys
import tempfile
import time
import tty
from pathlib import Path
from typing import Any, Sequence

__all__ = ["open_pty", "EmulatorProcess", "EmulatorStartError"]

log = logging.getLogger(__name__)

_ROOT = Path(__file__).resolve().parents[2]


class EmulatorStartError(RuntimeError):
    """The emulator process did not announce its port in time (its stderr is in the message)."""


def open_pty() -> tuple[int, int, str]:
    """Open a raw pty pair; return ``(master_fd, slave_fd, slave_path)``.

    The slave is set raw (no echo, no line discipline) so bytes pass unchanged. Keep the slave
    fd open in the emulator: on Linux, reading a master whose slave is closed by everyone
    raises EIO.
    """
    master, slave = os.openpty()
    tty.setraw(slave)
    os.set_blocking(master, False)
    return master, slave, os.ttyname(slave)


class EmulatorProcess:
    """``python -m module *args`` in its own process, announced by one JSON line on stdout.

    Parameters
    ----------
    module
        Dotted module path with a ``__main__`` entry (e.g. ``virtual.wire.dynamixel_bus``).
    args
        Command-line arguments.
    start_timeout
        Seconds to wait for the announcement line.

    Attributes
    ----------
    info : dict
        The announcement (``port``, ``control``, ``pid`` ...).
    """

    def __init__(self, module: str, args: Sequence[str] = (), start_timeout: float = 10.0) -> None:
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join([str(_ROOT)] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p])
        # stderr goes to a file, never a pipe nobody drains (a chatty emulator would block)
        self._stderr = tempfile.TemporaryFile()
        self.proc = subprocess.Popen(
            [sys.executable, "-m", module, *args], stdout=subprocess.PIPE, stderr=self._stderr,
            stdin=subprocess.DEVNULL, env=env, cwd=str(_ROOT), start_new_session=True)
        self.info: dict[str, Any] = {}
        try:
            self.info = self._read_announcement(start_timeout)
        except BaseException:
            self.close()
            raise

    def _read_announcement(self, timeout: float) -> dict[str, Any]:
        assert self.proc.stdout is not None
        fd = self.proc.stdout.fileno()
        deadline = time.monotonic() + timeout
        buf = b""
        while b"\n" not in buf:
            remaining = deadline - time.monotonic()
            if remaining <= 0 or self.proc.poll() is not None:
                err = self.stderr_text()
                raise EmulatorStartError(f"emulator {self.proc.args} did not start: "
                                         f"{err[-2000:]}")
            r, _, _ = select.select([fd], [], [], remaining)
            if r:
                chunk = os.read(fd, 4096)
                if not chunk:
                    continue
                buf += chunk
        return json.loads(buf.split(b"\n", 1)[0])

    def stderr_text(self) -> str:
        """What the emulator wrote to stderr so far (for failure messages)."""
        try:
            self._stderr.seek(0)
            return self._stderr.read().decode(errors="replace")
        except (OSError, ValueError):
            return ""

    @property
    def port(self) -> str:
        return str(self.info["port"])

    @property
    def control(self) -> tuple[str, int]:
        host, port = str(self.info["control"]).rsplit(":", 1)
        return host, int(port)

    @property
    def pid(self) -> int:
        return self.proc.pid

    def alive(self) -> bool:
        return self.proc.poll() is None

    def kill(self) -> None:
        """SIGKILL the emulator (its pty vanishes at once)."""
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(timeout=5)

    def close(self, timeout: float = 3.0) -> None:
        """Terminate, then kill if needed; close the pipes. Idempotent."""
        if self.proc.poll() is None:
            try:
                self.proc.send_signal(signal.SIGTERM)
                self.proc.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout=timeout)
        for f in (self.proc.stdout, self._stderr):
            if f is not None:
                try:
                    f.close()
                except OSError:
                    pass

    def __enter__(self) -> "EmulatorProcess":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:  # last resort: never leave an emulator behind
        try:
            if self.proc.poll() is None:
                self.proc.kill()
        except Exception:
            pass

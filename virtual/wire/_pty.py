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
import pickle
import select
import signal
import subprocess
import sys
import tempfile
import time
import tty
from pathlib import Path
from typing import Any, Callable, Sequence

from bench.core.errors import DeviceError, PortGoneError
from bench.core.roles import Closing

__all__ = ["open_pty", "open_raw_pty", "write_all", "EmulatorProcess", "EmulatorStartError", "PipeEmulator",
           "PARENT_ENV", "starting_parent", "exit_with_parent"]

#: environment variable by which an emulator process learns the pid of the process that started it
PARENT_ENV = "GONIOBENCH_EMULATOR_PARENT"

log = logging.getLogger(__name__)

_ROOT = Path(__file__).resolve().parents[2]


def starting_parent() -> int | None:
    """The pid of the process that started this emulator (:data:`PARENT_ENV`), or None when it
    was started by hand. Read from the environment, not ``os.getppid()``: a parent killed while
    this interpreter was still starting has already left us to init."""
    try:
        return int(os.environ[PARENT_ENV])
    except (KeyError, ValueError):
        return None


def exit_with_parent(poll_s: float = 0.2) -> None:
    """Exit this emulator process once the process that started it is gone (killed, however),
    so no emulator outlives its owner: a daemon thread checks every ``poll_s`` s that we still
    are its child (a dead parent's children are re-parented). Nothing when started by hand."""
    import threading

    parent = starting_parent()
    if parent is None:
        return

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(poll_s)
        os._exit(0)

    threading.Thread(target=watch, name="exit-with-parent", daemon=True).start()


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


def write_all(fd: int, data: bytes) -> None:
    """Write every byte of ``data`` to a non-blocking ``fd``, waiting while it is full."""
    view = memoryview(data)
    while view:
        try:
            n = os.write(fd, view)
            view = view[n:]
        except BlockingIOError:
            select.select([], [fd], [], 0.1)


def answer_control(conn: Any, lock: Any, handle: Callable[[Any, dict[str, Any], dict[str, Any]], dict[str, Any]]
                   ) -> bool:
    """Answer one message of an emulator's control pipe (the parent's hooks): ``{"cmd": ...}`` is
    answered ``{"ok": True, ...}``. ``die`` ends the process at once (a crash: nothing closed,
    nothing answered); ``stop`` is acknowledged; any other command is ``handle(cmd, msg, reply)``'s,
    called under ``lock``, which returns the reply (``{"ok": False, "error": ...}`` for a command
    it does not know). False when the emulator is to stop: ``stop``, or the pipe closed."""
    try:
        msg = conn.recv()
    except (EOFError, OSError):
        return False
    cmd = msg.get("cmd")
    reply: dict[str, Any] = {"ok": True}
    with lock:
        if cmd == "die":
            os._exit(1)
        if cmd == "stop":
            conn.send(reply)
            return False
        reply = handle(cmd, msg, reply)
    conn.send(reply)
    return True


def close_quietly(fds: Sequence[int]) -> None:
    """Close file descriptors an emulator held, whichever are still open."""
    for fd in fds:
        try:
            os.close(fd)
        except OSError:
            pass


def open_raw_pty() -> tuple[int, int, str]:
    """A pty pair with *both* ends raw and blocking (for emulators that read the master with
    select/read themselves); return ``(master_fd, slave_fd, slave_path)``."""
    master, slave = os.openpty()
    tty.setraw(slave)
    tty.setraw(master)
    return master, slave, os.ttyname(slave)


class PipeEmulator:
    """Handle on an emulator in its own process, controlled over a ``multiprocessing`` connection.

    The child sends one announcement dict (or ``{"error": ...}``) when it is ready, then answers
    control messages ``{"cmd": ...}`` with ``{"ok": True, ...}``; ``stop`` shuts it down cleanly
    and ``die`` makes it exit at once (an unplugged adapter). Subclasses add their fault
    injection methods on top of :meth:`_call`.
    """

    label = "emulator"

    def __init__(self, proc: Any, conn: Any, info: dict[str, Any]) -> None:
        import threading

        self._proc, self._conn = proc, conn
        self._lock = threading.Lock()
        self.info = info

    @classmethod
    def _spawn(cls, target: Any, head: tuple, tail: tuple, name: str,
               start_timeout: float) -> tuple[Any, Any, dict[str, Any]]:
        """Start ``target(*head, conn, *tail)`` in a new interpreter; wait for its announcement.

        The child is ``python -m virtual.wire._spawned`` (see there): unlike ``multiprocessing``
        spawn it never re-imports the caller's ``__main__``, so emulators start from a script
        without a ``__main__`` guard, from ``python -`` and from notebooks. ``name`` labels errors.
        """
        import secrets
        from multiprocessing.connection import Client

        authkey = secrets.token_bytes(32)
        proc = EmulatorProcess("virtual.wire._spawned", start_timeout=start_timeout,
                               stdin_data=pickle.dumps((authkey, os.getcwd(), target, head, tail)))
        try:
            parent = Client(proc.control, authkey=authkey)
            if not parent.poll(start_timeout):
                raise TimeoutError(f"{cls.label} ({name}) did not start within {start_timeout} s")
            info = parent.recv()
            if "error" in info:
                proc.wait(2)
                raise DeviceError(f"{cls.label} failed to start: {info['error']}")
        except BaseException:
            proc.close()
            raise
        return proc, parent, info

    def _call(self, msg: dict[str, Any], timeout: float = 5.0) -> dict[str, Any]:
        with self._lock:
            if not self._proc.alive():
                raise PortGoneError("the emulator process is not running")
            self._conn.send(msg)
            if not self._conn.poll(timeout):
                raise TimeoutError(f"emulator did not answer {msg}")
            reply = self._conn.recv()
        if not reply.get("ok"):
            raise DeviceError(reply.get("error", "emulator refused"))
        return reply

    @property
    def alive(self) -> bool:
        return self._proc.alive()

    @property
    def pid(self) -> int:
        return self._proc.pid

    def clear_faults(self) -> None:
        self._call({"cmd": "clear"})

    def die(self) -> None:
        """Make the process exit at once (like an unplugged adapter)."""
        with self._lock:
            try:
                self._conn.send({"cmd": "die"})
            except OSError:
                pass
        self._proc.wait(5)
        self.kill()

    def kill(self) -> None:
        """SIGKILL the process."""
        self._proc.kill()

    def stop(self, timeout: float = 3.0) -> None:
        """Shut the emulator down cleanly (kill it if it does not go)."""
        if self._proc.alive():
            try:
                self._call({"cmd": "stop"}, timeout=timeout)
            except Exception:
                pass
            self._proc.wait(timeout)
        self._proc.close()
        self._conn.close()

    close = stop

    def serve_until_interrupted(self, poll_s: float = 0.5) -> None:
        """Block while the emulator runs (a command-line ``main``); stop it on Ctrl-C or exit."""
        try:
            while self.alive:
                time.sleep(poll_s)
        except KeyboardInterrupt:
            pass
        finally:
            self.stop()

    def __enter__(self) -> Any:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


class EmulatorProcess(Closing):
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

    def __init__(self, module: str, args: Sequence[str] = (), start_timeout: float = 10.0,
                 stdin_data: bytes | None = None) -> None:
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join([str(_ROOT)] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p])
        env[PARENT_ENV] = str(os.getpid())  # the child exits when we are gone (exit_with_parent)
        # stderr goes to a file, never a pipe nobody drains (a chatty emulator would block)
        self._stderr = tempfile.TemporaryFile()
        self.proc = subprocess.Popen(
            [sys.executable, "-m", module, *args], stdout=subprocess.PIPE, stderr=self._stderr,
            stdin=subprocess.DEVNULL if stdin_data is None else subprocess.PIPE, env=env, cwd=str(_ROOT),
            start_new_session=True)
        self.info: dict[str, Any] = {}
        try:
            if stdin_data is not None:
                assert self.proc.stdin is not None
                self.proc.stdin.write(stdin_data)
                self.proc.stdin.close()
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

    def wait(self, timeout: float) -> None:
        """Wait up to ``timeout`` s for the process to end on its own."""
        try:
            self.proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            pass

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

    def __del__(self) -> None:  # last resort: never leave an emulator behind
        try:
            if self.proc.poll() is None:
                self.proc.kill()
        except Exception:
            pass

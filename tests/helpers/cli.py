"""Running ``bench`` from tests: in-process (:func:`run_main`), as a child process
(:func:`run_bench`), and in a long-lived child that a timeout can kill (:class:`GuardedWorker`,
for fuzzing: a signal alarm cannot interrupt compiled numba code, a killed process always stops).
"""

from __future__ import annotations

import contextlib
import importlib
import io
import multiprocessing
import subprocess
import sys
import traceback
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]


def run_main(capsys, *argv: object) -> tuple[int, str, str]:
    """``bench ARGV`` in this process (``bench.cli.main``): exit status, stdout, stderr."""
    from bench.cli import main

    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def run_bench(*argv: object, cwd: Path | str = ROOT, timeout: float = 600,
              env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    """``python -m bench.cli ARGV`` as a child process with captured text output."""
    return subprocess.run([sys.executable, "-m", "bench.cli", *[str(a) for a in argv]], capture_output=True,
                          text=True, cwd=cwd, timeout=timeout, env=env)


class Hang(AssertionError):
    """A guarded call ran past its timeout (its process was killed)."""


def _call(target: str, args: tuple) -> tuple[str, Any, str, str]:
    """Run ``module:function(*args)`` with captured output: ("ok", result, out, err) or
    ("raised", formatted traceback, out, err)."""
    module, name = target.split(":")
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            result = getattr(importlib.import_module(module), name)(*args)
            status = "ok"
        except BaseException:  # reported to the parent, which decides what it means
            result, status = traceback.format_exc(), "raised"
    return status, result, out.getvalue(), err.getvalue()


def _serve(conn) -> None:
    while True:
        request = conn.recv()
        if request is None:
            return
        conn.send(_call(*request))


class GuardedWorker:
    """One child process that runs calls sent to it; a call that outlives ``timeout_s`` is a
    :class:`Hang` and its process is killed (a fresh one serves the next call). One process
    start for many calls keeps fuzzing cheap."""

    def __init__(self, timeout_s: float) -> None:
        self.timeout_s = timeout_s
        self._ctx = multiprocessing.get_context("spawn")  # no forked numba threads
        self._proc = None
        self._conn = None

    def _start(self) -> None:
        self._conn, child = self._ctx.Pipe()
        self._proc = self._ctx.Process(target=_serve, args=(child,), daemon=True)
        self._proc.start()
        child.close()

    def call(self, target: str, *args: object) -> tuple[str, Any, str, str]:
        """``target`` ("module:function") on ``args`` in the child: (status, result, out, err)."""
        if self._proc is None or not self._proc.is_alive():
            self._start()
        self._conn.send((target, args))
        if not self._conn.poll(self.timeout_s):
            self.close(kill=True)
            raise Hang(f"{target}{args!r} ran longer than {self.timeout_s} s and was killed")
        return self._conn.recv()

    def bench(self, *argv: object) -> tuple[int, str, str]:
        """``bench ARGV`` in the child: exit status, stdout, stderr (a raised exception is a
        failure of the test, reported with its traceback)."""
        status, result, out, err = self.call("bench.cli:main", [str(a) for a in argv])
        if status != "ok":
            raise AssertionError(f"bench {argv!r} raised:\n{result}")
        return result, out, err

    def close(self, kill: bool = False) -> None:
        if self._proc is None:
            return
        if kill:
            self._proc.kill()
        else:
            with contextlib.suppress(OSError):
                self._conn.send(None)
        self._proc.join(timeout=10)
        if self._proc.is_alive():
            self._proc.kill()
            self._proc.join()
        self._conn.close()
        self._proc = self._conn = None

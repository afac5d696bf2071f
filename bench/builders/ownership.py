"""One owner per instrument: an exclusive lock per physical device a bench opens.

Two processes on one serial line or Modbus endpoint interleave their bytes: each sees the
other's replies as checksum or protocol errors, with no hint of why, and both move the arms. So
the builders of emulated and real benches lock every device before they send it a byte, and a
second process is refused in one line naming the owner (pid, command, run) -- exit 2, nothing
moved.

A lock is an advisory ``flock`` on a file named after the device's identity
(:func:`drivers.identity.device_identity`: the tty's resolved path, the endpoint's
``host:port``) in :func:`lock_dir`. The kernel releases it when its process ends, however it
ends (SIGKILL included), so a lock never outlives its owner. The file keeps the owner's record
(host, pid, start time, command, run id) for the refusal message; a clean release removes it
(while still holding the lock; a taker checks that the file it locked is still the one named). A
record left by a process that no longer runs (killed) is taken over with a warning naming it.

Read-only commands (``plan``, ``show``, ``runs``, ``export``) build no bench and take no lock.
"""

from __future__ import annotations

import datetime as _dt
import errno
import fcntl
import hashlib
import json
import logging
import os
import re
import sys
import tempfile
from pathlib import Path
from typing import Any, Mapping

from bench.core.errors import InputError
from bench.store.owner import process_identity, process_state
from drivers.identity import device_identity

log = logging.getLogger(__name__)

__all__ = ["DeviceBusy", "DeviceLocks", "LOCK_DIR_ENV", "lock_devices", "lock_dir", "note_run", "read_owner"]

#: environment variable naming the lock directory (tests, or a lab that wants its own)
LOCK_DIR_ENV = "GONIOBENCH_LOCK_DIR"

#: the locks this process holds (the run id is written into each when a run starts)
_HELD: list["_DeviceLock"] = []
_RUN: list[str | None] = [None]


class DeviceBusy(InputError):
    """A device of the bench is owned by another process (exit status 2: wait, or stop it)."""


def lock_dir() -> Path:
    """The directory of the device locks: ``$GONIOBENCH_LOCK_DIR``, else ``/run/lock/goniobench``
    (shared by every user of the host), else ``$XDG_RUNTIME_DIR/goniobench``, else one in the
    temporary directory. The first that exists or can be made, and can be written, is used."""
    env = os.environ.get(LOCK_DIR_ENV)
    if env:
        candidates = [Path(env)]
    else:
        candidates = [Path("/run/lock/goniobench")]
        if os.environ.get("XDG_RUNTIME_DIR"):
            candidates.append(Path(os.environ["XDG_RUNTIME_DIR"]) / "goniobench")
        candidates.append(Path(tempfile.gettempdir()) / "goniobench-locks")
    for d in candidates:
        try:
            if not d.is_dir():
                d.mkdir(parents=bool(env))
                os.chmod(d, 0o1777)  # every user of the bench host takes its locks here (sticky)
            if os.access(d, os.W_OK | os.X_OK):
                return d
        except OSError:
            continue
    raise InputError(f"no writable directory for device locks (tried {', '.join(map(str, candidates))}): "
                     f"set {LOCK_DIR_ENV} to one")


def _lock_path(identity: str) -> Path:
    readable = re.sub(r"[^A-Za-z0-9._-]+", "_", identity).strip("_")[:80]
    digest = hashlib.sha1(identity.encode()).hexdigest()[:10]
    return lock_dir() / f"{readable}-{digest}.lock"


def _command() -> str:
    argv = list(sys.argv) or ["?"]
    head = os.path.basename(argv[0])
    if head in ("__main__.py", "bench") or argv[0].endswith(os.path.join("bench", "cli", "__main__.py")):
        head = "bench"
    return " ".join([head, *argv[1:]])[:200]


def _read_record(fd: int) -> dict[str, Any] | None:
    try:
        raw = os.pread(fd, 4096, 0)
        rec = json.loads(raw.decode()) if raw.strip() else None
    except (OSError, UnicodeError, ValueError):
        return None
    return rec if isinstance(rec, dict) else None


def read_owner(identity: str) -> dict[str, Any] | None:
    """The record in ``identity``'s lock file (who owns or last owned the device), or None."""
    try:
        fd = os.open(_lock_path(identity), os.O_RDONLY | os.O_CLOEXEC)
    except OSError:
        return None
    try:
        return _read_record(fd)
    finally:
        os.close(fd)


def _owner_text(rec: dict[str, Any] | None) -> str:
    if not rec:
        return "another process (it has not written its name yet)"
    run = rec.get("run") or "none yet"
    return (f"pid {rec.get('pid')} ({rec.get('command', '?')}; run {run}; since {rec.get('since', '?')}"
            f"{'' if rec.get('host') in (None, process_identity()[0]) else ', host ' + str(rec.get('host'))})")


class _DeviceLock:
    """One held lock (an open descriptor with ``flock`` on it)."""

    def __init__(self, identity: str, roles: list[str], note_stale: bool = True) -> None:
        self.identity, self.roles = identity, roles
        self.path = path = _lock_path(identity)
        for _ in range(20):  # a file unlinked by its owner's release between our open and flock: again
            fd = self._open_locked(path)
            try:
                if os.stat(path).st_ino == os.fstat(fd).st_ino:
                    break
            except FileNotFoundError:
                pass
            os.close(fd)
        else:  # pragma: no cover - twenty releases in a row between an open and a flock
            raise DeviceBusy(f"{self.label}: its lock file {path} keeps changing hands; try again")
        self.fd = fd
        self.since = _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC")
        previous = _read_record(fd)
        if previous and previous.get("pid") is not None:
            try:
                state = process_state(str(previous.get("host")), int(previous["pid"]), previous.get("started"))
            except (TypeError, ValueError):
                state = "gone"
            (log.warning if note_stale else log.debug)(
                "%s: taking over the lock left by %s, which %s", self.label, _owner_text(previous),
                "no longer runs" if state == "gone" else "no longer holds it")
        self.write()

    def _open_locked(self, path: Path) -> int:
        """``path`` opened (created) and flocked, or :class:`DeviceBusy` naming its owner."""
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o666)
        except OSError as exc:
            raise InputError(f"cannot open the lock file {path} of {self.label}: {exc.strerror}") from exc
        try:
            if os.fstat(fd).st_uid == os.geteuid():
                os.fchmod(fd, 0o666)  # other users of the host read and take it after us
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            owner = _read_record(fd)
            os.close(fd)
            if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                raise DeviceBusy(f"{self.label} is in use by {_owner_text(owner)}: refused before any motion; "
                                 f"wait for it to finish or stop it") from None
            raise InputError(f"cannot lock {path} for {self.label}: {exc.strerror}") from exc
        return fd

    @property
    def label(self) -> str:
        kind, _, where = self.identity.partition(":")
        where = f"tcp://{where}" if kind == "tcp" else where
        return f"{'/'.join(self.roles)} device {where}"

    def write(self) -> None:
        host, pid, started = process_identity()
        rec = {"device": self.identity, "roles": self.roles, "host": host, "pid": pid, "started": started,
               "command": _command(), "run": _RUN[0], "since": self.since}
        data = json.dumps(rec).encode()
        try:
            os.ftruncate(self.fd, 0)
            os.pwrite(self.fd, data, 0)
        except OSError as exc:  # the lock holds without its record; a refusal then names no owner
            log.warning("%s: cannot write the owner record: %s", self.label, exc)

    def release(self) -> None:
        if self.fd < 0:
            return
        try:
            os.unlink(self.path)  # while still locked: a clean release leaves nothing to take over
        except OSError:
            pass
        os.close(self.fd)  # closing the descriptor drops the flock
        self.fd = -1


class DeviceLocks:
    """The locks of one bench's devices; :meth:`release` (a bench closer) drops them all."""

    def __init__(self, locks: list[_DeviceLock]) -> None:
        self.locks = locks

    @property
    def identities(self) -> list[str]:
        return [lk.identity for lk in self.locks]

    def release(self) -> None:
        for lk in self.locks:
            lk.release()
            if lk in _HELD:
                _HELD.remove(lk)
        self.locks = []


def lock_devices(ports: Mapping[str, str | None], note_stale: bool = True) -> DeviceLocks:
    """Lock the devices ``ports`` names (role -> port string; None or a port that is no device,
    like ``loop://``, is skipped) before any of them is opened. All or none: if one is owned by
    another process, the ones already taken are released and :class:`DeviceBusy` names the owner.
    ``note_stale``: warn when taking over a killed owner's lock (False for devices this process
    has just created itself, its own emulators: a record there is of an earlier device that had
    the same pty or port number)."""
    roles: dict[str, list[str]] = {}
    for role, port in ports.items():
        identity = device_identity(port) if port else None
        if identity is not None:
            roles.setdefault(identity, []).append(role)
    taken: list[_DeviceLock] = []
    try:
        for identity in sorted(roles):
            taken.append(_DeviceLock(identity, roles[identity], note_stale))
    except BaseException:
        DeviceLocks(taken).release()
        raise
    _HELD.extend(taken)
    return DeviceLocks(taken)


def note_run(run_id: str | None) -> None:
    """Write ``run_id`` into the owner record of every device this process holds (a second
    process on them is then told which run it would disturb)."""
    _RUN[0] = run_id
    for lk in list(_HELD):
        if lk.fd >= 0:
            lk.write()

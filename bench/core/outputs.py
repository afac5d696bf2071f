"""Writing an output: the one atomic writer and the policy every writer and the CLI's early
checks share (:mod:`bench.io.files` builds its text, CSV and figure writers on it).

A path that exists and is not a regular file (a device node such as ``/dev/full``, a FIFO, a
socket, a folder) is never written: one line, exit 2. An existing regular file is replaced only
when replacing is allowed -- :func:`replacing`, which the CLI sets from ``--force``; the Python
API replaces by default. A missing folder is never created unasked. A medium that fails while
writing (disk full, over quota, I/O error, read-only) is :class:`WriteFailed` (exit 1).

:func:`atomic_write` writes to a temporary file in the target's folder, fsyncs it and renames it
over the target, so a reader (or a crash) never sees a half-written file; on any error the
temporary file is removed and the target is left as it was.

Imports nothing heavy: the CLI checks its output arguments with it before any work.
"""

from __future__ import annotations

import contextlib
import contextvars
import errno
import os
import stat
import tempfile
from pathlib import Path
from typing import Any, Callable, Iterator

from bench.core.errors import BenchError, InputError

__all__ = ["WriteFailed", "MEDIUM_ERRORS", "replacing", "replace_allowed", "path_kind", "check_target",
           "write_failed", "atomic_write", "write_text", "save_figure"]

#: errors of the medium, not of the request: the disk is full, over quota, too big, failing, read-only
MEDIUM_ERRORS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EIO, errno.EROFS})

#: whether an existing regular file may be replaced (None: yes, the Python API's default)
_REPLACE: contextvars.ContextVar[bool | None] = contextvars.ContextVar("goniobench_replace", default=None)


class WriteFailed(BenchError):
    """The medium failed while writing (disk full, I/O error): nothing was written (exit 1)."""


@contextlib.contextmanager
def replacing(allowed: bool) -> Iterator[None]:
    """Within the block, writers replace an existing file only if ``allowed`` (the CLI wraps a
    command that has ``--force`` in ``replacing(args.force)``)."""
    token = _REPLACE.set(bool(allowed))
    try:
        yield
    finally:
        _REPLACE.reset(token)


def replace_allowed() -> bool:
    """Whether an existing file may be replaced here (see :func:`replacing`)."""
    return _REPLACE.get() is not False


def path_kind(mode: int) -> str:
    """What a ``st_mode`` is, in words (``a character device``, ``a FIFO`` ...)."""
    for test, name in ((stat.S_ISREG, "a regular file"), (stat.S_ISDIR, "a folder"),
                       (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                       (stat.S_ISFIFO, "a FIFO"), (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return name
    return "not a regular file"


def check_target(path: str | os.PathLike[str], *, force: bool | None = None) -> Path:
    """Refuse (:class:`InputError`, one line) an output path that exists and is not a regular
    file, an existing file when replacing is not allowed (``force``, default :func:`replacing`'s),
    or one whose folder does not exist. Returns the path."""
    p = Path(path)
    allowed = replace_allowed() if force is None else force
    try:
        st = os.stat(p)
    except FileNotFoundError:
        st = None
    except OSError as exc:  # a symlink loop, a name too long, a folder we may not search
        raise InputError(f"output {p}: {exc.strerror or exc}") from None
    if st is not None:
        if not stat.S_ISREG(st.st_mode):
            raise InputError(f"output {p} is {path_kind(st.st_mode)}, not a regular file: refused")
        if not allowed:
            raise InputError(f"output {p} exists: pass --force to replace it")
        return p
    if not p.parent.is_dir():
        raise InputError(f"output {p}: folder {p.parent} does not exist (no folder is created unasked)")
    return p


def write_failed(path: str | os.PathLike[str], exc: OSError) -> WriteFailed | None:
    """The :class:`WriteFailed` of a medium error while writing ``path``, None for any other error."""
    if exc.errno not in MEDIUM_ERRORS:
        return None
    return WriteFailed(f"could not write {path}: {os.strerror(exc.errno)}; nothing was written")


def atomic_write(path: str | os.PathLike[str], write: Callable[[Path], Any], *, force: bool | None = None) -> Path:
    """Call ``write(tmp_path)`` on a temporary file beside ``path``, fsync it, then
    ``os.replace`` it onto ``path``, after :func:`check_target` (``force`` overrides
    :func:`replacing`). The file gets the mode a plain ``open`` would give (``0666`` less the
    umask: 0644 usually), not ``mkstemp``'s 0600. On any error the temporary file is removed and
    ``path`` is left as it was; a medium error is :class:`WriteFailed`. Returns ``path``."""
    p = check_target(path, force=force)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".tmp", dir=p.parent)
    except OSError as exc:
        raise (write_failed(p, exc) or exc) from None
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        os.chmod(tmp_path, 0o666 & ~_umask())  # mkstemp makes 0600; a file people share reads as any other
        write(tmp_path)
        with open(tmp_path, "rb+") as f:
            os.fsync(f.fileno())
        check_target(p, force=force)  # a device or FIFO that appeared meanwhile is never replaced
        if (replace_allowed() if force is None else force):
            os.replace(tmp_path, p)
        else:
            _link_new(tmp_path, p)
    except BaseException as exc:
        try:
            tmp_path.unlink()
        except FileNotFoundError:
            pass
        failed = write_failed(p, exc) if isinstance(exc, OSError) else None
        if failed is not None:
            raise failed from None
        raise
    return p


def _link_new(tmp: Path, p: Path) -> None:
    """Move ``tmp`` to ``p`` only if ``p`` does not exist, atomically (a hard link fails on an
    existing name, so a file another process wrote meanwhile is never replaced)."""
    try:
        os.link(tmp, p)
    except FileExistsError:
        raise InputError(f"output {p} exists: pass --force to replace it") from None
    except OSError as exc:
        if exc.errno not in (errno.EPERM, errno.ENOTSUP, errno.EOPNOTSUPP, errno.EXDEV, errno.EMLINK):
            raise
        os.replace(tmp, p)  # a filesystem without hard links: the check above is what we have
        return
    tmp.unlink()


def _umask() -> int:
    """The process umask (read by setting it and putting it back)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def save_figure(fig: Any, path: str | os.PathLike[str], **savefig: Any) -> Path:
    """Save a matplotlib figure through :func:`atomic_write` (the format from ``path``'s suffix)."""
    fmt = Path(path).suffix.lstrip(".").lower() or None
    return atomic_write(path, lambda tmp: fig.savefig(tmp, format=fmt, **savefig))


def write_text(path: str | os.PathLike[str], text: str) -> Path:
    """Write ``text`` (UTF-8, ``\\n`` line ends) through :func:`atomic_write`; return the path."""
    def w(tmp: Path) -> None:
        with open(tmp, "w", encoding="utf-8", newline="\n") as f:
            f.write(text)
    return atomic_write(path, w)

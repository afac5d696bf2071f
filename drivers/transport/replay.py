"""Recorded exchanges: :class:`ScriptedTransport` replays a transcript byte-exactly,
:class:`RecordingTransport` records one, :func:`load_fixture` / :func:`save_fixture` read and
write the JSON-lines fixture format (see :mod:`drivers.transport`).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Iterable, Sequence

from bench.core.errors import ConfigError, InputError, PortGoneError, TransportMismatchError
from bench.core.parsing import json_problem, read_text
from drivers.transport.base import Pair, Transport, hexbytes

class ScriptedTransport:
    """Replay recorded ``(sent, reply)`` pairs; fail on the first byte that differs.

    Writes are compared byte by byte with the ``sent`` side of the current pair (a pair may be
    written in several pieces, and one write may span pairs). When a pair's ``sent`` bytes are
    complete its ``reply`` becomes readable. Reads never wait: a read that asks for more than
    is queued returns what is there (a timeout, instantly).

    Parameters
    ----------
    pairs
        ``[(sent, reply), ...]`` as bytes, e.g. from :func:`load_fixture`.
    strict_unread
        If true (default), reply bytes still unread at :meth:`close` (or discarded by
        :meth:`reset_input`) are a mismatch; the real SDK reads every reply it asks for.

    Attributes
    ----------
    written : list[bytes]
        Every ``write`` call, in order (also after the script ran out).
    index : int
        Index of the pair currently expected.
    """

    def __init__(self, pairs: Iterable[tuple[bytes, bytes]], strict_unread: bool = True) -> None:
        self.pairs: list[Pair] = [(bytes(s), bytes(r)) for s, r in pairs]
        self.strict_unread = strict_unread
        self.written: list[bytes] = []
        self.index = 0
        self._offset = 0  # bytes of pairs[index].sent already matched
        self._rx = bytearray()
        self._failed = False
        self._closed = False
        self._discarded: list[tuple[int, bytes]] = []
        self._queue_replies_without_sent()

    # -- helpers ----------------------------------------------------------------------------
    def _queue_replies_without_sent(self) -> None:
        while self.index < len(self.pairs) and not self.pairs[self.index][0]:
            self._rx += self.pairs[self.index][1]
            self.index += 1

    def _fail(self, message: str) -> TransportMismatchError:
        self._failed = True
        return TransportMismatchError(message)

    @property
    def done(self) -> bool:
        """True when every pair was sent and every reply read."""
        return self.index >= len(self.pairs) and not self._rx and self._offset == 0

    # -- Transport --------------------------------------------------------------------------
    def write(self, data: bytes) -> None:
        if self._closed:
            raise PortGoneError("scripted transport is closed")
        data = bytes(data)
        self.written.append(data)
        pos = 0
        while pos < len(data):
            if self.index >= len(self.pairs):
                raise self._fail(
                    f"unexpected write after the last of {len(self.pairs)} recorded pairs: "
                    f"got {hexbytes(data[pos:])}")
            sent, reply = self.pairs[self.index]
            want = sent[self._offset:]
            got = data[pos:pos + len(want)]
            for k, (a, b) in enumerate(zip(want, got)):
                if a != b:
                    at = self._offset + k
                    got_full = sent[:self._offset] + data[pos:pos + len(want)]
                    raise self._fail(
                        f"pair {self.index}: sent byte {at} differs "
                        f"(expected 0x{a:02X}, got 0x{b:02X}); expected {hexbytes(sent)} "
                        f"got {hexbytes(got_full)}")
            pos += len(got)
            self._offset += len(got)
            if self._offset == len(sent):
                self._rx += reply
                self.index += 1
                self._offset = 0
                self._queue_replies_without_sent()

    def read(self, n: int, timeout: float = 0.0) -> bytes:
        if self._closed:
            raise PortGoneError("scripted transport is closed")
        out = bytes(self._rx[:n])
        del self._rx[:n]
        return out

    @property
    def in_waiting(self) -> int:
        return len(self._rx)

    def reset_input(self) -> None:
        if self._rx:
            self._discarded.append((self.index, bytes(self._rx)))
            self._rx.clear()

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        if self._failed:
            return  # the first mismatch was already raised; do not mask it
        problems: list[str] = []
        if self._offset:
            sent = self.pairs[self.index][0]
            problems.append(f"pair {self.index} only partly sent ({self._offset} of {len(sent)} "
                            f"bytes: {hexbytes(sent)})")
            left = len(self.pairs) - self.index - 1
        else:
            left = len(self.pairs) - self.index
        if left > 0:
            nxt = self.pairs[len(self.pairs) - left][0]
            problems.append(f"{left} recorded pair(s) never sent, next is pair "
                            f"{len(self.pairs) - left}: {hexbytes(nxt)}")
        if self.strict_unread:
            if self._rx:
                problems.append(f"{len(self._rx)} reply byte(s) never read: {hexbytes(bytes(self._rx))}")
            for idx, d in self._discarded:
                problems.append(f"reply bytes discarded unread before pair {idx}: {hexbytes(d)}")
        if problems:
            raise TransportMismatchError("scripted transport closed with leftovers: "
                                         + "; ".join(problems))

    def __repr__(self) -> str:
        return f"ScriptedTransport({len(self.pairs)} pairs, at {self.index})"


# --- recording -----------------------------------------------------------------------------


class RecordingTransport:
    """Pass bytes through to ``inner`` and write the exchange to ``path`` as a fixture.

    A pair is one ``write`` plus every byte read until the next ``write``. The file is written
    at :meth:`close` (and by :meth:`flush`); parent directories are created.

    Parameters
    ----------
    inner
        The live transport.
    path
        Fixture file to write (JSON lines, see the module docstring).
    note
        Free text stored in the header line.
    """

    def __init__(self, inner: Transport, path: str | os.PathLike[str], note: str = "") -> None:
        self.inner = inner
        self.path = Path(path)
        self.note = note
        self.pairs: list[Pair] = []
        self._sent: bytes | None = None
        self._reply = bytearray()
        self._closed = False

    def _finish_pair(self) -> None:
        if self._sent is not None or self._reply:
            self.pairs.append((self._sent or b"", bytes(self._reply)))
        self._sent = None
        self._reply = bytearray()

    def write(self, data: bytes) -> None:
        self._finish_pair()
        self._sent = bytes(data)
        self.inner.write(data)

    def read(self, n: int, timeout: float) -> bytes:
        data = self.inner.read(n, timeout)
        self._reply += data
        return data

    @property
    def in_waiting(self) -> int:
        return int(getattr(self.inner, "in_waiting", 0))

    def reset_input(self) -> None:
        self.inner.reset_input()

    def flush(self) -> list[Pair]:
        """Write the pairs so far to :attr:`path`; return them (including the open pair)."""
        pairs = list(self.pairs)
        if self._sent is not None or self._reply:
            pairs.append((self._sent or b"", bytes(self._reply)))
        save_fixture(self.path, pairs, note=self.note)
        return pairs

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self._finish_pair()
        try:
            save_fixture(self.path, self.pairs, note=self.note)
        finally:
            self.inner.close()


def save_fixture(path: str | os.PathLike[str], pairs: Sequence[tuple[bytes, bytes]],
                 note: str = "") -> None:
    """Write ``pairs`` as a JSON-lines fixture (see the module docstring)."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    header = {"format": "goniobench-transcript", "version": 1}
    if note:
        header["note"] = note
    lines = [json.dumps(header)]
    lines += [json.dumps({"sent": hexbytes(s), "reply": hexbytes(r)}) for s, r in pairs]
    tmp = p.with_name(p.name + ".tmp")
    tmp.write_text("\n".join(lines) + "\n", encoding="utf-8")
    os.replace(tmp, p)


def _unhex(text: str, where: str) -> bytes:
    try:
        return bytes.fromhex(text.replace(" ", "").replace(":", ""))
    except (ValueError, AttributeError) as exc:
        raise ConfigError(f"{where}: not hex bytes: {text!r}") from exc


def load_fixture(path: str | os.PathLike[str]) -> list[Pair]:
    """Read a JSON-lines fixture; return ``[(sent, reply), ...]`` as bytes.

    Raises
    ------
    ConfigError
        If the file cannot be read, or a line is not JSON, lacks ``sent``/``reply`` or holds bad hex (naming the line).
    """
    try:
        text = read_text(Path(path), "fixture")
    except InputError as exc:
        raise ConfigError(str(exc)) from None
    pairs: list[Pair] = []
    for lineno, line in enumerate(text.splitlines(), 1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        where = f"{path}:{lineno}"
        try:
            obj = json.loads(s)
        except ValueError as exc:  # JSONDecodeError, or an integer longer than int() takes
            raise ConfigError(f"{where}: not JSON ({json_problem(exc, at=True)})") from None
        if not isinstance(obj, dict):
            raise ConfigError(f"{where}: expected an object")
        if "format" in obj:
            if obj.get("format") != "goniobench-transcript":
                raise ConfigError(f"{where}: unknown fixture format {obj.get('format')!r}")
            continue
        if "sent" not in obj or "reply" not in obj:
            raise ConfigError(f"{where}: needs 'sent' and 'reply'")
        pairs.append((_unhex(obj["sent"], where), _unhex(obj["reply"], where)))
    return pairs

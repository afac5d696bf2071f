"""The Ocean emulator's device: a byte parser for binary and ASCII modes, and its replies.

Owns :class:`_Device` (command letters and their data, ACK/NAK, queries, calibration slots,
acquisitions scheduled in time, triggers) and the fault injection state :class:`_Faults`.
"""

from __future__ import annotations

import logging
import random
import time
from typing import Callable


from virtual.wire._ocean_codec import ACK, CR, ETX, LF, NAK, STX, encode_frame, encode_frame_ascii
from virtual.wire.ocean_model import Settings, SpectrometerModel

log = logging.getLogger(__name__)

#: commands followed by one 16-bit word in binary mode
_NO_DATA = set(b"SQLv")
#: one-word settings the unit accepts: letter -> (state attribute, lowest, highest, type)
_SETTINGS: dict[str, tuple[str, int, int, type]] = {
    "A": ("scans", 1, 5000, int),
    "B": ("boxcar", 0, 15, int),
    "G": ("compression", 0, 1, bool),
    "I": ("integration_ms", 1, 65000, int),
    "J": ("lamp", 0, 1, bool),
    "K": ("baud_code", 0, 7, int),
    "M": ("storage", 0, 1, int),
    "T": ("trigger", 0, 4, int),
    "k": ("checksum", 0, 1, bool),
}
#: commands followed by one data word
_ONE_WORD = {ord(letter) for letter in _SETTINGS}

class _Faults:
    def __init__(self, rate: float = 0.0, seed: int = 0) -> None:
        self.nak: list[int | None] = []   # command letters (None = any) to NAK once each
        self.drop = 0
        self.corrupt = 0
        self.no_memory = 0
        #: random transient faults (soak): each command is NAKed, or its reply dropped, with
        #: probability ``rate`` / 2 each; each frame is corrupted with probability ``rate``
        self.rate = float(rate)
        self.rng = random.Random(seed)
        self.injected = {"nak": 0, "drop": 0, "corrupt": 0}

    def draw(self, kinds: tuple[str, ...]) -> str | None:
        """A random fault of ``kinds`` (each with probability rate / len(kinds)), or None."""
        if self.rate <= 0:
            return None
        u = self.rng.random()
        for k, kind in enumerate(kinds):
            if u < self.rate * (k + 1) / len(kinds):
                self.injected[kind] += 1
                return kind
        return None


class _Device:
    """Consumes received bytes, emits replies; acquisitions complete at a scheduled time."""

    def __init__(self, model: SpectrometerModel, write: Callable[[bytes], None]) -> None:
        self.model = model
        self.write = write
        self.buf = bytearray()
        self.faults = _Faults()
        self.pending: tuple[float, bytes] | None = None   # (ready time, reply)
        self.waiting_trigger: Callable[[], bytes] | None = None
        self.commands = 0
        self.acquisitions = 0
        self.last_rx = time.monotonic()

    # -- helpers ------------------------------------------------------------------------------
    @property
    def s(self) -> Settings:
        return self.model.settings

    def _fault_for(self, letter: int) -> str | None:
        f = self.faults
        if f.drop > 0:
            f.drop -= 1
            return "drop"
        for i, want in enumerate(f.nak):
            if want is None or want == letter:
                del f.nak[i]
                return "nak"
        return f.draw(("nak", "drop"))

    def feed(self, data: bytes) -> None:
        now = time.monotonic()
        if self.buf and now - self.last_rx > 1.0:
            log.info("discarding incomplete command %s", bytes(self.buf).hex(" "))
            self.buf.clear()
        self.last_rx = now
        if self.s.mode == "ascii":
            self.write(data)  # echo every byte as it arrives
        self.buf += data
        self.process()

    def process(self) -> None:
        while self.buf and self.pending is None and self.waiting_trigger is None:
            used = self._ascii_step() if self.s.mode == "ascii" else self._binary_step()
            if used == 0:
                return
            del self.buf[:used]

    # -- binary -------------------------------------------------------------------------------
    def _binary_step(self) -> int:
        b = self.buf
        c = b[0]
        if chr(c) in self.model.cfg.unsupported:
            self._reply_nak(c)  # a unit without this command: the letter alone is refused
            return 1

        def word(i: int) -> int:
            return b[i] << 8 | b[i + 1]

        if c in _ONE_WORD:
            if len(b) < 3:
                return 0
            self._command(c, [word(1)])
            return 3
        if c in _NO_DATA:
            self._command(c, [])
            return 1
        if c == ord("W"):
            if len(b) < 5:
                return 0
            self._command(c, [word(1), word(3)])
            return 5
        if c == ord("P"):
            if len(b) < 3:
                return 0
            mode = word(1)
            need = {0: 0, 1: 1, 3: 3}.get(mode)
            if mode in (4, 5):
                if len(b) < 5:
                    return 0
                cnt = word(3)
                need = 1 + cnt * (1 if mode == 4 else 2)
            if need is None:
                self._command(c, [mode])
                return 3
            if len(b) < 3 + 2 * need:
                return 0
            self._command(c, [mode] + [word(3 + 2 * i) for i in range(need)])
            return 3 + 2 * need
        shared = self._mode_or_plain_query(c, b)
        if shared is not None:
            return shared
        if c == ord("?"):  # ?x: one data word
            if len(b) < 4:
                return 0
            self._query(b[1], word(2))
            return 4
        self._reply_nak(c)
        return 1

    def _mode_or_plain_query(self, c: int, b: bytearray) -> int | None:
        """What both framings read alike: ``aA``/``bB`` (switch the framing) and ``?`` with a
        letter that takes no data (every query but ``?x``). Bytes used (0: wait for more), or None
        when the caller reads ``c`` itself."""
        if c in (ord("a"), ord("b")):
            return self._mode_switch(c, b)
        if c != ord("?"):
            return None
        if len(b) < 2:
            return 0
        if b[1] == ord("x"):
            return None
        self._query(b[1], None)
        return 2

    # -- ascii (per the manual: letter; each data value in decimal ending CR; aA/bB bare) --------
    def _ascii_values(self, start: int, count: int) -> tuple[list[int], int] | None | str:
        """``count`` CR-terminated decimal values from ``buf[start:]``: (values, end), None when
        incomplete, ``"bad"`` when a value is not a number."""
        vals, i = [], start
        for _ in range(count):
            try:
                end = self.buf.index(CR, i)
            except ValueError:
                return None
            text = bytes(self.buf[i:end]).decode("ascii", "replace").strip()
            if not text.lstrip("-").isdigit():
                return "bad"
            vals.append(int(text))
            i = end + 1
        return vals, i

    def _ascii_step(self) -> int:
        b = self.buf
        c = b[0]
        if chr(c) in self.model.cfg.unsupported:
            self._reply_nak(c)
            return 1
        if c in _NO_DATA:
            self._command(c, [])
            return 1
        shared = self._mode_or_plain_query(c, b)
        if shared is not None:
            return shared
        if c == ord("?"):  # ?x: one value
            got = self._ascii_values(2, 1)
            if got is None:
                return 0
            if got == "bad":
                self._reply_nak(c)
                return len(b)
            vals, used = got
            self._query(b[1], vals[0])
            return used
        if c in _ONE_WORD or c == ord("W"):
            got = self._ascii_values(1, 2 if c == ord("W") else 1)
        elif c == ord("P"):
            got = self._ascii_values(1, 1)
            if isinstance(got, tuple):
                mode = got[0][0]
                need = {0: 0, 1: 1, 3: 3}.get(mode, 0)
                if mode in (4, 5):
                    cnt = self._ascii_values(got[1], 1)
                    if not isinstance(cnt, tuple):
                        return 0 if cnt is None else self._nak_all(c)
                    need = 1 + cnt[0][0] * (1 if mode == 4 else 2)
                got = self._ascii_values(1, 1 + need)
        else:
            self._reply_nak(c)  # unknown letter (or a stray CR / LF)
            return 1
        if got is None:
            return 0
        if got == "bad":
            return self._nak_all(c)
        vals, used = got
        self._command(c, vals)
        return used

    def _nak_all(self, c: int) -> int:
        self._reply_nak(c)
        return len(self.buf)

    def _mode_switch(self, c: int, b: bytes | bytearray) -> int:
        """``aA`` / ``bB`` (two bare bytes, the same in either mode): bytes consumed, 0 to wait."""
        if len(b) < 2:
            return 0
        if b[1] == c - 32:
            self._command(c, [])
            return 2
        self._reply_nak(c)
        return 1

    # -- semantics ----------------------------------------------------------------------------
    def _reply_nak(self, c: int) -> None:
        log.info("NAK to %r", chr(c))
        self.write(bytes([NAK]))

    def _command(self, c: int, args: list[int]) -> None:
        self.commands += 1
        fault = self._fault_for(c)
        if fault == "drop":
            log.info("fault: no reply to %r", chr(c))
            return
        if fault == "nak":
            self._reply_nak(c)
            return
        s = self.s
        ok = True
        letter = chr(c)
        a0 = args[0] if args else None
        if letter == "S":
            self._acquire()
            return
        if letter in _SETTINGS:
            attr, lo, hi, kind = _SETTINGS[letter]
            ok = a0 is not None and lo <= a0 <= hi
            if ok:
                setattr(s, attr, kind(a0))
        elif letter == "P":
            ok = self._pixel_mode(args)
        elif letter == "Q":
            self.model.reset()
        elif letter == "L":
            pass
        elif letter == "W":
            ok = len(args) == 2
        elif letter == "v":
            self.write(bytes([ACK]) + self._value(self._version_word()))
            return
        elif letter == "a":
            s.mode = "ascii"
        elif letter == "b":
            s.mode = "binary"
        else:
            ok = False
        self.write(bytes([ACK if ok else NAK]))

    def _version_word(self) -> int:
        """The manual's reading: the version's decimal digits as one word ("1.00.0" -> 1000)."""
        return int("".join(ch for ch in self.model.cfg.firmware if ch.isdigit()))

    def _value(self, v: int, dword: bool = False) -> bytes:
        if self.s.mode == "ascii":
            return f"{v}\r\n".encode()
        return int(v).to_bytes(4 if dword else 2, "big")

    def _pixel_mode(self, args: list[int]) -> bool:
        n = self.model.cfg.pixels
        m, prm = args[0], args[1:]
        if m == 0 and not prm:
            pass
        elif m == 1 and len(prm) == 1 and 1 <= prm[0] < n:
            pass
        elif m == 3 and len(prm) == 3 and 0 <= prm[0] <= prm[1] < n and prm[2] >= 1:
            pass
        elif m == 4 and prm and prm[0] == len(prm) - 1 and 1 <= prm[0] <= 10 \
                and all(0 <= p < n for p in prm[1:]):
            pass
        elif m == 5 and prm and 1 <= prm[0] <= 10 and len(prm) == 1 + 2 * prm[0] \
                and all(0 <= a <= b < n for a, b in zip(prm[1::2], prm[2::2])):
            pass
        else:
            return False
        self.s.pixel_mode, self.s.pixel_params = m, list(prm)
        return True

    def _query(self, q: int, arg: int | None) -> None:
        self.commands += 1
        fault = self._fault_for(ord("?"))
        if fault == "drop":
            return
        if fault == "nak":
            self._reply_nak(ord("?"))
            return
        s = self.s
        letter = chr(q)
        if letter == "x":
            text = self.model.cfg.slot(int(arg or 0))
            if text is None:
                self._reply_nak(q)
                return
            self.write(bytes([ACK]) + text.encode("ascii") + bytes([CR, LF]))
            return
        table = {"A": s.scans, "B": s.boxcar, "I": s.integration_ms, "K": s.baud_code,
                 "T": s.trigger, "J": int(s.lamp)}
        if letter in table:
            self.write(bytes([ACK]) + self._value(table[letter]))
        elif letter == "i":
            self.write(bytes([ACK]) + self._value(s.integration_ms * 100, dword=True))
        elif letter == "j":
            self.write(bytes([ACK]) + self._value(s.integration_ms * 1000, dword=True))
        else:
            self._reply_nak(q)

    def _acquire(self) -> None:
        s, cfg, f = self.s, self.model.cfg, self.faults
        npix = len(self.model.selected_pixels())
        if f.no_memory > 0 or npix * s.scans > cfg.memory_pixels:
            f.no_memory = max(0, f.no_memory - 1)
            self.write(bytes([ETX]))
            return

        def build() -> bytes:
            values = self.model.acquire()
            self.acquisitions += 1
            if s.mode == "ascii":
                body = encode_frame_ascii(values, s, convention=cfg.dword_checksum)
            else:
                body = bytearray(encode_frame(values, s, convention=cfg.dword_checksum))
                if f.corrupt > 0 or f.draw(("corrupt",)):
                    f.corrupt = max(0, f.corrupt - 1)
                    i = 14 + len(s.pixel_params) * 2 + min(40, npix)  # inside the pixel data
                    body[i] ^= 0x10
                    log.info("fault: flipped byte %d of the frame", i)
                body = bytes(body)
            return bytes([STX]) + body

        if s.trigger >= 2:
            self.waiting_trigger = build
            return
        delay = s.integration_ms * s.scans / 1000.0 / max(cfg.time_scale, 1e-9)
        self.pending = (time.monotonic() + delay, build())

    def tick(self) -> float | None:
        """Send a finished acquisition; return seconds until the next event (None: idle)."""
        if self.pending is not None:
            ready, reply = self.pending
            left = ready - time.monotonic()
            if left > 0:
                return left
            self.pending = None
            self.write(reply)
            self.process()
        return None

    def external_trigger(self) -> None:
        if self.waiting_trigger is not None:
            build, self.waiting_trigger = self.waiting_trigger, None
            self.write(build())
            self.process()


class DeviceTransport:
    """An in-process emulated unit as a byte transport (``write``/``read``/``reset_input``/...).

    Replies are produced as the bytes are written; an acquisition is released by ``read`` once
    its time has come (waiting up to the read's timeout). For fast tests; the process emulator
    on a pty is the timing-faithful one.
    """

    def __init__(self, model: SpectrometerModel) -> None:
        self._rx = bytearray()
        self.device = _Device(model, self._rx.extend)
        self.written: list[bytes] = []
        self.closed = False

    def write(self, data: bytes) -> None:
        if self.closed:
            raise OSError(5, "device transport closed")
        self.written.append(bytes(data))
        self.device.feed(bytes(data))

    def read(self, n: int, timeout: float = 0.0) -> bytes:
        if self.closed:
            raise OSError(5, "device transport closed")
        end = time.monotonic() + timeout
        while len(self._rx) < n:
            left = self.device.tick()
            if left is None and self.device.pending is None:
                break
            now = time.monotonic()
            if now >= end:
                break
            time.sleep(min(left or 0.0, end - now))
        out = bytes(self._rx[:n])
        del self._rx[:n]
        return out

    @property
    def in_waiting(self) -> int:
        self.device.tick()
        return len(self._rx)

    def reset_input(self) -> None:
        self._rx.clear()

    def close(self) -> None:
        self.closed = True

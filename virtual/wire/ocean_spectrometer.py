"""An Ocean-Optics-style RS-232 spectrometer, emulated on a pseudo-terminal in its own process.

It speaks the protocol of ``/work/shared/reference/ocean-rs232.md`` as pinned down in
:mod:`drivers.ocean` (binary and ASCII modes, ACK/NAK, checksum mode, compression, scans to
add, trigger mode, ``?x`` calibration slots) and produces

    counts = lamp(lambda) * response(geometry, lambda) * integration_ms * peak_counts_per_ms
             + dark + noise,   through a mild detector non-linearity, saturating at 65535 per scan

where ``geometry = geometry_source()`` is asked once per acquisition (``None`` when there is no
goniometer) and ``response(geometry, wavelengths_nm) -> np.ndarray`` is the reflected fraction
(default: the constant ``reflectance``). Both may be given as callables (picklable: module-level
functions or ``functools.partial`` of them, since the emulator runs in a spawned process) or as
``"package.module:attribute"`` strings imported in the emulator process. Optically masked
pixels (``dark_pixels``) see only the dark signal.

Start, inject faults, stop::

    from virtual.wire.ocean_spectrometer import SpectrometerEmulator
    with SpectrometerEmulator.start(reflectance=0.5, seed=1) as emu:
        emu.port                 # the pty slave path: give it to the driver
        emu.nak("I")             # NAK the next I command (or emu.nak() for the next command)
        emu.drop_replies(1)      # the next command gets no reply at all
        emu.corrupt_frames(1)    # one byte of the next S frame's pixel data is flipped
        emu.no_memory(1)         # the next S answers ETX (insufficient memory)
        emu.trigger()            # release an acquisition waiting in an external trigger mode
        emu.state()              # settings, mode, counters
        emu.die()                # the process exits at once; the pty vanishes

From a shell: ``python -m virtual.wire.ocean_spectrometer`` prints one JSON line with the port.
"""

from __future__ import annotations

import argparse
import importlib
import json
import logging
import os
import select
import sys
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from virtual.wire.pty import PipeEmulator, open_raw_pty

log = logging.getLogger(__name__)

__all__ = ["SpectrometerConfig", "SpectrometerModel", "SpectrometerEmulator",
           "constant_response", "cosine_response", "file_geometry_source", "encode_frame",
           "compress", "start_spectrometer_emulator"]

ACK, NAK, STX, ETX, CR = 0x06, 0x15, 0x02, 0x03, 0x0D
#: commands followed by one 16-bit word in binary mode
_ONE_WORD = set(b"ABGIJKMTk")
_NO_DATA = set(b"SQLv")


def constant_response(geometry: Any, wavelengths_nm: np.ndarray, factor: float = 0.5) -> np.ndarray:
    """The default signal model: the same reflected fraction at every wavelength."""
    return np.full(np.shape(wavelengths_nm), float(factor))


def cosine_response(geometry: Any, wavelengths_nm: np.ndarray, factor: float = 0.5) -> np.ndarray:
    """A Lambertian specimen seen by a fixed detector: ``factor * cos(theta_i)``.

    ``geometry`` is a mapping or object with ``theta_i`` in degrees (``None``: normal incidence).
    """
    if geometry is None:
        theta = 0.0
    elif isinstance(geometry, dict):
        theta = float(geometry.get("theta_i", 0.0))
    else:
        theta = float(getattr(geometry, "theta_i", 0.0))
    return np.full(np.shape(wavelengths_nm), float(factor) * max(np.cos(np.radians(theta)), 0.0))


def file_geometry_source(path: str) -> Any:
    """Read the current geometry from a JSON file (``None`` when it does not exist yet).

    A stand-in for a goniometer emulator publishing its joint angles: bind the path with
    ``functools.partial(file_geometry_source, path)``.
    """
    try:
        with open(path, encoding="utf-8") as fh:
            return json.load(fh)
    except (FileNotFoundError, json.JSONDecodeError):
        return None


def _resolve(spec: Any) -> Any:
    if isinstance(spec, str):
        mod, _, attr = spec.partition(":")
        obj: Any = importlib.import_module(mod)
        for part in attr.split("."):
            obj = getattr(obj, part)
        return obj
    return spec


@dataclass
class SpectrometerConfig:
    """Settings of the emulated unit.

    ``wavelength_coeffs`` are served from ``?x1..?x4``; ``nonlinearity_coeffs`` (k0..k7) from
    ``?x6..?x13`` and applied to the counts (``counts / sum k_i counts^i`` undoes it);
    ``dark_pixels`` is the half-open index range of masked pixels; ``time_scale`` > 1 makes
    acquisitions faster than real time; ``memory_pixels`` limits pixels x scans to add
    (beyond it S answers ETX).
    """

    model: str = "EMU2000+"
    serial: str = "EMU00001"
    firmware: str = "3.0.1"
    pixels: int = 2048
    dark_pixels: tuple[int, int] = (6, 21)
    wavelength_coeffs: tuple[float, ...] = (339.0, 0.38, -1.5e-5, -1.0e-9)
    nonlinearity_coeffs: tuple[float, ...] = (1.0, -1.0e-6, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    nonlinearity_order: int = 1
    extra_slots: dict[int, str] = field(default_factory=dict)
    lamp_temperature_k: float = 2856.0
    peak_counts_per_ms: float = 1500.0
    reflectance: float = 0.5
    dark_counts: float = 1000.0
    dark_counts_per_s: float = 200.0
    read_noise: float = 6.0
    counts_per_electron: float = 0.1
    seed: int | None = 12345
    time_scale: float = 1.0
    memory_pixels: int = 2048 * 5000

    def slot(self, n: int) -> str | None:
        if n in self.extra_slots:
            return self.extra_slots[n]
        if n == 0:
            return self.serial
        if 1 <= n <= 4:
            c = list(self.wavelength_coeffs) + [0.0] * 4
            return f"{c[n - 1]:.9e}"
        if n == 5:
            return "0.0"
        if 6 <= n <= 13:
            k = list(self.nonlinearity_coeffs) + [0.0] * 8
            return f"{k[n - 6]:.9e}"
        if n == 14:
            return str(self.nonlinearity_order)
        return None


@dataclass
class Settings:
    mode: str = "binary"
    integration_ms: int = 100
    scans: int = 1
    boxcar: int = 0
    compression: bool = False
    checksum: bool = False
    trigger: int = 0
    lamp: bool = True  # the lamp-enable line (J): on at power-up here, so a plain acquisition sees light
    baud_code: int = 6
    storage: int = 0
    pixel_mode: int = 0
    pixel_params: list[int] = field(default_factory=list)


class SpectrometerModel:
    """The physics and the frame builder (no I/O)."""

    def __init__(self, cfg: SpectrometerConfig, geometry_source: Any = None,
                 response: Any = None) -> None:
        self.cfg = cfg
        self.geometry_source: Callable[[], Any] | None = _resolve(geometry_source)
        self.response: Callable[[Any, np.ndarray], np.ndarray] | None = _resolve(response)
        p = np.arange(cfg.pixels, dtype=float)
        c = list(cfg.wavelength_coeffs) + [0.0] * 4
        self.wavelengths = c[0] + c[1] * p + c[2] * p**2 + c[3] * p**3
        self.rng = np.random.default_rng(cfg.seed)
        # lamp (Planck at lamp_temperature_k) x a detector responsivity bump, peak 1
        wl_m = np.clip(self.wavelengths, 100.0, None) * 1e-9
        planck = 1.0 / (wl_m**5 * (np.exp(1.4388e-2 / (wl_m * cfg.lamp_temperature_k)) - 1.0))
        qe = np.exp(-0.5 * ((self.wavelengths - 600.0) / 220.0) ** 2)
        lamp = planck * qe
        self.lamp = lamp / lamp.max()
        self.settings = Settings()
        self.last_geometry: Any = None
        k = np.asarray(cfg.nonlinearity_coeffs[: cfg.nonlinearity_order + 1], dtype=float)
        grid = np.linspace(0.0, 65535.0, 257)
        sane = k.size > 0 and np.all(np.isfinite(k)) and k[0] > 0
        if sane:
            f = _poly(k, grid)
            sane = bool(np.all(np.isfinite(f)) and f.min() > 0.5 and f.max() < 2.0)
        self._nl = k if sane else None

    def reset(self) -> None:
        mode = self.settings.mode
        self.settings = Settings(mode=mode)

    def fraction(self) -> np.ndarray:
        geom = self.geometry_source() if self.geometry_source is not None else None
        self.last_geometry = geom
        if self.response is not None:
            r = np.asarray(self.response(geom, self.wavelengths), dtype=float)
        else:
            r = constant_response(geom, self.wavelengths, self.cfg.reflectance)
        return np.broadcast_to(r, self.wavelengths.shape)

    def scan(self, fraction: np.ndarray) -> np.ndarray:
        """One scan of counts (int64, saturated at 65535)."""
        cfg, s = self.cfg, self.settings
        t_ms = s.integration_ms
        # J0 switches the lamp-enable line off: the detector then sees only its dark signal
        signal = self.lamp * fraction * cfg.peak_counts_per_ms * t_ms * float(s.lamp)
        lo, hi = cfg.dark_pixels
        signal = signal.copy()
        signal[lo:hi] = 0.0
        dark = cfg.dark_counts + cfg.dark_counts_per_s * t_ms / 1000.0
        shot = np.sqrt(np.maximum(signal, 0.0) * cfg.counts_per_electron)
        noise = self.rng.normal(0.0, 1.0, signal.shape) * np.sqrt(shot**2 + cfg.read_noise**2)
        true = np.maximum(signal + dark + noise, 0.0)
        # detector non-linearity: measured m with m / p(m) = true (p from the calibration
        # slots), solved by fixed-point iteration; nonsense coefficients (what a driver must
        # refuse) leave the emulated detector linear
        measured = true
        if self._nl is not None:
            for _ in range(8):
                measured = true * _poly(self._nl, measured)
        return np.clip(np.rint(measured), 0, 65535).astype(np.int64)

    def selected_pixels(self) -> np.ndarray:
        s, n = self.settings, self.cfg.pixels
        m, prm = s.pixel_mode, s.pixel_params
        if m == 0:
            return np.arange(n)
        if m == 1:
            return np.arange(0, n, prm[0])
        if m == 3:
            return np.arange(prm[0], prm[1] + 1, prm[2])
        if m == 4:
            return np.asarray(prm[1:], dtype=int)
        if m == 5:
            idx = [np.arange(a, b + 1) for a, b in zip(prm[1::2], prm[2::2])]
            return np.concatenate(idx)
        raise ValueError(m)

    def acquire(self) -> np.ndarray:
        """Sum of ``scans`` scans over the selected pixels."""
        frac = self.fraction()
        total = np.zeros(self.cfg.pixels, dtype=np.int64)
        for _ in range(self.settings.scans):
            total += self.scan(frac)
        return total[self.selected_pixels()]


def _poly(k: np.ndarray, x: np.ndarray) -> np.ndarray:
    acc = np.zeros_like(np.asarray(x, dtype=float))
    for c in k[::-1]:
        acc = acc * x + c
    return acc


def _words(values: list[int]) -> bytes:
    return b"".join(int(v & 0xFFFF).to_bytes(2, "big") for v in values)


def compress(values: np.ndarray) -> bytes:
    """Signed 8-bit deltas from the previous pixel (the first from 0); else 0x80 + 16-bit value."""
    out = bytearray()
    prev = 0
    for v in values.tolist():
        d = v - prev
        if -127 <= d <= 127:
            out.append(d & 0xFF)
        else:
            out.append(0x80)
            out += int(v).to_bytes(2, "big")
        prev = v
    return bytes(out)


def encode_frame(values: np.ndarray, s: Settings, baseline: int = 0) -> bytes:
    """The binary S reply after STX (header ... 0xFFFD [checksum])."""
    dwords = s.scans > 1
    head = [0xFFFF, 1 if dwords else 0, s.scans, s.integration_ms,
            (baseline >> 16) & 0xFFFF, baseline & 0xFFFF, s.pixel_mode] + list(s.pixel_params)
    out = bytearray(_words(head))
    if dwords:
        out += b"".join(int(v).to_bytes(4, "big") for v in values.tolist())
    elif s.compression:
        out += compress(values)
    else:
        out += _words(values.tolist())
    out += _words([0xFFFD])
    if s.checksum:
        out += _words([int(values.sum()) & 0xFFFF])
    return bytes(out)


def encode_frame_ascii(values: np.ndarray, s: Settings, baseline: int = 0) -> bytes:
    dwords = s.scans > 1
    items = [0xFFFF, 1 if dwords else 0, s.scans, s.integration_ms,
             (baseline >> 16) & 0xFFFF, baseline & 0xFFFF, s.pixel_mode] + list(s.pixel_params)
    items += values.tolist() + [0xFFFD]
    if s.checksum:
        items.append(int(values.sum()) & 0xFFFF)
    return b"".join(f"{int(v)}\r".encode() for v in items)


# --------------------------------------------------------------------------------------------
# the device: byte parser and replies
# --------------------------------------------------------------------------------------------


class _Faults:
    def __init__(self) -> None:
        self.nak: list[int | None] = []   # command letters (None = any) to NAK once each
        self.drop = 0
        self.corrupt = 0
        self.no_memory = 0


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
        return None

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
        if c in (ord("a"), ord("b")):
            if len(b) < 2:
                return 0
            if b[1] == c - 32:
                self._command(c, [])
                return 2
            self._reply_nak(c)
            return 1
        if c == ord("?"):
            if len(b) < 2:
                return 0
            q = b[1]
            if q == ord("x"):
                if len(b) < 4:
                    return 0
                self._query(q, word(2))
                return 4
            self._query(q, None)
            return 2
        self._reply_nak(c)
        return 1

    # -- ascii --------------------------------------------------------------------------------
    def _ascii_step(self) -> int:
        try:
            end = self.buf.index(CR)
        except ValueError:
            return 0
        line = bytes(self.buf[:end]).decode("ascii", "replace").strip()
        used = end + 1
        if not line:
            return used
        c = ord(line[0])
        rest = line[1:].strip()
        if line in ("aA", "bB"):
            self._command(c, [])
            return used
        if c == ord("?"):
            if not rest:
                self._reply_nak(c)
                return used
            q = ord(rest[0])
            arg = rest[1:].strip()
            try:
                self._query(q, int(arg) if q == ord("x") else None)
            except ValueError:
                self._reply_nak(c)
            return used
        try:
            args = [int(x) for x in rest.replace(",", " ").split()]
        except ValueError:
            self._reply_nak(c)
            return used
        self._command(c, args)
        return used

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
        if letter in "ABGIJKMTk" and a0 is None:
            ok = False
        elif letter == "A":
            ok = 1 <= a0 <= 5000
            if ok:
                s.scans = a0
        elif letter == "B":
            ok = 0 <= a0 <= 15
            if ok:
                s.boxcar = a0
        elif letter == "G":
            ok = a0 in (0, 1)
            if ok:
                s.compression = bool(a0)
        elif letter == "I":
            ok = 1 <= a0 <= 65000
            if ok:
                s.integration_ms = a0
        elif letter == "J":
            ok = a0 in (0, 1)
            if ok:
                s.lamp = bool(a0)
        elif letter == "K":
            ok = 0 <= a0 <= 7
            if ok:
                s.baud_code = a0
        elif letter == "M":
            ok = a0 in (0, 1)
            if ok:
                s.storage = a0
        elif letter == "T":
            ok = 0 <= a0 <= 4
            if ok:
                s.trigger = a0
        elif letter == "k":
            ok = a0 in (0, 1)
            if ok:
                s.checksum = bool(a0)
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
        parts = (self.model.cfg.firmware.split(".") + ["0", "0", "0"])[:3]
        return int(parts[0]) << 12 | int(parts[1]) << 8 | int(parts[2])

    def _value(self, v: int, dword: bool = False) -> bytes:
        if self.s.mode == "ascii":
            return f"{v}\r".encode()
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
            self.write(bytes([ACK]) + text.encode("ascii") + bytes([CR]))
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
                body = encode_frame_ascii(values, s)
            else:
                body = bytearray(encode_frame(values, s))
                if f.corrupt > 0:
                    f.corrupt -= 1
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


def _child_main(cfg: dict[str, Any], geometry_source: Any, response: Any, conn: Any,
                log_level: int) -> None:
    logging.basicConfig(level=log_level, stream=sys.stderr,
                        format="ocean-emu %(levelname)s %(name)s: %(message)s")
    try:
        scfg = SpectrometerConfig(**cfg)
        model = SpectrometerModel(scfg, geometry_source, response)
        master, slave, path = open_raw_pty()
    except Exception as exc:
        conn.send({"error": f"{type(exc).__name__}: {exc}"})
        raise

    def write(data: bytes) -> None:
        view = memoryview(data)
        while view:
            try:
                n = os.write(master, view)
                view = view[n:]
            except BlockingIOError:
                select.select([], [master], [], 0.05)
            except OSError:
                return

    os.set_blocking(master, False)
    dev = _Device(model, write)
    conn.send({"port": path, "pid": os.getpid(), "pixels": scfg.pixels, "model": scfg.model})
    lock = threading.Lock()
    while True:
        wait = dev.tick()
        r, _, _ = select.select([master, conn], [], [], 0.5 if wait is None else min(wait, 0.5))
        if master in r:
            try:
                data = os.read(master, 65536)
            except (BlockingIOError, InterruptedError):
                data = b""
            except OSError:
                data = b""
            if data:
                dev.feed(data)
        if conn in r:
            try:
                msg = conn.recv()
            except (EOFError, OSError):
                break
            cmd = msg.get("cmd")
            reply: dict[str, Any] = {"ok": True}
            with lock:
                f = dev.faults
                if cmd == "die":
                    os._exit(1)
                elif cmd == "stop":
                    conn.send(reply)
                    break
                elif cmd == "nak":
                    letter = msg.get("command")
                    f.nak += [None if letter is None else ord(letter)] * int(msg.get("n", 1))
                elif cmd == "drop":
                    f.drop += int(msg.get("n", 1))
                elif cmd == "corrupt":
                    f.corrupt += int(msg.get("n", 1))
                elif cmd == "no_memory":
                    f.no_memory += int(msg.get("n", 1))
                elif cmd == "clear":
                    dev.faults = _Faults()
                elif cmd == "trigger":
                    dev.external_trigger()
                elif cmd == "state":
                    s = model.settings
                    reply["state"] = {**s.__dict__, "commands": dev.commands,
                                      "acquisitions": dev.acquisitions,
                                      "last_geometry": repr(model.last_geometry)}
                else:
                    reply = {"ok": False, "error": f"unknown command {cmd!r}"}
            conn.send(reply)
    for fd in (master, slave):
        try:
            os.close(fd)
        except OSError:
            pass


class SpectrometerEmulator(PipeEmulator):
    """Handle on a running spectrometer emulator process.

    Attributes
    ----------
    port : str
        The pty slave path the driver opens.
    pixels : int
        Number of detector pixels.
    """

    label = "spectrometer emulator"

    def __init__(self, proc: Any, conn: Any, info: dict[str, Any]) -> None:
        super().__init__(proc, conn, info)
        self.port: str = info["port"]
        self.pixels: int = info["pixels"]

    @classmethod
    def start(cls, *, geometry_source: Any = None, response: Any = None,
              start_timeout: float = 10.0, log_level: int = logging.WARNING,
              **config: Any) -> "SpectrometerEmulator":
        """Start the emulator; keyword arguments are :class:`SpectrometerConfig` fields.

        ``geometry_source`` (``() -> geometry | None``) and ``response``
        (``(geometry, wavelengths_nm) -> np.ndarray``) are picklable callables or
        ``"module:attr"`` strings.
        """
        SpectrometerConfig(**config)
        return cls(*cls._spawn(_child_main, (config, geometry_source, response), (log_level,),
                               "ocean-spectrometer-emulator", start_timeout))

    def state(self) -> dict[str, Any]:
        return self._call({"cmd": "state"})["state"]

    def nak(self, command: str | None = None, n: int = 1) -> None:
        """NAK the next ``n`` commands with letter ``command`` (any command if None)."""
        self._call({"cmd": "nak", "command": command, "n": n})

    def drop_replies(self, n: int = 1) -> None:
        self._call({"cmd": "drop", "n": n})

    def corrupt_frames(self, n: int = 1) -> None:
        self._call({"cmd": "corrupt", "n": n})

    def no_memory(self, n: int = 1) -> None:
        self._call({"cmd": "no_memory", "n": n})

    def trigger(self) -> None:
        self._call({"cmd": "trigger"})

    def __repr__(self) -> str:
        return f"SpectrometerEmulator({self.port}, pid={self._proc.pid})"


def start_spectrometer_emulator(**kwargs: Any) -> SpectrometerEmulator:
    """Start a spectrometer emulator process; the handle's ``port`` is what the driver opens."""
    return SpectrometerEmulator.start(**kwargs)


def main(argv: list[str] | None = None) -> int:
    """Serve until killed; print the port as one JSON line."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--config", default="{}", help="JSON object of SpectrometerConfig fields")
    a = p.parse_args(argv)
    emu = SpectrometerEmulator.start(**json.loads(a.config))
    print(json.dumps(emu.info), flush=True)
    emu.serve_until_interrupted()
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""An Ocean-Optics-style RS-232 spectrometer (USB2000+/USB4000/Flame-S family) through a Transport.

Protocol as implemented here (facts: ``/work/shared/reference/ocean-rs232.md``; the parts the
manual leaves open are pinned down below and marked *choice*):

Binary mode (power-up default)
    One ASCII letter per command; a data word follows as 16 bits, most significant byte first.
    ``A`` scans to add (1..5000), ``B`` boxcar, ``G`` compression (0/1), ``I`` integration time
    in ms (1..65000), ``J`` lamp, ``K`` baud code, ``M`` storage mode, ``T`` trigger mode (0..4),
    ``k`` checksum mode (0/1): letter + word. ``P`` pixel mode: letter + mode word + its
    parameter words (1: n; 3: x, y, n; 4: count + pixels; 5: count + (x, y) pairs). ``W``
    register + value. ``Q``, ``L``, ``S``, ``v``: letter alone. Each is answered ACK 0x06 or
    NAK 0x15; ``v`` answers ACK + version word. Queries ``?A ?B ?I ?K ?T ?J`` answer ACK + word,
    ``?i``/``?j`` ACK + 32-bit word (10 us / 1 us units); ``?x`` + slot word answers ACK + the
    slot's ASCII text + CR (*choice*: CR-terminated text in both modes).
ASCII mode (``aA``; back with ``bB``)
    Commands are text lines: letter, decimal argument(s) separated by spaces, CR. The device
    echoes every byte, then ACK/NAK; query values follow as decimal text + CR.
S reply
    ETX 0x03 = insufficient memory; NAK = refused; else STX 0x02 then the frame: ``0xFFFF``,
    data-size flag (0 words, 1 dwords; dwords when scans to add > 1), scans accumulated,
    integration time (ms), FPGA baseline MSW, LSW, pixel mode (+ its parameters), the pixel
    data, ``0xFFFD``, and with checksum mode on a 16-bit checksum = the sum of the pixel values
    modulo 65536 (*choice*). In ASCII mode every item (header, pixels, trailer, checksum) is a
    decimal number + CR (*choice*; compression does not apply). Compression applies to word
    frames only: each pixel is a signed 8-bit difference from the previous one (the first from
    0) when |d| <= 127, else 0x80 followed by the 16-bit value.
Calibration slots (``?x<n>``; the usual Ocean EEPROM layout)
    0 serial number; 1..4 wavelength coefficients c0..c3 (lambda(p) = c0 + c1 p + c2 p^2 +
    c3 p^3); 5 stray light; 6..13 non-linearity coefficients k0..k7; 14 non-linearity order.

The driver fills the ``Spectrometer`` role: :meth:`OceanSpectrometer.acquire` returns a
:class:`bench.core.roles.Reading` per pixel (mean over ``averages`` scans, per-scan counts when
scans are accumulated on the device), flags pixels that saturated in any scan (65535, or
65535 x scans for an accumulated frame), optionally subtracts the electrical dark of the masked
pixels and optionally applies the non-linearity correction (refused with
:class:`CalibrationError` when the stored coefficients are nonsense).

Every read has a deadline; timeouts and corrupt frames are retried a bounded number of times
(then :class:`DeviceTimeoutError` / :class:`ChecksumError`); NAK and ETX are
:class:`ProtocolError` naming the command; a vanished port is :class:`PortGoneError`.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field, fields, replace
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from bench.core.errors import (
    CalibrationError,
    ChecksumError,
    CommunicationError,
    ConfigError,
    DeviceTimeoutError,
    InputError,
    PortGoneError,
    ProtocolError,
)
from bench.core.roles import InstrumentInfo, Reading

__all__ = ["OceanConfig", "OceanSpectrometer", "MODELS", "decode_compressed",
           "nonlinearity_factor", "validate_nonlinearity", "wavelength_polynomial"]

log = logging.getLogger(__name__)

ACK, NAK, STX, ETX, CR = 0x06, 0x15, 0x02, 0x03, 0x0D
FULL_SCALE = 65535

#: Per-model defaults: pixel count and the half-open index range of optically masked pixels
#: (electrical dark). Values as python-seabreeze uses them; confirm against the unit in hand.
MODELS: dict[str, dict[str, Any]] = {
    "USB2000+": {"pixels": 2048, "dark_pixels": (6, 21)},
    "FLAME-S": {"pixels": 2048, "dark_pixels": (6, 21)},
    "USB4000": {"pixels": 3648, "dark_pixels": (5, 16)},
    "EMU2000+": {"pixels": 2048, "dark_pixels": (6, 21)},
}


@dataclass(frozen=True)
class OceanConfig:
    """Settings of one spectrometer (keys of a bench-config table; all optional).

    Attributes
    ----------
    model : str
        Key of :data:`MODELS` (sets ``pixels`` and ``dark_pixels`` unless given).
    pixels : int or None
        Number of detector pixels.
    dark_pixels : (int, int) or None
        Half-open index range of the optically masked pixels.
    mode : str
        ``"binary"`` (default) or ``"ascii"``.
    checksum : bool
        Turn checksum mode on (k1) and verify every frame.
    compression : bool
        Turn data compression on (G1).
    trigger_mode : int
        0 free running (default), 1 software, 2 external level, 3 external sync, 4 external edge.
    accumulate_on_device : bool
        Average by the device's scans-to-add (one frame of dwords, no ``std``) instead of
        ``averages`` separate frames.
    subtract_electrical_dark : bool
        Subtract the per-scan mean of the masked pixels.
    nonlinearity : bool
        Apply the non-linearity correction from the calibration slots (opt-in).
    nonlinearity_bounds : (float, float)
        Allowed range of the correction polynomial over 0..65535 counts.
    wavelength_limits_nm : (float, float)
        Plausible wavelength span; a calibration outside it is refused.
    timeout_s : float
        Reply deadline of a command (the acquisition time and the line time are added for S).
    retries : int
        Extra attempts after a timeout or a corrupt reply (NAK/ETX never retry).
    baudrate : int
        Line rate (used for the transfer-time part of deadlines; a pty ignores it).
    """

    model: str = "USB2000+"
    pixels: int | None = None
    dark_pixels: tuple[int, int] | None = None
    mode: str = "binary"
    checksum: bool = True
    compression: bool = False
    trigger_mode: int = 0
    accumulate_on_device: bool = False
    subtract_electrical_dark: bool = False
    nonlinearity: bool = False
    nonlinearity_bounds: tuple[float, float] = (0.5, 2.0)
    wavelength_limits_nm: tuple[float, float] = (150.0, 1200.0)
    timeout_s: float = 1.0
    retries: int = 2
    baudrate: int = 115200

    def resolved(self) -> "OceanConfig":
        spec = MODELS.get(self.model.upper(), {})
        pixels = self.pixels if self.pixels is not None else spec.get("pixels")
        dark = self.dark_pixels if self.dark_pixels is not None else spec.get("dark_pixels")
        if pixels is None:
            raise ConfigError(f"unknown spectrometer model {self.model!r} (known: "
                              f"{', '.join(MODELS)}); give pixels= and dark_pixels=")
        cfg = replace(self, pixels=int(pixels),
                      dark_pixels=tuple(dark) if dark is not None else (0, 0))
        cfg.validate()
        return cfg

    def validate(self) -> None:
        def bad(msg: str) -> None:
            raise ConfigError(f"spectrometer config: {msg}")

        if self.mode not in ("binary", "ascii"):
            bad(f"mode must be 'binary' or 'ascii', got {self.mode!r}")
        if not (isinstance(self.pixels, int) and self.pixels > 0):
            bad(f"pixels must be a positive integer, got {self.pixels!r}")
        lo, hi = self.dark_pixels or (0, 0)
        if not 0 <= lo <= hi <= (self.pixels or 0):
            bad(f"dark_pixels {self.dark_pixels} is not a range inside 0..{self.pixels}")
        if self.subtract_electrical_dark and hi <= lo:
            bad("subtract_electrical_dark needs a non-empty dark_pixels range")
        if self.trigger_mode not in (0, 1, 2, 3, 4):
            bad(f"trigger_mode must be 0..4, got {self.trigger_mode!r}")
        if not (self.timeout_s > 0 and math.isfinite(self.timeout_s)):
            bad("timeout_s must be > 0")
        if self.retries < 0:
            bad("retries must be >= 0")
        b0, b1 = self.nonlinearity_bounds
        if not 0 < b0 < 1 < b1:
            bad(f"nonlinearity_bounds must satisfy 0 < lo < 1 < hi, got {self.nonlinearity_bounds}")

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "OceanConfig":
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(d) - known)
        if unknown:
            raise ConfigError(f"spectrometer config: unknown key(s) {', '.join(unknown)}; "
                              f"known: {', '.join(sorted(known))}")
        kw = dict(d)
        for k in ("dark_pixels", "nonlinearity_bounds", "wavelength_limits_nm"):
            if k in kw and kw[k] is not None:
                kw[k] = tuple(kw[k])
        return cls(**kw)


# --- pure helpers ------------------------------------------------------------------------------


def wavelength_polynomial(coeffs: Sequence[float], pixels: int) -> np.ndarray:
    """lambda(p) = c0 + c1 p + c2 p^2 + c3 p^3 for p = 0..pixels-1."""
    c = list(coeffs) + [0.0] * (4 - len(coeffs))
    p = np.arange(pixels, dtype=float)
    return c[0] + c[1] * p + c[2] * p**2 + c[3] * p**3


def nonlinearity_factor(coeffs: Sequence[float], counts: np.ndarray) -> np.ndarray:
    """sum_i k_i counts^i (Horner)."""
    x = np.asarray(counts, dtype=float)
    acc = np.zeros_like(x)
    for k in reversed(list(coeffs)):
        acc = acc * x + k
    return acc


def validate_nonlinearity(coeffs: Sequence[float],
                          bounds: tuple[float, float] = (0.5, 2.0)) -> np.ndarray:
    """Return the coefficients as an array, or raise :class:`CalibrationError`.

    Refused: no coefficients, a non-finite one, k0 == 0 (the stored "empty EEPROM" case that
    makes the correction infinite), or a polynomial that is <= 0 or leaves ``bounds`` anywhere
    on 0..65535 counts.
    """
    k = np.asarray(list(coeffs), dtype=float)
    if k.size == 0:
        raise CalibrationError("non-linearity correction: no coefficients stored")
    if not np.all(np.isfinite(k)):
        raise CalibrationError(f"non-linearity correction: non-finite coefficient(s) {k.tolist()}")
    if k[0] == 0.0:
        raise CalibrationError("non-linearity correction: k0 = 0 (empty or erased calibration); "
                               "the correction would divide by ~0")
    grid = np.linspace(0.0, FULL_SCALE, 4097)
    f = nonlinearity_factor(k, grid)
    if not np.all(np.isfinite(f)) or np.any(f <= 0):
        bad = grid[np.argmax(~np.isfinite(f) | (f <= 0))]
        raise CalibrationError(f"non-linearity correction: polynomial {k.tolist()} is <= 0 or "
                               f"not finite at {bad:.0f} counts")
    lo, hi = float(f.min()), float(f.max())
    if lo < bounds[0] or hi > bounds[1]:
        raise CalibrationError(f"non-linearity correction: polynomial {k.tolist()} ranges "
                               f"{lo:.4g}..{hi:.4g} over 0..65535 counts, outside the plausible "
                               f"{bounds[0]}..{bounds[1]}; refusing to apply it")
    return k


def decode_compressed(data: bytes | bytearray, n: int, start: int = 0) -> tuple[np.ndarray, int]:
    """Decode ``n`` compressed pixel values from ``data[start:]``; return (values, end index).

    Raises
    ------
    ChecksumError
        If the data end before ``n`` values or a value leaves 0..65535.
    """
    out = np.empty(n, dtype=np.int64)
    i, prev = start, 0
    L = len(data)
    for j in range(n):
        if i >= L:
            raise ChecksumError(f"compressed pixel data ended after {j} of {n} pixels")
        b = data[i]
        if b == 0x80:
            if i + 2 >= L:
                raise ChecksumError(f"compressed pixel data ended inside the escape of pixel {j}")
            prev = data[i + 1] << 8 | data[i + 2]
            i += 3
        else:
            prev += b - 256 if b > 127 else b
            i += 1
            if not 0 <= prev <= FULL_SCALE:
                raise ChecksumError(f"compressed pixel data out of range at pixel {j}: {prev}")
        out[j] = prev
    return out, i


@dataclass
class _Frame:
    dwords: bool
    scans: int
    integration_ms: int
    baseline: int
    pixel_mode: int
    values: np.ndarray
    raw: bytes = field(repr=False, default=b"")


class _Retry(Exception):
    """Internal: a recoverable communication failure (becomes the wrapped error at the end)."""

    def __init__(self, error: CommunicationError) -> None:
        super().__init__(str(error))
        self.error = error


class OceanSpectrometer:
    """An Ocean-Optics-style RS-232 spectrometer in the ``Spectrometer`` role.

    Parameters
    ----------
    transport : Transport or str
        A :class:`drivers.transport.Transport`, or a pyserial URL / port path (opened with
        ``drivers.transport.SerialTransport``).
    config : OceanConfig or mapping, optional
        Settings; keyword arguments override single keys.
    name : str
        Name used in messages.

    Raises
    ------
    PortGoneError
        The port cannot be opened.
    CalibrationError
        The wavelength calibration is implausible, or the opt-in non-linearity correction
        has nonsense coefficients.
    """

    def __init__(self, transport: Any, *, config: OceanConfig | Mapping[str, Any] | None = None,
                 name: str = "spectrometer", **overrides: Any) -> None:
        base = config if isinstance(config, OceanConfig) else OceanConfig.from_dict(config or {})
        if overrides:
            merged = {f.name: getattr(base, f.name) for f in fields(OceanConfig)}
            unknown = sorted(set(overrides) - set(merged))
            if unknown:
                raise ConfigError(f"spectrometer: unknown setting(s) {', '.join(unknown)}")
            merged.update(overrides)
            base = OceanConfig.from_dict(merged)
        self.config: OceanConfig = base.resolved()
        self.name = name
        if isinstance(transport, str):
            from drivers.transport import SerialTransport
            self.port = transport
            self.t: Any = SerialTransport(transport, baudrate=self.config.baudrate)
        else:
            self.port = repr(transport)
            self.t = transport
        self._closed = False
        self._rx = bytearray()
        self._mode = "binary"
        self._state: dict[str, int] = {}
        self.serial = ""
        self.firmware = ""
        self.slots: dict[int, str] = {}
        self._nl: np.ndarray | None = None
        try:
            self._open()
        except BaseException:
            self._closed = True
            try:
                self.t.close()
            except Exception:
                pass
            raise

    @classmethod
    def from_config(cls, cfg: Mapping[str, Any]) -> "OceanSpectrometer":
        """Build from a bench-config table: ``port`` (required), ``name`` and OceanConfig keys."""
        d = dict(cfg)
        if "port" not in d:
            raise ConfigError("spectrometer config needs 'port'")
        port = str(d.pop("port"))
        name = str(d.pop("name", "spectrometer"))
        return cls(port, name=name, **d)

    # --- low-level I/O ------------------------------------------------------------------------
    def _read_exact(self, n: int, deadline: float, what: str) -> bytes:
        data = bytes(self._rx[:n])
        del self._rx[:n]
        if len(data) < n:
            data += self.t.read(n - len(data), max(0.0, deadline - time.monotonic()))
        if len(data) < n:
            raise _Retry(DeviceTimeoutError(
                f"{self.name}: {what}: got {len(data)} of {n} byte(s) before the deadline"
                + (f" ({data.hex(' ')})" if data else "")))
        return data

    def _read_until_cr(self, deadline: float, what: str, limit: int = 4096) -> bytes:
        while True:
            i = self._rx.find(CR)
            if 0 <= i <= limit:
                line = bytes(self._rx[:i])
                del self._rx[:i + 1]
                return line
            if len(self._rx) > limit:
                raise _Retry(ChecksumError(f"{self.name}: {what}: no CR within {limit} bytes"))
            # take what has already arrived (it belongs to this reply), at least one byte
            avail = int(getattr(self.t, "in_waiting", 0) or 0)
            chunk = self.t.read(max(1, avail), max(0.0, deadline - time.monotonic()))
            if not chunk:
                raise _Retry(DeviceTimeoutError(f"{self.name}: {what}: no CR-terminated reply "
                                                f"before the deadline"))
            self._rx += chunk

    def _drain(self) -> None:
        """Swallow whatever is still arriving (a late or partial reply) before a retry."""
        end = time.monotonic() + 0.05
        while time.monotonic() < end:
            n = int(getattr(self.t, "in_waiting", 0) or 0)
            if n:
                self.t.read(n, 0)
                end = time.monotonic() + 0.02
            else:
                time.sleep(0.002)
        self._rx.clear()
        self.t.reset_input()

    def _encode(self, letter: str, args: Sequence[int]) -> bytes:
        if self._mode == "ascii":
            text = letter + (" ".join(str(int(a)) for a in args) if args else "")
            return text.encode("ascii") + bytes([CR])
        out = letter.encode("ascii")
        for a in args:
            out += int(a & 0xFFFF).to_bytes(2, "big")
        return out

    def _send(self, cmd: bytes, deadline: float, what: str) -> None:
        stale = bytes(self._rx)
        self._rx.clear()
        n = int(getattr(self.t, "in_waiting", 0) or 0)
        if n:
            stale += self.t.read(n, 0)
        if stale:  # a late reply to an earlier command must not be taken for this one's
            log.warning("%s: discarding %d stale byte(s) before %s: %s", self.name, len(stale),
                        what, stale[:32].hex(" "))
        self.t.write(cmd)
        if self._mode == "ascii":
            echo = self._read_exact(len(cmd), deadline, f"{what} (echo)")
            if echo != cmd:
                raise _Retry(ChecksumError(f"{self.name}: {what}: echo {echo!r} differs from "
                                           f"the command {cmd!r}"))

    def _expect_ack(self, deadline: float, what: str) -> None:
        b = self._read_exact(1, deadline, what)[0]
        if b == NAK:
            raise ProtocolError(f"{self.name}: NAK to {what}")
        if b != ACK:
            raise _Retry(ChecksumError(f"{self.name}: {what}: expected ACK/NAK, got 0x{b:02X}"))

    def _retrying(self, what: str, fn: Callable[[], Any]) -> Any:
        last: CommunicationError | None = None
        for attempt in range(self.config.retries + 1):
            if self._closed:
                raise PortGoneError(f"{self.name}: closed")
            try:
                return fn()
            except _Retry as r:
                last = r.error
                log.warning("%s: %s failed (attempt %d of %d): %s", self.name, what, attempt + 1,
                            self.config.retries + 1, r.error)
                self._drain()
        assert last is not None
        tries = self.config.retries + 1
        raise type(last)(f"{last} [after {tries} attempt(s)]") from None

    def command(self, letter: str, *args: int) -> None:
        """Send a set command (``I``, ``A``, ``T``, ``k``, ...) and require ACK."""
        what = f"command {letter!r}" + (f" {list(args)}" if args else "")

        def once() -> None:
            deadline = time.monotonic() + self.config.timeout_s
            self._send(self._encode(letter, args), deadline, what)
            self._expect_ack(deadline, what)
        self._retrying(what, once)

    def query(self, letter: str) -> int:
        """``?<letter>``: a setting as an integer (``i``/``j`` are 32-bit)."""
        what = f"query '?{letter}'"
        wide = letter in ("i", "j")

        def once() -> int:
            deadline = time.monotonic() + self.config.timeout_s
            self._send(self._encode("?" + letter, []), deadline, what)
            self._expect_ack(deadline, what)
            if self._mode == "ascii":
                text = self._read_until_cr(deadline, what, 32)
                try:
                    return int(text)
                except ValueError:
                    raise _Retry(ChecksumError(f"{self.name}: {what}: not a number: {text!r}"))
            return int.from_bytes(self._read_exact(4 if wide else 2, deadline, what), "big")
        return self._retrying(what, once)

    def read_slot(self, n: int) -> str:
        """``?x<n>``: the calibration slot's text."""
        what = f"query '?x{n}'"

        def once() -> str:
            deadline = time.monotonic() + self.config.timeout_s
            self._send(self._encode("?x", [n]) if self._mode == "binary"
                       else f"?x{n}".encode() + bytes([CR]), deadline, what)
            self._expect_ack(deadline, what)
            return self._read_until_cr(deadline, what, 64).decode("ascii", "replace").strip()
        text = self._retrying(what, once)
        self.slots[n] = text
        return text

    def version(self) -> int:
        """``v``: the firmware version word."""
        what = "command 'v'"

        def once() -> int:
            deadline = time.monotonic() + self.config.timeout_s
            self._send(self._encode("v", []), deadline, what)
            self._expect_ack(deadline, what)
            if self._mode == "ascii":
                return int(self._read_until_cr(deadline, what, 32))
            return int.from_bytes(self._read_exact(2, deadline, what), "big")
        return self._retrying(what, once)

    def _set(self, letter: str, value: int) -> None:
        if self._state.get(letter) != value:
            self.command(letter, value)
            self._state[letter] = value

    def set_trigger_mode(self, mode: int) -> None:
        """``T``: 0 free running, 1 software, 2 external level, 3 external sync, 4 external edge.

        In the external modes an acquisition waits for the trigger; ``timeout_s`` must cover
        that wait.
        """
        if mode not in (0, 1, 2, 3, 4):
            raise InputError(f"{self.name}: trigger mode must be 0..4, got {mode!r}")
        self._set("T", int(mode))

    @property
    def trigger_mode(self) -> int:
        return self._state.get("T", 0)

    def reset_defaults(self) -> None:
        """``Q``: reset the device to its defaults (mode unchanged), then re-apply the config."""
        self.command("Q")
        self._state.clear()
        cfg = self.config
        self._set("k", int(cfg.checksum))
        self._set("G", int(cfg.compression))
        self._set("T", cfg.trigger_mode)

    # --- open ---------------------------------------------------------------------------------
    def _open(self) -> None:
        cfg = self.config
        self._sync_binary()
        if cfg.mode == "ascii":
            self.command_mode("ascii")
        v = self.version()
        self.firmware = f"{v >> 12}.{v >> 8 & 0xF}.{v & 0xFF}"
        self.serial = self.read_slot(0)
        coeffs = []
        for n in (1, 2, 3, 4):
            text = self.read_slot(n)
            try:
                coeffs.append(float(text))
            except ValueError:
                raise CalibrationError(f"{self.name}: wavelength coefficient ?x{n} = {text!r} "
                                       f"is not a number") from None
        self.wavelength_coeffs = coeffs
        wl = wavelength_polynomial(coeffs, cfg.pixels or 0)
        lo, hi = cfg.wavelength_limits_nm
        if not np.all(np.isfinite(wl)) or not np.all(np.diff(wl) > 0):
            raise CalibrationError(f"{self.name}: wavelength calibration {coeffs} is not finite "
                                   f"and strictly increasing over {cfg.pixels} pixels")
        if wl[0] < lo or wl[-1] > hi:
            raise CalibrationError(f"{self.name}: wavelength calibration {coeffs} spans "
                                   f"{wl[0]:.1f}..{wl[-1]:.1f} nm, outside the plausible "
                                   f"{lo}..{hi} nm")
        self._wavelengths = wl
        self._wavelengths.setflags(write=False)
        if cfg.nonlinearity:
            self.enable_nonlinearity()
        self._set("k", int(cfg.checksum))
        self._set("G", int(cfg.compression))
        self._set("T", cfg.trigger_mode)
        log.info("%s: %s serial %s firmware %s, %d pixels %.1f..%.1f nm", self.name, cfg.model,
                 self.serial, self.firmware, cfg.pixels, wl[0], wl[-1])

    def _sync_binary(self) -> None:
        """Bring the device into binary mode whatever mode it was left in."""
        what = "mode switch 'bB'"

        def once() -> None:
            deadline = time.monotonic() + self.config.timeout_s
            self.t.write(b"bB")
            first = self._read_exact(1, deadline, what)[0]
            if first == ord("b"):  # ASCII mode: it echoes and waits for CR
                self._read_exact(1, deadline, what)
                self.t.write(bytes([CR]))
                self._read_exact(1, deadline, what)
                first = self._read_exact(1, deadline, what)[0]
            if first == NAK:
                raise ProtocolError(f"{self.name}: NAK to {what}")
            if first != ACK:
                raise _Retry(ChecksumError(f"{self.name}: {what}: got 0x{first:02X}"))
        self._retrying(what, once)
        self._mode = "binary"

    def command_mode(self, mode: str) -> None:
        """Switch the device between ``"binary"`` and ``"ascii"`` mode."""
        if mode not in ("binary", "ascii"):
            raise InputError(f"mode must be 'binary' or 'ascii', got {mode!r}")
        if mode == self._mode:
            return
        cmd = b"aA" if mode == "ascii" else b"bB" + bytes([CR])
        what = f"mode switch {cmd[:2].decode()!r}"

        def once() -> None:
            deadline = time.monotonic() + self.config.timeout_s
            self.t.write(cmd)
            if self._mode == "ascii":
                echo = self._read_exact(len(cmd), deadline, what)
                if echo != cmd:
                    raise _Retry(ChecksumError(f"{self.name}: {what}: bad echo {echo!r}"))
            self._expect_ack(deadline, what)
        self._retrying(what, once)
        self._mode = mode

    # --- calibration --------------------------------------------------------------------------
    def enable_nonlinearity(self) -> None:
        """Read ``?x6..?x14`` and turn the correction on, or raise :class:`CalibrationError`."""
        order_text = self.read_slot(14)
        try:
            order = int(float(order_text))
        except ValueError:
            raise CalibrationError(f"{self.name}: non-linearity order ?x14 = {order_text!r}") from None
        if not 0 <= order <= 7:
            raise CalibrationError(f"{self.name}: non-linearity order {order} outside 0..7")
        ks = []
        for n in range(6, 7 + order):
            text = self.read_slot(n)
            try:
                ks.append(float(text))
            except ValueError:
                raise CalibrationError(f"{self.name}: non-linearity coefficient ?x{n} = "
                                       f"{text!r} is not a number") from None
        self._nl = validate_nonlinearity(ks, self.config.nonlinearity_bounds)

    def disable_nonlinearity(self) -> None:
        self._nl = None

    @property
    def nonlinearity_coeffs(self) -> np.ndarray | None:
        """The validated correction coefficients in use, or None when the correction is off."""
        return None if self._nl is None else self._nl.copy()

    @property
    def wavelengths(self) -> np.ndarray:
        """Wavelength (nm) of every pixel, from the stored calibration polynomial."""
        return self._wavelengths

    # --- acquisition --------------------------------------------------------------------------
    def _frame_deadline(self, integration_ms: int, scans: int) -> float:
        npix = self.config.pixels or 0
        per_value = 12 if self._mode == "ascii" else (4 if scans > 1 else 2)
        line_s = (npix * per_value + 64) * 10.0 / self.config.baudrate
        # free-running: the scan in progress is discarded, so allow one extra integration
        acq_s = integration_ms / 1000.0 * (scans + 1)
        return time.monotonic() + self.config.timeout_s + acq_s + line_s

    def _read_frame(self, integration_ms: int, scans: int) -> _Frame:
        what = "command 'S'"
        deadline = self._frame_deadline(integration_ms, scans)
        self._send(self._encode("S", []), deadline, what)
        first = self._read_exact(1, deadline, what)[0]
        if first == ETX:
            raise ProtocolError(f"{self.name}: 'S' answered ETX: insufficient memory for "
                                f"{self.config.pixels} pixels x {scans} scans")
        if first == NAK:
            raise ProtocolError(f"{self.name}: NAK to {what}")
        if first != STX:
            raise _Retry(ChecksumError(f"{self.name}: {what}: expected STX, got 0x{first:02X}"))
        if self._mode == "ascii":
            return self._read_frame_ascii(deadline, what)
        return self._read_frame_binary(deadline, what)

    def _read_frame_binary(self, deadline: float, what: str) -> _Frame:
        npix = self.config.pixels or 0
        head = self._read_exact(14, deadline, what)
        w = [int.from_bytes(head[i:i + 2], "big") for i in range(0, 14, 2)]
        if w[0] != 0xFFFF or w[1] not in (0, 1):
            raise _Retry(ChecksumError(f"{self.name}: frame header {head.hex(' ')} is not "
                                       f"0xFFFF + a data-size flag"))
        dwords, scans, integ = bool(w[1]), w[2], w[3]
        baseline, pmode = w[4] << 16 | w[5], w[6]
        if pmode != 0:
            raise _Retry(ChecksumError(f"{self.name}: frame pixel mode {pmode}, expected 0 "
                                       f"(this driver runs the device in pixel mode 0)"))
        raw = bytearray(head)
        if dwords:
            data = self._read_exact(4 * npix, deadline, what)
            values = np.frombuffer(data, dtype=">u4").astype(np.int64)
        elif self._state.get("G"):
            # every pixel takes at least one byte and the trailer follows: read that lower
            # bound, then whatever the escapes (3 bytes each) still need
            buf = bytearray(self._read_exact(npix, deadline, what))
            while (missing := self._compressed_missing(buf, npix)) > 0:
                buf += self._read_exact(missing, deadline, what)
            try:
                values, end = decode_compressed(buf, npix)
            except ChecksumError as exc:
                raise _Retry(ChecksumError(f"{self.name}: {what}: {exc}")) from None
            data, extra = bytes(buf[:end]), bytes(buf[end:])
        else:
            data = self._read_exact(2 * npix, deadline, what)
            values = np.frombuffer(data, dtype=">u2").astype(np.int64)
        raw += data
        tail = extra if (not dwords and self._state.get("G")) else b""
        need_tail = 2 + (2 if self._state.get("k") else 0)
        if len(tail) < need_tail:
            tail += self._read_exact(need_tail - len(tail), deadline, what)
        if tail[:2] != b"\xff\xfd":
            raise _Retry(ChecksumError(f"{self.name}: frame trailer {tail[:2].hex(' ')} is not "
                                       f"FF FD (wrong pixel count or a corrupted frame)"))
        if self._state.get("k"):
            got = int.from_bytes(tail[2:4], "big")
            want = int(values.sum()) & 0xFFFF
            if got != want:
                raise _Retry(ChecksumError(f"{self.name}: frame checksum 0x{got:04X} != "
                                           f"0x{want:04X} computed over the pixel data"))
        return _Frame(dwords, scans, integ, baseline, pmode, values, bytes(raw))

    @staticmethod
    def _compressed_missing(data: bytes | bytearray, npix: int) -> int:
        """Lower bound of the bytes still missing to hold ``npix`` compressed values."""
        i = j = 0
        L = len(data)
        while j < npix and i < L:
            i += 3 if data[i] == 0x80 else 1
            j += 1
        return max(i - L, 0) + (npix - j)

    def _read_frame_ascii(self, deadline: float, what: str) -> _Frame:
        npix = self.config.pixels or 0

        def num() -> int:
            text = self._read_until_cr(deadline, what, 16)
            try:
                return int(text)
            except ValueError:
                raise _Retry(ChecksumError(f"{self.name}: {what}: {text!r} is not a number"))
        w = [num() for _ in range(7)]
        if w[0] != 0xFFFF or w[1] not in (0, 1) or w[6] != 0:
            raise _Retry(ChecksumError(f"{self.name}: ASCII frame header {w} is malformed"))
        values = np.array([num() for _ in range(npix)], dtype=np.int64)
        if num() != 0xFFFD:
            raise _Retry(ChecksumError(f"{self.name}: ASCII frame trailer is not 65533"))
        if self._state.get("k"):
            got = num()
            if got != int(values.sum()) & 0xFFFF:
                raise _Retry(ChecksumError(f"{self.name}: ASCII frame checksum {got} is wrong"))
        return _Frame(bool(w[1]), w[2], w[3], w[4] << 16 | w[5], w[6], values)

    def acquire_frame(self, integration_ms: int, scans: int) -> np.ndarray:
        """One S acquisition: the raw (accumulated) counts of every pixel, after the retries."""
        self._set("I", integration_ms)
        self._set("A", scans)
        self._set("P", 0)

        def once() -> np.ndarray:
            fr = self._read_frame(integration_ms, scans)
            if fr.scans != scans or fr.integration_ms != integration_ms or \
                    fr.dwords != (scans > 1):
                raise _Retry(ChecksumError(
                    f"{self.name}: frame says {fr.scans} scans of {fr.integration_ms} ms "
                    f"(dwords={fr.dwords}), expected {scans} of {integration_ms} ms"))
            return fr.values
        return self._retrying("command 'S'", once)

    def acquire(self, integration_s: float, averages: int = 1) -> Reading:
        """Acquire ``averages`` scans of ``integration_s`` seconds and return their mean.

        Raises
        ------
        InputError
            ``integration_s`` not finite or outside 1 ms..65 s; ``averages`` not an integer >= 1.
        ProtocolError, ChecksumError, DeviceTimeoutError, PortGoneError
            See the module docstring.
        """
        if isinstance(integration_s, bool) or not isinstance(integration_s, (int, float)) \
                or not math.isfinite(integration_s) or integration_s <= 0:
            raise InputError(f"{self.name}: integration time must be a finite number of seconds "
                             f"> 0, got {integration_s!r}")
        ms = int(round(integration_s * 1000.0))
        if not 1 <= ms <= 65000:
            raise InputError(f"{self.name}: integration time {integration_s} s is outside "
                             f"1 ms..65 s")
        if isinstance(averages, bool) or not isinstance(averages, (int, np.integer)) or averages < 1:
            raise InputError(f"{self.name}: averages must be an integer >= 1, got {averages!r}")
        averages = int(averages)
        if self.config.accumulate_on_device and averages > 5000:
            raise InputError(f"{self.name}: at most 5000 scans can be accumulated on the device")
        ts = time.time()
        if self.config.accumulate_on_device:
            total = self.acquire_frame(ms, averages)
            scans_per_frame = [(total, averages)]
        else:
            scans_per_frame = [(self.acquire_frame(ms, 1), 1) for _ in range(averages)]
        per_scan = []
        saturated = np.zeros(self.config.pixels or 0, dtype=bool)
        for values, scans in scans_per_frame:
            saturated |= values >= FULL_SCALE * scans
            per_scan.append(self._correct(values / scans, saturated))
        stack = np.vstack(per_scan)
        signal = stack.mean(axis=0)
        std = stack.std(axis=0, ddof=1) / math.sqrt(len(per_scan)) if len(per_scan) > 1 else None
        return Reading(wavelengths=self._wavelengths, signal=signal, saturated=saturated,
                       integration_s=ms / 1000.0, averages=averages, timestamp=ts, std=std)

    def _correct(self, counts: np.ndarray, saturated: np.ndarray) -> np.ndarray:
        out = counts.astype(float)
        if self._nl is not None:
            ok = ~saturated
            out[ok] = out[ok] / nonlinearity_factor(self._nl, out[ok])
        if self.config.subtract_electrical_dark:
            lo, hi = self.config.dark_pixels or (0, 0)
            out = out - out[lo:hi].mean()
        return out

    # --- Instrument ---------------------------------------------------------------------------
    def describe(self) -> InstrumentInfo:
        wl = self._wavelengths
        cfg = self.config
        return InstrumentInfo(
            kind="spectrometer", model=cfg.model, serial=self.serial, firmware=self.firmware,
            uncertainty=None,
            ranges={"wavelength_nm": (float(wl[0]), float(wl[-1])),
                    "integration_s": (0.001, 65.0), "counts": (0.0, float(FULL_SCALE))},
            extra={"name": self.name, "port": self.port, "pixels": cfg.pixels,
                   "dark_pixels": list(cfg.dark_pixels or ()), "mode": cfg.mode,
                   "checksum": cfg.checksum, "compression": cfg.compression,
                   "trigger_mode": cfg.trigger_mode,
                   "wavelength_coeffs": list(self.wavelength_coeffs),
                   "nonlinearity": None if self._nl is None else self._nl.tolist(),
                   "electrical_dark": cfg.subtract_electrical_dark})

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self.t.close()

    def __enter__(self) -> "OceanSpectrometer":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"OceanSpectrometer({self.name!r}, {self.port!r})"

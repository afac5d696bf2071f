"""The Ocean spectrometer driver: :class:`OceanSpectrometer`, the ``Spectrometer`` role over a
byte transport (open, mode switching, settings, calibration, acquisition, describe). The
protocol as implemented is described in :mod:`drivers.ocean`.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import fields
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
from drivers.ocean.codec import (
    ACK, CR, ETX, FULL_SCALE, NAK, STX, _Frame, decode_compressed, nonlinearity_factor,
    validate_nonlinearity, wavelength_polynomial,
)
from drivers.ocean.config import OceanConfig

log = logging.getLogger(__name__)


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

"""The Ocean spectrometer driver: :class:`OceanSpectrometer`, the ``Spectrometer`` role over a
byte transport (open, settings, calibration, acquisition, describe). Byte-level I/O is
:mod:`drivers.ocean._link`, frame decoding :mod:`drivers.ocean.codec`; the protocol as
implemented is described in :mod:`drivers.ocean`.
"""

from __future__ import annotations

import logging
import math
import time
from typing import Any, Callable, Mapping

import numpy as np

from bench.core.errors import (
    CalibrationError,
    ChecksumError,
    InputError,
    ProtocolError,
)
from bench.core.roles import InstrumentBase, InstrumentInfo, Reading
from drivers._settings import port_and_name, settings_with_overrides
from drivers.ocean._calibration import nonlinearity_factor, validate_nonlinearity, wavelength_polynomial
from drivers.ocean.codec import (
    ETX, FULL_SCALE, NAK, STX, Frame, FrameLayoutError, NeedMore, decode_version, encode_ascii,
    encode_binary, parse_ascii_frame, parse_binary_frame,
)
from drivers.ocean.config import OceanConfig
from drivers._faultlog import FaultLog
from drivers.ocean._link import Nak, OceanLink, Retry
from drivers.transport import SerialTransport

log = logging.getLogger(__name__)

#: Settings as the device has them after ``Q`` (reset to defaults; manual: free-running trigger,
#: no compression, no checksum). On open nothing is assumed: every setting is sent.
POWER_UP = {"T": 0, "G": 0, "k": 0}
#: settings the device reports back (``?A``, ``?I``, ``?T``): each is read back after it is set
READ_BACK = ("A", "I", "T")
#: Commands a session can do without: a NAK to one is recorded as "not supported".
OPTIONAL = {"G", "k"}


class OceanSpectrometer(InstrumentBase):
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
    clock : callable, optional
        Time source of the link's deadlines (default wall time; tests pass a fake one).

    Raises
    ------
    PortGoneError
        The port cannot be opened.
    CalibrationError
        The wavelength calibration is implausible, or the opt-in non-linearity correction
        has nonsense coefficients.
    """

    def __init__(self, transport: Any, *, config: OceanConfig | Mapping[str, Any] | None = None,
                 name: str = "spectrometer", clock: Callable[[], float] = time.monotonic,
                 **overrides: Any) -> None:
        base = settings_with_overrides(OceanConfig, config, overrides, "spectrometer")
        self.config: OceanConfig = base.resolved()
        self.name = name
        if isinstance(transport, str):
            self.port = transport
            t: Any = SerialTransport(transport, baudrate=self.config.baudrate)
        else:
            self.port = repr(transport)
            t = transport
        self.link = OceanLink(t, name, self.config.timeout_s, self.config.retries, clock)
        self._closed = False
        self._state: dict[str, int] = {}      # what the device is known to have: nothing until set
        self._sent: set[str] = set()          # letters actually sent this session
        self._suspect_compression = False
        self.unsupported: set[str] = set()
        self.found_mode = "binary"
        self.dword_checksum: str = self.config.dword_checksum  # "auto" until a frame proves it
        self.serial = ""
        self.firmware = ""
        self.version_word = 0
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

    @property
    def t(self) -> Any:
        """The byte transport."""
        return self.link.t

    @classmethod
    def from_config(cls, cfg: Mapping[str, Any]) -> "OceanSpectrometer":
        """Build from a bench-config table: ``port`` (required), ``name`` and OceanConfig keys."""
        port, name, d = port_and_name(cfg, "spectrometer config", "spectrometer")
        return cls(port, name=name, **d)

    # --- commands -----------------------------------------------------------------------------
    def _encode(self, letter: str, args: Any = ()) -> bytes:
        return encode_ascii(letter, args) if self.link.mode == "ascii" else encode_binary(letter, args)

    def command(self, letter: str, *args: int) -> None:
        """Send a set command (``I``, ``A``, ``T``, ``k``, ...) and require ACK."""
        what = f"command {letter!r}" + (f" {list(args)}" if args else "")

        def once() -> None:
            deadline = self.link.deadline()
            self.link.send(self._encode(letter, args), deadline, what)
            self.link.expect_ack(deadline, what)
        self.link.retrying(what, once)

    def _ack_then(self, cmd: str, args: Any, what: str, read: Any) -> Any:
        def once() -> Any:
            deadline = self.link.deadline()
            self.link.send(self._encode(cmd, args), deadline, what)
            self.link.expect_ack(deadline, what)
            return read(deadline)
        return self.link.retrying(what, once)

    def _number(self, deadline: float, what: str, nbytes: int) -> int:
        if self.link.mode == "ascii":
            text = self.link.read_line(deadline, what, 32)
            try:
                return int(text)
            except ValueError:
                raise Retry(ChecksumError(f"{self.name}: {what}: not a number: {text!r}")) from None
        return int.from_bytes(self.link.read_exact(nbytes, deadline, what), "big")

    def query(self, letter: str) -> int:
        """``?<letter>``: a setting as an integer (``i``/``j`` are 32-bit)."""
        what = f"query '?{letter}'"
        n = 4 if letter in ("i", "j") else 2
        return self._ack_then("?" + letter, (), what, lambda d: self._number(d, what, n))

    def read_slot(self, n: int) -> str:
        """``?x<n>``: the calibration slot's text (a line ending CR LF)."""
        what = f"query '?x{n}'"
        text = self._ack_then("?x", (n,), what, lambda d: self.link.read_line(d, what, 64))
        text = text.decode("ascii", "replace").strip()
        self.slots[n] = text
        return text

    def read_number_slot(self, n: int, what: str) -> float:
        """``?x<n>`` read as a number; :class:`CalibrationError` naming ``what`` if it is not one."""
        text = self.read_slot(n)
        try:
            return float(text)
        except ValueError:
            raise CalibrationError(f"{self.name}: {what} ?x{n} = {text!r} is not a number") from None

    def version(self) -> int:
        """``v``: the firmware version word (its decimal digits are the version)."""
        what = "command 'v'"
        return self._ack_then("v", (), what, lambda d: self._number(d, what, 2))

    def _set(self, letter: str, value: int) -> None:
        """Send ``letter value`` only when it changes the device's setting. A NAK to an optional
        command (:data:`OPTIONAL`) is recorded in :attr:`unsupported`, not raised."""
        if self._state.get(letter) == value or letter in self.unsupported:
            return
        try:
            self.command(letter, value)
            self._sent.add(letter)
            if letter in READ_BACK and letter not in self.unsupported:
                got = self.query(letter)
                if got != value:
                    raise ProtocolError(f"{self.name}: set {letter} {value} but the device reports {got}")
        except Nak:
            if letter not in OPTIONAL:
                raise
            self.unsupported.add(letter)
            log.warning("%s: %r is not supported by this unit (NAK); continuing without it",
                        self.name, letter)
            return
        self._state[letter] = value

    @property
    def checksum_on(self) -> bool:
        return bool(self._state.get("k"))

    @property
    def compression_on(self) -> bool:
        return bool(self._state.get("G"))

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
        self._state = dict(POWER_UP)
        self._apply_settings()

    def _apply_settings(self) -> None:
        """Every setting the driver relies on, sent whatever the device is assumed to have (a unit
        keeps them from an earlier program): checksum, compression, trigger, scans to add 1, all
        pixels; the integration time is set by the first acquisition."""
        cfg = self.config
        self._set("k", int(cfg.checksum))
        self._set("G", int(cfg.compression))
        self._set("T", cfg.trigger_mode)
        self._set("A", 1)
        self._set("P", 0)

    # --- open ---------------------------------------------------------------------------------
    def _open(self) -> None:
        cfg = self.config
        self.found_mode = self.link.sync_binary()
        if cfg.mode == "ascii":
            self.command_mode("ascii")
        self.version_word = self.version()
        self.firmware = decode_version(self.version_word)
        self.serial = self.read_slot(0)
        self.wavelength_coeffs = coeffs = [self.read_number_slot(n, "wavelength coefficient") for n in (1, 2, 3, 4)]
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
        self._apply_settings()
        log.info("%s: %s serial %s firmware %s, %d pixels %.1f..%.1f nm", self.name, cfg.model,
                 self.serial, self.firmware, cfg.pixels, wl[0], wl[-1])

    def command_mode(self, mode: str) -> None:
        """Switch the device between ``"binary"`` and ``"ascii"`` mode (bare ``aA`` / ``bB``)."""
        if mode not in ("binary", "ascii"):
            raise InputError(f"mode must be 'binary' or 'ascii', got {mode!r}")
        if mode == self.link.mode:
            return
        if mode == "ascii":
            self.link.to_ascii()
        else:
            self.link.to_binary()

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
        ks = [self.read_number_slot(n, "non-linearity coefficient") for n in range(6, 7 + order)]
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
        per_value = 12 if self.link.mode == "ascii" else (4 if scans > 1 else 2)
        line_s = (npix * per_value + 64) * 10.0 / self.config.baudrate
        # free-running: the scan in progress is discarded, so allow one extra integration
        acq_s = integration_ms / 1000.0 * (scans + 1)
        return self.link.deadline(acq_s + line_s)

    def _read_frame(self, integration_ms: int, scans: int) -> Frame:
        what = "command 'S'"
        deadline = self._frame_deadline(integration_ms, scans)
        self.link.send(self._encode("S"), deadline, what)
        first = self.link.read_exact(1, deadline, what)[0]
        if first == ETX:
            raise ProtocolError(f"{self.name}: 'S' answered ETX: insufficient memory for "
                                f"{self.config.pixels} pixels x {scans} scans")
        if first == NAK:
            raise Nak(f"{self.name}: NAK to {what}")
        if first != STX:
            raise Retry(ChecksumError(f"{self.name}: {what}: expected STX, got 0x{first:02X}"))
        npix = self.config.pixels or 0
        kw: dict[str, Any] = dict(checksum=self.checksum_on, convention=self.dword_checksum,
                  expect_scans=scans, expect_integration_ms=integration_ms)
        try:
            if self.link.mode == "ascii":
                n = 7 + npix + 1 + (1 if self.checksum_on else 0)
                nums = []
                for _ in range(n):
                    text = self.link.read_line(deadline, what, 16)
                    try:
                        nums.append(int(text))
                    except ValueError:
                        raise Retry(ChecksumError(f"{self.name}: {what}: {text!r} is not a "
                                                  f"number")) from None
                fr = parse_ascii_frame(nums, npix, **kw)
            else:
                buf = bytearray()
                need = 14
                try:
                    while True:
                        buf += self.link.read_exact(need, deadline, what)
                        try:
                            fr, _ = parse_binary_frame(buf, npix, compressed=self.compression_on,
                                                       **kw)
                            break
                        except NeedMore as more:
                            need = more.n
                except (Retry, FrameLayoutError):
                    # a good header, then data that do not fit an uncompressed frame: the unit
                    # may have been left compressing (G 1) by an earlier session
                    if len(buf) >= 14 and not self.compression_on and "G" not in self._sent:
                        self._suspect_compression = True
                    raise
        except (ChecksumError, ProtocolError) as exc:
            raise Retry(ChecksumError(f"{self.name}: {what}: {exc}")) from None
        if fr.checksum_convention and self.dword_checksum == "auto":
            self.dword_checksum = fr.checksum_convention
            log.info("%s: DWORD frame checksum convention detected: sum of %s", self.name,
                     "pixel values" if fr.checksum_convention == "pixels" else "16-bit data words")
        return fr

    def acquire_frame(self, integration_ms: int, scans: int) -> np.ndarray:
        """One S acquisition: the raw (accumulated) counts of every pixel, after the retries."""
        self._set("I", integration_ms)
        self._set("A", scans)
        self._set("P", 0)

        def once() -> np.ndarray:
            if self._suspect_compression and "G" not in self.unsupported:
                self._suspect_compression = False
                self._state.pop("G", None)  # unknown now: G 0 changes something
                self._set("G", 0)
            return self._read_frame(integration_ms, scans).values
        return self.link.retrying("command 'S'", once)

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
    @property
    def faults(self) -> FaultLog:
        """The line's transaction faults and recoveries (:class:`drivers._faultlog.FaultLog`)."""
        return self.link.faults

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
                   "checksum": self.checksum_on, "compression": self.compression_on,
                   "dword_checksum": self.dword_checksum if self.dword_checksum != "auto"
                   else "undetermined", "unsupported": sorted(self.unsupported),
                   "found_in_mode": self.found_mode,
                   "trigger_mode": cfg.trigger_mode,
                   "wavelength_coeffs": list(self.wavelength_coeffs),
                   "nonlinearity": None if self._nl is None else self._nl.tolist(),
                   "electrical_dark": cfg.subtract_electrical_dark})

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self.link.closed = True
            self.t.close()

    def __repr__(self) -> str:
        return f"OceanSpectrometer({self.name!r}, {self.port!r})"

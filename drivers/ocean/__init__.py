"""An Ocean-Optics-style RS-232 spectrometer (USB2000+/USB4000/Flame-S family) through a Transport.

Protocol as implemented here (facts: the Ocean Optics Flame-S manual, chapter "Firmware and Advanced
Communications", the authority; where the manual is silent the driver copes with every reasonable
reading, marked *open*):

Binary mode (power-up default)
    One ASCII letter per command; a data word follows as 16 bits, most significant byte first.
    ``A`` scans to add (1..5000), ``B`` boxcar, ``G`` compression (0/1), ``I`` integration time
    in ms (1..65000), ``J`` lamp, ``K`` baud code, ``M`` storage mode, ``T`` trigger mode (0..4),
    ``k`` checksum mode (0/1): letter + word. ``P`` pixel mode: letter + mode word + its
    parameter words. ``Q``, ``L``, ``S``, ``v``: letter alone. Each is answered ACK 0x06 or
    NAK 0x15; ``v`` answers ACK + a word whose decimal digits are the version (1000 =
    "1.00.0"). Queries ``?A ?B ?I ?K ?T ?J`` answer ACK + word, ``?i``/``?j`` ACK + 32-bit
    word; ``?x`` + slot word answers ACK + the slot's ASCII text + CR LF.
ASCII mode (``aA``; back with ``bB``; both two bare bytes, no CR)
    The device echoes every byte it receives: the driver writes a command byte by byte and
    reads each echo back. Data values are decimal and end with CR; a command without data is
    the letter alone. Values the device sends back end with CR LF (a bare CR is accepted too).
Settings
    A unit keeps its settings from an earlier program, so on open the driver assumes none: it
    sends ``k``, ``G``, ``T``, ``A 1`` and ``P 0`` and reads back ``?T`` and ``?A`` (``I`` with
    ``?I`` at the first acquisition); later a setting is sent only when it changes. A NAK, a
    timeout or a corrupt reply is retried (bounded, after draining the line) and counted in
    ``OceanSpectrometer.faults``. ``G`` and ``k`` are optional: a NAK to them is recorded as "not supported" (``describe().extra["unsupported"]``)
    and the session goes on without them; the device's answers to the refused command's data
    bytes are drained, never read as later answers. ``open`` brings the device back to binary
    mode from either mode (a bare ``bB``: echoed and ACKed in ASCII mode, ACKed in binary).
S reply
    ETX 0x03 = insufficient memory; NAK = refused; else STX 0x02 then the frame: ``0xFFFF``,
    data-size flag (0 words, 1 dwords; dwords when scans to add > 1), scans accumulated,
    integration time (ms), FPGA baseline MSW, LSW, pixel mode (+ its parameters), the pixel
    data, ``0xFFFD``, and with checksum mode on a 16-bit checksum (sum of the pixel values
    modulo 65536). *Open*: on DWORD frames the sum may run over the pixel values or over all
    16-bit data words; ``dword_checksum = "auto"`` (default) accepts either, detects the
    convention on the first frame that distinguishes them and keeps it (``describe()`` reports
    it), or set ``"pixels"`` / ``"words"``. A frame whose header does not match the request
    (scans, integration time, pixel mode) is never accepted. In ASCII mode every item is a
    decimal number + CR LF (compression does not apply). Compression: each pixel is a signed
    8-bit difference from the previous one (the first from 0) when |d| <= 127, else 0x80
    followed by the 16-bit value.
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
from drivers.ocean._calibration import (
    nonlinearity_factor, validate_nonlinearity, wavelength_polynomial,
)
from drivers.ocean.codec import decode_compressed, decode_version, dword_checksums
from drivers.ocean.config import MODELS, OceanConfig
from drivers.ocean.spectrometer import OceanSpectrometer

__all__ = ["OceanConfig", "OceanSpectrometer", "MODELS", "decode_compressed",
           "nonlinearity_factor", "validate_nonlinearity", "wavelength_polynomial",
           "decode_version", "dword_checksums"]

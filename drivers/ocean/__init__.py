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
from drivers.ocean.codec import (
    decode_compressed, nonlinearity_factor, validate_nonlinearity, wavelength_polynomial,
)
from drivers.ocean.config import MODELS, OceanConfig
from drivers.ocean.spectrometer import OceanSpectrometer

__all__ = ["OceanConfig", "OceanSpectrometer", "MODELS", "decode_compressed",
           "nonlinearity_factor", "validate_nonlinearity", "wavelength_polynomial"]

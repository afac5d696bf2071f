"""An Ocean-Optics-style RS-232 spectrometer, emulated on a pseudo-terminal in its own process.

It speaks the protocol of the Ocean Optics Flame-S manual (chapter "Firmware and Advanced
Communications") as pinned down in
:mod:`drivers.ocean` (binary and ASCII modes, ACK/NAK, checksum mode, compression, scans to
add, trigger mode, ``?x`` calibration slots) and produces

    counts = lamp(lambda) * response(geometry, lambda) * integration_ms * peak_counts_per_ms
             + dark + noise,   through a mild detector non-linearity, reading full scale (65535) from ``saturation_counts`` per scan

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
        emu.fault_rate(0.01, seed=3)  # random NAKs, dropped replies and corrupt frames (soak)
        emu.no_memory(1)         # the next S answers ETX (insufficient memory)
        emu.trigger()            # release an acquisition waiting in an external trigger mode
        emu.state()              # settings, mode, counters
        emu.die()                # the process exits at once; the pty vanishes

From a shell: ``python -m virtual.wire.ocean_spectrometer`` prints one JSON line with the port.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import select
import sys
import threading
from typing import Any

from virtual.wire._ocean_device import _Device, _Faults
from virtual.wire.ocean_model import (
    SpectrometerConfig, SpectrometerModel,
)
from virtual.wire._pty import PipeEmulator, answer_control, close_quietly, open_raw_pty, write_all


log = logging.getLogger(__name__)

__all__ = ["SpectrometerEmulator"]



def _child_main(cfg: dict[str, Any], geometry_source: Any, response: Any, conn: Any,
                log_level: int) -> None:
    logging.basicConfig(level=log_level, stream=sys.stderr,
                        format="ocean-emu %(levelname)s %(name)s: %(message)s")
    try:
        scfg = SpectrometerConfig(**cfg)
        model = SpectrometerModel(scfg, geometry_source, response)
        model.prepare()  # before the port is announced: no command waits for the response's tables
        master, slave, path = open_raw_pty()
    except Exception as exc:
        conn.send({"error": f"{type(exc).__name__}: {exc}"})
        raise

    def write(data: bytes) -> None:
        try:
            write_all(master, data)
        except OSError:  # the host closed its end: the reply has nowhere to go
            return

    os.set_blocking(master, False)
    dev = _Device(model, write)
    conn.send({"port": path, "pid": os.getpid(), "pixels": scfg.pixels, "model": scfg.model})
    lock = threading.Lock()

    def handle(cmd: Any, msg: dict[str, Any], reply: dict[str, Any]) -> dict[str, Any]:
        f = dev.faults
        if cmd == "nak":
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
        elif cmd == "rates":
            dev.faults.rate = float(msg.get("rate", 0.0))
            dev.faults.rng.seed(int(msg.get("seed", 0)))
        elif cmd == "injected":
            reply["injected"] = dict(dev.faults.injected)
        elif cmd == "trigger":
            dev.external_trigger()
        elif cmd == "state":
            s = model.settings
            reply["state"] = {**s.__dict__, "commands": dev.commands, "acquisitions": dev.acquisitions,
                              "last_geometry": repr(model.last_geometry)}
        else:
            return {"ok": False, "error": f"unknown command {cmd!r}"}
        return reply

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
        if conn in r and not answer_control(conn, lock, handle):
            break
    close_quietly((master, slave))


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
        ``"module:attr"`` strings. The response is asked once without a geometry before the port
        is announced (:meth:`SpectrometerModel.prepare`), within ``start_timeout``.
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

    def fault_rate(self, rate: float, seed: int = 0) -> None:
        """Random transient faults from now on (seeded): NAKs and dropped replies, rate / 2 of the
        commands each, and corrupted frames, ``rate`` of them."""
        self._call({"cmd": "rates", "rate": rate, "seed": seed})

    def injected(self) -> dict[str, int]:
        """Random faults injected so far, by kind."""
        return self._call({"cmd": "injected"})["injected"]

    def __repr__(self) -> str:
        return f"SpectrometerEmulator({self.port}, pid={self._proc.pid})"


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

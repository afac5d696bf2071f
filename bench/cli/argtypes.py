"""Declared argument types of the ``bench`` command line: every value a user types is checked here.

Each factory returns an argparse ``type=`` callable that refuses non-finite numbers, values out of
range and sizes beyond a stated bound with an :class:`argparse.ArgumentTypeError`; argparse then
names the option (``argument --rays: ...``) and :class:`BenchArgumentParser` prints that as ONE
line and exits 2. Imports nothing heavy (the CLI must start fast).
"""

from __future__ import annotations

import argparse
import math
import re
import sys
from typing import Callable, Iterable, Iterator, NoReturn
from urllib.parse import urlsplit

__all__ = ["BenchArgumentParser", "one_line", "renamed", "MAX_ERROR_CHARS", "RegistryChoices", "count", "real", "seed", "rays", "incidence", "wavelengths", "collector",
           "int_list", "scheduler_address", "run_id", "listen_address", "MAX_RAYS", "MAX_PATCHES", "MAX_SEED", "RAYS_PER_SECOND"]

#: the most rays per wavelength a command accepts at all (the time bound, --max-seconds, comes first)
MAX_RAYS = 10**15
#: the most patches one collector may have (rings x sectors, per hemisphere; bench.core.parsing's bound)
MAX_PATCHES = 1_000_000
#: seeds are 63-bit non-negative integers (numpy SeedSequence entropy; SQLite INTEGER)
MAX_SEED = 2**63 - 1
#: the stated ray rate of the counting kernels, used to turn a ray count into an estimated time
RAYS_PER_SECOND = 2e7


#: the longest error line the CLI prints (a 60,000-character value must not make a 120 KB line)
MAX_ERROR_CHARS = 600


def one_line(text: object, limit: int = MAX_ERROR_CHARS) -> str:
    """``text`` on one line (whitespace runs become one space), at most ``limit`` characters: a
    longer one keeps its head and tail around a note of how much was left out."""
    line = " ".join(str(text).split()) or "(no message)"
    if len(line) <= limit:
        return line
    cut = len(line) - limit + 40
    head = (limit - 40) * 2 // 3
    return f"{line[:head]} [... {cut:,} characters left out ...] {line[head + cut:]}"


class BenchArgumentParser(argparse.ArgumentParser):
    """An ArgumentParser whose usage errors are one line on stderr (exit 2), not usage + error."""

    def _get_values(self, action: argparse.Action, arg_strings: list[str]) -> object:
        # argparse strips a lone "--" from an option's value (``--seed=--``) and then hands the
        # command an empty list instead of calling the type: refuse it as the value it is
        if arg_strings == ["--"] and action.option_strings and action.nargs in (None, "?"):
            raise argparse.ArgumentError(action, "expected a value, got '--'")
        return super()._get_values(action, arg_strings)

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {one_line(message)} (see {self.prog} --help)\n")


class _Renamed(argparse.Action):
    """An option's old spelling: refused, whatever follows it, with one line naming the new one."""

    def __init__(self, option_strings: list[str], dest: str, *, reason: str, **kwargs: object) -> None:
        super().__init__(option_strings, argparse.SUPPRESS, nargs="*", default=argparse.SUPPRESS,
                         help=argparse.SUPPRESS)
        self.reason = reason

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: object,
                 option_string: str | None = None) -> None:
        raise argparse.ArgumentError(None, f"{self.option_strings[0]} {self.reason}")


def renamed(parser: argparse.ArgumentParser | argparse._ArgumentGroup, old: str, new: str, why: str) -> None:
    """Refuse ``old``, an option's former spelling, in ``parser``: ``bench CMD: error: OLD WHY; did
    you mean NEW?`` (one line, exit 2 -- as every usage error of :class:`BenchArgumentParser`).
    The old spelling is hidden from ``--help``; as an exact option it also keeps argparse from
    reading it as an abbreviation of another option."""
    parser.add_argument(old, action=_Renamed, reason=f"{why}; did you mean {new}?")


class RegistryChoices:
    """``choices=`` read from a registry when first needed (to check a value or print help), so
    building the parser imports no registry -- and plugins registered by then are offered too."""

    def __init__(self, names: Callable[[], Iterable[str]]) -> None:
        self._names = names

    def __contains__(self, value: object) -> bool:
        return value in tuple(self._names())

    def __iter__(self) -> Iterator[str]:
        return iter(tuple(self._names()))


def _number(text: str) -> float:
    try:
        v = float(text)
    except (TypeError, ValueError, OverflowError):
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return v


def _integer(text: str) -> int:
    s = str(text).strip()
    try:
        return int(s)
    except ValueError:
        pass
    v = _number(s)  # 1e7 is accepted when it is a whole number
    if v != math.floor(v):
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}")
    return int(v)


def _bounds(lo: float | None, hi: float | None, lo_open: bool, hi_open: bool) -> str:
    left = "" if lo is None else f"{'>' if lo_open else '>='} {lo:g}"
    right = "" if hi is None else f"{'<' if hi_open else '<='} {hi:g}"
    return " and ".join(p for p in (left, right) if p)


def real(lo: float | None = None, hi: float | None = None, *, lo_open: bool = False,
         hi_open: bool = False) -> Callable[[str], float]:
    """A finite float within ``[lo, hi]`` (open ends with ``lo_open``/``hi_open``)."""

    def parse(text: str) -> float:
        v = _number(text)
        if (lo is not None and (v < lo or (lo_open and v == lo))) or \
                (hi is not None and (v > hi or (hi_open and v == hi))):
            raise argparse.ArgumentTypeError(f"expected a number {_bounds(lo, hi, lo_open, hi_open)}, got {text!r}")
        return v

    parse.__name__ = "number"
    return parse


def count(lo: int = 1, hi: int = 10**9) -> Callable[[str], int]:
    """An integer within ``[lo, hi]`` (``1e7`` accepted when whole)."""

    def parse(text: str) -> int:
        v = _integer(text)
        if not lo <= v <= hi:
            raise argparse.ArgumentTypeError(f"expected an integer from {lo:,} to {hi:,}, got {text!r}")
        return v

    parse.__name__ = "integer"
    return parse


#: a seed: an integer 0 .. 2^63-1
seed = count(0, MAX_SEED)
seed.__name__ = "seed"
#: a ray count per wavelength: 1 .. MAX_RAYS
rays = count(1, MAX_RAYS)
rays.__name__ = "ray count"


def incidence(text: str) -> tuple[float, float]:
    """``THETA`` or ``THETA,PHI`` in degrees: THETA in [0, 90], PHI in [-360, 360]."""
    parts = str(text).split(",")
    if len(parts) not in (1, 2):
        raise argparse.ArgumentTypeError(f"expected THETA or THETA,PHI in degrees, got {text!r}")
    theta = real(0.0, 90.0)(parts[0])
    phi = real(-360.0, 360.0)(parts[1]) if len(parts) == 2 else 0.0
    return float(theta), float(phi)


def wavelengths(text: str) -> str:
    """``START:STOP:STEP``, ``a,b,c`` or one number (nm), checked (finite, positive, bounded count);
    returned as given, for the instruments to parse again."""
    from bench.core.parsing import parse_wavelengths
    from bench.core.errors import InputError

    try:
        parse_wavelengths(text)
    except InputError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def collector(text: str) -> str:
    """``SCHEME:RINGSxSECTORS`` with at most :data:`MAX_PATCHES` patches
    (:func:`bench.core.parsing.check_collector_spec`; the scheme itself is checked by the collector)."""
    from bench.core.errors import InputError
    from bench.core.parsing import check_collector_spec

    try:
        check_collector_spec(text)
    except InputError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def int_list(lo: int, hi: int, most: int = 100) -> Callable[[str], list[int]]:
    """Comma-separated integers within ``[lo, hi]``, at most ``most`` of them."""
    one = count(lo, hi)

    def parse(text: str) -> list[int]:
        items = [p for p in str(text).split(",") if p.strip()]
        if not items or len(items) > most:
            raise argparse.ArgumentTypeError(f"expected 1 to {most} comma-separated integers, got {text!r}")
        return [one(p) for p in items]

    parse.__name__ = "integer list"
    return parse


_SCHEMES = ("tcp", "tls", "inproc", "ucx", "ws", "wss")


def scheduler_address(text: str) -> str:
    """A Dask scheduler address, ``tcp://HOST:PORT`` (or ``HOST:PORT``), checked at once."""
    s = str(text).strip()
    url = s if "://" in s else f"tcp://{s}"
    try:
        parts = urlsplit(url)
        port = parts.port
    except ValueError:
        parts, port = None, None
    if parts is None or parts.scheme not in _SCHEMES or not parts.hostname or \
            (parts.scheme != "inproc" and port is None) or parts.path not in ("", "/") or \
            re.search(r"\s", s):
        raise argparse.ArgumentTypeError(f"expected a scheduler address like tcp://127.0.0.1:8786, got {text!r}")
    return url


def listen_address(text: str) -> str:
    """``HOST:PORT`` for a service to listen on (port 0..65535; 0 = any free port)."""
    host, sep, port = str(text).strip().rpartition(":")
    if not sep or not port.isdigit() or int(port) > 65535 or re.search(r"[\s/]", host):
        raise argparse.ArgumentTypeError(f"expected HOST:PORT such as 127.0.0.1:8787, got {text!r}")
    return f"{host or '127.0.0.1'}:{int(port)}"


_RUN_ID = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._:-]{0,127}$")


def iso_date(text: str) -> str:
    """A date YYYY-MM-DD (ISO 8601), returned in that form."""
    import datetime as dt

    try:
        return dt.date.fromisoformat(text).isoformat()
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a date YYYY-MM-DD, got {text!r}") from None


def run_id(text: str) -> str:
    """A run id as ``bench runs`` prints it (letters, digits, ``-._:``; at most 128 characters)."""
    if not _RUN_ID.match(str(text)):
        shown = str(text).encode("utf-8", "backslashreplace").decode("ascii", "backslashreplace")[:60]
        raise argparse.ArgumentTypeError(f"expected a run id such as 20261122-0930-1a2b (see `bench runs`), "
                                         f"got {shown!r}")
    return text


def estimated_seconds(n_rays: int, n_wavelengths: int, rate: float = RAYS_PER_SECOND) -> float:
    """Seconds to count ``n_rays`` per wavelength over ``n_wavelengths`` at the stated rate."""
    return float(n_rays) * max(1, int(n_wavelengths)) / rate


def stderr_is_terminal() -> bool:
    """Progress bars only on a terminal (never in a pipe, a file or a test)."""
    try:
        return sys.stderr.isatty()
    except (AttributeError, ValueError):
        return False

"""Register maps of Modbus drives, held as data.

A drive is described by a TOML file in this folder (or a plain dict of the same shape), loaded
into a :class:`RegisterMap`. Another drive that speaks "direct data operation" with a different
layout is a new map, not new code::

    from drivers.registers import load_register_map
    rmap = load_register_map("oriental_az")            # drivers/registers/oriental_az.toml
    rmap = load_register_map("/path/to/my_drive.toml")
    rmap = load_register_map({"name": ..., "registers": {...}, ...})

Shape of the data (every key of ``registers``, ``input_bits`` and ``status_bits`` listed in
:data:`REQUIRED_REGISTERS` / :data:`REQUIRED_INPUT_BITS` / :data:`REQUIRED_STATUS_BITS` is
required; 32-bit values occupy two registers starting at the given address)::

    name = "oriental-az"
    word_order = "big"                 # "big": upper word first
    [registers]   direct_data_no, direct_type, direct_position, direct_speed, direct_accel,
                  direct_decel, direct_current, direct_trigger, input_command, output_status,
                  present_alarm, feedback_position, command_position
    [input_bits]  START, STOP, ALM-RST (+ ZHOME, FREE)          bit numbers in the 32-bit word
    [status_bits] READY, ALM, BUSY, MOVE, IN-POS                bit numbers in the 32-bit word
    [values]      type_absolute, trigger_all, current_max
    [alarms]      "0x30" = "overload"                           code -> name (messages only)
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Annotated, Any, ClassVar, Literal, Mapping

from pydantic import Field, field_validator, model_validator

from bench.core.errors import ConfigError
from bench.core.validation import Settings, Whole

__all__ = [
    "RegisterMap",
    "load_register_map",
    "REQUIRED_REGISTERS",
    "REQUIRED_INPUT_BITS",
    "REQUIRED_STATUS_BITS",
]

HERE = Path(__file__).resolve().parent

REQUIRED_REGISTERS = (
    "direct_data_no", "direct_type", "direct_position", "direct_speed", "direct_accel",
    "direct_decel", "direct_current", "direct_trigger", "input_command", "output_status",
    "present_alarm", "feedback_position", "command_position",
)
REQUIRED_INPUT_BITS = ("START", "STOP", "ALM-RST")
REQUIRED_STATUS_BITS = ("READY", "ALM", "BUSY", "MOVE", "IN-POS")
_DIRECT_ORDER = (
    "direct_data_no", "direct_type", "direct_position", "direct_speed", "direct_accel",
    "direct_decel", "direct_current", "direct_trigger",
)


_Address = Annotated[Whole, Field(ge=0, le=0xFFFE)]
_Bit = Annotated[Whole, Field(ge=0, le=31)]


class RegisterMap(Settings):
    """Addresses, bit numbers and codes of one drive family (see the module docstring), each
    table declared once with its range (validated by pydantic like every settings table); the
    required keys and the consecutive direct-data slots in one model validator."""

    settings_of: ClassVar[str] = "register map"

    name: str
    registers: dict[str, _Address]
    input_bits: dict[str, _Bit]
    status_bits: dict[str, _Bit]
    values: dict[str, Whole] = Field(default_factory=dict)
    alarms: dict[int, str] = Field(default_factory=dict)
    word_order: Literal["big", "little"] = "big"
    description: str = ""

    @field_validator("alarms", mode="before")
    @classmethod
    def _codes(cls, v: Any) -> Any:
        """TOML keys are strings: ``"0x30" = "overload"`` is code 0x30."""
        if isinstance(v, Mapping):
            try:
                return {(int(k, 0) if isinstance(k, str) else k): a for k, a in v.items()}
            except ValueError as exc:
                raise ValueError(f"alarm codes are integers (\"0x30\" or 48): {exc}") from None
        return v

    @model_validator(mode="after")
    def _required_and_consecutive(self) -> "RegisterMap":
        for what, have, need in (("registers", self.registers, REQUIRED_REGISTERS),
                                 ("input_bits", self.input_bits, REQUIRED_INPUT_BITS),
                                 ("status_bits", self.status_bits, REQUIRED_STATUS_BITS)):
            missing = [k for k in need if k not in have]
            if missing:
                raise ValueError(f"{self.name!r}: [{what}] lacks {', '.join(missing)}")
        addrs = [self.registers[k] for k in _DIRECT_ORDER]
        if any(b - a != 2 for a, b in zip(addrs, addrs[1:])):
            raise ValueError(f"{self.name!r}: the direct data registers must be consecutive 32-bit slots "
                             f"({', '.join(_DIRECT_ORDER)})")
        return self

    # --- helpers --------------------------------------------------------------------------
    def addr(self, key: str) -> int:
        """Address of register ``key``."""
        return self.registers[key]

    def value(self, key: str, default: int) -> int:
        return int(self.values.get(key, default))

    @property
    def direct_block(self) -> tuple[int, int]:
        """``(first address, register count)`` of the direct-data block written with FC16."""
        return self.registers["direct_data_no"], 2 * len(_DIRECT_ORDER)

    def alarm_name(self, code: int) -> str:
        return self.alarms.get(code, "unknown alarm")

    def status_flags(self, status: int) -> list[str]:
        """Names of the status bits set in ``status``."""
        return [k for k, b in self.status_bits.items() if status >> b & 1]

    def to_words(self, value: int) -> list[int]:
        """Signed 32-bit ``value`` as two registers in the map's word order."""
        v = int(value) & 0xFFFFFFFF
        words = [v >> 16, v & 0xFFFF]
        return words if self.word_order == "big" else words[::-1]

    def from_words(self, words: list[int], signed: bool = True) -> int:
        hi, lo = (words[0], words[1]) if self.word_order == "big" else (words[1], words[0])
        v = (hi & 0xFFFF) << 16 | (lo & 0xFFFF)
        if signed and v & 0x80000000:
            v -= 1 << 32
        return v


def load_register_map(spec: "str | Path | Mapping[str, Any] | RegisterMap") -> RegisterMap:
    """Load a register map from a name in this folder, a TOML path, a dict, or pass one through."""
    if isinstance(spec, RegisterMap):
        return spec
    if isinstance(spec, Mapping):
        return RegisterMap.from_dict(spec)
    path = Path(spec)
    if not path.suffix:
        path = HERE / f"{str(spec).replace('-', '_')}.toml"
    if not path.is_file():
        known = sorted(p.stem for p in HERE.glob("*.toml"))
        raise ConfigError(f"no register map {str(spec)!r} (known: {', '.join(known)})")
    try:
        with path.open("rb") as fh:
            data = tomllib.load(fh)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"register map {path}: {exc}") from None
    return RegisterMap.from_dict(data, f"register map {path}")

"""The bench's light source (the LightSource role) as a bench file declares it: ``[light]``.

A dark reading needs the light off. A bench that cannot switch its light (no ``[light]``) cannot
take darks, and a plan that asks for them is refused before motion (:mod:`bench.preflight`)
rather than run without them. Declared kinds::

    [light]
    kind = "spectrometer-lamp"   # a lamp on the spectrometer's lamp-enable line (command ``J``)
    settle_s = 0.0               # wait after switching before a reading (lamp or shutter settling)

The emulated bench always has this lamp (its spectrometer emulator answers ``J``); a real
bench has it when its file says so.
"""

from __future__ import annotations

import time
from typing import Any, Final, Literal, Mapping

from pydantic import BaseModel, ConfigDict, Field

from bench.core.roles import InstrumentBase, InstrumentInfo
from bench.core.schemas import Finite, validate_document

__all__ = ["LampLine", "LightTable", "light_settings", "build_light", "declares_light", "LAMP_LINE"]

#: the ``[light] kind`` of a lamp switched by the spectrometer's lamp-enable line
LAMP_LINE: Final = "spectrometer-lamp"


class LightTable(BaseModel):
    """``[light]``: how the bench switches its light for darks."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    kind: Literal["spectrometer-lamp"] = LAMP_LINE
    settle_s: Finite = Field(0.0, ge=0, le=60)


class LampLine(InstrumentBase):
    """The LightSource role through the spectrometer's lamp-enable line (command ``J``)."""

    def __init__(self, spectrometer: Any, settle_s: float = 0.0) -> None:
        self.spectrometer = spectrometer
        self.settle_s = settle_s

    def describe(self) -> InstrumentInfo:
        return InstrumentInfo(kind="light source", model="lamp on the spectrometer's lamp-enable line")

    def _switch(self, on: bool) -> None:
        self.spectrometer.command("J", 1 if on else 0)
        if self.settle_s > 0:
            time.sleep(self.settle_s)

    def on(self) -> None:
        self._switch(True)

    def off(self) -> None:
        self._switch(False)


def declares_light(d: Mapping[str, Any]) -> bool:
    """Whether description ``d`` has a light it can switch off, whatever body executes it: a
    virtual or emulated description always (the virtual source, the emulator's lamp line); a
    real one when it says so in ``[light]`` -- so its virtual and emulated bodies refuse darks
    as the real bench does."""
    return str(d.get("kind", "virtual")) != "real" or d.get("light") is not None


def light_settings(table: Mapping[str, Any] | None, source: str = "bench config") -> LightTable | None:
    """The ``[light]`` table validated (one line naming file, key and value), or None when the
    bench declares no switchable light. Called before any port opens."""
    return None if table is None else validate_document(LightTable, table, f"{source} [light]")


def build_light(settings: LightTable | None, spectrometer: Any) -> LampLine | None:
    """The light ``settings`` declare, switched on (a run starts lit), or None."""
    if settings is None:
        return None
    lamp = LampLine(spectrometer, float(settings.settle_s))
    lamp.on()
    return lamp

"""Deprecated: moved to :mod:`bench.builders.emulated` (emulated benches) and
:mod:`bench.builders.real` (``build_real_bench``); this module re-exports both for one release."""

from __future__ import annotations

from bench.builders.emulated import (ARM_IDS, DEFAULT_EMULATED_CONFIG, Emulators, LampLine, build_emulated_bench,
                                     emulated_geometry, emulated_response)
from bench.builders.real import build_real_bench

__all__ = ["build_emulated_bench", "build_real_bench", "Emulators", "DEFAULT_EMULATED_CONFIG", "emulated_geometry",
           "emulated_response", "LampLine", "ARM_IDS"]

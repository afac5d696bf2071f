"""Deprecated: ``bench tradeoff`` moved to :mod:`bench.cli.tradeoff` and the adaptive budget to
:mod:`bench.adaptive`; this module re-exports both for one release."""

from __future__ import annotations

from bench.adaptive import DEFAULT_MAX_SECONDS, AdaptiveMeasurement, adaptive_measure
from bench.cli.tradeoff import cmd_tradeoff, register

__all__ = ["register", "cmd_tradeoff", "adaptive_measure", "AdaptiveMeasurement", "DEFAULT_MAX_SECONDS"]

"""goniobench: one instrument interface for real, emulated and virtual goniophotometry benches."""

__version__ = "0.1.0"

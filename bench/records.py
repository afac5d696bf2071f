"""Deprecated: moved to :mod:`bench.core.records` (the contract layer); this re-export goes after one release."""

import warnings as _warnings

from bench.core.records import *  # noqa: F401,F403
from bench.core.records import __all__ as _all  # noqa: F401

_warnings.warn("bench.records is deprecated; import bench.core.records", DeprecationWarning, stacklevel=2)

"""Deprecated: moved to :mod:`bench.core.conformance` (the contract layer); this re-export goes after one release."""

import warnings as _warnings

from bench.core.conformance import *  # noqa: F401,F403
from bench.core.conformance import __all__ as _all  # noqa: F401

_warnings.warn("bench.testing is deprecated; import bench.core.conformance", DeprecationWarning, stacklevel=2)

"""Deprecated: moved to :mod:`bench.core.errors` (the contract layer); this re-export goes after one release."""

import warnings as _warnings

from bench.core.errors import *  # noqa: F401,F403
from bench.core.errors import __all__ as _all  # noqa: F401

_warnings.warn("bench.errors is deprecated; import bench.core.errors", DeprecationWarning, stacklevel=2)

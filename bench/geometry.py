"""Deprecated: moved to :mod:`bench.core.geometry` (the contract layer); this re-export goes after one release."""

import warnings as _warnings

from bench.core.geometry import *  # noqa: F401,F403
from bench.core.geometry import __all__ as _all  # noqa: F401

_warnings.warn("bench.geometry is deprecated; import bench.core.geometry", DeprecationWarning, stacklevel=2)

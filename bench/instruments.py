"""Deprecated: moved to :mod:`bench.core.roles` (the contract layer); this re-export goes after one release."""

import warnings as _warnings

from bench.core.roles import *  # noqa: F401,F403
from bench.core.roles import __all__ as _all  # noqa: F401

_warnings.warn("bench.instruments is deprecated; import bench.core.roles", DeprecationWarning, stacklevel=2)

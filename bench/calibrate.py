"""Deprecated: moved to :mod:`bench.core.calibration` (the contract layer); this re-export goes after one release."""

import warnings as _warnings

from bench.core.calibration import *  # noqa: F401,F403
from bench.core.calibration import __all__ as _all  # noqa: F401

_warnings.warn("bench.calibrate is deprecated; import bench.core.calibration", DeprecationWarning, stacklevel=2)

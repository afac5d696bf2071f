"""Deprecated path: Mitsuba 3 specimens live in :mod:`virtual.specimens.mitsuba` (inside the
specimens package, so importing them first no longer meets a half-initialized package)."""

from virtual.specimens.mitsuba import *  # noqa: F401,F403
from virtual.specimens.mitsuba import __all__  # noqa: F401

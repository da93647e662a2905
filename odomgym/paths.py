"""Deprecated name of :mod:`odomgym.routes` (renamed for what it holds: routes and the progress
along them). Importing this module still works and warns; it will be removed in a later
release."""

from __future__ import annotations

import warnings

from odomgym.routes import *  # noqa: F403
from odomgym.routes import __all__  # noqa: F401

warnings.warn(
    "odomgym.paths is now odomgym.routes; import from there",
    DeprecationWarning,
    stacklevel=2,
)

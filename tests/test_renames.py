"""Modules renamed by the conventions issue stay importable under their old names, with a
warning that names the new one."""

from __future__ import annotations

import importlib
import sys

import pytest


def test_paths_is_routes_with_a_deprecation_warning() -> None:
    sys.modules.pop("odomgym.paths", None)
    with pytest.warns(DeprecationWarning, match=r"odomgym\.routes"):
        old = importlib.import_module("odomgym.paths")
    new = importlib.import_module("odomgym.routes")
    assert old.square_route is new.square_route
    assert old.RouteProgress is new.RouteProgress

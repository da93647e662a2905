"""Shared test set-up: headless rendering, and the location of the shared data."""

from __future__ import annotations

import os
from pathlib import Path

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
os.environ.setdefault("SDL_AUDIODRIVER", "dummy")

# CI clones the repository with shared/ beside it.
SHARED = Path(__file__).resolve().parents[1].parent / "shared"

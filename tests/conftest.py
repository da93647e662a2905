"""Shared test set-up: headless rendering, and the location of the shared data."""

from __future__ import annotations

import os
from pathlib import Path

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
os.environ.setdefault("SDL_AUDIODRIVER", "dummy")

# CI clones the repository with shared/ beside it.
SHARED = Path(__file__).resolve().parents[1].parent / "shared"


def _optiodom_data() -> Path:
    """The OptiOdom data the real-data tests read: the full set in ``shared/`` (14 sessions)
    when it is there, else the six sessions shipped in the package (unpacked into the user
    cache, or a temporary one if that cannot be written), so those tests never skip.
    ``ODOMGYM_TEST_DATA=shipped`` forces the shipped sessions."""
    full = SHARED / "data" / "optiodom-diff"
    if (
        os.environ.get("ODOMGYM_TEST_DATA") != "shipped"
        and (full / "published_results.csv").is_file()
    ):
        return full
    from odomgym.data import sample_data
    from odomgym.errors import SpecError

    try:
        return sample_data()
    except SpecError:
        import tempfile

        os.environ["XDG_CACHE_HOME"] = tempfile.mkdtemp(prefix="odomgym-cache-")
        return sample_data()


# The OptiOdom data set's root (<kind>/<session>/…, published_results.csv).
OPTIODOM = _optiodom_data()

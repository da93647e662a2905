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


def pytest_collection_modifyitems(config: object, items: list[object]) -> None:
    """Start the tests marked ``longest`` first, then the modules with the most ``slow``
    tests, each module's tests together and in their own order (module-scoped fixtures are then
    built once per worker).

    Why: on parallel workers (``scripts/test.sh``: ``-n auto --dist worksteal``) the suite ends
    when the last worker does, and a six-minute test started late leaves the other worker idle
    at the end. Longest jobs first, the rest shared out as workers fall idle, is the classic
    schedule for that (Graham 1969, "Bounds on multiprocessing timing anomalies"). The order
    changes no test: each is independent of the others."""
    import pytest

    weight: dict[str, int] = {}
    first: dict[str, int] = {}
    for index, item in enumerate(items):
        assert isinstance(item, pytest.Item)
        module = item.nodeid.split("::", 1)[0]
        first.setdefault(module, index)
        weight[module] = weight.get(module, 0) + (item.get_closest_marker("slow") is not None)

    def key(item: object) -> tuple[bool, int, int]:
        assert isinstance(item, pytest.Item)
        module = item.nodeid.split("::", 1)[0]
        return (item.get_closest_marker("longest") is None, -weight[module], first[module])

    items.sort(key=key)

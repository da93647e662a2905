"""The World's three ways across the pymunk boundary give bit-identical trajectories.

Batch I/O (``pymunk.batch``, four or more robots), direct Chipmunk calls (smaller batches) and
pymunk's properties (the fallback if a pymunk release hides the C pointers) are speed choices
only (docs/architecture.md, "Performance design"); a robot's motion must not depend on them.
"""

from __future__ import annotations

import numpy as np
import pytest

import odomgym.physics as physics
from odomgym.floor import FLOORS
from odomgym.physics import World
from odomgym.robot import PRESETS

STEPS = 300


def _commands(n: int) -> np.ndarray:
    rng = np.random.default_rng(7)
    return rng.uniform(-1.0, 1.0, size=(STEPS, 1, 2)).repeat(n, axis=1)


def _drive(world: World) -> np.ndarray:
    scale = np.full(world.n, 5.0)  # rad/s per unit command
    for command in _commands(world.n):
        world.step(command, scale=scale)
    return world.pose.copy()


@pytest.mark.parametrize("floor", ["smooth", "bumpy"])
def test_batch_direct_and_property_io_agree(floor: str, monkeypatch: pytest.MonkeyPatch) -> None:
    robot = PRESETS["labmate"]
    direct = World(robot, FLOORS[floor])
    assert direct._direct_io and not direct._use_batch_io
    batch = World([robot] * 4, FLOORS[floor])
    assert batch._use_batch_io
    monkeypatch.setattr(physics, "_direct_access_works", lambda bodies: False)
    fallback = World(robot, FLOORS[floor])
    assert not fallback._direct_io
    expected = _drive(fallback)[0]
    np.testing.assert_array_equal(_drive(direct)[0], expected)
    assert direct._raw_space is not None  # stepped through Chipmunk directly
    for row in _drive(batch):
        np.testing.assert_array_equal(row, expected)
    assert np.hypot(*expected[:2]) > 0.1  # the robots moved

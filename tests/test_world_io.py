"""The World's two ways across the pymunk boundary give bit-identical trajectories.

Compiled kernels calling Chipmunk's functions by address
(:class:`odomgym.sim.chipmunk_link.SpaceExchange`) and pymunk's own properties and ``Space.step``
(the fallback if a pymunk release changes the internals the compiled path relies on) are speed
choices only (docs/architecture.md, "Performance design"); a robot's motion must not depend on
them, nor on its batch.
"""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from odomgym.floor import FLOORS
from odomgym.robot import PRESETS
from odomgym.sim.chipmunk_link import SpaceExchange
from odomgym.sim.world import World

STEPS = 300


def _commands(n: int) -> np.ndarray:
    rng = np.random.default_rng(7)
    return rng.uniform(-1.0, 1.0, size=(STEPS, 1, 2)).repeat(n, axis=1)


def _drive(world: World, commands: np.ndarray) -> np.ndarray:
    scale = np.full(world.n, 5.0)  # rad/s per unit command
    for command in commands:
        world.step(command, scale=scale)
    return np.hstack([world.pose, world.velocity, world.counts, world.slip])


def _streams(n: int) -> list[np.random.Generator]:
    """For each of n robots the noise stream a one-robot World seeded 3 gives its robot."""
    return [np.random.default_rng(3).spawn(1)[0] for _ in range(n)]


@pytest.mark.parametrize("substeps", [1, 2])
@pytest.mark.parametrize("track_slip", [False, True])
@pytest.mark.parametrize("floor", ["smooth", "bumpy", "rough"])
def test_compiled_and_pymunk_exchange_agree(
    floor: str, track_slip: bool, substeps: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Also the three substep paths: whole compiled substeps on a plain floor
    (``step_plain``), on cables or a rough floor (``step_floor``, its roughness draws crossing
    blocks of 256 in 600 substeps), and the staged path stage by stage, which the fallback and
    ``track_slip`` take."""
    robot = PRESETS["labmate"]
    options = {"track_slip": track_slip, "substeps": substeps}
    single = World(robot, FLOORS[floor], rng=_streams(1), **options)
    batch = World([robot] * 4, FLOORS[floor], rng=_streams(4), **options)
    assert single._io.compiled and batch._io.compiled
    assert single._floor_only == (floor != "smooth")
    monkeypatch.setattr(SpaceExchange, "_link", lambda self: False)
    fallback = World(robot, FLOORS[floor], rng=_streams(1), **options)
    assert not fallback._io.compiled
    expected = _drive(fallback, _commands(1))[0]
    np.testing.assert_array_equal(_drive(single, _commands(1))[0], expected)
    for row in _drive(batch, _commands(4)):
        np.testing.assert_array_equal(row, expected)
    assert np.hypot(*expected[:2]) > 0.1  # the robots moved


def test_an_unpickled_world_links_to_its_own_space(monkeypatch: pytest.MonkeyPatch) -> None:
    """The compiled exchange points at C structures of one space: a World unpickled mid-run
    links to its own, and checking that link leaves the bodies as they were (the copy goes on
    exactly as a copy through pymunk's own functions does)."""
    world = World([PRESETS["labmate"]] * 2, FLOORS["smooth"])
    commands = _commands(2)
    _drive(world, commands[:100])
    data = pickle.dumps(world)
    linked = pickle.loads(data)
    assert linked._io.compiled
    monkeypatch.setattr(SpaceExchange, "_link", lambda self: False)
    fallback = pickle.loads(data)
    assert not fallback._io.compiled
    for mine, theirs in zip(linked.space.bodies, fallback.space.bodies, strict=True):
        assert (mine.position, mine.velocity) == (theirs.position, theirs.velocity)
    np.testing.assert_array_equal(_drive(linked, commands[100:]), _drive(fallback, commands[100:]))


def test_skid_steer_chassis_velocities_cross_both_ways_alike(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A skid-steer robot's velocity is solved by the World and set on its chassis each
    substep: through the link's third block (one compiled call for the batch) or through
    pymunk's properties, the same floats; beside a differential-drive robot in one batch."""
    robots = [PRESETS["scout2"], PRESETS["labmate"], PRESETS["husky"]]
    linked = World(robots, FLOORS["smooth"], substeps=2)
    assert linked._io.compiled
    monkeypatch.setattr(SpaceExchange, "_link", lambda self: False)
    fallback = World(robots, FLOORS["smooth"], substeps=2)
    assert not fallback._io.compiled
    expected = _drive(fallback, _commands(3))
    np.testing.assert_array_equal(_drive(linked, _commands(3)), expected)
    assert np.all(np.hypot(expected[:, 0], expected[:, 1]) > 0.1)  # every robot moved

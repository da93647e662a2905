"""``ClapperStraight-v0`` and ``ClapperRectangle-v0``: Gymnasium conventions, the pluggable
estimator and the §6.1 result through the env."""

from __future__ import annotations

import functools
import math

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import odomgym  # noqa: F401  (registers the envs)
from odomgym.vehicle.estimator import DeadReckoning
from odomgym.vehicle.ipec import IPEC


@pytest.mark.parametrize("env_id", ["ClapperStraight-v0", "ClapperRectangle-v0"])
def test_envs_pass_gymnasiums_checker(env_id: str) -> None:
    env = gym.make(env_id, bumps=2)
    check_env(env.unwrapped, skip_render_check=True)
    env.close()


def test_the_encoder_trailer_is_a_vehicle_option() -> None:
    """Borenstein 1995, §7: the same envs drive the ``trailer`` vehicle (a LabMate towing an
    encoder trailer, one rotary encoder at the hitch)."""
    env = gym.make("ClapperRectangle-v0", vehicle="trailer", bumps=2)
    check_env(env.unwrapped, skip_render_check=True)
    _, info = env.reset(seed=1)
    assert info["psi"][1] == 0.0  # the rigid tongue: no second rotary encoder
    env.close()


def _episode(env: gym.Env, speed: float = 1.0) -> tuple[dict, int]:  # type: ignore[type-arg]
    env.reset(seed=0)
    steps = 0
    while True:
        _, _, terminated, truncated, info = env.step(np.array([speed], dtype=np.float32))
        steps += 1
        if terminated or truncated:
            return info, steps


@pytest.mark.slow
def test_straight_env_with_ipec_reproduces_section_6_1() -> None:
    info, _ = _episode(gym.make("ClapperStraight-v0", bumps=20))
    assert abs(math.degrees(float(info["return_error"][2]))) < 1.0
    assert info["truck_return_errors"].shape == (2, 3)
    assert {"true_poses", "estimated_poses", "odometry_poses", "psi", "link_length"} <= set(info)
    # Every truck crossed every cable, the linkage never reached its end stops, and each
    # truck's own heading is within the paper's ±1.0° too.
    assert list(info["cable_crossings"]) == [20, 20]
    assert info["link_force"] == 0.0 and info["link_force_max"] == 0.0
    assert np.all(np.abs(np.degrees(info["truck_errors"][:, 2])) < 1.0)
    env = gym.make("ClapperStraight-v0")
    assert env.unwrapped.floor.name == "concrete"  # the one stated floor (odomgym.vehicle.trial)


@pytest.mark.slow
def test_estimator_is_pluggable_and_ipec_false_is_dead_reckoning() -> None:
    # A non-default estimator (IPEC with the composite translational correction, Eqs. 14-15,
    # which the default leaves out) is the one the env runs.
    mine = gym.make(
        "ClapperStraight-v0",
        bumps=3,
        estimator=functools.partial(IPEC, heading="midpoint", translation_correction=True),
    )
    default, _ = _episode(gym.make("ClapperStraight-v0", bumps=3))
    custom, _ = _episode(mine)
    estimator = mine.unwrapped._trial.estimator
    assert isinstance(estimator, IPEC) and estimator.translation_correction
    assert not np.array_equal(custom["return_error"], default["return_error"])
    # Without correction the estimate is each truck's own wheel odometry.
    plain, _ = _episode(gym.make("ClapperStraight-v0", bumps=3, ipec=False))
    np.testing.assert_allclose(plain["estimated_poses"], plain["odometry_poses"], atol=1e-9)
    with pytest.raises(ValueError, match="not both"):
        gym.make("ClapperStraight-v0", ipec=False, estimator=DeadReckoning)


def test_same_seed_same_run_on_a_noisy_floor() -> None:
    """The concrete floor's wheel noise comes from the env's seed (np_random)."""

    def roll(seed: int) -> list[np.ndarray]:
        env = gym.make("ClapperRectangle-v0", floor="concrete", bumps=0)
        env.reset(seed=seed)
        return [env.step(np.array([1.0], dtype=np.float32))[4]["true_poses"] for _ in range(150)]

    first, again, other = roll(3), roll(3), roll(4)
    assert all(np.array_equal(a, b) for a, b in zip(first, again, strict=True))
    assert not np.array_equal(first[-1], other[-1])


def test_slower_commands_take_longer_and_bad_actions_are_refused() -> None:
    env = gym.make("ClapperRectangle-v0", bumps=0)
    env.reset(seed=0)
    for _ in range(50):
        env.step(np.array([0.3], dtype=np.float32))
    slow = env.unwrapped._path_done()
    env.reset(seed=0)
    for _ in range(50):
        env.step(np.array([1.0], dtype=np.float32))
    assert env.unwrapped._path_done() > slow > 0.0
    with pytest.raises(ValueError, match="one finite number"):
        env.step(np.array([np.nan], dtype=np.float32))
    with pytest.raises(ValueError, match="direction"):
        gym.make("ClapperRectangle-v0", direction="up")

"""``ClapperStraight-v0`` and ``ClapperRectangle-v0``: Gymnasium conventions, the pluggable
estimator and the §6.1 result through the env."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import odomgym  # noqa: F401  (registers the envs)
from odomgym.internal import DeadReckoning


@pytest.mark.parametrize("env_id", ["ClapperStraight-v0", "ClapperRectangle-v0"])
def test_envs_pass_gymnasiums_checker(env_id: str) -> None:
    env = gym.make(env_id, bumps=2)
    check_env(env.unwrapped, skip_render_check=True)
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


@pytest.mark.slow
def test_estimator_is_pluggable_and_ipec_false_is_dead_reckoning() -> None:
    plain, _ = _episode(gym.make("ClapperStraight-v0", bumps=3, ipec=False))
    mine, _ = _episode(gym.make("ClapperStraight-v0", bumps=3, estimator=DeadReckoning))
    np.testing.assert_array_equal(plain["return_error"], mine["return_error"])
    # Without correction the estimate is each truck's own wheel odometry.
    np.testing.assert_allclose(plain["estimated_poses"], plain["odometry_poses"], atol=1e-9)


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

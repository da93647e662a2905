"""The native vector env: same physics as the single env, batched, with next-step autoreset."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import odomgym
from odomgym.drivers import ReferenceDriver


def test_make_vec_uses_the_native_vector_env() -> None:
    envs = gym.make_vec("UMBmarkSquare-v0", num_envs=4)
    assert type(envs).__name__ == "OdometryVectorEnv"
    obs, _ = envs.reset(seed=0)
    assert obs.shape == (4, 8) and obs.dtype == np.float32
    assert envs.single_observation_space.contains(obs[0])


def test_vector_env_matches_single_env() -> None:
    robot = odomgym.PRESETS["labmate"]
    single = gym.make("UMBmarkSquare-v0", robot=robot, side=1.0)
    vector = gym.make_vec("UMBmarkSquare-v0", num_envs=3, robot=robot, side=1.0)
    driver = ReferenceDriver(robot)
    obs_s, _ = single.reset(seed=0)
    obs_v, _ = vector.reset(seed=0)
    for _ in range(200):
        obs_s, *_ = single.step(driver(obs_s).astype(np.float32))
        obs_v, *_ = vector.step(driver(obs_v).astype(np.float32))
    # Batch I/O and per-body I/O round differently in the last bits only.
    np.testing.assert_allclose(obs_v, np.repeat(obs_s[None], 3, axis=0), atol=1e-5)


def test_vector_env_autoresets_next_step() -> None:
    robot = odomgym.PRESETS["navbot"]
    envs = gym.make_vec("StraightLine-v0", num_envs=2, robot=robot, distance=0.2)
    driver = ReferenceDriver(robot)
    obs, _ = envs.reset(seed=1)
    ended = None
    for step in range(2000):
        actions = driver(obs).astype(np.float32)
        obs, _rewards, terminated, _truncated, info = envs.step(actions)
        if terminated.any():
            ended = step
            assert "return_error" in info and info["_return_error"].any()
            break
    assert ended is not None
    obs, rewards, terminated, _truncated, _ = envs.step(np.zeros((2, 2), dtype=np.float32))
    assert np.all(rewards == 0.0) and not terminated.any()
    assert np.all(obs[:, 7] == 0.0)  # back at the start of the route


def test_vector_env_rejects_bad_actions() -> None:
    envs = gym.make_vec("UMBmarkSquare-v0", num_envs=2)
    envs.reset(seed=0)
    with pytest.raises(ValueError, match="finite"):
        envs.step(np.full((2, 2), np.nan, dtype=np.float32))
    with pytest.raises(ValueError, match="shape"):
        envs.step(np.zeros((3, 2), dtype=np.float32))


def test_vector_env_truncates_every_episode_after_the_same_number_of_steps() -> None:
    envs = gym.make_vec("StraightLine-v0", num_envs=1, max_episode_steps=5)
    envs.reset(seed=0)
    ends = []
    for step in range(1, 16):
        _, _, terminated, truncated, info = envs.step(np.zeros((1, 2), dtype=np.float32))
        assert set(info["reward_terms"]) == {"progress", "time", "completion"}
        if truncated[0] or terminated[0]:
            ends.append(step)
    # 5 steps, then a reset step, then 5 more: truncation at steps 5, 11 and (next) 17.
    assert ends == [5, 11]


def test_vector_env_rejects_covariance_option() -> None:
    with pytest.raises(ValueError, match="covariance_k"):
        gym.make_vec("UMBmarkSquare-v0", num_envs=2, covariance_k=(0.001, 0.001))

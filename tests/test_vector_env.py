"""The native vector env: same physics as the single env, batched, with next-step autoreset."""

from __future__ import annotations

import copy
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

import odomgym
from odomgym.sim.driver import ReferenceDriver


def test_make_vec_uses_the_native_vector_env() -> None:
    envs = gym.make_vec("UMBmarkSquare-v0", num_envs=4)
    assert type(envs).__name__ == "OdometryVectorEnv"
    obs, _ = envs.reset(seed=0)
    assert obs.shape == (4, 8) and obs.dtype == np.float32
    assert envs.single_observation_space.contains(obs[0])


@pytest.mark.parametrize("env_id", ["UMBmarkSquare-v0", "StraightLine-v0"])
def test_a_render_mode_the_native_vector_env_cannot_serve_is_refused(env_id: str) -> None:
    """``render_mode="rgb_array"`` was accepted and failed only at ``render()`` with
    NotImplementedError: now one line when the env is made, naming the mode that renders."""
    from odomgym.errors import SpecError

    with pytest.raises(SpecError, match=r"vectorization_mode='sync'") as caught:
        gym.make_vec(env_id, num_envs=2, render_mode="rgb_array")
    assert caught.value.field == "render_mode"
    gym.make_vec(env_id, num_envs=2, render_mode=None).close()


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
        terms = {"progress", "time", "completion"}
        # As SyncVectorEnv: a step that only resets the sub-env reports no reward terms.
        expected = set() if step in (6, 12) else terms | {f"_{t}" for t in terms}
        assert set(info["reward_terms"]) == expected
        if truncated[0] or terminated[0]:
            ends.append(step)
    # 5 steps, then a reset step, then 5 more: truncation at steps 5, 11 and (next) 17.
    assert ends == [5, 11]


def test_vector_env_rejects_covariance_option() -> None:
    with pytest.raises(ValueError, match="covariance_k"):
        gym.make_vec("UMBmarkSquare-v0", num_envs=2, covariance_k=(0.001, 0.001))


def _rollout(
    envs: gym.vector.VectorEnv, robot: odomgym.RobotSpec, steps: int, **reset: Any
) -> list:
    driver = ReferenceDriver(robot)
    obs, info = envs.reset(**reset)
    out = [(obs, info)]
    for _ in range(steps):
        obs, *rest = envs.step(driver(obs).astype(np.float32))
        out.append((obs, *rest))
    return out


def _assert_same(a: Any, b: Any, path: str = "") -> None:
    """Equal structure, dtypes and values (physics to 1e-5: batch and per-body I/O round
    differently in the last bits)."""
    if isinstance(a, dict):
        assert set(a) == set(b), f"{path}: keys {sorted(a)} vs {sorted(b)}"
        for key in a:
            _assert_same(a[key], b[key], f"{path}.{key}")
    elif isinstance(a, (tuple, list)):
        assert len(a) == len(b)
        for k, (x, y) in enumerate(zip(a, b, strict=True)):
            _assert_same(x, y, f"{path}[{k}]")
    else:
        x, y = np.asarray(a), np.asarray(b)
        assert x.shape == y.shape and x.dtype == y.dtype, (
            f"{path}: {x.dtype}{x.shape} vs {y.dtype}{y.shape}"
        )
        if x.dtype == np.bool_ or np.issubdtype(x.dtype, np.integer):
            np.testing.assert_array_equal(x, y, err_msg=path)
        else:
            np.testing.assert_allclose(x, y, atol=1e-5, err_msg=path)


def test_native_vector_env_gives_what_sync_vector_env_gives() -> None:
    """Seeds per sub-env, reset options, autoreset, info keys, masks and dtypes: the native
    vector env against Gymnasium's SyncVectorEnv over single envs, on a rough floor (so every
    sub-env draws its own noise) with episodes that end at different steps."""
    robot = odomgym.PRESETS["navbot"]
    kwargs = {"robot": robot, "floor": "rough", "distance": 0.3, "return_trip": False}
    native = gym.make_vec("StraightLine-v0", num_envs=3, **kwargs)
    sync = gym.make_vec("StraightLine-v0", num_envs=3, vectorization_mode="sync", **kwargs)
    reset = {"seed": [5, 11, 7], "options": {"return_trip": True}}
    a = _rollout(native, robot, 400, **reset)
    b = _rollout(sync, robot, 400, **reset)
    ends = sum(int(np.sum(step[2])) for step in a[1:])
    assert ends >= 3  # episodes ended (and were autoreset) during the rollout
    _assert_same(a, b)


def test_sub_env_k_equals_a_single_env_reset_with_seed_k() -> None:
    robot = odomgym.PRESETS["navbot"]
    kwargs = {"robot": robot, "floor": "rough", "side": 0.5}
    vector = gym.make_vec("UMBmarkSquare-v0", num_envs=2, **kwargs)
    obs_v, _ = vector.reset(seed=[1, 99], options={"direction": "ccw"})
    singles = [gym.make("UMBmarkSquare-v0", **kwargs) for _ in range(2)]
    obs_s = [
        env.reset(seed=s, options={"direction": "ccw"})[0]
        for env, s in zip(singles, [1, 99], strict=True)
    ]
    driver = ReferenceDriver(robot)
    for _ in range(300):
        actions = driver(obs_v).astype(np.float32)
        obs_v, _, _, _, info = vector.step(actions)
        for k, env in enumerate(singles):
            obs_s[k], *_, info_s = env.step(actions[k])
            np.testing.assert_allclose(info["true_pose"][k], info_s["true_pose"], atol=1e-6)
    # Different seeds, different noise: the two sub-envs went different ways.
    assert np.abs(info["true_pose"][0] - info["true_pose"][1]).max() > 1e-4
    # And a list [1, 2] differs from [1, 99] in sub-env 1 only.
    other = _rollout(
        gym.make_vec("UMBmarkSquare-v0", num_envs=2, **kwargs), robot, 300, seed=[1, 2]
    )
    again = _rollout(
        gym.make_vec("UMBmarkSquare-v0", num_envs=2, **kwargs), robot, 300, seed=[1, 99]
    )
    assert np.array_equal(other[-1][-1]["true_pose"][0], again[-1][-1]["true_pose"][0])
    assert not np.array_equal(other[-1][-1]["true_pose"][1], again[-1][-1]["true_pose"][1])


def test_render_fps_follows_the_control_period() -> None:
    assert gym.make("UMBmarkSquare-v0", dt=0.1).metadata["render_fps"] == 10.0
    vector = gym.make_vec("UMBmarkSquare-v0", num_envs=2, dt=0.025)
    assert vector.metadata["render_fps"] == 40.0
    assert vector.metadata["autoreset_mode"] == gym.vector.AutoresetMode.NEXT_STEP


def test_partial_reset_with_reset_mask_matches_sync_vector_env() -> None:
    robot = odomgym.PRESETS["navbot"]
    kwargs = {"robot": robot, "floor": "rough", "distance": 0.3}
    results = []
    for mode in ("vector_entry_point", "sync"):
        envs = gym.make_vec("StraightLine-v0", num_envs=3, vectorization_mode=mode, **kwargs)
        out = _rollout(envs, robot, 30, seed=[3, 4, 5])
        mask = np.array([False, True, False])
        out.append(envs.reset(seed=[None, 9, None], options={"reset_mask": mask}))
        results.append(out)
    _assert_same(results[0], results[1])


def test_a_step_info_read_later_is_the_one_read_at_its_step() -> None:
    """The native vector env's ``info`` is made at its first read (``LazyInfo``): read after
    many later steps, autoresets and a reset, it equals a twin env's info read at once, with
    ``return_error`` where episodes ended. Nothing it is made from changes after its step, not
    even when the caller writes into the arrays the step returned."""
    from odomgym.envs.info import LazyInfo

    robot = odomgym.PRESETS["navbot"]
    kwargs = {"robot": robot, "floor": "rough", "distance": 0.3, "return_trip": False}
    envs, twin = (gym.make_vec("StraightLine-v0", num_envs=3, **kwargs) for _ in range(2))
    obs, _ = envs.reset(seed=[5, 11, 7])
    twin.reset(seed=[5, 11, 7])
    driver = ReferenceDriver(robot)
    unread, read_at_once = [], []
    for _ in range(200):
        actions = driver(obs).astype(np.float32)
        obs, _, terminated, _, info = envs.step(actions)
        terminated[:] = False  # the caller's array: the info keeps its own copy
        unread.append(info)
        read_at_once.append(copy.deepcopy(dict(twin.step(actions)[4])))
    envs.reset(seed=1)
    assert sum("return_error" in info for info in read_at_once) >= 3
    for lazy, eager in zip(unread, read_at_once, strict=True):
        assert isinstance(lazy, LazyInfo)
        _assert_same(dict(lazy), eager)
